!> The velocity operator of a centred capsule in Poiseuille flow in a circular tube,
!> axisymmetric (the fast path for tube databases): ring Stokeslets on the capsule meridian and
!> on the tube boundary (axisymmetric_wall), the viscosity ratio, and the velocity Jacobian by
!> incremental finite differences. The time integrators (axisymmetric_integrators), the steady
!> Newton solver (axisymmetric_steady) and the model the program runs (axisymmetric_tube) are
!> built on it.
!>
!> Non-dimensional: lengths in l (tube radius), velocities in V (mean velocity), time in
!> l/V, forces in G_s; Ca_s = mu V / G_s. The undisturbed flow is v_inf = 2 (1 - r**2) e_z.
!> The disturbance is represented by single layers on the membrane (known force density f,
!> P1 on the meridian) and on the tube boundary B (unknown disturbance traction g, constant
!> per wall element, collocated at element mid-points): the disturbance velocity vanishes on
!> B (no-slip on the wall, undisturbed Poiseuille on the end sections), so
!>     W g = -(membrane single layer at the wall collocation points),
!> with W factorised once (LAPACK), and the membrane moves with
!>     v = v_inf + 1/(8 pi Ca) [ membrane single layer + wall single layer ].
!> The capsule's centroid is kept at z = 0 in the middle of the tube (frame moving with it);
!> its velocity v_c is recorded.
!>
!> Viscosity ratio lambda /= 1 (inner/outer viscosity): the membrane velocity u then also
!> carries the capsule's double layer D (ring_stresslet; D[c] = -c/2 on the membrane, 0 at the
!> wall),
!>     (1 + lambda)/2 u - (1 - lambda) D[u] = v_inf + 1/(8 pi Ca) [membrane + wall single layers],
!>     W g = -(membrane single layer) - 8 pi Ca (1 - lambda) D[u]   at the wall collocation points
!> (the disturbance, now including the double layer, vanishes on B; D is smooth there). Eliminating
!> g = g_1 + g_lambda (g_1 the lambda = 1 traction) leaves, for the node velocities U (lab frame),
!>     [(1 + lambda)/2 I - (1 - lambda) (D_nodes - S_wall W**-1 D_wall)] U = U_1,
!> U_1 the lambda = 1 velocity (S_wall: the wall single layer at the nodes per unit traction).
!> The matrix is 2 (n + 1) square (130 at 64 elements) and depends on the shape only: it is
!> assembled and LU-factorised (LAPACK) at every velocity evaluation, which costs about what the
!> single layers do, while a GMRES would need the same double-layer entries (or as many
!> operator applications, each a full quadrature pass) for a system this small. Its spectrum lies
!> between min(1, lambda) and max(1, lambda) (D's eigenvalues are in [-1/2, 1/2]). A rigid
!> motion U = c e_z is its own image for every lambda (D[c] = -c/2 exactly, by the identity, and
!> D_wall[c] = 0): the steady shape, at rest in the capsule frame, solves the lambda = 1 equations.
!> lambda = 1 skips all of it (the same arithmetic as before, bit for bit).
module axisymmetric_operator
   use capsim_kinds, only: dp, pi
   use lapack_interfaces, only: dgeev, dgetrf, dgetrs
   use membrane_law, only: make_membrane_law
   use axisymmetric_bending, only: meridian_bending_t
   use axisymmetric_membrane, only: meridian_reference_t, meridian_forces, meridian_node_areas, &
                                    meridian_area_volume, meridian_volume_gradient
   use ring_stokeslet, only: segment_integral
   use ring_stresslet, only: double_layer_row, element_double_layer, nearest_node
   use run_options, only: run_options_t
   use capsule_model, only: capsule_model_t
   use axisymmetric_wall, only: tube_wall_elements, wall_element_velocity, wall_single_layer, factorise_wall, &
                                wall_left_null_vector, remove_wall_flux
   implicit none
   private
   public :: axisymmetric_operator_t, velocity_jacobian, largest_growth_rate, pack_dofs, unpack_dofs, &
             restore_volume_and_centre, jacobian_fd_step, rigid_fd_step

   !> Capsules this large start as a spheroid of this equatorial radius (they do not fit as
   !> spheres); their stresses are still measured from the spherical reference.
   real(dp), parameter :: predeform_from = 0.9_dp, predeform_radius = 0.8_dp
   !> Finite-difference step of the Jacobian, relative to a: the velocity carries quadrature
   !> noise of ~1e-9 V, and at a/l = 0.9 a step of 1e-7 l gave a Jacobian too noisy for Newton
   !> to converge, 1e-6 l stalled it at a residual of 5e-4 V, 1e-5 l converged to 1e-7 V; a
   !> nearly rigid capsule (Newton continuation from Ca_s = 1e-4) needs the smaller step
   !> rigid_fd_step (l): with 4e-6 l it did not converge at a/l = 0.4.
   real(dp), parameter :: jacobian_fd_step = 1.0e-5_dp, rigid_fd_step = 1.0e-6_dp

   !> Work arrays of velocity_jacobian (see jacobian_with_work), allocated at its first call.
   type :: jacobian_work_t
      real(dp), allocatable :: density0(:, :), raw0(:, :), b0(:), g0(:), influence(:, :), u0(:, :), packed0(:)
      real(dp), allocatable :: element_at_wall(:, :, :), element_at_node(:, :, :)
      !> lambda /= 1: the node velocities U (lab frame) at the unperturbed shape, each element's
      !> part of D[U] at every node and wall point, the wall points' reference nodes, and
      !> W**-1 D_wall U (see lambda_column).
      real(dp), allocatable :: u_lambda(:, :), dl_at_node(:, :, :), dl_at_wall(:, :, :), wall_dl_u(:)
      integer, allocatable :: wall_ref(:)
   end type jacobian_work_t


   !> The capsule's meridian, its membrane, the tube wall and the viscosity ratio, with the
   !> velocity they give; the model (axisymmetric_tube) adds how it is advanced.
   type, abstract, extends(capsule_model_t) :: axisymmetric_operator_t
      type(meridian_reference_t) :: ref
      !> Bending stiffness (--kb); set up only when k_b > 0.
      type(meridian_bending_t) :: bending
      real(dp) :: ca = 0, a = 0, h_min = 0, energy = 0, v_c = 0, volume0 = 0, tube_length = 10
      logical :: volume_correction = .true.
      !> Largest time step (l/V); largest_growth_rate falls back on its inverse.
      real(dp) :: dt_max = 0
      !> Work of largest_growth_rate (LAPACK dgeev).
      real(dp), allocatable :: eig_re(:), eig_im(:), eig_work(:)
      type(jacobian_work_t) :: jacobian_work
      real(dp), allocatable :: rz_ref(:, :)
      !> Wall elements: end points and mid-points (r, z); factorised wall matrix.
      integer :: n_wall = 0
      real(dp), allocatable :: wall_a(:, :), wall_b(:, :), wall_mid(:, :)
      real(dp), allocatable :: wall_lu(:, :), wall_traction(:)
      integer, allocatable :: wall_pivot(:)
      !> Viscosity ratio (inner/outer) and, for lambda /= 1, the LU of the boundary-integral
      !> matrix of the node velocities and W**-1 D_wall, both at the shape last factorised.
      real(dp) :: lambda = 1
      real(dp), allocatable :: lambda_lu(:, :), wall_dl(:, :), wall_null(:)
      integer, allocatable :: lambda_pivot(:)
      ! Work arrays (allocated once).
      real(dp), allocatable :: rz_pred(:, :), u0(:, :), u1(:, :), force(:, :), density(:, :), node_area(:), grad(:, :)
      real(dp), allocatable :: dofs(:), dofs_trial(:), res_trial(:)
      !> The last shape `velocity` evaluated and its result, while the state that call left
      !> (v_c, energy, density, wall traction, lambda's factorisation) is still that shape's:
      !> a history row after an implicit step, whose last evaluation was at the accepted
      !> shape, needs no second one (it was 22 % of a time-stepped case's CPU time).
      real(dp), allocatable :: rz_evaluated(:, :), u_evaluated(:, :)
      real(dp) :: ca_evaluated = 0
      logical :: evaluated_state_current = .false.
   contains
      procedure :: init_operator
      procedure :: velocity
      procedure :: velocity_here
   end type axisymmetric_operator_t

contains

   !> The meridian (sphere of radius a/l, or a spheroid for large capsules), the membrane law,
   !> the tube wall and its LU, and the work arrays of the velocity and of its Jacobian.
   subroutine init_operator(self, opts, stat, errmsg)
      class(axisymmetric_operator_t), intent(inout) :: self
      type(run_options_t), intent(in) :: opts
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: n, k, m
      real(dp) :: theta, c_axis, area

      call make_membrane_law(trim(opts%law), opts%nu_s, opts%c, self%law, stat, errmsg)
      if (stat /= 0) return
      self%a = opts%a_over_l
      self%ca = opts%ca
      self%evaluated_state_current = .false.
      self%volume_correction = opts%volume_correction
      n = opts%n_meridian + 1
      allocate (self%rz_ref(2, n), self%start_positions(2, n))
      c_axis = self%a
      if (self%a >= predeform_from) c_axis = self%a**3 / predeform_radius**2
      do k = 1, n
         theta = pi * (k - 1) / (n - 1)
         self%rz_ref(:, k) = self%a * [sin(theta), cos(theta)]
         if (self%a >= predeform_from) then
            self%start_positions(:, k) = [predeform_radius * sin(theta), c_axis * cos(theta)]
         else
            self%start_positions(:, k) = self%rz_ref(:, k)
         end if
      end do
      self%rz_ref(1, [1, n]) = 0.0_dp
      self%start_positions(1, [1, n]) = 0.0_dp
      self%positions = self%start_positions
      ! Strains are measured from the stress-free sphere of radius a/(1 + alpha).
      call self%ref%init(self%rz_ref / (1.0_dp + opts%prestress))
      self%h_min = minval(self%ref%length0) * (1.0_dp + opts%prestress)
      ! Bending from the sphere at rest; K_B = k_b G_s a**2 is k_b (a/l)**2 in units G_s l**2.
      if (opts%kb > 0.0_dp) call self%bending%init(self%rz_ref, opts%kb * self%a**2)
      allocate (self%rz_pred(2, n), self%u0(2, n), self%u1(2, n), self%force(2, n), self%density(2, n))
      allocate (self%node_area(n), self%grad(2, n))
      ! The last evaluation's shape and velocity (velocity_here), here so that the first
      ! `velocity` of the time loop does not allocate them.
      allocate (self%rz_evaluated(2, n), self%u_evaluated(2, n))

      self%tube_length = opts%tube_length
      call tube_wall_elements(0.5_dp * self%tube_length, self%wall_a, self%wall_b)
      self%n_wall = size(self%wall_a, 2)
      self%wall_mid = 0.5_dp * (self%wall_a + self%wall_b)
      allocate (self%wall_traction(2 * self%n_wall))
      call factorise_wall(self%wall_a, self%wall_b, self%wall_mid, self%wall_lu, self%wall_pivot, stat, errmsg)
      if (stat /= 0) return
      self%lambda = opts%lambda
      if (self%lambda /= 1.0_dp) then
         allocate (self%lambda_lu(2 * n, 2 * n), self%lambda_pivot(2 * n), self%wall_dl(2 * self%n_wall, 2 * n))
         allocate (self%wall_null(2 * self%n_wall))
         call wall_left_null_vector(self%wall_lu, self%wall_pivot, self%wall_null)
      end if
      m = 2 * n - 2
      allocate (self%dofs(m), self%dofs_trial(m), self%res_trial(m))
      allocate (self%eig_re(m), self%eig_im(m), self%eig_work(8 * m))
      call meridian_area_volume(self%start_positions, area, self%volume0)
   end subroutine init_operator

   !> Membrane velocity (r, z components) at meridian rz in the frame of the capsule; sets v_c.
   subroutine velocity(self, rz, u)
      class(axisymmetric_operator_t), intent(inout) :: self
      real(dp), intent(in) :: rz(:, :)
      real(dp), intent(out) :: u(:, :)
      integer :: n, i, k, info
      real(dp) :: raw(2, size(rz, 2)), rhs(2 * self%n_wall, 1)

      n = size(rz, 2)
      call membrane_density(self, rz, self%density, self%energy)
      ! Membrane single layer at the wall collocation points, then the wall traction.
      !$omp parallel do default(none) shared(self, rz, rhs, n) private(i) schedule(static)
      do i = 1, self%n_wall
         rhs(2 * i - 1:2 * i, 1) = -membrane_single_layer(rz, self%density, self%wall_mid(:, i), 1, n - 1, 0)
      end do
      !$omp end parallel do
      call dgetrs('N', 2 * self%n_wall, 1, self%wall_lu, 2 * self%n_wall, self%wall_pivot, rhs, 2 * self%n_wall, info)
      self%wall_traction = rhs(:, 1)
      !$omp parallel do default(none) shared(self, rz, raw, n) private(k) schedule(static)
      do k = 1, n
         raw(:, k) = membrane_single_layer(rz, self%density, rz(:, k), 1, n - 1, k) + &
                     wall_single_layer(self%wall_a, self%wall_b, self%wall_traction, rz(:, k))
      end do
      !$omp end parallel do
      if (self%lambda /= 1.0_dp) then
         block
            real(dp) :: u_lab(2 * n)
            call factorise_viscosity_ratio(self, rz)
            call apply_viscosity_ratio(self, rz, raw, u_lab)
            self%wall_traction = self%wall_traction - 8.0_dp * pi * self%ca * (1.0_dp - self%lambda) * &
                                 matmul(self%wall_dl, u_lab)
         end block
      end if
      call finish_velocity(self, rz, raw, u, self%v_c)
      self%rz_evaluated = rz
      self%u_evaluated = u
      self%ca_evaluated = self%ca
      self%evaluated_state_current = .true.
   end subroutine velocity

   !> velocity at rz, reusing the last evaluation when it was at this very shape and Ca_s (bit
   !> for bit) and nothing has overwritten its state since: the same u, v_c and energy to the
   !> last bit. (The law, tube and lambda are fixed after init_operator.)
   subroutine velocity_here(self, rz, u)
      class(axisymmetric_operator_t), intent(inout) :: self
      real(dp), intent(in) :: rz(:, :)
      real(dp), intent(out) :: u(:, :)
      if (self%evaluated_state_current .and. self%ca_evaluated == self%ca) then
         if (all(shape(self%rz_evaluated) == shape(rz))) then
            if (all(self%rz_evaluated == rz)) then
               u = self%u_evaluated
               return
            end if
         end if
      end if
      call self%velocity(rz, u)
   end subroutine velocity_here

   !> The boundary-integral matrix of lambda /= 1 at shape rz (see the module header), factorised.
   subroutine factorise_viscosity_ratio(self, rz)
      class(axisymmetric_operator_t), intent(inout) :: self
      real(dp), intent(in) :: rz(:, :)
      real(dp) :: d_nodes(2 * size(rz, 2), 2 * size(rz, 2)), s_wall(2 * size(rz, 2), 2 * self%n_wall)
      integer :: n, nw, i, k, info
      n = size(rz, 2)
      nw = self%n_wall
      !$omp parallel do default(none) shared(self, rz, d_nodes, s_wall, n, nw) private(i, k) schedule(dynamic)
      do k = 1, n
         call double_layer_row(rz, rz(:, k), k, .false., d_nodes(2 * k - 1:2 * k, :))
         do i = 1, nw
            s_wall(2 * k - 1:2 * k, 2 * i - 1) = wall_element_velocity(self%wall_a(:, i), self%wall_b(:, i), &
                                                                       [1.0_dp, 0.0_dp], rz(1, k), rz(2, k), .false.)
            s_wall(2 * k - 1:2 * k, 2 * i) = wall_element_velocity(self%wall_a(:, i), self%wall_b(:, i), &
                                                                   [0.0_dp, 1.0_dp], rz(1, k), rz(2, k), .false.)
         end do
      end do
      !$omp end parallel do
      !$omp parallel do default(none) shared(self, rz, nw) private(i) schedule(dynamic)
      do i = 1, nw
         call double_layer_row(rz, self%wall_mid(:, i), 0, .false., self%wall_dl(2 * i - 1:2 * i, :))
      end do
      !$omp end parallel do
      call remove_wall_flux(self%wall_null, self%wall_dl)
      call dgetrs('N', 2 * nw, 2 * n, self%wall_lu, 2 * nw, self%wall_pivot, self%wall_dl, 2 * nw, info)
      self%lambda_lu = -(1.0_dp - self%lambda) * (d_nodes - matmul(s_wall, self%wall_dl))
      do k = 1, 2 * n
         self%lambda_lu(k, k) = self%lambda_lu(k, k) + 0.5_dp * (1.0_dp + self%lambda)
      end do
      ! Nonsingular for every lambda > 0 (spectrum in [min(1, lambda), max(1, lambda)]).
      call dgetrf(2 * n, 2 * n, self%lambda_lu, 2 * n, self%lambda_pivot, info)
   end subroutine factorise_viscosity_ratio

   !> From the lambda = 1 single-layer sums raw (at shape rz) to those that give the lambda
   !> velocity through finish_velocity, with the matrix last factorised; u_lab: the node
   !> velocities (lab frame) solved for. The lambda = 1 velocity U_1 gets finish_velocity's
   !> axis and volume corrections before the solve: a steady shape has U_1 = v_c e_z + (the
   !> discretisation's flux error, which the correction removes), so that U_1 corrected is a
   !> rigid translation, which A maps onto itself: the steady shapes of every lambda are then
   !> those of lambda = 1 to the solver tolerance (applied after the solve only, they differed by
   !> the flux error, 1e-4 of L_z at 64 elements).
   subroutine apply_viscosity_ratio(self, rz, raw, u_lab)
      class(axisymmetric_operator_t), intent(in) :: self
      real(dp), intent(in) :: rz(:, :)
      real(dp), intent(inout) :: raw(:, :)
      real(dp), intent(out) :: u_lab(:)
      real(dp) :: scale, rhs(size(u_lab), 1)
      integer :: k, n, info
      n = size(rz, 2)
      scale = 8.0_dp * pi * self%ca
      block
         real(dp) :: u1(2, size(rz, 2))
         do k = 1, n
            u1(:, k) = raw(:, k) / scale + [0.0_dp, 2.0_dp * (1.0_dp - rz(1, k)**2)]
         end do
         call axis_and_volume_correction(self, rz, u1)
         rhs(:, 1) = reshape(u1, [2 * n])
      end block
      call dgetrs('N', 2 * n, 1, self%lambda_lu, 2 * n, self%lambda_pivot, rhs, 2 * n, info)
      u_lab = rhs(:, 1)
      do k = 1, n
         raw(:, k) = scale * (u_lab(2 * k - 1:2 * k) - [0.0_dp, 2.0_dp * (1.0_dp - rz(1, k)**2)])
      end do
   end subroutine apply_viscosity_ratio

   !> finish_velocity for the lambda of the model, with the matrix last factorised at rz.
   subroutine finish_lambda_velocity(self, rz, raw, u, v_c)
      class(axisymmetric_operator_t), intent(in) :: self
      real(dp), intent(in) :: rz(:, :), raw(:, :)
      real(dp), intent(out) :: u(:, :), v_c
      real(dp) :: raw_lambda(2, size(rz, 2)), u_lab(2 * size(rz, 2))
      if (self%lambda == 1.0_dp) then
         call finish_velocity(self, rz, raw, u, v_c)
         return
      end if
      raw_lambda = raw
      call apply_viscosity_ratio(self, rz, raw_lambda, u_lab)
      call finish_velocity(self, rz, raw_lambda, u, v_c)
   end subroutine finish_lambda_velocity

   !> lambda /= 1, before the Jacobian's columns at shape rz: the matrix A there, the node
   !> velocities U it gives (from the lambda = 1 velocity, as `velocity` does), and each
   !> element's part of D[U] at every node and wall point (see lambda_column).
   subroutine prepare_lambda_columns(self, rz)
      class(axisymmetric_operator_t), intent(inout) :: self
      real(dp), intent(in) :: rz(:, :)
      real(dp) :: u(2, size(rz, 2)), raw(2, size(rz, 2)), u_lab(2 * size(rz, 2)), energy
      integer :: n, nw, e, k, i
      n = size(rz, 2)
      nw = self%n_wall
      associate (w => self%jacobian_work)
         if (.not. allocated(w%u_lambda)) then
            allocate (w%u_lambda(2, n), w%dl_at_node(2, n, n - 1), w%dl_at_wall(2, nw, n - 1), w%wall_dl_u(2 * nw))
            allocate (w%wall_ref(nw))
         end if
      end associate
      ! The lambda = 1 single-layer sums at rz (as in `velocity`); they overwrite the state
      ! of the last `velocity` call.
      self%evaluated_state_current = .false.
      call membrane_density(self, rz, self%density, energy)
      block
         real(dp) :: rhs(2 * nw, 1)
         integer :: info
         !$omp parallel do default(none) shared(self, rz, rhs, n, nw) private(i) schedule(static)
         do i = 1, nw
            rhs(2 * i - 1:2 * i, 1) = -membrane_single_layer(rz, self%density, self%wall_mid(:, i), 1, n - 1, 0)
         end do
         !$omp end parallel do
         call dgetrs('N', 2 * nw, 1, self%wall_lu, 2 * nw, self%wall_pivot, rhs, 2 * nw, info)
         !$omp parallel do default(none) shared(self, rz, raw, rhs, n) private(k) schedule(static)
         do k = 1, n
            raw(:, k) = membrane_single_layer(rz, self%density, rz(:, k), 1, n - 1, k) + &
                        wall_single_layer(self%wall_a, self%wall_b, rhs(:, 1), rz(:, k))
         end do
         !$omp end parallel do
      end block
      call factorise_viscosity_ratio(self, rz)
      call apply_viscosity_ratio(self, rz, raw, u_lab)
      u = reshape(u_lab, [2, n])
      associate (w => self%jacobian_work)
         w%u_lambda = u
         w%wall_dl_u = matmul(self%wall_dl, u_lab)
         do i = 1, nw
            w%wall_ref(i) = nearest_node(rz, self%wall_mid(:, i))
         end do
      end associate
      !$omp parallel do default(none) shared(self, rz, u, n, nw) private(e, k, i) schedule(dynamic)
      do e = 1, n - 1
         do k = 1, n
            self%jacobian_work%dl_at_node(:, k, e) = element_double_layer(rz, u, rz(:, k), e, k, k)
         end do
         do i = 1, nw
            self%jacobian_work%dl_at_wall(:, i, e) = element_double_layer(rz, u, self%wall_mid(:, i), e, 0, &
                                                                          self%jacobian_work%wall_ref(i))
         end do
      end do
      !$omp end parallel do
   end subroutine prepare_lambda_columns

   !> A Jacobian column's lambda velocity: node `node` moved, rz -> rz1, raw the lambda = 1
   !> single-layer sums at rz1, turned into lambda sums. To first order in the step,
   !>    U(rz1) = A(rz1)**-1 U_1(rz1) = A**-1 [U_1(rz1) - (A(rz1) - A) U],
   !> A and U at rz, and (A(rz1) - A) U needs the double layer of the fixed density U only where
   !> the move changes it: the two elements at the node (at every node and wall point), the
   !> moved node's own principal value, and the wall single layer at the moved node.
   subroutine lambda_column(self, rz, rz1, node, raw)
      class(axisymmetric_operator_t), intent(in) :: self
      real(dp), intent(in) :: rz(:, :), rz1(:, :)
      integer, intent(in) :: node
      real(dp), intent(inout) :: raw(:, :)
      real(dp) :: d_change(2, size(rz, 2)), wall_change(2 * self%n_wall, 1), du(2, size(rz, 2)), scale
      real(dp) :: rhs(2 * size(rz, 2), 1)
      integer :: n, nw, e, k, i, first, last, info
      n = size(rz, 2)
      nw = self%n_wall
      associate (w => self%jacobian_work)
         first = max(1, node - 1)
         last = min(n - 1, node)
         ! (D_nodes(rz1) - D_nodes) U; the constant term -U_k/2 does not move.
         d_change = 0.0_dp
         do k = 1, n
            if (k == node) then
               do e = 1, n - 1
                  d_change(:, k) = d_change(:, k) + element_double_layer(rz1, w%u_lambda, rz1(:, k), e, k, k) &
                                   - w%dl_at_node(:, k, e)
               end do
            else
               do e = first, last
                  d_change(:, k) = d_change(:, k) + element_double_layer(rz1, w%u_lambda, rz1(:, k), e, k, k) &
                                   - w%dl_at_node(:, k, e)
               end do
            end if
         end do
         ! W**-1 (D_wall(rz1) - D_wall) U, with the reference nodes of rz.
         do i = 1, nw
            wall_change(2 * i - 1:2 * i, 1) = 0.0_dp
            do e = first, last
               wall_change(2 * i - 1:2 * i, 1) = wall_change(2 * i - 1:2 * i, 1) &
                                                 + element_double_layer(rz1, w%u_lambda, self%wall_mid(:, i), e, 0, &
                                                                        w%wall_ref(i)) - w%dl_at_wall(:, i, e)
            end do
         end do
         call remove_wall_flux(self%wall_null, wall_change)
         call dgetrs('N', 2 * nw, 1, self%wall_lu, 2 * nw, self%wall_pivot, wall_change, 2 * nw, info)
         ! S_wall(rz1) W**-1 D_wall(rz1) U - S_wall W**-1 D_wall U at every node: the wall single
         ! layer of the traction change, plus, at the moved node, that of W**-1 D_wall U itself.
         do k = 1, n
            du(:, k) = wall_single_layer(self%wall_a, self%wall_b, wall_change(:, 1), rz1(:, k))
         end do
         du(:, node) = du(:, node) + wall_single_layer(self%wall_a, self%wall_b, w%wall_dl_u, rz1(:, node)) &
                       - wall_single_layer(self%wall_a, self%wall_b, w%wall_dl_u, rz(:, node))
         ! (A(rz1) - A) U = -(1 - lambda) [d_change - du].
         scale = 8.0_dp * pi * self%ca
         block
            real(dp) :: u1(2, size(rz, 2))
            do k = 1, n
               u1(:, k) = raw(:, k) / scale + [0.0_dp, 2.0_dp * (1.0_dp - rz1(1, k)**2)]
            end do
            call axis_and_volume_correction(self, rz1, u1)
            do k = 1, n
               rhs(2 * k - 1:2 * k, 1) = u1(:, k) + (1.0_dp - self%lambda) * (d_change(:, k) - du(:, k))
            end do
         end block
      end associate
      call dgetrs('N', 2 * n, 1, self%lambda_lu, 2 * n, self%lambda_pivot, rhs, 2 * n, info)
      do k = 1, n
         raw(:, k) = scale * (rhs(2 * k - 1:2 * k, 1) - [0.0_dp, 2.0_dp * (1.0_dp - rz1(1, k)**2)])
      end do
   end subroutine lambda_column

   !> Force density f = F/A on the meridian (F = -dE/dx, A the dual-cell areas).
   pure subroutine membrane_density(self, rz, density, energy)
      class(axisymmetric_operator_t), intent(in) :: self
      real(dp), intent(in) :: rz(:, :)
      real(dp), intent(out) :: density(:, :), energy
      real(dp) :: force(2, size(rz, 2)), area(size(rz, 2))
      integer :: k
      call meridian_forces(self%ref, self%law, rz, force, energy)
      if (self%bending%kb > 0.0_dp) call self%bending%add_forces(rz, force, energy)
      call meridian_node_areas(rz, area)
      do k = 1, size(rz, 2)
         density(:, k) = force(:, k) / area(k)
      end do
   end subroutine membrane_density

   !> Sum over membrane elements e1..e2 of the ring single layer (without 1/(8 pi)) at point x;
   !> `node` > 0 says that x is that meridian node (the log singularity sits at a segment end).
   pure function membrane_single_layer(rz, density, x, e1, e2, node) result(acc)
      real(dp), intent(in) :: rz(:, :), density(:, :), x(2)
      integer, intent(in) :: e1, e2, node
      real(dp) :: acc(2)
      integer :: e, end_flag
      acc = 0.0_dp
      do e = e1, e2
         end_flag = 0
         if (node == e) end_flag = 1
         if (node == e + 1) end_flag = 2
         acc = acc + segment_integral(x(1), x(2), rz(1, e), rz(2, e), rz(1, e + 1), rz(2, e + 1), &
                                      density(:, e), density(:, e + 1), end_flag)
      end do
   end function membrane_single_layer

   !> From the raw single-layer sums to the membrane velocity in the capsule frame: scale by
   !> 1/(8 pi Ca), add v_inf, keep the poles on the axis, remove the net flux (as in 3D),
   !> subtract the centroid velocity v_c.
   pure subroutine finish_velocity(self, rz, raw, u, v_c)
      class(axisymmetric_operator_t), intent(in) :: self
      real(dp), intent(in) :: rz(:, :), raw(:, :)
      real(dp), intent(out) :: u(:, :), v_c
      integer :: n, k
      n = size(rz, 2)
      do k = 1, n
         u(:, k) = raw(:, k) / (8.0_dp * pi * self%ca) + [0.0_dp, 2.0_dp * (1.0_dp - rz(1, k)**2)]
      end do
      call axis_and_volume_correction(self, rz, u)
      v_c = centroid_velocity(rz, u)
      u(2, :) = u(2, :) - v_c
   end subroutine finish_velocity

   !> Node velocities u (lab frame): poles kept on the axis, net flux removed (as in 3D).
   pure subroutine axis_and_volume_correction(self, rz, u)
      class(axisymmetric_operator_t), intent(in) :: self
      real(dp), intent(in) :: rz(:, :)
      real(dp), intent(inout) :: u(:, :)
      real(dp) :: grad(2, size(rz, 2)), flux, norm_sum
      integer :: n, k
      n = size(rz, 2)
      u(1, [1, n]) = 0.0_dp
      if (self%volume_correction) then
         call meridian_volume_gradient(rz, grad)
         grad(1, [1, n]) = 0.0_dp
         flux = sum(u * grad)
         norm_sum = sum(norm2(grad, dim=1))
         do k = 1, n
            u(:, k) = u(:, k) - (flux / norm_sum) * grad(:, k) / norm2(grad(:, k))
         end do
      end if
   end subroutine axis_and_volume_correction

   !> Forward-difference Jacobian of the packed velocity at rz, column by column, but with
   !> each column costing ~1/15 of a velocity evaluation: moving node k changes the force
   !> density only at nodes k-1..k+1, so only elements k-2..k+1 change their single layer
   !> (the difference is added to the stored sums), the wall traction follows from the
   !> factorised wall matrix, and the wall's single layer at the unmoved nodes is a stored
   !> matrix (wall traction -> node velocity) applied to it. Only the moved node's own sums
   !> are recomputed in full. Agrees with brute-force differences to the quadrature noise.
   !> lambda /= 1: see lambda_column (the same first-order differences, to the same noise).
   subroutine velocity_jacobian(self, rz, fd_step, jacobian)
      class(axisymmetric_operator_t), intent(inout) :: self
      real(dp), intent(in) :: rz(:, :), fd_step
      real(dp), intent(out) :: jacobian(:, :)
      integer :: n, nw
      n = size(rz, 2)
      nw = self%n_wall
      ! Work arrays kept by the model: the time loop refreshes the Jacobian every few steps.
      associate (w => self%jacobian_work)
         if (.not. allocated(w%density0)) then
            allocate (w%density0(2, n), w%raw0(2, n), w%b0(2 * nw), w%g0(2 * nw), w%influence(2 * n, 2 * nw))
            allocate (w%u0(2, n), w%packed0(2 * n - 2), w%element_at_wall(2, nw, n - 1), w%element_at_node(2, n, n - 1))
         end if
      end associate
      if (self%lambda /= 1.0_dp) call prepare_lambda_columns(self, rz)
      call jacobian_with_work(self, rz, fd_step, jacobian, self%jacobian_work%density0, self%jacobian_work%raw0, &
                              self%jacobian_work%b0, self%jacobian_work%g0, self%jacobian_work%influence, &
                              self%jacobian_work%u0, self%jacobian_work%packed0, self%jacobian_work%element_at_wall, &
                              self%jacobian_work%element_at_node)
   end subroutine velocity_jacobian

   !> velocity_jacobian's work, on arrays the caller keeps. element_at_wall/node: the single
   !> layer of each membrane element e at every wall point and node (a column moves one node,
   !> which changes four elements, six with bending; their old contributions are looked up there).
   subroutine jacobian_with_work(self, rz, fd_step, jacobian, density0, raw0, b0, g0, influence, u0, packed0, &
                                 element_at_wall, element_at_node)
      class(axisymmetric_operator_t), intent(in) :: self
      real(dp), intent(in) :: rz(:, :), fd_step
      real(dp), intent(out) :: jacobian(:, :)
      real(dp), intent(out) :: density0(:, :), raw0(:, :), b0(:), g0(:), influence(:, :), u0(:, :), packed0(:)
      real(dp), intent(out) :: element_at_wall(:, :, :), element_at_node(:, :, :)
      integer :: n, nw, i, k, j, m, comp, info, e
      real(dp) :: energy, v_c

      n = size(rz, 2)
      nw = self%n_wall
      m = 2 * n - 2
      call membrane_density(self, rz, density0, energy)
      !$omp parallel do default(none) shared(self, rz, density0, element_at_wall, element_at_node, n, nw) &
      !$omp private(i, k, e) schedule(static)
      do e = 1, n - 1
         do i = 1, nw
            element_at_wall(:, i, e) = membrane_single_layer(rz, density0, self%wall_mid(:, i), e, e, 0)
         end do
         do k = 1, n
            element_at_node(:, k, e) = membrane_single_layer(rz, density0, rz(:, k), e, e, k)
         end do
      end do
      !$omp end parallel do
      b0 = reshape(sum(element_at_wall, dim=3), [2 * nw])
      ! influence(2k-1:2k, 2i-1:2i): wall element i's single layer at node k per unit traction.
      !$omp parallel do default(none) shared(self, rz, influence, n, nw) private(i, k) schedule(static)
      do k = 1, n
         do i = 1, nw
            influence(2 * k - 1:2 * k, 2 * i - 1) = wall_element_velocity(self%wall_a(:, i), self%wall_b(:, i), &
                                                                          [1.0_dp, 0.0_dp], rz(1, k), rz(2, k), .false.)
            influence(2 * k - 1:2 * k, 2 * i) = wall_element_velocity(self%wall_a(:, i), self%wall_b(:, i), &
                                                                      [0.0_dp, 1.0_dp], rz(1, k), rz(2, k), .false.)
         end do
      end do
      !$omp end parallel do
      block
         real(dp) :: rhs(2 * nw, 1)
         rhs(:, 1) = -b0
         call dgetrs('N', 2 * nw, 1, self%wall_lu, 2 * nw, self%wall_pivot, rhs, 2 * nw, info)
         g0 = rhs(:, 1)
         raw0 = sum(element_at_node, dim=3)
         do k = 1, n
            raw0(:, k) = raw0(:, k) + matmul(influence(2 * k - 1:2 * k, :), g0)
         end do
      end block
      call finish_lambda_velocity(self, rz, raw0, u0, v_c)
      call pack_dofs(u0, packed0)

      !$omp parallel do default(none) shared(self, rz, density0, raw0, b0, g0, influence, packed0, jacobian, fd_step) &
      !$omp shared(element_at_wall, element_at_node, n, nw, m) private(j, k, comp) schedule(dynamic)
      do j = 1, m
         call dof_node(j, n, k, comp)
         call one_column(j, k, comp)
      end do
      !$omp end parallel do

   contains

      subroutine one_column(col, node, c)
         integer, intent(in) :: col, node, c
         real(dp) :: rz1(2, n), density1(2, n), raw1(2, n), u1(2, n), packed1(m), rhs(2 * nw, 1), e1
         real(dp) :: vc1, traction_change(2 * nw), wall_change(2 * n)
         integer :: first, last, q, info1, w
         rz1 = rz
         rz1(c, node) = rz(c, node) + fd_step
         call membrane_density(self, rz1, density1, e1)
         ! Bending couples a node's force to the nodes two away: one more element each side.
         first = max(1, node - 2 - merge(1, 0, self%bending%kb > 0.0_dp))
         last = min(n - 1, node + 1 + merge(1, 0, self%bending%kb > 0.0_dp))
         do w = 1, nw
            rhs(2 * w - 1:2 * w, 1) = -(b0(2 * w - 1:2 * w) &
                                        + membrane_single_layer(rz1, density1, self%wall_mid(:, w), first, last, 0) &
                                        - sum(element_at_wall(:, w, first:last), dim=2))
         end do
         call dgetrs('N', 2 * nw, 1, self%wall_lu, 2 * nw, self%wall_pivot, rhs, 2 * nw, info1)
         ! The wall traction's change, seen at every node at once (one product over the
         ! contiguous columns of influence, not a strided row pair per node).
         traction_change = rhs(:, 1) - g0
         wall_change = matmul(influence, traction_change)
         do q = 1, n
            if (q == node) then
               raw1(:, q) = membrane_single_layer(rz1, density1, rz1(:, q), 1, n - 1, q) + &
                            wall_single_layer(self%wall_a, self%wall_b, rhs(:, 1), rz1(:, q))
            else
               raw1(:, q) = raw0(:, q) + wall_change(2 * q - 1:2 * q) &
                            + membrane_single_layer(rz1, density1, rz1(:, q), first, last, q) &
                            - sum(element_at_node(:, q, first:last), dim=2)
            end if
         end do
         if (self%lambda /= 1.0_dp) call lambda_column(self, rz, rz1, node, raw1)
         call finish_velocity(self, rz1, raw1, u1, vc1)
         call pack_dofs(u1, packed1)
         jacobian(:, col) = (packed1 - packed0) / fd_step
      end subroutine one_column

   end subroutine jacobian_with_work

   !> Node and component (1 = r, 2 = z) of packed degree of freedom j (see pack_dofs).
   pure subroutine dof_node(j, n, node, comp)
      integer, intent(in) :: j, n
      integer, intent(out) :: node, comp
      if (j == 1) then
         node = 1
         comp = 2
      else if (j == 2 * n - 2) then
         node = n
         comp = 2
      else
         node = 2 + (j - 2) / 2
         comp = 1 + mod(j - 2, 2)
      end if
   end subroutine dof_node

   !> d/dt of the volume centroid's z for node velocities u: (1/V) [oint z (u.n) dS - z_c oint u.n dS],
   !> with P1 velocity on the straight elements (3-point Gauss per element).
   pure real(dp) function centroid_velocity(rz, u) result(v_c)
      real(dp), intent(in) :: rz(:, :), u(:, :)
      real(dp), parameter :: gx(3) = [0.5_dp - sqrt(0.15_dp), 0.5_dp, 0.5_dp + sqrt(0.15_dp)]
      real(dp), parameter :: gw(3) = [5.0_dp / 18, 8.0_dp / 18, 5.0_dp / 18]
      real(dp) :: area, volume, moment, flux, zc, d(2), normal(2), p(2), uq(2), s
      integer :: e, q
      call meridian_area_volume(rz, area, volume)
      zc = centroid_z(rz, volume)
      moment = 0.0_dp
      flux = 0.0_dp
      do e = 1, size(rz, 2) - 1
         d = rz(:, e + 1) - rz(:, e)
         s = norm2(d)
         normal = [-d(2), d(1)] / s
         do q = 1, 3
            p = rz(:, e) + gx(q) * d
            uq = u(:, e) + gx(q) * (u(:, e + 1) - u(:, e))
            moment = moment + gw(q) * 2 * pi * p(1) * s * p(2) * dot_product(uq, normal)
            flux = flux + gw(q) * 2 * pi * p(1) * s * dot_product(uq, normal)
         end do
      end do
      v_c = (moment - zc * flux) / volume
   end function centroid_velocity

   !> z of the volume centroid: integral z dV / V over the frusta.
   pure real(dp) function centroid_z(rz, volume)
      real(dp), intent(in) :: rz(:, :), volume
      real(dp) :: ra, rb, za, zb, dz, m
      integer :: e
      m = 0.0_dp
      do e = 1, size(rz, 2) - 1
         ra = rz(1, e)
         rb = rz(1, e + 1)
         za = rz(2, e)
         zb = rz(2, e + 1)
         dz = zb - za
         ! -pi integral_0^1 r(t)**2 z(t) dt dz, r and z linear in t (exact polynomial integral).
         m = m - pi * dz * (ra * ra * (za / 4 + zb / 12) + 2 * ra * rb * (za / 12 + zb / 12) &
                            + rb * rb * (za / 12 + zb / 4))
      end do
      centroid_z = m / volume
   end function centroid_z

   !> Largest real part of the eigenvalues of the Jacobian jac (LAPACK dgeev on a copy).
   real(dp) function largest_growth_rate(self, jac) result(rate)
      class(axisymmetric_operator_t), intent(inout) :: self
      real(dp), intent(in) :: jac(:, :)
      real(dp) :: a(size(jac, 1), size(jac, 2)), no_left(1, 1), no_right(1, 1)
      integer :: m, info
      m = size(a, 1)
      a = jac
      call dgeev('N', 'N', m, a, m, self%eig_re, self%eig_im, no_left, 1, no_right, 1, self%eig_work, &
                 size(self%eig_work), info)
      rate = maxval(self%eig_re)
      if (info /= 0) rate = 1.0_dp / self%dt_max
   end function largest_growth_rate

   !> Put the centroid back at z = 0 and, for the Newton updates (which conserve volume only
   !> to first order), the volume back to its initial value by a uniform displacement along
   !> the node normals (dV = sum_k dV/dx_k . delta_k).
   subroutine restore_volume_and_centre(self, rz)
      class(axisymmetric_operator_t), intent(inout) :: self
      real(dp), intent(inout) :: rz(:, :)
      real(dp) :: area, volume, shift
      call meridian_area_volume(rz, area, volume)
      call meridian_volume_gradient(rz, self%grad)
      self%grad(1, [1, size(rz, 2)]) = 0.0_dp
      shift = (self%volume0 - volume) / sum(self%grad**2)
      rz = rz + shift * self%grad
      call meridian_area_volume(rz, area, volume)
      rz(2, :) = rz(2, :) - centroid_z(rz, volume)
   end subroutine restore_volume_and_centre

   !> Degrees of freedom: (r, z) of every node but the poles' r (on the axis).
   pure subroutine pack_dofs(rz, q)
      real(dp), intent(in) :: rz(:, :)
      real(dp), intent(out) :: q(:)
      integer :: n
      n = size(rz, 2)
      q(1) = rz(2, 1)
      q(2:2 * n - 3) = reshape(rz(:, 2:n - 1), [2 * n - 4])
      q(2 * n - 2) = rz(2, n)
   end subroutine pack_dofs

   pure subroutine unpack_dofs(q, rz)
      real(dp), intent(in) :: q(:)
      real(dp), intent(out) :: rz(:, :)
      integer :: n
      n = size(rz, 2)
      rz(:, 1) = [0.0_dp, q(1)]
      rz(:, 2:n - 1) = reshape(q(2:2 * n - 3), [2, n - 2])
      rz(:, n) = [0.0_dp, q(2 * n - 2)]
   end subroutine unpack_dofs

end module axisymmetric_operator
