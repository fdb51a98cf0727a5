!> Single-layer potential of a closed P1 surface in unbounded Stokes flow.
!>
!> Normalisation (stated once, as in FMM3D):  u(x) = 1/(8 pi mu) integral_S J(x - y) . f(y) dS(y),
!> J(r) = I/|r| + r r^T/|r|**3, with mu = 1 here; callers scale by 1/Ca.
!> f is the nodal force density (P1 interpolation between nodes).
!>
!> Quadrature: the far field uses the vertex rule on every triangle, which collapses into one
!> Stokeslet per node with strength f_j A_j (A_j = a third of the surrounding triangle areas):
!> an N**2 pair loop over contiguous arrays (structure of arrays) that vectorises. For each
!> target node, the vertex rule is then replaced on the triangles that touch it (Duffy rule,
!> the 1/r singularity is integrated exactly up to Gauss error) and on the next ring of
!> triangles (subdivided 7-point Gauss rule), where the vertex rule is inaccurate.
!> The correction lists depend only on the connectivity and are built once.
module stokes_single_layer
   use capsim_kinds, only: dp, pi
   use sphere_mesh, only: surface_mesh_t
   use triangle_quadrature, only: quadrature_rule_t, dunavant7_rule, duffy_rule
   implicit none
   private
   public :: single_layer_t, triangle_areas, node_areas

   type :: single_layer_t
      integer :: n_nodes = 0
      !> Per target node (CSR): triangles whose vertex-rule contribution is replaced, and the
      !> local vertex (1..3) at which the target sits (0 for a near, non-touching triangle).
      integer, allocatable :: corr_start(:), corr_tri(:), corr_vertex(:)
      type(quadrature_rule_t) :: near_rule
      type(quadrature_rule_t) :: duffy(3)
      ! Work arrays, allocated once (no allocation inside the time loop).
      real(dp), allocatable :: xs(:), ys(:), zs(:), qx(:), qy(:), qz(:)
      real(dp), allocatable :: tri_area(:), node_area(:)
   contains
      procedure :: init
      procedure :: velocity
   end type single_layer_t

contains

   !> Build the correction lists. `duffy_order` Gauss points per direction on touching
   !> triangles; `near_levels` subdivisions of the 7-point rule on the next ring.
   subroutine init(self, mesh, duffy_order, near_levels)
      class(single_layer_t), intent(inout) :: self
      type(surface_mesh_t), intent(in) :: mesh
      integer, intent(in) :: duffy_order, near_levels
      integer, allocatable :: mark(:)
      integer :: i, p, q, t, k, j, n_corr, pass

      self%n_nodes = mesh%n_nodes
      self%near_rule = dunavant7_rule(near_levels)
      do k = 1, 3
         self%duffy(k) = duffy_rule(duffy_order, k)
      end do
      allocate (self%xs(mesh%n_nodes), self%ys(mesh%n_nodes), self%zs(mesh%n_nodes))
      allocate (self%qx(mesh%n_nodes), self%qy(mesh%n_nodes), self%qz(mesh%n_nodes))
      allocate (self%tri_area(mesh%n_tri), self%node_area(mesh%n_nodes))
      allocate (mark(mesh%n_tri), self%corr_start(mesh%n_nodes + 1))
      ! Two passes over the same traversal: count, then fill.
      do pass = 1, 2
         mark = 0
         n_corr = 0
         do i = 1, mesh%n_nodes
            if (pass == 2) self%corr_start(i) = n_corr + 1
            do p = mesh%node_tri_start(i), mesh%node_tri_start(i + 1) - 1
               t = mesh%node_tri(p)
               mark(t) = i
               n_corr = n_corr + 1
               if (pass == 2) then
                  self%corr_tri(n_corr) = t
                  self%corr_vertex(n_corr) = mesh%node_tri_vertex(p)
               end if
            end do
            do p = mesh%node_tri_start(i), mesh%node_tri_start(i + 1) - 1
               do k = 1, 3
                  j = mesh%tri(k, mesh%node_tri(p))
                  do q = mesh%node_tri_start(j), mesh%node_tri_start(j + 1) - 1
                     t = mesh%node_tri(q)
                     if (mark(t) == i) cycle
                     mark(t) = i
                     n_corr = n_corr + 1
                     if (pass == 2) then
                        self%corr_tri(n_corr) = t
                        self%corr_vertex(n_corr) = 0
                     end if
                  end do
               end do
            end do
         end do
         if (pass == 1) allocate (self%corr_tri(n_corr), self%corr_vertex(n_corr))
      end do
      self%corr_start(mesh%n_nodes + 1) = n_corr + 1
   end subroutine init

   !> Area of each triangle.
   subroutine triangle_areas(mesh, x, area)
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: area(:)
      integer :: t
      real(dp) :: e1(3), e2(3)
      !$omp parallel do default(none) shared(mesh, x, area) private(t, e1, e2) schedule(static)
      do t = 1, mesh%n_tri
         e1 = x(:, mesh%tri(2, t)) - x(:, mesh%tri(1, t))
         e2 = x(:, mesh%tri(3, t)) - x(:, mesh%tri(1, t))
         area(t) = 0.5_dp * norm2([e1(2) * e2(3) - e1(3) * e2(2), e1(3) * e2(1) - e1(1) * e2(3), &
                                   e1(1) * e2(2) - e1(2) * e2(1)])
      end do
      !$omp end parallel do
   end subroutine triangle_areas

   !> Area attached to each node: a third of the areas of its triangles.
   subroutine node_areas(mesh, tri_area, area)
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: tri_area(:)
      real(dp), intent(out) :: area(:)
      integer :: i, p
      !$omp parallel do default(none) shared(mesh, tri_area, area) private(i, p) schedule(static)
      do i = 1, mesh%n_nodes
         area(i) = 0.0_dp
         do p = mesh%node_tri_start(i), mesh%node_tri_start(i + 1) - 1
            area(i) = area(i) + tri_area(mesh%node_tri(p)) / 3.0_dp
         end do
      end do
      !$omp end parallel do
   end subroutine node_areas

   !> u = 1/(8 pi) integral J . f dS at every node, for nodal force density f (3, n).
   subroutine velocity(self, mesh, x, f, u)
      class(single_layer_t), intent(inout) :: self
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :), f(:, :)
      real(dp), intent(out) :: u(:, :)
      integer :: n

      n = mesh%n_nodes
      call triangle_areas(mesh, x, self%tri_area)
      call node_areas(mesh, self%tri_area, self%node_area)
      self%xs = x(1, 1:n)
      self%ys = x(2, 1:n)
      self%zs = x(3, 1:n)
      self%qx = f(1, 1:n) * self%node_area
      self%qy = f(2, 1:n) * self%node_area
      self%qz = f(3, 1:n) * self%node_area
      call pair_sum_and_corrections(self, mesh, x, f, u)
   end subroutine velocity

   subroutine pair_sum_and_corrections(sl, mesh, x, f, u)
      type(single_layer_t), intent(in) :: sl
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :), f(:, :)
      real(dp), intent(out) :: u(:, :)
      integer :: i, n
      real(dp) :: acc(3), corr(3)

      n = mesh%n_nodes
      !$omp parallel do default(none) shared(sl, mesh, x, f, u, n) private(i, acc, corr) schedule(static)
      do i = 1, n
         acc = 0.0_dp
         call add_stokeslets(sl, x(:, i), 1, i - 1, acc)
         call add_stokeslets(sl, x(:, i), i + 1, n, acc)
         call near_correction(sl, mesh, x, f, i, corr)
         u(:, i) = (acc + corr) / (8.0_dp * pi)
      end do
      !$omp end parallel do
   end subroutine pair_sum_and_corrections

   !> Hot loop: point Stokeslets j = j1..j2 at target xt, accumulated into acc.
   pure subroutine add_stokeslets(sl, xt, j1, j2, acc)
      type(single_layer_t), intent(in) :: sl
      real(dp), intent(in) :: xt(3)
      integer, intent(in) :: j1, j2
      real(dp), intent(inout) :: acc(3)
      integer :: j
      real(dp) :: dx, dy, dz, rinv, rinv3, proj, ax, ay, az
      ax = 0.0_dp
      ay = 0.0_dp
      az = 0.0_dp
      do j = j1, j2
         dx = xt(1) - sl%xs(j)
         dy = xt(2) - sl%ys(j)
         dz = xt(3) - sl%zs(j)
         rinv = 1.0_dp / sqrt(dx * dx + dy * dy + dz * dz)
         rinv3 = rinv * rinv * rinv
         proj = (dx * sl%qx(j) + dy * sl%qy(j) + dz * sl%qz(j)) * rinv3
         ax = ax + sl%qx(j) * rinv + dx * proj
         ay = ay + sl%qy(j) * rinv + dy * proj
         az = az + sl%qz(j) * rinv + dz * proj
      end do
      acc = acc + [ax, ay, az]
   end subroutine add_stokeslets

   !> Accurate integral minus vertex-rule contribution over the correction triangles of node i.
   pure subroutine near_correction(sl, mesh, x, f, i, corr)
      type(single_layer_t), intent(in) :: sl
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :), f(:, :)
      integer, intent(in) :: i
      real(dp), intent(out) :: corr(3)
      integer :: p, t, k, m, v(3), corner
      real(dp) :: xv(3, 3), fv(3, 3), y(3), fy(3), area

      corr = 0.0_dp
      do p = sl%corr_start(i), sl%corr_start(i + 1) - 1
         t = sl%corr_tri(p)
         corner = sl%corr_vertex(p)
         v = mesh%tri(:, t)
         area = sl%tri_area(t)
         do m = 1, 3
            xv(:, m) = x(:, v(m))
            fv(:, m) = f(:, v(m))
            if (v(m) /= i) corr = corr - (area / 3.0_dp) * stokeslet(x(:, i) - xv(:, m), fv(:, m))
         end do
         if (corner > 0) then
            do k = 1, size(sl%duffy(corner)%weight)
               y = matmul(xv, sl%duffy(corner)%bary(:, k))
               fy = matmul(fv, sl%duffy(corner)%bary(:, k))
               corr = corr + area * sl%duffy(corner)%weight(k) * stokeslet(x(:, i) - y, fy)
            end do
         else
            do k = 1, size(sl%near_rule%weight)
               y = matmul(xv, sl%near_rule%bary(:, k))
               fy = matmul(fv, sl%near_rule%bary(:, k))
               corr = corr + area * sl%near_rule%weight(k) * stokeslet(x(:, i) - y, fy)
            end do
         end if
      end do
   end subroutine near_correction

   pure function stokeslet(r, g) result(w)
      real(dp), intent(in) :: r(3), g(3)
      real(dp) :: w(3), rinv
      rinv = 1.0_dp / norm2(r)
      w = g * rinv + r * (dot_product(r, g) * rinv**3)
   end function stokeslet

end module stokes_single_layer
