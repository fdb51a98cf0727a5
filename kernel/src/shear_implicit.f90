!> The linear algebra of the linearly implicit (Rosenbrock) steps of the 3D capsule in shear
!> (capsule_dynamics, --integrator implicit): the velocity Jacobian
!>     J = 2/(1+lambda) (grad v_inf + (1/Ca) M(x) K(x))
!> and the LU of I - gamma dt J. At lambda /= 1 the velocity also carries the double layer of
!> the interface equation (interface_equation); it is left out of J: on the membrane waves of
!> length h that make the explicit step stiff it vanishes (stokes_double_layer), so their
!> relaxation rates are the single layer's times 2/(1+lambda).
!>   M: the single-layer matrix, nodal force density -> velocity, with the quadrature of
!>      stokes_single_layer (vertex rule far, Duffy and 7-point corrections near), so that
!>      M f is single_layer_t%velocity's u to round-off.
!>   K = df/dx: the nodal load density's derivative, sparse because a node's load depends only
!>      on the nodes within `radius` edges (1: elastic law and node area; 2: with bending, whose
!>      energy at a node reads its ring of dihedral angles). The caller fills it by forward
!>      differences over a colouring of the nodes: nodes more than 2 radius edges apart never
!>      load a common node, so one load evaluation per colour and direction moves them all.
!> Neglected: dM/dx f (the kernel's change with the geometry) and the volume-flux correction.
!> They only change the path of the Rosenbrock-W steps, not their order or the steady state;
!> the stiffness of the explicit step is in K (membrane waves of length h relax at ~ 1/(Ca h)).
module shear_implicit
   use capsim_kinds, only: dp, pi
   use lapack_interfaces, only: dgetrf, dgetrs
   use sphere_mesh, only: surface_mesh_t
   use stokes_single_layer, only: single_layer_t, stokeslet_block
   use triangle_quadrature, only: quadrature_rule_t
   implicit none
   private
   public :: load_stencil_t, single_layer_matrix, stencil_product, add_shear_gradient, step_matrix_lu, step_solve

   !> Which nodes load which: per node j (CSR), the nodes m within `radius` edges and the block
   !> d f(m) / d x(j) (3, 3); and a colouring of the nodes for the finite differences.
   type :: load_stencil_t
      integer :: radius = 1, n_colours = 0
      integer, allocatable :: colour(:)
      integer, allocatable :: start(:), node(:)
      real(dp), allocatable :: block(:, :, :)
   contains
      procedure :: init => stencil_init
   end type load_stencil_t


contains

   !> Stencils of the given radius and a greedy colouring in which nodes of one colour are
   !> more than 2 radius edges apart (their stencils are disjoint).
   subroutine stencil_init(self, mesh, radius)
      class(load_stencil_t), intent(inout) :: self
      type(surface_mesh_t), intent(in) :: mesh
      integer, intent(in) :: radius
      integer, allocatable :: mark(:), list(:), used(:)
      integer :: n, j, m, total, pass, q

      n = mesh%n_nodes
      self%radius = radius
      allocate (mark(n), list(n), used(n), self%colour(n), self%start(n + 1))
      mark = 0
      do pass = 1, 2
         total = 0
         do j = 1, n
            call ball(mesh, j, radius, mark, list, m)
            if (pass == 2) then
               self%start(j) = total + 1
               self%node(total + 1:total + m) = list(1:m)
            end if
            total = total + m
         end do
         if (pass == 1) allocate (self%node(total), self%block(3, 3, total))
      end do
      self%start(n + 1) = total + 1
      self%colour = 0
      used = 0
      self%n_colours = 0
      do j = 1, n
         call ball(mesh, j, 2 * radius, mark, list, m)
         do q = 1, m
            if (self%colour(list(q)) > 0) used(self%colour(list(q))) = j
         end do
         do q = 1, n
            if (used(q) /= j) exit
         end do
         self%colour(j) = q
         self%n_colours = max(self%n_colours, q)
      end do
   end subroutine stencil_init

   !> Nodes within r edges of node i (i first) in list(1:m); `mark` is scratch (0 on entry
   !> and exit).
   subroutine ball(mesh, i, r, mark, list, m)
      type(surface_mesh_t), intent(in) :: mesh
      integer, intent(in) :: i, r
      integer, intent(inout) :: mark(:)
      integer, intent(out) :: list(:), m
      integer :: layer, first, last, q, p, v, k, l
      m = 1
      list(1) = i
      mark(i) = 1
      first = 1
      do layer = 1, r
         last = m
         do q = first, last
            k = list(q)
            do p = mesh%node_tri_start(k), mesh%node_tri_start(k + 1) - 1
               do v = 1, 3
                  l = mesh%tri(v, mesh%node_tri(p))
                  if (mark(l) == 0) then
                     mark(l) = 1
                     m = m + 1
                     list(m) = l
                  end if
               end do
            end do
         end do
         first = last + 1
      end do
      mark(list(1:m)) = 0
   end subroutine ball

   !> mat (3n, 3n): u = mat f is single_layer_t%velocity (mu = 1) for nodal densities f, row
   !> 3(i-1)+a the a-th velocity component at node i (the layout of x(3, n) in memory).
   subroutine single_layer_matrix(sl, mesh, x, tri_area, node_area, mat)
      type(single_layer_t), intent(in) :: sl
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :), tri_area(:), node_area(:)
      real(dp), intent(out) :: mat(:, :)
      real(dp), parameter :: c = 1.0_dp / (8.0_dp * pi)
      integer :: i, j, p, t, corner, m, q, v(3), ri, cm
      real(dp) :: area, y(3), w
      type(quadrature_rule_t) :: rule

      !$omp parallel do default(none) shared(sl, mesh, x, tri_area, node_area, mat) &
      !$omp private(i, j, p, t, corner, m, q, v, ri, cm, area, y, w, rule) schedule(static)
      do i = 1, mesh%n_nodes
         ri = 3 * (i - 1)
         do j = 1, mesh%n_nodes
            if (j == i) then
               mat(ri + 1:ri + 3, 3 * j - 2:3 * j) = 0.0_dp
            else
               mat(ri + 1:ri + 3, 3 * j - 2:3 * j) = (c * node_area(j)) * stokeslet_block(x(:, i) - x(:, j))
            end if
         end do
         ! The correction triangles: their vertex-rule terms out, their accurate rule in.
         do p = sl%corr_start(i), sl%corr_start(i + 1) - 1
            t = sl%corr_tri(p)
            corner = sl%corr_vertex(p)
            v = mesh%tri(:, t)
            area = tri_area(t)
            do m = 1, 3
               cm = 3 * (v(m) - 1)
               if (v(m) /= i) mat(ri + 1:ri + 3, cm + 1:cm + 3) = mat(ri + 1:ri + 3, cm + 1:cm + 3) &
                                                                 - (c * area / 3.0_dp) * stokeslet_block(x(:, i) - x(:, v(m)))
            end do
            if (corner > 0) then
               rule = sl%duffy(corner)
            else if (sl%near_levels >= 0) then
               rule = sl%near_rule
            else
               cycle
            end if
            do q = 1, size(rule%weight)
               y = rule%bary(1, q) * x(:, v(1)) + rule%bary(2, q) * x(:, v(2)) + rule%bary(3, q) * x(:, v(3))
               do m = 1, 3
                  cm = 3 * (v(m) - 1)
                  w = c * area * rule%weight(q) * rule%bary(m, q)
                  mat(ri + 1:ri + 3, cm + 1:cm + 3) = mat(ri + 1:ri + 3, cm + 1:cm + 3) + w * stokeslet_block(x(:, i) - y)
               end do
            end do
         end do
      end do
      !$omp end parallel do
   end subroutine single_layer_matrix

   !> jac = scale * mat K, K the sparse load derivative of the stencil.
   subroutine stencil_product(mat, st, scale, jac)
      real(dp), intent(in) :: mat(:, :), scale
      type(load_stencil_t), intent(in) :: st
      real(dp), intent(out) :: jac(:, :)
      integer :: j, d, p, m, e, col
      !$omp parallel do default(none) shared(mat, st, scale, jac) private(j, d, p, m, e, col) schedule(static)
      do j = 1, size(st%colour)
         do d = 1, 3
            col = 3 * (j - 1) + d
            jac(:, col) = 0.0_dp
            do p = st%start(j), st%start(j + 1) - 1
               m = st%node(p)
               do e = 1, 3
                  jac(:, col) = jac(:, col) + (scale * st%block(e, d, p)) * mat(:, 3 * (m - 1) + e)
               end do
            end do
         end do
      end do
      !$omp end parallel do
   end subroutine stencil_product

   !> Adds scale times the gradient of the undisturbed shear v_inf = y e_z: d v_z / d y = 1.
   pure subroutine add_shear_gradient(jac, scale)
      real(dp), intent(inout) :: jac(:, :)
      real(dp), intent(in) :: scale
      integer :: i
      do i = 1, size(jac, 1) / 3
         jac(3 * i, 3 * i - 1) = jac(3 * i, 3 * i - 1) + scale
      end do
   end subroutine add_shear_gradient

   !> lu = LU of I - h jac (LAPACK dgetrf); info as dgetrf's.
   subroutine step_matrix_lu(jac, h, lu, pivot, info)
      real(dp), intent(in) :: jac(:, :), h
      real(dp), intent(out) :: lu(:, :)
      integer, intent(out) :: pivot(:), info
      integer :: j, n
      n = size(jac, 1)
      !$omp parallel do default(none) shared(jac, lu, h, n) private(j) schedule(static)
      do j = 1, n
         lu(:, j) = -h * jac(:, j)
         lu(j, j) = lu(j, j) + 1.0_dp
      end do
      !$omp end parallel do
      call dgetrf(n, n, lu, n, pivot, info)
   end subroutine step_matrix_lu

   !> b(3, n) <- (I - h J)^{-1} b with the LU of step_matrix_lu.
   subroutine step_solve(lu, pivot, b)
      real(dp), intent(in) :: lu(:, :)
      integer, intent(in) :: pivot(:)
      real(dp), intent(inout) :: b(:, :)
      integer :: n, info
      n = size(lu, 1)
      call dgetrs('N', n, 1, lu, n, pivot, b, n, info)
   end subroutine step_solve

end module shear_implicit
