!> Bending stiffness of the 3D membrane: a discrete Helfrich energy on the P1 triangle mesh,
!> with nodal forces as its exact gradient.
!>
!> Continuum energy: E = (K_B/2) int (2H - c0)**2 dA, 2H = kappa_1 + kappa_2, with the reference
!> (initial sphere) curvature as spontaneous curvature, so that the capsule at rest carries no
!> bending load (a pre-stressed capsule at rest stays at rest).
!> Discretisation (Juelicher 1996; Bian, Litvinov & Koumoutsakos 2020): the integrated mean
!> curvature of node i's dual cell is 2 M_i = (1/2) sum over its edges of |e| theta_e
!> (theta_e the signed dihedral angle, > 0 where convex), its area A_i the Voronoi area (see
!> voronoi_corners), and
!>     E = (K_B/2) sum_i (2 M_i - c_i A_i)**2 / A_i,   c_i = 2 M_i / A_i of the reference mesh.
!> Why this one: unlike the "discrete shells" dihedral energy, which is scale invariant (a
!> sphere inflated from radius a to R keeps its angles and would feel no bending force), it
!> has the Helfrich continuum limit with a spontaneous curvature, the form the axisymmetric
!> model (axisymmetric_bending) discretises too; unlike the cotangent Laplacian, its gradient
!> needs only edge lengths, dihedral angles and corner cotangents, each with a short
!> closed-form gradient. Taking c_i from the discrete reference (not 2/a) makes the reference mesh an exact
!> minimum: zero force to round-off at rest; c_i -> 2/a as the mesh is refined.
!> Units: K_B in the caller's units (k_b G_s a**2 scaled to them); the energy is invariant
!> under scaling of lengths, so only k_b (a/L)**2 enters for lengths in L.
!> Assembly: per edge and per triangle in parallel into work arrays, then gathered per node
!> (no atomics; the same bits on any number of threads). Nothing is allocated after init.
module membrane_bending
   use capsim_kinds, only: dp
   use vector_algebra, only: cross
   use sphere_mesh, only: surface_mesh_t
   implicit none
   private
   public :: bending_t

   type :: bending_t
      !> Bending modulus K_B in units of (force unit) x (length unit); 0: no bending.
      real(dp) :: kb = 0
      integer :: n_edges = 0
      !> Per edge: end nodes i, j (the edge runs i -> j in triangle edge_tri(1)), and the nodes
      !> k, l opposite it in its two triangles.
      integer, allocatable :: edge(:, :)
      !> Reference curvature 2H of each node's dual cell.
      real(dp), allocatable :: c0(:)
      !> Per node, the (edge, slot) pairs it takes part in (CSR; slot 1..4 as in edge(:, e)).
      integer, allocatable :: node_edge_start(:), node_edge(:), node_edge_slot(:)
      ! Work arrays.
      !> |e| theta_e per edge; per triangle, the Voronoi area of each corner.
      real(dp), allocatable :: len_theta(:), corner_area(:, :), de_ds(:), de_da(:)
      real(dp), allocatable :: edge_grad(:, :, :), tri_grad(:, :, :)
   contains
      procedure :: init => bending_init
      procedure :: add_forces
      procedure :: energy_at
   end type bending_t

contains

   !> Edge structure of the closed mesh and reference curvatures from x_ref.
   subroutine bending_init(self, mesh, x_ref, kb)
      class(bending_t), intent(inout) :: self
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x_ref(:, :), kb
      integer :: t, a, i, j, p, q, e, n, s
      integer, allocatable :: count(:)
      n = mesh%n_nodes
      self%kb = kb
      ! Closed mesh: each edge is in two triangles, once as i -> j and once as j -> i; it is
      ! created by the triangle where i < j and completed from the other.
      self%n_edges = 3 * mesh%n_tri / 2
      allocate (self%edge(4, self%n_edges))
      e = 0
      do t = 1, mesh%n_tri
         do a = 1, 3
            i = mesh%tri(a, t)
            j = mesh%tri(mod(a, 3) + 1, t)
            if (i > j) cycle
            e = e + 1
            self%edge(:, e) = [i, j, mesh%tri(mod(a + 1, 3) + 1, t), 0]
            ! The opposite triangle contains j -> i.
            do p = mesh%node_tri_start(j), mesh%node_tri_start(j + 1) - 1
               q = mesh%node_tri_vertex(p)
               if (mesh%tri(mod(q, 3) + 1, mesh%node_tri(p)) == i) then
                  self%edge(4, e) = mesh%tri(mod(q + 1, 3) + 1, mesh%node_tri(p))
                  exit
               end if
            end do
         end do
      end do
      allocate (count(n + 1))
      count = 0
      do e = 1, self%n_edges
         do s = 1, 4
            count(self%edge(s, e)) = count(self%edge(s, e)) + 1
         end do
      end do
      allocate (self%node_edge_start(n + 1), self%node_edge(4 * self%n_edges), self%node_edge_slot(4 * self%n_edges))
      self%node_edge_start(1) = 1
      do i = 1, n
         self%node_edge_start(i + 1) = self%node_edge_start(i) + count(i)
      end do
      count(1:n) = self%node_edge_start(1:n)
      do e = 1, self%n_edges
         do s = 1, 4
            i = self%edge(s, e)
            self%node_edge(count(i)) = e
            self%node_edge_slot(count(i)) = s
            count(i) = count(i) + 1
         end do
      end do
      allocate (self%len_theta(self%n_edges), self%corner_area(3, mesh%n_tri), self%de_ds(n), self%de_da(n))
      allocate (self%edge_grad(3, 4, self%n_edges), self%tri_grad(3, 3, mesh%n_tri), self%c0(n))
      self%c0 = 0
      call edge_and_triangle_measures(self, mesh, x_ref)
      do i = 1, n
         self%c0(i) = node_curvature(self, mesh, i)
      end do
   end subroutine bending_init

   !> |e| theta_e per edge and the Voronoi corner areas of each triangle at positions x.
   subroutine edge_and_triangle_measures(self, mesh, x)
      type(bending_t), intent(inout) :: self
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      integer :: e, t
      !$omp parallel do default(none) shared(self, mesh, x) private(e) schedule(static)
      do e = 1, self%n_edges
         self%len_theta(e) = norm2(x(:, self%edge(2, e)) - x(:, self%edge(1, e))) * dihedral_angle(x, self%edge(:, e))
      end do
      !$omp end parallel do
      !$omp parallel do default(none) shared(self, mesh, x) private(t) schedule(static)
      do t = 1, mesh%n_tri
         self%corner_area(:, t) = voronoi_corners(x(:, mesh%tri(1, t)), x(:, mesh%tri(2, t)), x(:, mesh%tri(3, t)))
      end do
      !$omp end parallel do
   end subroutine edge_and_triangle_measures

   !> Signed dihedral angle of the hinge (i, j, k, l): 0 when flat, > 0 when convex.
   pure real(dp) function dihedral_angle(x, hinge) result(theta)
      real(dp), intent(in) :: x(:, :)
      integer, intent(in) :: hinge(4)
      real(dp) :: e(3), n1(3), n2(3)
      e = x(:, hinge(2)) - x(:, hinge(1))
      n1 = cross(e, x(:, hinge(3)) - x(:, hinge(1)))
      n2 = cross(-e, x(:, hinge(4)) - x(:, hinge(2)))
      theta = atan2(dot_product(cross(n1, n2), e) / norm2(e), dot_product(n1, n2))
   end function dihedral_angle

   !> Sum over node i's edges of |e| theta_e (= 4 M_i) and the dual-cell area A_i, from the
   !> current work arrays.
   pure subroutine node_sums(self, mesh, i, s_i, a_i)
      type(bending_t), intent(in) :: self
      type(surface_mesh_t), intent(in) :: mesh
      integer, intent(in) :: i
      real(dp), intent(out) :: s_i, a_i
      integer :: p
      s_i = 0
      do p = self%node_edge_start(i), self%node_edge_start(i + 1) - 1
         if (self%node_edge_slot(p) <= 2) s_i = s_i + self%len_theta(self%node_edge(p))
      end do
      a_i = 0
      do p = mesh%node_tri_start(i), mesh%node_tri_start(i + 1) - 1
         a_i = a_i + self%corner_area(mesh%node_tri_vertex(p), mesh%node_tri(p))
      end do
   end subroutine node_sums

   !> Mean curvature 2H_i = 2 M_i / A_i = (S_i / 2) / A_i of node i from the work arrays.
   pure real(dp) function node_curvature(self, mesh, i) result(c)
      type(bending_t), intent(in) :: self
      type(surface_mesh_t), intent(in) :: mesh
      integer, intent(in) :: i
      real(dp) :: s_i, a_i
      call node_sums(self, mesh, i, s_i, a_i)
      c = 0.5_dp * s_i / a_i
   end function node_curvature

   !> Bending energy at positions x (work arrays are overwritten).
   real(dp) function energy_at(self, mesh, x) result(energy)
      class(bending_t), intent(inout) :: self
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      integer :: i
      real(dp) :: s_i, a_i
      call edge_and_triangle_measures(self, mesh, x)
      energy = 0
      do i = 1, mesh%n_nodes
         call node_sums(self, mesh, i, s_i, a_i)
         energy = energy + 0.5_dp * self%kb * a_i * (0.5_dp * s_i / a_i - self%c0(i))**2
      end do
   end function energy_at

   !> force += -dE/dx, energy += E.
   subroutine add_forces(self, mesh, x, force, energy)
      class(bending_t), intent(inout) :: self
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(inout) :: force(:, :)
      real(dp), intent(inout) :: energy
      integer :: e, t, i, p
      real(dp) :: s_i, a_i, u, e_bend, ev(3), length, n1(3), n2(3), theta, dth_k(3), dth_l(3)
      real(dp) :: alpha1, alpha2, g(3, 4)

      call edge_and_triangle_measures(self, mesh, x)
      e_bend = 0
      !$omp parallel default(none) shared(self, mesh, x, force) &
      !$omp private(e, t, i, p, s_i, a_i, u, ev, length, n1, n2, theta, dth_k, dth_l, alpha1, alpha2, g) &
      !$omp reduction(+:e_bend)
      ! Per node: E_i = (K/2) A_i u**2 with u = S_i/(2 A_i) - c_i; dE/dS_i = K u / 2 and
      ! dE/dA_i = -(K/2) u (u + 2 c_i).
      !$omp do schedule(static)
      do i = 1, mesh%n_nodes
         call node_sums(self, mesh, i, s_i, a_i)
         u = 0.5_dp * s_i / a_i - self%c0(i)
         e_bend = e_bend + 0.5_dp * self%kb * a_i * u**2
         self%de_ds(i) = 0.5_dp * self%kb * u
         self%de_da(i) = -0.5_dp * self%kb * u * (u + 2.0_dp * self%c0(i))
      end do
      !$omp end do
      ! Per edge: d(|e| theta)/dx of the hinge, times dE/dS of its two end nodes. With n1, n2
      ! the (unnormalised) normals of the triangles (i, j, k) and (j, i, l):
      !   dtheta/dx_k = -|e| n1/|n1|**2, dtheta/dx_l = -|e| n2/|n2|**2,
      !   dtheta/dx_i = -(1 - alpha1) dtheta/dx_k - (1 - alpha2) dtheta/dx_l,
      !   dtheta/dx_j = -alpha1 dtheta/dx_k - alpha2 dtheta/dx_l,
      ! alpha the position of the foot of k (l) along the edge (translation and rotation
      ! invariance of theta fix the last two from the first two).
      !$omp do schedule(static)
      do e = 1, self%n_edges
         associate (h => self%edge(:, e))
            ev = x(:, h(2)) - x(:, h(1))
            length = norm2(ev)
            n1 = cross(ev, x(:, h(3)) - x(:, h(1)))
            n2 = cross(-ev, x(:, h(4)) - x(:, h(2)))
            theta = atan2(dot_product(cross(n1, n2), ev) / length, dot_product(n1, n2))
            dth_k = -length * n1 / dot_product(n1, n1)
            dth_l = -length * n2 / dot_product(n2, n2)
            alpha1 = dot_product(x(:, h(3)) - x(:, h(1)), ev) / length**2
            alpha2 = dot_product(x(:, h(4)) - x(:, h(1)), ev) / length**2
            g(:, 3) = length * dth_k
            g(:, 4) = length * dth_l
            g(:, 1) = -(1.0_dp - alpha1) * g(:, 3) - (1.0_dp - alpha2) * g(:, 4) - theta * ev / length
            g(:, 2) = -alpha1 * g(:, 3) - alpha2 * g(:, 4) + theta * ev / length
            self%edge_grad(:, :, e) = (self%de_ds(h(1)) + self%de_ds(h(2))) * g
         end associate
      end do
      !$omp end do
      ! Per triangle: the gradient of sum_a dE/dA_a A_a over its Voronoi corner areas A_a.
      !$omp do schedule(static)
      do t = 1, mesh%n_tri
         self%tri_grad(:, :, t) = voronoi_corners_gradient(x(:, mesh%tri(1, t)), x(:, mesh%tri(2, t)), &
                                                           x(:, mesh%tri(3, t)), self%de_da(mesh%tri(:, t)))
      end do
      !$omp end do
      !$omp do schedule(static)
      do i = 1, mesh%n_nodes
         do p = self%node_edge_start(i), self%node_edge_start(i + 1) - 1
            force(:, i) = force(:, i) - self%edge_grad(:, self%node_edge_slot(p), self%node_edge(p))
         end do
         do p = mesh%node_tri_start(i), mesh%node_tri_start(i + 1) - 1
            force(:, i) = force(:, i) - self%tri_grad(:, mesh%node_tri_vertex(p), mesh%node_tri(p))
         end do
      end do
      !$omp end do
      !$omp end parallel
      energy = energy + e_bend
   end subroutine add_forces

   !> Voronoi (circumcentric dual) areas of the corners of triangle (p1, p2, p3):
   !> A_a = (|ab|**2 cot(angle c) + |ac|**2 cot(angle b)) / 8. Why Voronoi and not a third of the
   !> triangle: the flat triangles inscribed in a sphere have their normals through their
   !> circumcentres, so theta_e = (cot alpha + cot beta) |e| / (2R) and sum |e| theta_e / 2 is
   !> 2/R times the Voronoi area exactly; with barycentric areas the node curvature of the
   !> icosahedral sphere scatters by 15 % and the force density of an inflated sphere grows
   !> as 1/h**2 under refinement. (The icosahedral meshes have no obtuse triangles.)
   pure function voronoi_corners(p1, p2, p3) result(area)
      real(dp), intent(in) :: p1(3), p2(3), p3(3)
      real(dp) :: area(3)
      real(dp) :: cot1, cot2, cot3
      cot1 = cotangent(p2 - p1, p3 - p1)
      cot2 = cotangent(p3 - p2, p1 - p2)
      cot3 = cotangent(p1 - p3, p2 - p3)
      area(1) = 0.125_dp * (sum((p2 - p1)**2) * cot3 + sum((p3 - p1)**2) * cot2)
      area(2) = 0.125_dp * (sum((p3 - p2)**2) * cot1 + sum((p1 - p2)**2) * cot3)
      area(3) = 0.125_dp * (sum((p1 - p3)**2) * cot2 + sum((p2 - p3)**2) * cot1)
   end function voronoi_corners

   !> cot of the angle between u and v.
   pure real(dp) function cotangent(u, v)
      real(dp), intent(in) :: u(3), v(3)
      cotangent = dot_product(u, v) / norm2(cross(u, v))
   end function cotangent

   !> d/d(p1, p2, p3) of sum_a w_a A_a (voronoi_corners): each corner angle c, opposite the
   !> edge ab, enters as (w_a + w_b) |ab|**2 cot(c) / 8.
   pure function voronoi_corners_gradient(p1, p2, p3, w) result(grad)
      real(dp), intent(in) :: p1(3), p2(3), p3(3), w(3)
      real(dp) :: grad(3, 3)
      real(dp) :: p(3, 3), u(3), v(3), d, nn, cot, lsq, du(3), dv(3), weight
      integer :: c, a, b
      p(:, 1) = p1
      p(:, 2) = p2
      p(:, 3) = p3
      grad = 0
      do c = 1, 3
         a = mod(c, 3) + 1
         b = mod(c + 1, 3) + 1
         u = p(:, a) - p(:, c)
         v = p(:, b) - p(:, c)
         d = dot_product(u, v)
         nn = norm2(cross(u, v))
         cot = d / nn
         lsq = sum((u - v)**2)
         ! cot = d/N, N**2 = |u|**2 |v|**2 - d**2: dcot/du = v/N - d (|v|**2 u - d v)/N**3.
         du = v / nn - d * (dot_product(v, v) * u - d * v) / nn**3
         dv = u / nn - d * (dot_product(u, u) * v - d * u) / nn**3
         weight = 0.125_dp * (w(a) + w(b))
         grad(:, a) = grad(:, a) + weight * (2.0_dp * cot * (u - v) + lsq * du)
         grad(:, b) = grad(:, b) + weight * (-2.0_dp * cot * (u - v) + lsq * dv)
         grad(:, c) = grad(:, c) - weight * lsq * (du + dv)
      end do
   end function voronoi_corners_gradient

end module membrane_bending
