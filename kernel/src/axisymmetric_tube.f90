!> A centred capsule in Poiseuille flow in a circular tube, axisymmetric (the fast path for
!> tube databases): ring Stokeslets on the capsule meridian and on the tube boundary.
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
module axisymmetric_tube
   use capsim_kinds, only: dp, pi
   use lapack_interfaces, only: dgeev, dgesv, dgetrf, dgetrs
   use hdf5_writer, only: h5_file_t
   use membrane_law, only: make_membrane_law
   use axisymmetric_bending, only: meridian_bending_t
   use axisymmetric_membrane, only: meridian_reference_t, meridian_forces, meridian_node_areas, &
                                    meridian_area_volume, meridian_volume_gradient
   use ring_stokeslet, only: segment_integral
   use ring_stresslet, only: double_layer_row, element_double_layer, nearest_node
   use run_options, only: run_options_t
   use text_format, only: int_text
   use tube_history, only: h_t, h_area, h_volume, h_lz, h_lp, h_vc, h_rmax, h_energy, h_stretch, &
                           tube_history_names, tube_history_units, tube_progress_text
   use capsule_model, only: capsule_model_t, num
   use case_output, only: case_summary_t
   implicit none
   private
   public :: axisymmetric_tube_t, tube_wall_elements, velocity_jacobian, largest_growth_rate, pack_dofs, unpack_dofs


   !> Wall element sizes: fine over |z| < 2, growing geometrically (ratio wall_growth) to
   !> coarse_size towards the end sections (the tube length is a run option).
   real(dp), parameter :: fine_size = 0.04_dp, coarse_size = 0.3_dp, wall_growth = 1.2_dp
   integer, parameter :: disk_elements = 10
   !> The automatic solver choice uses Newton below this Ca and RK2 time stepping above (see run).
   real(dp), parameter :: newton_max_ca = 0.005_dp
   !> Capsules this large start as a spheroid of this equatorial radius (they do not fit as
   !> spheres); their stresses are still measured from the spherical reference.
   real(dp), parameter :: predeform_from = 0.9_dp, predeform_radius = 0.8_dp
   !> Element stretch beyond which the meridian no longer resolves the parachute rim. Steady
   !> shapes of the development grid (64 elements) have stretches below 2.9, except three NH
   !> shapes at the end of the steady branch (5.4 to 9.3, reached after creeping for 30 l/V)
   !> which finer meridians do not have: at a/l = 0.85, Ca_s = 0.15, 96 elements elongate past
   !> 10 while 64 stall at 9. A capsule still elongating when its rim passes 4 is therefore
   !> continuous elongation (the paper's NH result at that point).
   real(dp), parameter :: meridian_stretch_limit = 4.0_dp
   integer, parameter :: solver_newton = 1, solver_implicit = 2, solver_rk2 = 3
   !> Linearly implicit steps: largest step (l/V) and largest age of a Jacobian (steps).
   real(dp), parameter :: implicit_dt = 0.1_dp
   integer, parameter :: jacobian_max_age = 20
   !> Largest defect of an implicit step, relative to its size (see implicit_step).
   real(dp), parameter :: defect_tol = 0.5_dp
   !> Finite-difference step of the Jacobian, relative to a: the velocity carries quadrature
   !> noise of ~1e-9 V, and at a/l = 0.9 a step of 1e-7 l gave a Jacobian too noisy for Newton
   !> to converge, 1e-6 l stalled it at a residual of 5e-4 V, 1e-5 l converged to 1e-7 V; a
   !> nearly rigid capsule (Newton continuation from Ca_s = 1e-4) needs the smaller step
   !> rigid_fd_step (l): with 4e-6 l it did not converge at a/l = 0.4.
   real(dp), parameter :: jacobian_fd_step = 1.0e-5_dp, rigid_fd_step = 1.0e-6_dp
   !> Newton tolerance of the polish after time stepping (largest node velocity, V).
   real(dp), parameter :: polish_tol = 1.0e-6_dp
   !> Largest lambda dt for the growing modes (Re lambda > 0) of an implicit step.
   real(dp), parameter :: growth_step_limit = 0.5_dp


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

   type, extends(capsule_model_t) :: axisymmetric_tube_t
      type(meridian_reference_t) :: ref
      !> Bending stiffness (--kb); set up only when k_b > 0.
      type(meridian_bending_t) :: bending
      real(dp) :: ca = 0, a = 0, h_min = 0, energy = 0, v_c = 0, volume0 = 0, tube_length = 10
      logical :: volume_correction = .true.
      !> Steady solver (Newton with continuation in Ca), linearly implicit Euler steps, or
      !> Heun's RK2 (explicit, dt ~ Ca h).
      integer :: solver = solver_implicit
      !> Linearly implicit steps: the velocity Jacobian J and the LU of I - dt J (see implicit_step).
      real(dp), allocatable :: jacobian(:, :), step_matrix(:, :), step_rhs(:), eig_re(:), eig_im(:), eig_work(:)
      !> Positions at which u_here is the velocity (the implicit step reuses it).
      real(dp), allocatable :: rz_here(:, :), u_here(:, :)
      integer, allocatable :: step_pivot(:)
      integer :: jacobian_age = huge(1)
      type(jacobian_work_t) :: jacobian_work
      !> Counts of the implicit solver: Jacobians computed, steps redone.
      integer :: n_jacobians = 0, n_rejected = 0
      !> Largest implicit step (l/V): the step is this or growth_step_limit / (largest growth
      !> rate of the Jacobian), whichever is smaller.
      real(dp) :: dt_max = 0
      !> Step cap after halvings (see implicit_step), dt_max when none.
      real(dp) :: dt_limit = huge(1.0_dp)
      real(dp), allocatable :: system(:, :), step_vector(:), border(:, :)
      real(dp), allocatable :: dofs(:), dofs_trial(:), res(:), res_trial(:), rz_good(:, :)
      integer, allocatable :: pivot(:)
      !> The bordered system's LU from the last Newton step, reused for the Ca predictor.
      logical :: have_lu = .false.
      !> Reference meridian (sphere of radius a/l); the run starts from a sphere or a spheroid.
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
   contains
      procedure :: init
      procedure :: velocity
      procedure :: advance
      procedure :: record
      procedure :: run
      procedure :: progress_text
      procedure :: write_geometry
   end type axisymmetric_tube_t

contains

   subroutine init(self, opts, stat, errmsg)
      class(axisymmetric_tube_t), intent(inout) :: self
      type(run_options_t), intent(in) :: opts
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: n, k, m
      real(dp) :: theta, c_axis

      call make_membrane_law(trim(opts%law), opts%nu_s, opts%c, self%law, stat, errmsg)
      if (stat /= 0) return
      self%a = opts%a_over_l
      self%ca = opts%ca
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

      self%tube_length = opts%tube_length
      call tube_wall_elements(0.5_dp * self%tube_length, self%wall_a, self%wall_b)
      self%n_wall = size(self%wall_a, 2)
      self%wall_mid = 0.5_dp * (self%wall_a + self%wall_b)
      allocate (self%wall_traction(2 * self%n_wall))
      call factorise_wall(self, stat, errmsg)
      if (stat /= 0) return
      self%lambda = opts%lambda
      if (self%lambda /= 1.0_dp) then
         allocate (self%lambda_lu(2 * n, 2 * n), self%lambda_pivot(2 * n), self%wall_dl(2 * self%n_wall, 2 * n))
         allocate (self%wall_null(2 * self%n_wall))
         call wall_left_null_vector(self)
      end if

      select case (trim(opts%integrator))
      case ('newton')
         self%solver = solver_newton
      case ('implicit')
         self%solver = solver_implicit
      case ('rk2')
         self%solver = solver_rk2
      case default
         self%solver = solver_implicit
         if (opts%ca < newton_max_ca) self%solver = solver_newton
      end select
      if (opts%dt > 0) then
         self%dt = opts%dt
      else if (self%solver == solver_implicit) then
         self%dt = implicit_dt
      else
         self%dt = min(opts%dt_factor * opts%ca * self%h_min, 0.01_dp)
         ! Bending limit of the explicit steps (see capsule_dynamics), K_B = k_b a**2.
         if (opts%kb > 0.0_dp) self%dt = min(self%dt, opts%dt_factor * opts%ca * self%h_min**3 / (opts%kb * self%a**2))
      end if
      ! Every solver ends with Newton iterations (time stepping polishes its steady shape).
      m = 2 * n - 2
      allocate (self%system(m + 2, m + 2), self%step_vector(m + 2), self%border(m, 2), self%pivot(m + 2))
      allocate (self%dofs(m), self%dofs_trial(m), self%res(m), self%res_trial(m), self%rz_good(2, n))
      allocate (self%jacobian(m, m), self%step_matrix(m, m), self%step_rhs(m), self%step_pivot(m))
      allocate (self%rz_here(2, n), self%u_here(2, n))
      self%rz_here = huge(1.0_dp)
      allocate (self%eig_re(m), self%eig_im(m), self%eig_work(8 * m))
      self%dt_max = self%dt
      self%dt_limit = self%dt
      block
         real(dp) :: area
         call meridian_area_volume(self%start_positions, area, self%volume0)
      end block
      call self%allocate_history(tube_history_names, tube_history_units, opts%t_max, opts%record_every)
      self%col_length = h_lz
      self%col_stretch = h_stretch
      self%col_shape = [h_lz, h_lp, h_vc]
      self%area_scale = 4 * pi * self%a**2
      self%length_limit = 2 * opts%max_length * self%a
      ! Lengths and v_c settle to 1e-3 (l, V) per time unit: a relative tolerance let a long
      ! NH capsule creeping at 0.008 l per unit (a/l = 0.85, Ca = 0.15) pass for steady.
      self%shape_rel_tol = 0.0_dp
      self%shape_abs_tol = 1.0e-3_dp
      self%stretch_limit = meridian_stretch_limit
   end subroutine init

   !> Wall elements of the tube boundary, inlet disk, cylinder, outlet disk (end points (r, z)).
   subroutine tube_wall_elements(tube_half_length, wall_a, wall_b)
      real(dp), intent(in) :: tube_half_length
      real(dp), allocatable, intent(out) :: wall_a(:, :), wall_b(:, :)
      real(dp), allocatable :: z_half(:), z(:)
      real(dp) :: h, zc
      integer :: k, nz, nh, m
      ! Half-cylinder node positions from z = 0 outwards.
      allocate (z_half(1000))
      nh = 1
      z_half(1) = 0.0_dp
      h = fine_size
      do while (z_half(nh) < tube_half_length - 1.0e-12_dp)
         zc = z_half(nh)
         if (zc >= 2.0_dp) h = min(h * wall_growth, coarse_size)
         nh = nh + 1
         z_half(nh) = min(zc + h, tube_half_length)
         ! Avoid a sliver at the end.
         if (tube_half_length - z_half(nh) < 0.3_dp * h) z_half(nh) = tube_half_length
      end do
      nz = 2 * nh - 1
      allocate (z(nz))
      z(nh:nz) = z_half(1:nh)
      z(1:nh - 1) = -z_half(nh:2:-1)
      m = disk_elements + (nz - 1) + disk_elements
      allocate (wall_a(2, m), wall_b(2, m))
      do k = 1, disk_elements
         wall_a(:, k) = [real(k - 1, dp) / disk_elements, -tube_half_length]
         wall_b(:, k) = [real(k, dp) / disk_elements, -tube_half_length]
      end do
      do k = 1, nz - 1
         wall_a(:, disk_elements + k) = [1.0_dp, z(k)]
         wall_b(:, disk_elements + k) = [1.0_dp, z(k + 1)]
      end do
      do k = 1, disk_elements
         wall_a(:, disk_elements + nz - 1 + k) = [1.0_dp - real(k - 1, dp) / disk_elements, tube_half_length]
         wall_b(:, disk_elements + nz - 1 + k) = [1.0_dp - real(k, dp) / disk_elements, tube_half_length]
      end do
   end subroutine tube_wall_elements

   !> Single layer of a constant traction g on wall element j at point (r0, z0); an element
   !> that contains the point (its own mid-point) is split there so that the log singularity
   !> sits at a segment end.
   pure function wall_element_velocity(wa, wb, g, r0, z0, own) result(u)
      real(dp), intent(in) :: wa(2), wb(2), g(2), r0, z0
      logical, intent(in) :: own
      real(dp) :: u(2), mid(2)
      if (own) then
         mid = 0.5_dp * (wa + wb)
         u = segment_integral(r0, z0, wa(1), wa(2), mid(1), mid(2), g, g, 2) + &
             segment_integral(r0, z0, mid(1), mid(2), wb(1), wb(2), g, g, 1)
      else
         u = segment_integral(r0, z0, wa(1), wa(2), wb(1), wb(2), g, g, 0)
      end if
   end function wall_element_velocity

   subroutine factorise_wall(self, stat, errmsg)
      type(axisymmetric_tube_t), intent(inout) :: self
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: i, j, m, info
      m = 2 * self%n_wall
      allocate (self%wall_lu(m, m), self%wall_pivot(m))
      !$omp parallel do default(none) shared(self) private(i, j) schedule(dynamic)
      do j = 1, self%n_wall
         do i = 1, self%n_wall
            self%wall_lu(2 * i - 1:2 * i, 2 * j - 1) = wall_element_velocity(self%wall_a(:, j), self%wall_b(:, j), &
                                                                             [1.0_dp, 0.0_dp], self%wall_mid(1, i), &
                                                                             self%wall_mid(2, i), i == j)
            self%wall_lu(2 * i - 1:2 * i, 2 * j) = wall_element_velocity(self%wall_a(:, j), self%wall_b(:, j), &
                                                                         [0.0_dp, 1.0_dp], self%wall_mid(1, i), &
                                                                         self%wall_mid(2, i), i == j)
         end do
      end do
      !$omp end parallel do
      call dgetrf(m, m, self%wall_lu, m, self%wall_pivot, info)
      stat = info
      errmsg = ''
      if (info /= 0) errmsg = 'tube wall matrix is singular (LAPACK dgetrf info /= 0)'
   end subroutine factorise_wall

   !> Membrane velocity (r, z components) at meridian rz in the frame of the capsule; sets v_c.
   subroutine velocity(self, rz, u)
      class(axisymmetric_tube_t), intent(inout) :: self
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
                     wall_single_layer_at(self, self%wall_traction, rz(:, k))
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
   end subroutine velocity

   !> The boundary-integral matrix of lambda /= 1 at shape rz (see the module header), factorised.
   subroutine factorise_viscosity_ratio(self, rz)
      type(axisymmetric_tube_t), intent(inout) :: self
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
      call remove_wall_flux(self, self%wall_dl)
      call dgetrs('N', 2 * nw, 2 * n, self%wall_lu, 2 * nw, self%wall_pivot, self%wall_dl, 2 * nw, info)
      self%lambda_lu = -(1.0_dp - self%lambda) * (d_nodes - matmul(s_wall, self%wall_dl))
      do k = 1, 2 * n
         self%lambda_lu(k, k) = self%lambda_lu(k, k) + 0.5_dp * (1.0_dp + self%lambda)
      end do
      ! Nonsingular for every lambda > 0 (spectrum in [min(1, lambda), max(1, lambda)]).
      call dgetrf(2 * n, 2 * n, self%lambda_lu, 2 * n, self%lambda_pivot, info)
   end subroutine factorise_viscosity_ratio

   !> W is singular along a uniform pressure on B (it moves no fluid inside: W's smallest
   !> singular value is ~1e-11 of its largest), so W g = b needs b without a component along
   !> W's left null vector (the flux of b through B). The single layers have none (to the
   !> quadrature error), but the double layer of U carries the flux of U through the membrane,
   !> dV/dt, which the physical U lacks and the discrete one has at the discretisation error:
   !> W**-1 turned it, and the quadrature noise, into tractions of 1e7 whose velocity at the
   !> nodes was noise. Removing that component from the right-hand sides b(:, j) solves for
   !> the flux-free part of the double layer, which is the whole of it for the physical U.
   subroutine remove_wall_flux(self, b)
      type(axisymmetric_tube_t), intent(in) :: self
      real(dp), intent(inout) :: b(:, :)
      integer :: j
      do j = 1, size(b, 2)
         b(:, j) = b(:, j) - dot_product(self%wall_null, b(:, j)) * self%wall_null
      end do
   end subroutine remove_wall_flux

   !> W's left null vector (unit norm) by inverse iteration on W**T with the LU of W.
   subroutine wall_left_null_vector(self)
      type(axisymmetric_tube_t), intent(inout) :: self
      real(dp) :: x(2 * self%n_wall, 1)
      integer :: it, info
      x = 1.0_dp
      do it = 1, 4
         call dgetrs('T', 2 * self%n_wall, 1, self%wall_lu, 2 * self%n_wall, self%wall_pivot, x, 2 * self%n_wall, info)
         x = x / norm2(x)
      end do
      self%wall_null = x(:, 1)
   end subroutine wall_left_null_vector

   !> From the lambda = 1 single-layer sums raw (at shape rz) to those that give the lambda
   !> velocity through finish_velocity, with the matrix last factorised; u_lab: the node
   !> velocities (lab frame) solved for. The lambda = 1 velocity U_1 gets finish_velocity's
   !> axis and volume corrections before the solve: a steady shape has U_1 = v_c e_z + (the
   !> discretisation's flux error, which the correction removes), so that U_1 corrected is a
   !> rigid translation, which A maps onto itself: the steady shapes of every lambda are then
   !> those of lambda = 1 to the solver tolerance (applied after the solve only, they differed by
   !> the flux error, 1e-4 of L_z at 64 elements).
   subroutine apply_viscosity_ratio(self, rz, raw, u_lab)
      type(axisymmetric_tube_t), intent(in) :: self
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
      type(axisymmetric_tube_t), intent(in) :: self
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
      type(axisymmetric_tube_t), intent(inout) :: self
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
      ! The lambda = 1 single-layer sums at rz (as in `velocity`).
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
                        wall_single_layer_at(self, rhs(:, 1), rz(:, k))
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
      type(axisymmetric_tube_t), intent(in) :: self
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
         call remove_wall_flux(self, wall_change)
         call dgetrs('N', 2 * nw, 1, self%wall_lu, 2 * nw, self%wall_pivot, wall_change, 2 * nw, info)
         ! S_wall(rz1) W**-1 D_wall(rz1) U - S_wall W**-1 D_wall U at every node: the wall single
         ! layer of the traction change, plus, at the moved node, that of W**-1 D_wall U itself.
         do k = 1, n
            du(:, k) = wall_single_layer_at(self, wall_change(:, 1), rz1(:, k))
         end do
         du(:, node) = du(:, node) + wall_single_layer_at(self, w%wall_dl_u, rz1(:, node)) &
                       - wall_single_layer_at(self, w%wall_dl_u, rz(:, node))
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
      type(axisymmetric_tube_t), intent(in) :: self
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

   !> Wall single layer (without 1/(8 pi)) of the wall traction g at point x.
   pure function wall_single_layer_at(self, g, x) result(acc)
      type(axisymmetric_tube_t), intent(in) :: self
      real(dp), intent(in) :: g(:), x(2)
      real(dp) :: acc(2)
      integer :: i
      acc = 0.0_dp
      do i = 1, self%n_wall
         acc = acc + wall_element_velocity(self%wall_a(:, i), self%wall_b(:, i), g(2 * i - 1:2 * i), x(1), x(2), .false.)
      end do
   end function wall_single_layer_at

   !> From the raw single-layer sums to the membrane velocity in the capsule frame: scale by
   !> 1/(8 pi Ca), add v_inf, keep the poles on the axis, remove the net flux (as in 3D),
   !> subtract the centroid velocity v_c.
   pure subroutine finish_velocity(self, rz, raw, u, v_c)
      type(axisymmetric_tube_t), intent(in) :: self
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
      type(axisymmetric_tube_t), intent(in) :: self
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
      type(axisymmetric_tube_t), intent(inout) :: self
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
      type(axisymmetric_tube_t), intent(in) :: self
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
         real(dp) :: vc1
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
         do q = 1, n
            if (q == node) then
               raw1(:, q) = membrane_single_layer(rz1, density1, rz1(:, q), 1, n - 1, q) + &
                            wall_single_layer_at(self, rhs(:, 1), rz1(:, q))
            else
               raw1(:, q) = raw0(:, q) + matmul(influence(2 * q - 1:2 * q, :), rhs(:, 1) - g0) &
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

   !> One time step: linearly implicit (implicit_step), or Heun's RK2 in the capsule frame
   !> (time-accurate) with the centroid put back at z = 0.
   subroutine advance(self)
      class(axisymmetric_tube_t), intent(inout) :: self
      if (self%solver == solver_implicit) then
         call implicit_step(self)
         return
      end if
      call self%velocity(self%positions, self%u0)
      self%rz_pred = self%positions + self%dt * self%u0
      call self%velocity(self%rz_pred, self%u1)
      self%positions = self%positions + 0.5_dp * self%dt * (self%u0 + self%u1)
      call restore_volume_and_centre(self, self%positions)
      self%t = self%t + self%dt
      self%step = self%step + 1
   end subroutine advance

   !> One linearly implicit (Rosenbrock-Euler) step, (I - dt J) delta = dt u(x), x <- x + delta,
   !> with J the velocity Jacobian (velocity_jacobian), reused over steps while it serves.
   !> Why: the explicit step is bound to dt ~ Ca h by the membrane's stiffness (dt = 3e-3
   !> at a/l = 0.9, Ca_s = 0.1, 48 elements: 4400 RK2 steps to steady state); the implicit
   !> step damps the stiff elastic modes whatever dt. The rear-buckling modes (Jacobian
   !> eigenvalues up to ~ +50 V/l just after the start, ~ +9 V/l at the rear later) must
   !> still grow, by 1/(1 - lambda dt) per step, which needs lambda dt < 1: dt is set to
   !> growth_step_limit / (largest growth rate) at each new Jacobian, at most dt_max.
   !> A fixed point of the step is a zero of u, whatever J: a stale Jacobian changes the
   !> path, never the steady shape; but a stale J let a buckling rear (a/l = 0.3, Ca_s =
   !> 0.05) blow up. So each step checks itself: delta should equal dt u(x + delta) (the
   !> implicit Euler equation), and the step is redone with a new Jacobian, or with half the
   !> step if the Jacobian is new, when the defect exceeds defect_tol |delta|. The velocity at
   !> the new position is the next step's u(x): the check costs no extra evaluation.
   subroutine implicit_step(self)
      type(axisymmetric_tube_t), intent(inout) :: self
      integer, parameter :: max_attempts = 12
      integer :: m, info, attempt
      real(dp) :: defect, change
      m = size(self%dofs)
      if (any(self%positions /= self%rz_here)) then
         call self%velocity(self%positions, self%u_here)
         self%rz_here = self%positions
      end if
      if (self%jacobian_age >= jacobian_max_age) call refresh_jacobian(self)
      call pack_dofs(self%positions, self%dofs)
      do attempt = 1, max_attempts
         call pack_dofs(self%u_here, self%step_rhs)
         self%step_rhs = self%dt * self%step_rhs
         call dgetrs('N', m, 1, self%step_matrix, m, self%step_pivot, self%step_rhs, m, info)
         call unpack_dofs(self%dofs + self%step_rhs, self%rz_pred)
         call restore_volume_and_centre(self, self%rz_pred)
         call self%velocity(self%rz_pred, self%u1)
         call pack_dofs(self%rz_pred, self%dofs_trial)
         call pack_dofs(self%u1, self%res_trial)
         change = maxval(abs(self%dofs_trial - self%dofs))
         defect = maxval(abs(self%dt * self%res_trial - (self%dofs_trial - self%dofs)))
         if (defect <= defect_tol * change) exit
         self%n_rejected = self%n_rejected + 1
         if (self%jacobian_age == 0) then
            self%dt = 0.5_dp * self%dt
            self%dt_limit = self%dt
            call factorise_step_matrix(self)
         else
            call refresh_jacobian(self)
         end if
      end do
      self%positions = self%rz_pred
      self%rz_here = self%rz_pred
      self%u_here = self%u1
      self%jacobian_age = self%jacobian_age + 1
      ! A step that had to be halved caps the next ones; the cap relaxes by half per accepted step.
      self%dt_limit = min(self%dt_max, 1.5_dp * self%dt_limit)
      self%t = self%t + self%dt
      self%step = self%step + 1
   end subroutine implicit_step

   !> New Jacobian at the current positions, the step it allows, and the LU of I - dt J.
   subroutine refresh_jacobian(self)
      type(axisymmetric_tube_t), intent(inout) :: self
      call velocity_jacobian(self, self%positions, jacobian_fd_step * self%a, self%jacobian)
      self%n_jacobians = self%n_jacobians + 1
      self%dt = min(self%dt_limit, growth_step_limit / max(largest_growth_rate(self, self%jacobian), tiny(1.0_dp)))
      call factorise_step_matrix(self)
      self%jacobian_age = 0
   end subroutine refresh_jacobian

   subroutine factorise_step_matrix(self)
      type(axisymmetric_tube_t), intent(inout) :: self
      integer :: j, m, info
      m = size(self%jacobian, 1)
      self%step_matrix = -self%dt * self%jacobian
      do j = 1, m
         self%step_matrix(j, j) = self%step_matrix(j, j) + 1.0_dp
      end do
      call dgetrf(m, m, self%step_matrix, m, self%step_pivot, info)
   end subroutine factorise_step_matrix

   !> Newton tolerance on the largest node velocity (V): the requested one, but not below the
   !> noise of the velocity, ~1e-9 / Ca_s (quadrature noise of the membrane single layer,
   !> scaled by 1/Ca: at a/l = 0.4, Ca_s = 1e-3, 64 elements, Newton stalled at 5e-7 V).
   pure real(dp) function newton_tolerance(self, opts) result(tol)
      type(axisymmetric_tube_t), intent(in) :: self
      type(run_options_t), intent(in) :: opts
      real(dp), parameter :: velocity_noise = 1.0e-9_dp
      tol = max(opts%newton_tol, velocity_noise / self%ca)
   end function newton_tolerance

   !> Largest real part of the eigenvalues of the Jacobian jac (LAPACK dgeev on a copy).
   real(dp) function largest_growth_rate(self, jac) result(rate)
      type(axisymmetric_tube_t), intent(inout) :: self
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
      type(axisymmetric_tube_t), intent(inout) :: self
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

   !> The steady shape as the root of u(x) = 0 (membrane at rest in the capsule frame), by
   !> Newton's method with a finite-difference Jacobian and continuation in Ca from a nearly
   !> rigid capsule. Why not time stepping: at small Ca the rear of the membrane is under
   !> compression, and a membrane without bending stiffness then has mesh-scale modes that
   !> grow at ~10 V/l whatever Ca (measured from the Jacobian's eigenvalues); explicit steps,
   !> bound to dt ~ Ca h, let them wrinkle the rear long before the shape is steady.
   !> Newton-type iterations (newton_solve) converge to the steady shape the paper reports.
   !> When continuation cannot pass some Ca (the steady branch ends), the run is reported
   !> as continuous elongation at that Ca.
   subroutine newton_run(self, opts, summary, steady_index)
      type(axisymmetric_tube_t), intent(inout) :: self
      type(run_options_t), intent(in) :: opts
      type(case_summary_t), intent(inout) :: summary
      integer, intent(out) :: steady_index
      real(dp), parameter :: ca_start = 1.0e-3_dp, min_factor = 1.02_dp
      real(dp) :: ca_target, ca_good, factor, ca_try
      logical :: converged

      steady_index = 0
      ca_target = opts%ca
      call self%reset()
      self%t = 0
      self%step = 0
      self%n_rec = 0
      self%ca = min(ca_target, ca_start)
      call self%record()
      call newton_solve(self, newton_tolerance(self, opts), rigid_fd_step, converged)
      if (.not. converged) then
         summary%status = 'failed'
         summary%message = 'Newton did not converge for the nearly rigid capsule at Ca = '//num(self%ca)
         return
      end if
      ca_good = self%ca
      self%rz_good = self%positions
      factor = 2.0_dp
      do while (ca_good < ca_target)
         ca_try = min(ca_good * factor, ca_target)
         call predict_shape(self, ca_good, ca_try)
         self%ca = ca_try
         call newton_solve(self, newton_tolerance(self, opts), rigid_fd_step, converged)
         if (converged) then
            ca_good = ca_try
            self%rz_good = self%positions
            if (.not. opts%quiet) write (*, '(a,es10.3,a)') 'capsim: steady shape at Ca = ', ca_good, &
               '  '//self%progress_text()
            factor = min(factor**1.5_dp, 2.0_dp)
         else
            self%positions = self%rz_good
            self%have_lu = .false.
            factor = sqrt(factor)
            if (factor < min_factor) exit
         end if
         if (self%n_rec >= self%record_limit - 1) exit
      end do
      self%ca = ca_target
      if (ca_good >= ca_target) then
         summary%status = 'steady'
         summary%message = 'steady: Newton residual (largest membrane velocity in the capsule frame) '// &
                           num(self%residual)//' after continuation in Ca'
         steady_index = self%n_rec
      else
         self%positions = self%rz_good
         self%ca = ca_good
         call self%record()
         summary%status = 'continuous_elongation'
         summary%message = 'no steady shape beyond Ca = '//num(ca_good)//' (L_z/l = '// &
                           num(self%history(h_lz, self%n_rec))//'): the steady branch ends before Ca = '// &
                           num(ca_target)
      end if
   end subroutine newton_run

   !> Newton iterations on u(x) = 0 with a finite-difference Jacobian J. J is singular along
   !> the inflation of the capsule (a uniform pressure moves no fluid) and nearly so along
   !> its axial translation (only the tube's ends feel it): plain Newton followed those
   !> directions into steps of the order of the capsule size. The step is therefore the
   !> bordered system
   !>     J delta + lambda_V g + lambda_z t = -u,   g . delta = 0,   t . delta = 0,
   !> with g = dV/dx and t the uniform axial shift: delta keeps the volume and position, and
   !> the multipliers absorb what no shape change can cancel. The residual is u with its
   !> g and t components removed; a backtracking line search keeps every step downhill.
   !> Tangent predictor for the continuation: from the steady shape at ca_from,
   !> x(ca_to) ~ x + (ca_to - ca_from) dx/dCa with J dx/dCa = -du/dCa (bordered as in
   !> newton_solve, with the LU of its last step); du/dCa by a difference in Ca at fixed shape.
   !> Without it each doubling of Ca starts Newton half an elastic velocity away from the
   !> root, which near the wall film takes ten or more damped steps.
   subroutine predict_shape(self, ca_from, ca_to)
      type(axisymmetric_tube_t), intent(inout) :: self
      real(dp), intent(in) :: ca_from, ca_to
      real(dp), parameter :: rel_step = 1.0e-4_dp
      integer :: m, info
      if (.not. self%have_lu) return
      m = size(self%dofs)
      self%ca = ca_from
      call self%velocity(self%positions, self%u0)
      call pack_dofs(self%u0, self%res)
      self%ca = ca_from * (1.0_dp + rel_step)
      call self%velocity(self%positions, self%u1)
      call pack_dofs(self%u1, self%res_trial)
      self%step_vector(1:m) = -(self%res_trial - self%res) / (ca_from * rel_step) * (ca_to - ca_from)
      self%step_vector(m + 1:m + 2) = 0.0_dp
      call dgetrs('N', m + 2, 1, self%system, m + 2, self%pivot, self%step_vector, m + 2, info)
      if (info /= 0) return
      call pack_dofs(self%positions, self%dofs)
      call unpack_dofs(self%dofs + self%step_vector(1:m), self%positions)
      call restore_volume_and_centre(self, self%positions)
   end subroutine predict_shape

   subroutine newton_solve(self, tol, fd_step, converged)
      type(axisymmetric_tube_t), intent(inout) :: self
      real(dp), intent(in) :: tol, fd_step
      logical, intent(out) :: converged
      integer, parameter :: max_iterations = 40
      integer :: m, it, info
      real(dp) :: residual, trial, alpha

      converged = .false.
      m = size(self%dofs)
      call self%velocity(self%positions, self%u0)
      call pack_dofs(self%u0, self%res)
      call constraint_directions(self, self%positions)
      residual = projected_residual(self, self%res)
      do it = 1, max_iterations
         self%residual = residual
         if (residual < tol) then
            converged = .true.
            call self%record()
            return
         end if
         call pack_dofs(self%positions, self%dofs)
         call velocity_jacobian(self, self%positions, fd_step, self%system(1:m, 1:m))
         self%system(1:m, m + 1:m + 2) = self%border
         self%system(m + 1:m + 2, 1:m) = transpose(self%border)
         self%system(m + 1:m + 2, m + 1:m + 2) = 0.0_dp
         self%step_vector(1:m) = -self%res
         self%step_vector(m + 1:m + 2) = 0.0_dp
         call dgesv(m + 2, 1, self%system, m + 2, self%pivot, self%step_vector, m + 2, info)
         if (info /= 0) return
         self%have_lu = .true.
         alpha = 1.0_dp
         do
            call unpack_dofs(self%dofs + alpha * self%step_vector(1:m), self%rz_pred)
            call restore_volume_and_centre(self, self%rz_pred)
            call self%velocity(self%rz_pred, self%u1)
            call pack_dofs(self%u1, self%dofs_trial)
            call constraint_directions(self, self%rz_pred)
            trial = projected_residual(self, self%dofs_trial)
            if (trial < (1.0_dp - 0.1_dp * alpha) * residual) exit
            alpha = 0.5_dp * alpha
            if (alpha < 1.0_dp / 64) return
         end do
         self%positions = self%rz_pred
         self%res = self%dofs_trial
         residual = trial
         self%t = self%t + 1
         self%step = self%step + 1
      end do
      self%residual = residual
   end subroutine newton_solve

   !> The two border columns at rz: the volume gradient and the uniform axial shift, orthonormalised.
   subroutine constraint_directions(self, rz)
      type(axisymmetric_tube_t), intent(inout) :: self
      real(dp), intent(in) :: rz(:, :)
      integer :: m
      m = size(self%dofs)
      call meridian_volume_gradient(rz, self%grad)
      call pack_dofs(self%grad, self%border(:, 1))
      self%border(:, 2) = 0.0_dp
      self%border(1, 2) = 1.0_dp
      self%border(2:m - 1:2, 2) = 1.0_dp
      self%border(m, 2) = 1.0_dp
      self%border(:, 2) = self%border(:, 2) / norm2(self%border(:, 2))
      self%border(:, 1) = self%border(:, 1) - dot_product(self%border(:, 1), self%border(:, 2)) * self%border(:, 2)
      self%border(:, 1) = self%border(:, 1) / norm2(self%border(:, 1))
   end subroutine constraint_directions

   !> Largest component of u once its inflation and translation parts are removed.
   pure real(dp) function projected_residual(self, u) result(r)
      type(axisymmetric_tube_t), intent(in) :: self
      real(dp), intent(in) :: u(:)
      r = maxval(abs(u - matmul(self%border, matmul(transpose(self%border), u))))
   end function projected_residual

   !> Newton continuation for nearly rigid capsules, the shared time loop (RK2) otherwise.
   !> Time stepping is the physical choice: at small a/l the compressed rear of the membrane
   !> buckles inward within ~1 l/V (Jacobian eigenvalues ~ +9 V/l localised at the rear
   !> pole), and the state it settles into is the parachute the paper reports. Newton
   !> converges to the convex shape that this buckling leaves behind (a steady but unstable
   !> solution); it is used only where the explicit step (dt ~ Ca h) would cost more than
   !> ~10**5 steps and the parachute is negligible: Ca below newton_max_ca.
   subroutine run(self, opts, checkpoint_path, summary, steady_index)
      class(axisymmetric_tube_t), intent(inout) :: self
      type(run_options_t), intent(in) :: opts
      character(len=*), intent(in) :: checkpoint_path
      type(case_summary_t), intent(inout) :: summary
      integer, intent(out) :: steady_index
      character(len=:), allocatable :: newton_failure
      if (self%solver == solver_newton) then
         summary%dt = 0
         call newton_run(self, opts, summary, steady_index)
         summary%volume_change = self%history(h_volume, self%n_rec) / self%history(h_volume, 1) - 1.0_dp
         if (trim(summary%status) /= 'failed' .or. trim(opts%integrator) /= 'auto') return
         ! Newton from the sphere is fragile at fine meshes (a/l = 0.6, Ca_s = 0.004, 64
         ! elements: no convergence at Ca_s = 1e-3); `auto` then falls back on time stepping.
         newton_failure = summary%message
         self%solver = solver_implicit
         self%dt = implicit_dt
         self%dt_max = implicit_dt
         self%dt_limit = implicit_dt
         self%n_rec = 0
         call self%time_loop(opts, checkpoint_path, summary, steady_index)
         summary%message = summary%message//' (implicit steps after: '//newton_failure//')'
         if (steady_index > 0) call polish_steady_shape(self, opts, summary, steady_index)
      else
         call self%time_loop(opts, checkpoint_path, summary, steady_index)
         if (self%solver == solver_implicit) then
            summary%message = summary%message//' ('//int_text(self%step)//' implicit steps, '// &
                              int_text(self%n_jacobians)//' Jacobians, '//int_text(self%n_rejected)//' steps redone)'
         end if
         if (steady_index > 0) call polish_steady_shape(self, opts, summary, steady_index)
      end if
   end subroutine run

   !> Time stepping declares a steady state when the lengths drift by less than 1e-3 per
   !> time unit; the shape is then within ~1e-3 l of the steady one, and how far depends on
   !> the path (a/l = 0.9, Ca_s = 0.1: L_z 2.2193 after RK2, 2.2153 after implicit steps).
   !> Newton's method from there converges to the steady shape itself, in whose basin the
   !> time stepping ended; the polished shape is kept only if it is linearly stable (no
   !> Jacobian eigenvalue with a real part above stable_rate_limit), so that Newton cannot
   !> swap the physical shape for an unstable neighbour.
   subroutine polish_steady_shape(self, opts, summary, steady_index)
      type(axisymmetric_tube_t), intent(inout) :: self
      type(run_options_t), intent(in) :: opts
      type(case_summary_t), intent(inout) :: summary
      integer, intent(inout) :: steady_index
      real(dp), parameter :: stable_rate_limit = 1.0e-2_dp
      real(dp) :: t_settled, rate
      real(dp), allocatable :: settled(:, :)
      integer :: n_settled
      logical :: converged
      t_settled = self%t
      allocate (settled, source=self%positions)
      n_settled = self%n_rec
      call newton_solve(self, max(newton_tolerance(self, opts), polish_tol), jacobian_fd_step * self%a, converged)
      self%t = t_settled
      rate = huge(1.0_dp)
      if (converged) then
         call velocity_jacobian(self, self%positions, jacobian_fd_step * self%a, self%jacobian)
         rate = largest_growth_rate(self, self%jacobian)
      end if
      if (converged .and. rate < stable_rate_limit) then
         self%history(h_t, self%n_rec) = t_settled
         steady_index = self%n_rec
         summary%message = summary%message//'; Newton polish: residual '//num(self%residual)// &
                           ', largest growth rate '//num(rate)//' V/l'
      else
         self%positions = settled
         self%n_rec = n_settled
         if (converged) then
            summary%message = summary%message//'; the Newton polish found an unstable shape (growth rate '// &
                              num(rate)//' V/l) and was discarded'
         else
            summary%message = summary%message//'; the Newton polish stopped at residual '//num(self%residual)// &
                              ' V and was discarded'
         end if
      end if
   end subroutine polish_steady_shape

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

   !> Append diagnostics: L_z (front to rear), L_p (rear pole to the rear-most point: the
   !> parachute depth, 0 for a convex rear), v_c/V, film-side radius r_max.
   subroutine record(self)
      class(axisymmetric_tube_t), intent(inout) :: self
      real(dp) :: area, volume, l_z, l_p, stretch, lam_s, lam_p
      integer :: n, e
      n = size(self%positions, 2)
      call self%velocity(self%positions, self%u0)
      call meridian_area_volume(self%positions, area, volume)
      l_z = maxval(self%positions(2, :)) - minval(self%positions(2, :))
      l_p = self%positions(2, n) - minval(self%positions(2, :))
      stretch = 1.0_dp
      do e = 1, n - 1
         lam_s = norm2(self%positions(:, e + 1) - self%positions(:, e)) / self%ref%length0(e)
         lam_p = 0.5_dp * (self%positions(1, e) + self%positions(1, e + 1)) / self%ref%radius0(e)
         stretch = max(stretch, lam_s, lam_p, 1.0_dp / lam_s, 1.0_dp / lam_p)
      end do
      call self%next_record()
      self%history(:, self%n_rec) = [self%t, area, volume, l_z, l_p, self%v_c, maxval(self%positions(1, :)), &
                                     self%energy, stretch]
   end subroutine record

   function progress_text(self) result(text)
      class(axisymmetric_tube_t), intent(in) :: self
      character(len=:), allocatable :: text
      text = tube_progress_text(self%history(:, self%n_rec))
   end function progress_text

   !> /mesh (reference and current meridian as (n, 2) arrays of (r, z)) and /profile (r, z).
   subroutine write_geometry(self, f, stat, errmsg)
      class(axisymmetric_tube_t), intent(in) :: self
      type(h5_file_t), intent(inout) :: f
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      call f%write_attr('/', 'n_nodes', size(self%positions, 2), stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'n_wall_elements', self%n_wall, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'tube_length', self%tube_length, stat, errmsg)
      if (stat == 0) call f%make_group('/mesh', stat, errmsg)
      if (stat == 0) call f%write_dataset('/mesh/reference_meridian', self%rz_ref, 'l', stat, errmsg)
      if (stat == 0) call f%write_dataset('/mesh/meridian', self%positions, 'l', stat, errmsg)
      if (stat == 0) call f%make_group('/profile', stat, errmsg)
      if (stat == 0) call f%write_attr('/profile', 'plane', 'meridian, front pole first (flow along +z)', stat, errmsg)
      if (stat == 0) call f%write_dataset('/profile/r', self%positions(1, :), 'l', stat, errmsg)
      if (stat == 0) call f%write_dataset('/profile/z', self%positions(2, :), 'l', stat, errmsg)
   end subroutine write_geometry

end module axisymmetric_tube
