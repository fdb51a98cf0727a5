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
   public :: single_layer_t, triangle_areas, node_areas, add_stokeslets, stokeslet_block, rule_integral

   type :: single_layer_t
      integer :: n_nodes = 0
      !> Per target node (CSR): triangles whose vertex-rule contribution is replaced, and the
      !> local vertex (1..3) at which the target sits (0 for a near, non-touching triangle).
      integer, allocatable :: corr_start(:), corr_tri(:), corr_vertex(:)
      type(quadrature_rule_t) :: near_rule
      !> Subdivision levels of the near rule; -1 keeps the vertex rule on the next ring.
      integer :: near_levels = 0
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
      self%near_levels = near_levels
      self%near_rule = dunavant7_rule(max(near_levels, 0))
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
         call add_stokeslets(n, sl%xs, sl%ys, sl%zs, sl%qx, sl%qy, sl%qz, x(:, i), 1, i - 1, acc)
         call add_stokeslets(n, sl%xs, sl%ys, sl%zs, sl%qx, sl%qy, sl%qz, x(:, i), i + 1, n, acc)
         call near_correction(sl, mesh, x, f, i, corr)
         u(:, i) = (acc + corr) / (8.0_dp * pi)
      end do
      !$omp end parallel do
   end subroutine pair_sum_and_corrections

   !> Hot loop: point Stokeslets j = j1..j2 at target xt, accumulated into acc. Explicit-shape
   !> contiguous arrays and scalar target coordinates let the compiler vectorise it.
   pure subroutine add_stokeslets(n, xs, ys, zs, qx, qy, qz, xt, j1, j2, acc)
      integer, intent(in) :: n, j1, j2
      real(dp), intent(in) :: xs(n), ys(n), zs(n), qx(n), qy(n), qz(n), xt(3)
      real(dp), intent(inout) :: acc(3)
      integer :: j
      real(dp) :: x1, x2, x3, dx, dy, dz, rinv, rinv3, proj, ax, ay, az
      x1 = xt(1)
      x2 = xt(2)
      x3 = xt(3)
      ax = 0.0_dp
      ay = 0.0_dp
      az = 0.0_dp
      ! OpenMP simd lets the sums be reassociated (vectorised) without -ffast-math elsewhere.
      !$omp simd reduction(+:ax, ay, az) private(dx, dy, dz, rinv, rinv3, proj)
      do j = j1, j2
         dx = x1 - xs(j)
         dy = x2 - ys(j)
         dz = x3 - zs(j)
         rinv = 1.0_dp / sqrt(dx * dx + dy * dy + dz * dz)
         rinv3 = rinv * rinv * rinv
         proj = (dx * qx(j) + dy * qy(j) + dz * qz(j)) * rinv3
         ax = ax + qx(j) * rinv + dx * proj
         ay = ay + qy(j) * rinv + dy * proj
         az = az + qz(j) * rinv + dz * proj
      end do
      acc(1) = acc(1) + ax
      acc(2) = acc(2) + ay
      acc(3) = acc(3) + az
   end subroutine add_stokeslets

   !> Accurate integral minus vertex-rule contribution over the correction triangles of node i.
   pure subroutine near_correction(sl, mesh, x, f, i, corr)
      type(single_layer_t), intent(in) :: sl
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :), f(:, :)
      integer, intent(in) :: i
      real(dp), intent(out) :: corr(3)
      integer :: p, t, m, v(3), corner
      real(dp) :: xv(3, 3), fv(3, 3), area

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
            corr = corr + area * rule_integral(sl%duffy(corner), x(:, i), xv, fv)
         else if (sl%near_levels >= 0) then
            corr = corr + area * rule_integral(sl%near_rule, x(:, i), xv, fv)
         end if
      end do
   end subroutine near_correction

   !> sum_q w_q J(xt - y_q) . f(y_q) over a barycentric rule on the triangle (xv, fv).
   pure function rule_integral(rule, xt, xv, fv) result(acc)
      type(quadrature_rule_t), intent(in) :: rule
      real(dp), intent(in) :: xt(3), xv(3, 3), fv(3, 3)
      real(dp) :: acc(3)
      integer :: q
      real(dp) :: b1, b2, b3, r(3), g(3), rinv
      acc = 0.0_dp
      do q = 1, size(rule%weight)
         b1 = rule%bary(1, q)
         b2 = rule%bary(2, q)
         b3 = rule%bary(3, q)
         r = xt - (b1 * xv(:, 1) + b2 * xv(:, 2) + b3 * xv(:, 3))
         g = b1 * fv(:, 1) + b2 * fv(:, 2) + b3 * fv(:, 3)
         rinv = 1.0_dp / sqrt(r(1)**2 + r(2)**2 + r(3)**2)
         acc = acc + (rule%weight(q) * rinv) * (g + r * ((r(1) * g(1) + r(2) * g(2) + r(3) * g(3)) * rinv**2))
      end do
   end function rule_integral

   pure function stokeslet(r, g) result(w)
      real(dp), intent(in) :: r(3), g(3)
      real(dp) :: w(3), rinv
      rinv = 1.0_dp / norm2(r)
      w = g * rinv + r * (dot_product(r, g) * rinv**3)
   end function stokeslet

   !> The Stokeslet tensor J(r) = I/|r| + r r^T/|r|**3 (a 3 x 3 block of an assembled matrix).
   pure function stokeslet_block(r) result(blk)
      real(dp), intent(in) :: r(3)
      real(dp) :: blk(3, 3), rinv
      integer :: a
      rinv = 1.0_dp / norm2(r)
      do a = 1, 3
         blk(:, a) = r * (r(a) * rinv**3)
         blk(a, a) = blk(a, a) + rinv
      end do
   end function stokeslet_block

end module stokes_single_layer
