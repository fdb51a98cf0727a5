!> The membrane's own single layer at its nodes to the accuracy of the 7-point rule on every
!> triangle (the 3D tube model's `--self-quadrature full`),
!> u(x_i) = 1/(8 pi) int J(x_i - y) . f(y) dS(y) for the P1 density f.
!>
!> Why not stokes_single_layer's rule (Duffy on the touching triangles, 7-point rule on the
!> next ring, one Stokeslet per node beyond): its vertex rule has an O(h) mid-field error,
!> which a confined capsule, carrying large loads f/Ca_s whose net force cancels, turns into
!> a first-order v_c/V error (README "Tube flow (3D)", issue 3). Here:
!>  - far: every triangle's `far_rule` (far_edge: the edge-midpoint rule of degree 2, one
!>    point per edge with the strengths of both triangles; far_interior3: the interior 3-point
!>    rule of degree 2; far_dunavant7: the 7-point rule), as one contiguous structure of arrays
!>    of its points and strengths (weight x area x P1 density), built once per evaluation and
!>    summed per target node by the vectorised pair loop of stokes_single_layer
!>    (add_stokeslets);
!>  - near (centroid within near_ratio of its diameters of the node, not touching it): the
!>    7-point rule, subdivided until every piece lies sub_ratio of its diameters away,
!>    replaces the far rule;
!>  - touching: the Duffy rule replaces the far rule.
!> The far rule's points lie inside the triangles, never on a node, so the far sum may include
!> the near and touching triangles and the correction takes them out again.
module self_single_layer
   use capsim_kinds, only: dp, pi
   use sphere_mesh, only: surface_mesh_t
   use triangle_quadrature, only: quadrature_rule_t, dunavant7_rule, interior3_rule, edge3_rule, duffy_rule
   use triangle_cells, only: triangle_cells_t
   use stokes_single_layer, only: add_stokeslets, rule_integral
   use wall_single_layer, only: point_sum, subdivided_single_layer
   implicit none
   private
   public :: self_single_layer_t, far_edge, far_interior3, far_dunavant7

   !> Far rules (the value is the number of the rule's points per triangle, but far_edge's
   !> points are shared: one per edge).
   integer, parameter :: far_edge = 1, far_interior3 = 3, far_dunavant7 = 7

   type :: self_single_layer_t
      integer :: n_tri = 0, n_points = 0
      integer :: far_kind = far_edge
      !> far_edge: the edge of each triangle's point k (3, n_tri); the two triangles of each
      !> edge and the point's index in each (2, n_edges).
      integer, allocatable :: tri_edge(:, :), edge_tri(:, :), edge_slot(:, :)
      !> Near triangles: centroid within near_ratio diameters of the node; pieces subdivided
      !> until their centroid lies sub_ratio of their diameters away.
      real(dp) :: near_ratio = 3.0_dp, sub_ratio = 3.0_dp
      type(quadrature_rule_t) :: far_rule, rule7
      type(quadrature_rule_t) :: duffy(3)
      !> Per evaluation: the far rule's points and strengths (structure of arrays).
      real(dp), allocatable :: px(:), py(:), pz(:), sx(:), sy(:), sz(:)
      !> Per evaluation, per triangle: corners, corner densities, centroid, diameter, and its
      !> far rule's points and strengths (3, far_points).
      real(dp), allocatable :: tri_x(:, :, :), tri_f(:, :, :), centroid(:, :), diameter(:)
      real(dp), allocatable :: qp(:, :, :), qs(:, :, :)
      !> The triangles by cell of their centroid, reach near_ratio diameters.
      type(triangle_cells_t) :: cells
   contains
      procedure :: init
      procedure :: velocity
   end type self_single_layer_t

contains

   !> Work arrays for `mesh`; `duffy_order` Gauss points per direction on touching triangles
   !> (stokes_single_layer's choice: 4); `far_points` 3 or 7; the near and subdivision ratios.
   subroutine init(self, mesh, duffy_order, far_kind, near_ratio, sub_ratio)
      class(self_single_layer_t), intent(inout) :: self
      type(surface_mesh_t), intent(in) :: mesh
      integer, intent(in) :: duffy_order, far_kind
      real(dp), intent(in) :: near_ratio, sub_ratio
      integer :: k, nq
      self%far_kind = far_kind
      self%near_ratio = near_ratio
      self%sub_ratio = sub_ratio
      self%rule7 = dunavant7_rule(0)
      select case (far_kind)
      case (far_dunavant7)
         self%far_rule = self%rule7
      case (far_interior3)
         self%far_rule = interior3_rule()
      case default
         self%far_rule = edge3_rule()
      end select
      do k = 1, 3
         self%duffy(k) = duffy_rule(duffy_order, k)
      end do
      nq = size(self%far_rule%weight)
      self%n_tri = mesh%n_tri
      self%n_points = nq * mesh%n_tri
      if (far_kind == far_edge) then
         call find_edges(mesh, self%tri_edge, self%edge_tri, self%edge_slot)
         self%n_points = size(self%edge_tri, 2)
      end if
      if (allocated(self%px)) deallocate (self%px, self%py, self%pz, self%sx, self%sy, self%sz, self%tri_x, self%tri_f, &
                                           self%centroid, self%diameter, self%qp, self%qs)
      allocate (self%px(self%n_points), self%py(self%n_points), self%pz(self%n_points))
      allocate (self%sx(self%n_points), self%sy(self%n_points), self%sz(self%n_points))
      allocate (self%tri_x(3, 3, mesh%n_tri), self%tri_f(3, 3, mesh%n_tri), self%centroid(3, mesh%n_tri))
      allocate (self%diameter(mesh%n_tri), self%qp(3, nq, mesh%n_tri), self%qs(3, nq, mesh%n_tri))
   end subroutine init

   !> u(:, i) = 1/(8 pi) int J(x_i - y) . f(y) dS at every node, for positions x, nodal force
   !> density f (P1) and the triangle areas tri_area of x. Per-step routine: allocates nothing
   !> once the cells have their size.
   subroutine velocity(self, mesh, x, f, tri_area, u)
      class(self_single_layer_t), intent(inout) :: self
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :), f(:, :), tri_area(:)
      real(dp), intent(out) :: u(:, :)
      integer :: t, q, nq, i, j
      real(dp) :: acc(3)

      nq = size(self%far_rule%weight)
      !$omp parallel do default(none) shared(self, mesh, x, f, tri_area, nq) private(t, q, j) schedule(static)
      do t = 1, mesh%n_tri
         self%tri_x(:, :, t) = x(:, mesh%tri(:, t))
         self%tri_f(:, :, t) = f(:, mesh%tri(:, t))
         self%centroid(:, t) = (self%tri_x(:, 1, t) + self%tri_x(:, 2, t) + self%tri_x(:, 3, t)) / 3.0_dp
         self%diameter(t) = max(norm2(self%tri_x(:, 2, t) - self%tri_x(:, 1, t)), &
                                norm2(self%tri_x(:, 3, t) - self%tri_x(:, 2, t)), &
                                norm2(self%tri_x(:, 1, t) - self%tri_x(:, 3, t)))
         do q = 1, nq
            associate (b => self%far_rule%bary(:, q))
               self%qp(:, q, t) = b(1) * self%tri_x(:, 1, t) + b(2) * self%tri_x(:, 2, t) + b(3) * self%tri_x(:, 3, t)
               self%qs(:, q, t) = (tri_area(t) * self%far_rule%weight(q)) * (b(1) * self%tri_f(:, 1, t) &
                                  + b(2) * self%tri_f(:, 2, t) + b(3) * self%tri_f(:, 3, t))
            end associate
            if (self%far_kind == far_edge) cycle
            j = nq * (t - 1) + q
            self%px(j) = self%qp(1, q, t)
            self%py(j) = self%qp(2, q, t)
            self%pz(j) = self%qp(3, q, t)
            self%sx(j) = self%qs(1, q, t)
            self%sy(j) = self%qs(2, q, t)
            self%sz(j) = self%qs(3, q, t)
         end do
      end do
      !$omp end parallel do
      if (self%far_kind == far_edge) then
         ! One point per edge (both triangles put it at the same midpoint), both strengths.
         !$omp parallel do default(none) shared(self) private(j) schedule(static)
         do j = 1, self%n_points
            associate (t1 => self%edge_tri(1, j), t2 => self%edge_tri(2, j), k1 => self%edge_slot(1, j), &
                       k2 => self%edge_slot(2, j))
               self%px(j) = self%qp(1, k1, t1)
               self%py(j) = self%qp(2, k1, t1)
               self%pz(j) = self%qp(3, k1, t1)
               self%sx(j) = self%qs(1, k1, t1) + self%qs(1, k2, t2)
               self%sy(j) = self%qs(2, k1, t1) + self%qs(2, k2, t2)
               self%sz(j) = self%qs(3, k1, t1) + self%qs(3, k2, t2)
            end associate
         end do
         !$omp end parallel do
      end if
      call self%cells%build(self%centroid, self%diameter, 0.0_dp, self%near_ratio, self%near_ratio * maxval(self%diameter))
      !$omp parallel do default(none) shared(self, mesh, x, tri_area, u) private(i, acc) schedule(dynamic, 16)
      do i = 1, mesh%n_nodes
         acc = 0.0_dp
         call add_stokeslets(self%n_points, self%px, self%py, self%pz, self%sx, self%sy, self%sz, x(:, i), 1, &
                             self%n_points, acc)
         u(:, i) = (acc + near_correction(self, mesh, x(:, i), i, tri_area)) / (8.0_dp * pi)
      end do
      !$omp end parallel do
   end subroutine velocity

   !> At node i (position p), what replaces the far rule: the Duffy rule on the triangles
   !> touching i, the subdivided 7-point rule on the others within near_ratio diameters.
   function near_correction(self, mesh, p, i, tri_area) result(corr)
      type(self_single_layer_t), intent(in) :: self
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: p(3), tri_area(:)
      integer, intent(in) :: i
      real(dp) :: corr(3)
      integer :: list(self%n_tri), m, j, t, s

      corr = 0.0_dp
      do s = mesh%node_tri_start(i), mesh%node_tri_start(i + 1) - 1
         t = mesh%node_tri(s)
         corr = corr + tri_area(t) * rule_integral(self%duffy(mesh%node_tri_vertex(s)), p, self%tri_x(:, :, t), &
                                                   self%tri_f(:, :, t)) - point_sum(p, self%qp(:, :, t), self%qs(:, :, t))
      end do
      block
         real(dp) :: dist(self%n_tri)
         call self%cells%near(p, list, dist, m)
      end block
      do j = 1, m
         t = list(j)
         if (any(mesh%tri(:, t) == i)) cycle
         corr = corr + subdivided_single_layer(self%rule7, p, self%tri_x(:, :, t), self%tri_f(:, :, t), tri_area(t), &
                                               self%sub_ratio) - point_sum(p, self%qp(:, :, t), self%qs(:, :, t))
      end do
   end function near_correction

   !> The edges of a closed conforming mesh: tri_edge(k, t) is the edge from corner k to k+1 of
   !> triangle t; edge e has triangles edge_tri(:, e) in which it is edge edge_slot(:, e).
   subroutine find_edges(mesh, tri_edge, edge_tri, edge_slot)
      type(surface_mesh_t), intent(in) :: mesh
      integer, allocatable, intent(out) :: tri_edge(:, :), edge_tri(:, :), edge_slot(:, :)
      integer :: t, k, a, b, s, t2, k2, n_edges
      allocate (tri_edge(3, mesh%n_tri))
      tri_edge = 0
      ! Closed surface: 3 n_tri / 2 edges, each between two triangles.
      allocate (edge_tri(2, 3 * mesh%n_tri / 2), edge_slot(2, 3 * mesh%n_tri / 2))
      n_edges = 0
      do t = 1, mesh%n_tri
         do k = 1, 3
            if (tri_edge(k, t) /= 0) cycle
            a = mesh%tri(k, t)
            b = mesh%tri(mod(k, 3) + 1, t)
            n_edges = n_edges + 1
            tri_edge(k, t) = n_edges
            edge_tri(1, n_edges) = t
            edge_slot(1, n_edges) = k
            ! The other triangle holds the edge as b -> a.
            do s = mesh%node_tri_start(b), mesh%node_tri_start(b + 1) - 1
               t2 = mesh%node_tri(s)
               if (t2 == t) cycle
               do k2 = 1, 3
                  if (mesh%tri(k2, t2) == b .and. mesh%tri(mod(k2, 3) + 1, t2) == a) then
                     tri_edge(k2, t2) = n_edges
                     edge_tri(2, n_edges) = t2
                     edge_slot(2, n_edges) = k2
                  end if
               end do
            end do
         end do
      end do
      if (n_edges /= size(edge_tri, 2) .or. any(tri_edge == 0)) error stop 'self_single_layer: the mesh is not closed'
   end subroutine find_edges

end module self_single_layer
