!> Double-layer potential of a closed P1 surface in unbounded Stokes flow, at the nodes.
!>
!> Normalisation (that of stokes_single_layer, mu = 1):
!>   D[u](x) = 1/(8 pi) PV integral_S u(y) . T(y - x) . n(y) dS(y),
!>   T_klm(r) = -6 r_k r_l r_m / |r|**5,   n the OUTWARD normal.
!> With this sign the Gauss identity reads PV integral_S T . n dS = -4 pi I on a smooth closed
!> surface, so D[c] = -c/2 for a constant c, and D[U + Omega x y] = -(U + Omega x x)/2 for any
!> rigid-body motion (the eigenvalue -1 of 2D that makes the plain iteration stall as
!> lambda -> infinity). On a sphere D[n] = +n/2 (the eigenvalue +1, lambda -> 0).
!>
!> Singularity subtraction: D[u](x_i) = 1/(8 pi) integral (u(y) - u(x_i)) . T . n dS - u(x_i)/2.
!> The subtracted integrand is bounded (|u(y) - u(x_i)| = O(r) against T . n = O(1/r) on a
!> smooth surface), so ordinary rules apply; the -1/2 is the exact identity of the smooth
!> surface. Doing the PV integral of T . n by quadrature instead is only first order on flat
!> triangles: at a vertex of a convex polyhedron the interior cone falls short of a half-space by
!> an angle O(h), and the tensor integral with it (see `principal_value_tensor`, measured by
!> kernel_probe double-layer-identity).
!>
!> Quadrature (the single layer's structure): far field by the vertex rule, which collapses into
!> one doublet per node with the node area vector a_j = (1/3) sum of (area x unit normal) of its
!> triangles (a structure-of-arrays pair loop, OpenMP over targets); on the triangles that touch
!> the target node the flat-triangle integrand vanishes identically ((y - x_i) . n_t = 0), and on
!> the next ring of triangles the vertex rule is replaced by the 7-point Gauss rule. The
!> correction lists are the single layer's (copied at init). `set_geometry` precomputes the
!> per-step geometry once, so the many applications of an iterative solve reuse it.
module stokes_double_layer
   use capsim_kinds, only: dp, pi
   use vector_algebra, only: cross
   use sphere_mesh, only: surface_mesh_t
   use triangle_quadrature, only: quadrature_rule_t, dunavant7_rule
   use stokes_single_layer, only: single_layer_t
   implicit none
   private
   public :: double_layer_t

   type :: double_layer_t
      integer :: n_nodes = 0
      !> Per target node (CSR): triangles whose vertex-rule contribution is replaced; local
      !> vertex (1..3) of the target in it, 0 for a near, non-touching triangle.
      integer, allocatable :: corr_start(:), corr_tri(:), corr_vertex(:)
      type(quadrature_rule_t) :: near_rule
      ! Geometry of the current positions (set_geometry): node positions and area vectors as
      ! structure of arrays, triangle unit normals and areas, node unit normals.
      real(dp), allocatable :: xs(:), ys(:), zs(:), ax(:), ay(:), az(:)
      real(dp), allocatable :: tri_normal(:, :), tri_area(:), node_normal(:, :), x(:, :)
      !> sum_j |a_j|: the discrete area that normalises the deflation term.
      real(dp) :: area_sum = 0
      ! The density as structure of arrays (work, filled by apply).
      real(dp), allocatable :: us(:), vs(:), ws(:)
   contains
      procedure :: init
      procedure :: set_geometry
      procedure :: apply
      procedure :: principal_value_tensor
      procedure :: tensor_off_surface
      procedure :: normal_flux
      procedure :: apply_outside
   end type double_layer_t

   !> Off-surface near field (apply_outside): as the wall's rules (wall_single_layer), a
   !> (sub-)triangle is a 7-point leaf beyond leaf_ratio of its diameters, or at max_depth.
   real(dp), parameter :: leaf_ratio = 3.0_dp
   integer, parameter :: max_depth = 10

contains

   !> Allocate once and take the correction lists of an initialised single layer on the same mesh.
   subroutine init(self, mesh, single_layer)
      class(double_layer_t), intent(inout) :: self
      type(surface_mesh_t), intent(in) :: mesh
      type(single_layer_t), intent(in) :: single_layer
      integer :: n
      n = mesh%n_nodes
      self%n_nodes = n
      self%corr_start = single_layer%corr_start
      self%corr_tri = single_layer%corr_tri
      self%corr_vertex = single_layer%corr_vertex
      self%near_rule = dunavant7_rule(0)
      allocate (self%xs(n), self%ys(n), self%zs(n), self%ax(n), self%ay(n), self%az(n))
      allocate (self%us(n), self%vs(n), self%ws(n), self%x(3, n), self%node_normal(3, n))
      allocate (self%tri_normal(3, mesh%n_tri), self%tri_area(mesh%n_tri))
   end subroutine init

   !> Per-step geometry at positions x: triangle normals and areas, node area vectors.
   subroutine set_geometry(self, mesh, x)
      class(double_layer_t), intent(inout) :: self
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      integer :: t, i, p
      real(dp) :: c(3), a(3), area_sum
      !$omp parallel do default(none) shared(self, mesh, x) private(t, c) schedule(static)
      do t = 1, mesh%n_tri
         c = cross(x(:, mesh%tri(2, t)) - x(:, mesh%tri(1, t)), x(:, mesh%tri(3, t)) - x(:, mesh%tri(1, t)))
         self%tri_area(t) = 0.5_dp * norm2(c)
         self%tri_normal(:, t) = c / norm2(c)
      end do
      !$omp end parallel do
      area_sum = 0
      !$omp parallel do default(none) shared(self, mesh, x) private(i, p, t, a) reduction(+:area_sum) schedule(static)
      do i = 1, mesh%n_nodes
         a = 0
         do p = mesh%node_tri_start(i), mesh%node_tri_start(i + 1) - 1
            t = mesh%node_tri(p)
            a = a + (self%tri_area(t) / 3.0_dp) * self%tri_normal(:, t)
         end do
         self%ax(i) = a(1)
         self%ay(i) = a(2)
         self%az(i) = a(3)
         self%node_normal(:, i) = a / norm2(a)
         self%xs(i) = x(1, i)
         self%ys(i) = x(2, i)
         self%zs(i) = x(3, i)
         self%x(:, i) = x(:, i)
         area_sum = area_sum + norm2(a)
      end do
      !$omp end parallel do
      self%area_sum = area_sum
   end subroutine set_geometry

   !> w = D[u] at every node (singularity subtracted), for the geometry of set_geometry.
   subroutine apply(self, mesh, u, w)
      class(double_layer_t), intent(inout) :: self
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: u(:, :)
      real(dp), intent(out) :: w(:, :)
      call set_density(self, u)
      call doublet_sums(self, mesh, u, 1.0_dp, w)
   end subroutine apply

   !> M_i = 1/(8 pi) PV integral T . n dS at node i by the same quadrature, without the
   !> subtraction (the Gauss identity says -I/2 on a smooth surface): column k is the raw
   !> double layer of the constant density e_k.
   subroutine principal_value_tensor(self, mesh, m)
      class(double_layer_t), intent(inout) :: self
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(out) :: m(:, :, :)
      real(dp), allocatable :: e(:, :), w(:, :)
      integer :: k
      allocate (e(3, mesh%n_nodes), w(3, mesh%n_nodes))
      do k = 1, 3
         e = 0
         e(k, :) = 1
         call set_density(self, e)
         call doublet_sums(self, mesh, e, 0.0_dp, w)
         m(:, k, :) = w
      end do
   end subroutine principal_value_tensor

   !> 1/(8 pi) integral T(y - x0) . n(y) dS_y at a point x0 off the surface, by the vertex rule
   !> alone (accurate for x0 several element sizes away). The Gauss identity gives -I inside,
   !> 0 outside, exactly for the polyhedron too, so the error is the far-field rule's.
   pure function tensor_off_surface(self, x0) result(m)
      class(double_layer_t), intent(in) :: self
      real(dp), intent(in) :: x0(3)
      real(dp) :: m(3, 3), r(3), a(3), r2
      integer :: j, k
      m = 0
      do j = 1, self%n_nodes
         r = [self%xs(j), self%ys(j), self%zs(j)] - x0
         a = [self%ax(j), self%ay(j), self%az(j)]
         r2 = dot_product(r, r)
         do k = 1, 3
            m(:, k) = m(:, k) - 6.0_dp * r(k) * dot_product(r, a) / (r2 * r2 * sqrt(r2)) * r
         end do
      end do
      m = m / (8.0_dp * pi)
   end function tensor_off_surface

   !> Discrete flux sum_j u_j . a_j (the integral of u . n over the surface).
   pure real(dp) function normal_flux(self, u)
      class(double_layer_t), intent(in) :: self
      real(dp), intent(in) :: u(:, :)
      normal_flux = sum(u(1, :) * self%ax) + sum(u(2, :) * self%ay) + sum(u(3, :) * self%az)
   end function normal_flux

   !> w(:, k) = 1/(8 pi) integral u(y) . T(y - p_k) . n(y) dS_y at points p_k OUTSIDE the
   !> closed surface (the wall nodes of the 3D tube), for the geometry of set_geometry.
   !> Near-surface treatment, as the capsule's single layer at the wall nodes: (1) the density
   !> at the node nearest p_k is subtracted, u -> u - u_c, since the double layer of a constant
   !> vanishes outside any closed surface (the polyhedron included): the integrand then
   !> vanishes where it peaks and a constant density gives exactly 0; (2) the vertex rule (one
   !> doublet per node) is replaced on the triangles whose centroid is nearer than near_radius,
   !> or than leaf_ratio of their diameters, by the 7-point rule subdivided until each piece
   !> lies leaf_ratio of its diameters from p_k. Per-step routine: no allocation.
   subroutine apply_outside(self, mesh, u, points, near_radius, w)
      class(double_layer_t), intent(inout) :: self
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: u(:, :), points(:, :), near_radius
      real(dp), intent(out) :: w(:, :)
      integer :: k, n, t, j, nearest
      real(dp) :: p(3), acc(3), corr(3), uc(3), xv(3, 3), gv(3, 3), c(3), diam, dist, d2, d2_min
      real(dp) :: lo(3), hi(3), reach
      n = self%n_nodes
      call set_density(self, u)
      lo = minval(self%x, dim=2)
      hi = maxval(self%x, dim=2)
      reach = 0.0_dp
      do t = 1, mesh%n_tri
         xv = self%x(:, mesh%tri(:, t))
         reach = max(reach, norm2(xv(:, 2) - xv(:, 1)), norm2(xv(:, 3) - xv(:, 2)), norm2(xv(:, 1) - xv(:, 3)))
      end do
      ! Points farther than `reach` from the surface's bounding box need no correction.
      reach = max(near_radius, leaf_ratio * reach) + reach
      lo = lo - reach
      hi = hi + reach
      !$omp parallel do default(none) shared(self, mesh, u, points, w, n, lo, hi, near_radius) &
      !$omp private(k, t, j, nearest, p, acc, corr, uc, xv, gv, c, diam, dist, d2, d2_min) schedule(dynamic, 16)
      do k = 1, size(points, 2)
         p = points(:, k)
         nearest = 1
         d2_min = huge(1.0_dp)
         do j = 1, n
            d2 = (self%xs(j) - p(1))**2 + (self%ys(j) - p(2))**2 + (self%zs(j) - p(3))**2
            if (d2 < d2_min) then
               d2_min = d2
               nearest = j
            end if
         end do
         uc = u(:, nearest)
         acc = 0.0_dp
         call add_doublets(n, self%xs, self%ys, self%zs, self%us, self%vs, self%ws, self%ax, self%ay, self%az, p, uc, &
                           1, n, acc)
         corr = 0.0_dp
         if (all(p > lo) .and. all(p < hi)) then
            do t = 1, mesh%n_tri
               xv = self%x(:, mesh%tri(:, t))
               c = (xv(:, 1) + xv(:, 2) + xv(:, 3)) / 3.0_dp
               diam = max(norm2(xv(:, 2) - xv(:, 1)), norm2(xv(:, 3) - xv(:, 2)), norm2(xv(:, 1) - xv(:, 3)))
               dist = norm2(p - c)
               if (dist >= near_radius .and. dist >= leaf_ratio * diam) cycle
               do j = 1, 3
                  gv(:, j) = u(:, mesh%tri(j, t)) - uc
               end do
               corr = corr + near_doublet_correction(self%near_rule, p, xv, gv, self%tri_normal(:, t), self%tri_area(t))
            end do
         end if
         w(:, k) = (acc + corr) / (8.0_dp * pi)
      end do
      !$omp end parallel do
   end subroutine apply_outside

   !> Double layer of one flat P1 triangle (corners xv, densities gv, unit normal nt, area) at
   !> an off-surface point p, the adaptive 7-point rule minus the triangle's share of the
   !> one-doublet-per-node sum (its vertex rule), without 1/(8 pi). Iterative subdivision on
   !> an explicit stack, as the wall's near_triangle_correction for the single layer.
   pure function near_doublet_correction(rule, p, xv, gv, nt, area) result(corr)
      type(quadrature_rule_t), intent(in) :: rule
      real(dp), intent(in) :: p(3), xv(3, 3), gv(3, 3), nt(3), area
      real(dp) :: corr(3)
      integer, parameter :: stack_size = 3 * max_depth + 1
      real(dp) :: sx(3, 3, stack_size), sg(3, 3, stack_size), c(3, 3), g(3, 3), mx(3, 3), mg(3, 3)
      real(dp) :: diam, wt
      integer :: depth(stack_size), top, d, q, m
      corr = 0.0_dp
      top = 1
      sx(:, :, 1) = xv
      sg(:, :, 1) = gv
      depth(1) = 0
      do while (top > 0)
         c = sx(:, :, top)
         g = sg(:, :, top)
         d = depth(top)
         top = top - 1
         diam = max(norm2(c(:, 2) - c(:, 1)), norm2(c(:, 3) - c(:, 2)), norm2(c(:, 1) - c(:, 3)))
         if (d >= max_depth .or. norm2(p - (c(:, 1) + c(:, 2) + c(:, 3)) / 3.0_dp) > leaf_ratio * diam) then
            wt = area / 4.0_dp**d
            do q = 1, size(rule%weight)
               corr = corr + (wt * rule%weight(q)) * doublet(matmul(c, rule%bary(:, q)) - p, matmul(g, rule%bary(:, q)), nt)
            end do
         else
            do m = 1, 3
               mx(:, m) = 0.5_dp * (c(:, m) + c(:, mod(m, 3) + 1))
               mg(:, m) = 0.5_dp * (g(:, m) + g(:, mod(m, 3) + 1))
            end do
            sx(:, :, top + 1) = reshape([c(:, 1), mx(:, 1), mx(:, 3)], [3, 3])
            sg(:, :, top + 1) = reshape([g(:, 1), mg(:, 1), mg(:, 3)], [3, 3])
            sx(:, :, top + 2) = reshape([mx(:, 1), c(:, 2), mx(:, 2)], [3, 3])
            sg(:, :, top + 2) = reshape([mg(:, 1), g(:, 2), mg(:, 2)], [3, 3])
            sx(:, :, top + 3) = reshape([mx(:, 3), mx(:, 2), c(:, 3)], [3, 3])
            sg(:, :, top + 3) = reshape([mg(:, 3), mg(:, 2), g(:, 3)], [3, 3])
            sx(:, :, top + 4) = mx
            sg(:, :, top + 4) = mg
            depth(top + 1:top + 4) = d + 1
            top = top + 4
         end if
      end do
      do m = 1, 3
         corr = corr - (area / 3.0_dp) * doublet(xv(:, m) - p, gv(:, m), nt)
      end do
   end function near_doublet_correction

   subroutine set_density(self, u)
      class(double_layer_t), intent(inout) :: self
      real(dp), intent(in) :: u(:, :)
      integer :: n
      n = self%n_nodes
      self%us = u(1, 1:n)
      self%vs = u(2, 1:n)
      self%ws = u(3, 1:n)
   end subroutine set_density

   !> s = 1: subtracted form, w_i = 1/(8 pi) integral (u - u_i) . T . n dS - u_i/2;
   !> s = 0: raw quadrature of the PV integral, w_i = 1/(8 pi) sum u . T . n (for the identity).
   subroutine doublet_sums(dl, mesh, u, s, w)
      type(double_layer_t), intent(in) :: dl
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: u(:, :), s
      real(dp), intent(out) :: w(:, :)
      integer :: i, n
      real(dp) :: acc(3), corr(3), ut(3)
      n = dl%n_nodes
      !$omp parallel do default(none) shared(dl, mesh, u, s, w, n) private(i, acc, corr, ut) schedule(static)
      do i = 1, n
         acc = 0.0_dp
         ut = s * u(:, i)
         call add_doublets(n, dl%xs, dl%ys, dl%zs, dl%us, dl%vs, dl%ws, dl%ax, dl%ay, dl%az, dl%x(:, i), ut, &
                           1, i - 1, acc)
         call add_doublets(n, dl%xs, dl%ys, dl%zs, dl%us, dl%vs, dl%ws, dl%ax, dl%ay, dl%az, dl%x(:, i), ut, &
                           i + 1, n, acc)
         call near_correction(dl, mesh, u, ut, i, corr)
         w(:, i) = (acc + corr) / (8.0_dp * pi) - 0.5_dp * ut
      end do
      !$omp end parallel do
   end subroutine doublet_sums

   !> Hot loop: doublets j = j1..j2 (density u_j - ut, area vector a_j) at target xt.
   pure subroutine add_doublets(n, xs, ys, zs, us, vs, ws, ax, ay, az, xt, ut, j1, j2, acc)
      integer, intent(in) :: n, j1, j2
      real(dp), intent(in) :: xs(n), ys(n), zs(n), us(n), vs(n), ws(n), ax(n), ay(n), az(n), xt(3), ut(3)
      real(dp), intent(inout) :: acc(3)
      integer :: j
      real(dp) :: dx, dy, dz, rinv2, c, sx, sy, sz
      sx = 0.0_dp
      sy = 0.0_dp
      sz = 0.0_dp
      !$omp simd reduction(+:sx, sy, sz) private(dx, dy, dz, rinv2, c)
      do j = j1, j2
         dx = xs(j) - xt(1)
         dy = ys(j) - xt(2)
         dz = zs(j) - xt(3)
         rinv2 = 1.0_dp / (dx * dx + dy * dy + dz * dz)
         c = -6.0_dp * ((us(j) - ut(1)) * dx + (vs(j) - ut(2)) * dy + (ws(j) - ut(3)) * dz) &
             * (dx * ax(j) + dy * ay(j) + dz * az(j)) * (rinv2 * rinv2 * sqrt(rinv2))
         sx = sx + c * dx
         sy = sy + c * dy
         sz = sz + c * dz
      end do
      acc(1) = acc(1) + sx
      acc(2) = acc(2) + sy
      acc(3) = acc(3) + sz
   end subroutine add_doublets

   !> Accurate integral minus vertex-rule contribution over the correction triangles of node i.
   !> Touching triangles contribute nothing either way (flat, containing x_i).
   pure subroutine near_correction(dl, mesh, u, ut, i, corr)
      type(double_layer_t), intent(in) :: dl
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: u(:, :), ut(3)
      integer, intent(in) :: i
      real(dp), intent(out) :: corr(3)
      integer :: p, t, m, q, v(3)
      real(dp) :: xv(3, 3), uv(3, 3), nt(3), area, b(3), acc(3)
      corr = 0.0_dp
      do p = dl%corr_start(i), dl%corr_start(i + 1) - 1
         if (dl%corr_vertex(p) > 0) cycle
         t = dl%corr_tri(p)
         v = mesh%tri(:, t)
         area = dl%tri_area(t)
         nt = dl%tri_normal(:, t)
         do m = 1, 3
            xv(:, m) = dl%x(:, v(m))
            uv(:, m) = u(:, v(m))
            corr = corr - (area / 3.0_dp) * doublet(xv(:, m) - dl%x(:, i), uv(:, m) - ut, nt)
         end do
         acc = 0.0_dp
         do q = 1, size(dl%near_rule%weight)
            b = dl%near_rule%bary(:, q)
            acc = acc + dl%near_rule%weight(q) * doublet(matmul(xv, b) - dl%x(:, i), matmul(uv, b) - ut, nt)
         end do
         corr = corr + area * acc
      end do
   end subroutine near_correction

   !> d . T(r) . n = -6 (d . r)(r . n) r / |r|**5.
   pure function doublet(r, d, nv) result(w)
      real(dp), intent(in) :: r(3), d(3), nv(3)
      real(dp) :: w(3), r2
      r2 = dot_product(r, r)
      w = (-6.0_dp * dot_product(d, r) * dot_product(r, nv) / (r2 * r2 * sqrt(r2))) * r
   end function doublet

end module stokes_double_layer
