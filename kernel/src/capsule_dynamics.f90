!> One capsule in unbounded simple shear flow, 3D: the membrane (P1 forces) coupled to the
!> fluid (boundary integrals), advanced by RK2 (Heun) or, with --integrator implicit, by
!> linearly implicit ROS2 steps (implicit_step). The time loop and the classification
!> of the run are capsule_model's.
!>
!> Non-dimensional velocity of the membrane nodes (lengths in a, time in 1/gamma_dot,
!> forces in G_s), viscosity ratio 1:  v = v_inf + 1/(8 pi Ca) integral J . f dS,
!> f = F/A_node, F = -dE/dx. With an inner viscosity lambda /= 1 the velocity solves the
!> second-kind equation of interface_equation, v = 2/(1+lambda) (v_inf + S[f]/Ca) + kappa 2D[v],
!> by GMRES from the previous solutions; at lambda = 1 the explicit formula is taken unchanged
!> (the same operations, bit for bit, as before the option existed).
module capsule_dynamics
   use capsim_kinds, only: dp, pi
   use vector_algebra, only: cross
   use hdf5_writer, only: h5_file_t
   use sphere_mesh, only: surface_mesh_t, icosphere
   use membrane_law, only: make_membrane_law
   use membrane_forces, only: membrane_reference_t, membrane_nodal_forces, principal_stretches
   use membrane_bending, only: bending_t
   use stokes_single_layer, only: single_layer_t, triangle_areas, node_areas
   use stokes_double_layer, only: double_layer_t
   use interface_equation, only: interface_equation_t
   use surface_diagnostics, only: shape_measures_t, shape_measures, shear_plane_contour
   use background_flow, only: flow_shear, undisturbed_velocity
   use run_options, only: run_options_t
   use case_output, only: write_surface_mesh, case_summary_t
   use capsule_model, only: capsule_model_t
   use state_vector, only: state_cursor_t
   use text_format, only: int_text, real_text
   use shear_implicit, only: load_stencil_t, single_layer_matrix, stencil_product, add_shear_gradient, &
                             step_matrix_lu, step_solve
   implicit none
   private
   public :: capsule_t

   !> Columns of the history table.
   integer, parameter :: h_t = 1, h_area = 2, h_volume = 3, h_d12 = 4, h_l1 = 5, h_l2 = 6, h_l3 = 7, &
                         h_theta = 8, h_energy = 9, h_stretch = 10
   character(len=*), parameter :: shear_history_names(10) = [character(len=16) :: &
                                  't', 'area', 'volume', 'D12', 'L1', 'L2', 'L3', 'theta', 'energy', 'max_stretch']
   character(len=*), parameter :: shear_history_units(10) = [character(len=16) :: &
                                  '1/gamma_dot', 'a^2', 'a^3', '1', 'a', 'a', 'a', 'rad', 'G_s a^2', '1']

   !> Implicit steps (implicit_step). implicit_tol: the largest error estimate of a step (node
   !> displacement, a); at level 2 it kept the steady D12, L1, L2 and theta within 6e-4 of
   !> RK2's at lambda = 1 (NH Ca_s 0.01-0.2, GH, k_b) and 1.4e-3 at lambda = 5 and 0.2; 3e-4
   !> gave 1.9e-3 (theta, lambda = 5), and at level 3 1e-3 gave 3.6e-3 (theta, Ca_s 0.01).
   !> implicit_dt_max: the largest step (1/gamma_dot). A Jacobian is renewed after
   !> jacobian_max_age accepted steps, or sooner when a step's estimate exceeds stale_error (in
   !> units of the tolerance); the step that comes with it is chosen to make the first estimate
   !> fresh_target: the estimate then grows as the membrane tank-treads away from the Jacobian
   !> (at Ca_s 0.01, from 0.3 to 1 in about 15 steps), and renewals cost more than steps (at
   !> level 3 a Jacobian and its LU take as long as ~50 velocity evaluations).
   !> jacobian_fd_step: the finite-difference step of the load derivative (a).
   real(dp), parameter :: ros2_gamma = 1.0_dp + 1.0_dp / sqrt(2.0_dp)
   real(dp), parameter :: implicit_tol = 2.0e-4_dp, implicit_dt_max = 0.1_dp
   integer, parameter :: jacobian_max_age = 60
   real(dp), parameter :: fresh_target = 0.3_dp, stale_error = 0.8_dp
   !> The LU of I - gamma h J serves steps dt within a factor lu_band of h (see implicit_step).
   real(dp), parameter :: lu_band = 2.0_dp
   real(dp), parameter :: jacobian_fd_step = 1.0e-6_dp

   type, extends(capsule_model_t) :: capsule_t
      type(surface_mesh_t) :: mesh
      type(membrane_reference_t) :: ref
      !> Bending stiffness (--kb); set up only when k_b > 0.
      type(bending_t) :: bending
      type(single_layer_t) :: single_layer
      !> Viscosity ratio; the double layer and its equation are set up only when lambda /= 1.
      real(dp) :: lambda = 1
      type(double_layer_t) :: double_layer
      type(interface_equation_t) :: interface
      !> Solutions of the interface equation at the last two RK2 steps, per stage (1: at x_n,
      !> 2: at the predictor), from which the next solve's initial guess is extrapolated.
      real(dp), allocatable :: v_stage(:, :, :, :), rhs(:, :)
      integer :: n_stage(2) = 0, stage = 1
      integer :: flow = flow_shear
      real(dp) :: ca = 0, h_min = 0, energy = 0
      !> Reference (stress-free) positions; the run starts from them.
      real(dp), allocatable :: x_ref(:, :)
      logical :: volume_correction = .true.
      ! Work arrays allocated once by init: the time loop allocates nothing.
      real(dp), allocatable :: x_pred(:, :), u0(:, :), u1(:, :), force(:, :), density(:, :), v_inf(:, :)
      real(dp), allocatable :: tri_area(:), node_area(:)
      !> --integrator implicit (see implicit_step): the load stencil and its derivative, the
      !> single-layer matrix, the Jacobian and the LU of I - gamma dt J.
      logical :: implicit = .false.
      type(load_stencil_t) :: stencil
      real(dp), allocatable :: sl_matrix(:, :), jacobian(:, :), lu(:, :)
      integer, allocatable :: pivot(:)
      real(dp), allocatable :: k1(:, :), k2(:, :), x_fd(:, :), f_fd(:, :)
      !> Positions at which the Jacobian in use was made: a resumed run makes it again there.
      real(dp), allocatable :: x_jacobian(:, :)
      !> Largest and smallest step; the Jacobian's age in accepted steps; whether the LU must
      !> be redone (new dt or J), J renewed, and the next step's estimate kept (err_fresh).
      real(dp) :: dt_max = 0, dt_min = 0
      integer :: jacobian_age = huge(1)
      logical :: lu_stale = .true., want_refresh = .false., measure_next = .true.
      !> Error estimate (in units of the tolerance) of the first step after the last new
      !> Jacobian or step change, and that step's dt.
      real(dp) :: err_fresh = 0, dt_fresh = 0
      !> The step h of the factorised I - gamma h J.
      real(dp) :: dt_lu = 0
      !> Counts for the run's message (velocity evaluations counted on both paths).
      integer :: n_velocity = 0, n_jacobians = 0, n_factorisations = 0, n_rejected = 0
   contains
      procedure :: init
      procedure :: velocity
      procedure :: advance
      procedure :: run
      procedure :: exchange_state
      procedure :: record
      procedure :: progress_text
      procedure :: write_geometry
   end type capsule_t

contains

   subroutine init(self, opts, stat, errmsg)
      class(capsule_t), intent(inout) :: self
      type(run_options_t), intent(in) :: opts
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: n, t, k
      real(dp) :: h

      call icosphere(opts%level, self%mesh, self%x_ref, stat, errmsg)
      if (stat /= 0) return
      call make_membrane_law(trim(opts%law), opts%nu_s, opts%c, self%law, stat, errmsg)
      if (stat /= 0) return
      n = self%mesh%n_nodes
      self%positions = self%x_ref
      self%start_positions = self%x_ref
      ! Strains are measured from the stress-free sphere of radius 1/(1 + alpha).
      call self%ref%init(self%mesh, self%x_ref / (1.0_dp + opts%prestress))
      ! Bending is measured from the sphere at rest (radius a), pre-stressed or not.
      if (opts%kb > 0.0_dp) call self%bending%init(self%mesh, self%x_ref, opts%kb)
      ! Duffy 4x4 on touching triangles, 7-point rule on the next ring: the quadrature error is
      ! then far below the flat-triangle geometry error (translating-sphere test, orders 3-6).
      call self%single_layer%init(self%mesh, 4, 0)
      allocate (self%x_pred(3, n), self%u0(3, n), self%u1(3, n), self%force(3, n), self%density(3, n))
      allocate (self%v_inf(3, n), self%tri_area(self%mesh%n_tri), self%node_area(n))
      self%h_min = huge(1.0_dp)
      do t = 1, self%mesh%n_tri
         do k = 1, 3
            h = norm2(self%x_ref(:, self%mesh%tri(k, t)) - self%x_ref(:, self%mesh%tri(mod(k, 3) + 1, t)))
            self%h_min = min(self%h_min, h)
         end do
      end do
      self%ca = opts%ca
      self%flow = flow_shear
      self%volume_correction = opts%volume_correction
      self%lambda = opts%lambda
      if (self%lambda /= 1.0_dp) then
         call self%double_layer%init(self%mesh, self%single_layer)
         call self%interface%init(n, self%lambda)
         allocate (self%v_stage(3, n, 2, 2), self%rhs(3, n))
      end if
      ! Explicit membrane stiffness: stable for dt < O(Ca h); 0.02 bounds the advection error.
      if (opts%dt > 0) then
         self%dt = opts%dt
      else if (self%lambda < 1.0_dp) then
         ! A less viscous interior lets the short membrane waves relax up to 2/(1+lambda)
         ! times faster (the single layer's factor; the double layer vanishes on them).
         ! Measured at level 2, Ca 0.1: lambda = 0.001 breaks down at twice the lambda = 1
         ! step, where lambda = 1 still runs; this factor keeps the lambda = 1 margin.
         self%dt = min(opts%dt_factor * opts%ca * self%h_min * (0.5_dp * (1.0_dp + self%lambda)), 0.02_dp)
      else
         self%dt = min(opts%dt_factor * opts%ca * self%h_min, 0.02_dp)
      end if
      ! Bending waves of length h relax at ~ K_B / (mu h**3): stable for dt < O(Ca h**3 / k_b).
      ! Measured at Ca 0.1 (NH): the limit is 1.0 - 1.9 Ca h_min**3 / k_b (level 2 k_b 1,
      ! level 3 k_b 0.1 and 1), so dt_factor keeps the elastic step's margin of about 2.
      if (opts%dt <= 0 .and. opts%kb > 0.0_dp) &
         self%dt = min(self%dt, opts%dt_factor * opts%ca * self%h_min**3 / opts%kb)
      if (trim(opts%integrator) == 'implicit') call init_implicit(self, opts)
      call self%allocate_history(shear_history_names, shear_history_units, opts%t_max, opts%record_every)
      self%col_length = h_l1
      self%col_stretch = h_stretch
      self%col_shape = [h_d12]
      ! D12 decays slowly after its overshoot: the old criterion alone (D12 varies by less
      ! than 5e-3 over one time unit) stopped NH at Ca_s 0.6 1.5 % above the limit.
      self%col_limit = h_d12
      self%area_scale = 4 * pi
      self%length_limit = opts%max_length
      self%shape_rel_tol = opts%shape_tol
   end subroutine init

   !> Membrane velocity at positions x.
   subroutine velocity(self, x, u)
      class(capsule_t), intent(inout) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: u(:, :)
      self%n_velocity = self%n_velocity + 1
      call load_density(self, x, self%density)
      call self%single_layer%velocity(self%mesh, x, self%density, u)
      call undisturbed_velocity(self%flow, x, self%v_inf)
      if (self%lambda /= 1.0_dp) then
         call interface_velocity(self, x, u)
         if (allocated(self%fault)) return
      else
         u = self%v_inf + u / self%ca
      end if
      if (self%volume_correction) call remove_volume_flux(self%mesh, x, u, self%force)
   end subroutine velocity

   !> Membrane load density f = F / A_node at positions x (F in self%force, areas in
   !> self%tri_area, self%node_area).
   subroutine load_density(self, x, density)
      class(capsule_t), intent(inout) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: density(:, :)
      integer :: i
      call membrane_nodal_forces(self%ref, self%mesh, self%law, x, self%force, self%energy)
      if (self%bending%kb > 0.0_dp) call self%bending%add_forces(self%mesh, x, self%force, self%energy)
      call triangle_areas(self%mesh, x, self%tri_area)
      call node_areas(self%mesh, self%tri_area, self%node_area)
      do i = 1, self%mesh%n_nodes
         density(:, i) = self%force(:, i) / self%node_area(i)
      end do
   end subroutine load_density

   !> lambda /= 1: on entry u = S[f] (the single layer of the membrane load), on exit the
   !> solution of u = 2/(1+lambda) (v_inf + S[f]/Ca) + kappa L'[u] (interface_equation).
   subroutine interface_velocity(self, x, u)
      class(capsule_t), intent(inout) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(inout) :: u(:, :)
      integer :: stat
      character(len=:), allocatable :: errmsg
      integer :: k
      k = self%stage
      self%rhs = (2.0_dp / (1.0_dp + self%lambda)) * (self%v_inf + u / self%ca)
      call self%double_layer%set_geometry(self%mesh, x)
      ! Initial guess: the same stage's solutions of the last two steps extrapolated linearly
      ! in time (v(t + dt) = 2 v(t) - v(t - dt) + O(dt**2): 6 operator applications per solve
      ! instead of 7 at level 2, lambda = 5); with one such solution, that solution; the very
      ! first predictor solve starts from the first stage's solution, and the very first
      ! solve from the right-hand side (the lambda = 1 velocity scaled by 2/(1+lambda)).
      if (self%n_stage(k) >= 2) then
         u = 2.0_dp * self%v_stage(:, :, 1, k) - self%v_stage(:, :, 2, k)
      else if (self%n_stage(k) == 1) then
         u = self%v_stage(:, :, 1, k)
      else if (k == 2 .and. self%n_stage(1) > 0) then
         u = self%v_stage(:, :, 1, 1)
      else
         u = self%rhs
      end if
      call self%interface%solve(self%double_layer, self%mesh, self%rhs, u, stat, errmsg)
      if (stat /= 0) then
         self%fault = errmsg
         return
      end if
      self%v_stage(:, :, 2, k) = self%v_stage(:, :, 1, k)
      self%v_stage(:, :, 1, k) = u
      self%n_stage(k) = min(self%n_stage(k) + 1, 2)
   end subroutine interface_velocity

   !> dV/dx_i of the polyhedron at node i: a third of the area vectors of its triangles,
   !> (1/6) sum of (x2 - x1) x (x3 - x1).
   pure function node_volume_gradient(mesh, x, i) result(g)
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      integer, intent(in) :: i
      real(dp) :: g(3)
      integer :: p, t
      g = 0
      do p = mesh%node_tri_start(i), mesh%node_tri_start(i + 1) - 1
         t = mesh%node_tri(p)
         g = g + cross(x(:, mesh%tri(2, t)) - x(:, mesh%tri(1, t)), x(:, mesh%tri(3, t)) - x(:, mesh%tri(1, t)))
      end do
      g = g / 6.0_dp
   end function node_volume_gradient

   !> The exact single layer carries no net flux through the closed membrane, its P1
   !> discretisation does at O(h**2): at level 3, Ca_s = 0.3, the capsule lost 12 % of its
   !> volume over 25 time units, and the lost volume, not the membrane law, then set D12.
   !> Subtracting the spurious flux along the node normals, u_i -= c n_i with
   !> dV/dt = sum_i u_i . dV/dx_i = 0, removes a term of the discretisation error's order.
   !> `grad` is scratch for dV/dx_i = (1/3) sum of the area vectors of the node's triangles.
   subroutine remove_volume_flux(mesh, x, u, grad)
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(inout) :: u(:, :)
      real(dp), intent(out) :: grad(:, :)
      integer :: i
      real(dp) :: flux, norm_sum
      flux = 0
      norm_sum = 0
      !$omp parallel do default(none) shared(mesh, x, u, grad) private(i) &
      !$omp reduction(+:flux, norm_sum) schedule(static)
      do i = 1, mesh%n_nodes
         grad(:, i) = node_volume_gradient(mesh, x, i)
         flux = flux + dot_product(u(:, i), grad(:, i))
         norm_sum = norm_sum + norm2(grad(:, i))
      end do
      !$omp end parallel do
      do i = 1, mesh%n_nodes
         u(:, i) = u(:, i) - (flux / norm_sum) * grad(:, i) / norm2(grad(:, i))
      end do
   end subroutine remove_volume_flux

   subroutine advance(self)
      class(capsule_t), intent(inout) :: self
      if (self%implicit) then
         call implicit_step(self)
      else
         call rk2_step(self)
      end if
   end subroutine advance

   !> Heun's RK2: predictor with v(x), corrector with the mean of v(x) and v(x_pred).
   subroutine rk2_step(self)
      class(capsule_t), intent(inout) :: self
      self%stage = 1
      call self%velocity(self%positions, self%u0)
      if (allocated(self%fault)) return
      self%x_pred = self%positions + self%dt * self%u0
      self%stage = 2
      call self%velocity(self%x_pred, self%u1)
      if (allocated(self%fault)) return
      self%positions = self%positions + 0.5_dp * self%dt * (self%u0 + self%u1)
      self%t = self%t + self%dt
      self%step = self%step + 1
   end subroutine rk2_step

   !> --integrator implicit: the load stencil (radius 2 with bending, whose nodal energy reads
   !> the node's ring of dihedral angles; 1 otherwise) and the dense matrices of the Jacobian.
   !> The first step starts from the explicit step dt and the error control grows it.
   subroutine init_implicit(self, opts)
      class(capsule_t), intent(inout) :: self
      type(run_options_t), intent(in) :: opts
      integer :: n
      n = self%mesh%n_nodes
      self%implicit = .true.
      if (opts%kb > 0.0_dp) then
         call self%stencil%init(self%mesh, 2)
      else
         call self%stencil%init(self%mesh, 1)
      end if
      allocate (self%sl_matrix(3 * n, 3 * n), self%jacobian(3 * n, 3 * n), self%lu(3 * n, 3 * n), self%pivot(3 * n))
      allocate (self%k1(3, n), self%k2(3, n), self%x_fd(3, n), self%f_fd(3, n), self%x_jacobian(3, n))
      self%x_jacobian = 0
      self%dt_max = implicit_dt_max
      self%dt = min(self%dt, self%dt_max)
      self%dt_min = 1.0e-3_dp * self%dt
   end subroutine init_implicit

   !> One step of ROS2, the two-stage Rosenbrock-W method of Verwer et al. (1999,
   !> SIAM J. Sci. Comput. 20, 1456), gamma = 1 + 1/sqrt(2):
   !>     (I - gamma dt J) k1 = u(x_n)
   !>     (I - gamma dt J) k2 = u(x_n + dt k1) - 2 k1
   !>     x_{n+1} = x_n + dt (3/2 k1 + 1/2 k2)
   !> It is of second order for any matrix J (a W-method), so the approximate, reused Jacobian
   !> of refresh_jacobian costs no accuracy, and L-stable for J exact: the stiff membrane modes
   !> that bind RK2 to dt ~ Ca h are damped whatever dt. Two velocity evaluations per step, as
   !> RK2. Why not linearly implicit Euler: a tank-treading membrane never stops moving, and a
   !> first-order step shifts the steady shape by O(dt). The embedded first-order solution
   !> x_n + dt k1 gives the error estimate dt |k1 + k2| / 2 (largest node displacement, a),
   !> held below implicit_tol. With a reused Jacobian the estimate grows with its age (the
   !> stiff modes are damped less exactly), so a step above the tolerance, or one above
   !> stale_error of it, renews the Jacobian (and picks the step for it, see refresh_jacobian);
   !> a step above the tolerance on a new Jacobian is redone shorter; a step far below it (the
   !> start) lengthens the next one on the same Jacobian. The LU of I - gamma h J is kept while
   !> dt stays within a factor lu_band of h: with h /= dt the step is still ROS2 with the matrix
   !> (h/dt) J, second order as any W-method, and on the stiffest modes its amplification
   !> tends to 1 - 2q + q**2/2, q = dt/(gamma h): 0 at dt = h, 0.46 at h/2, -0.66 at 2h (it
   !> stays below 1 in modulus up to dt = 4 gamma h). So a new LU comes with a new Jacobian or
   !> a step change beyond the band, and serves many steps. The volume is then put back to its value at x_n along the node normals (the
   !> RK2 path's flux-free velocity conserves it to O(dt**3) per step; a Rosenbrock increment,
   !> mixing velocities through (I - gamma dt J)^-1, does not).
   subroutine implicit_step(self)
      class(capsule_t), intent(inout) :: self
      integer, parameter :: max_attempts = 30
      integer :: attempt
      real(dp) :: err, growth, v_start
      self%stage = 1
      call self%velocity(self%positions, self%u0)
      if (allocated(self%fault)) return
      err = huge(1.0_dp)
      do attempt = 1, max_attempts
         if (self%jacobian_age >= jacobian_max_age .or. self%want_refresh) call refresh_jacobian(self)
         if (self%lu_stale .or. self%dt > lu_band * self%dt_lu .or. self%dt < self%dt_lu / lu_band) &
            call factorise(self)
         if (allocated(self%fault)) return
         self%k1 = self%u0
         call step_solve(self%lu, self%pivot, self%k1)
         self%x_pred = self%positions + self%dt * self%k1
         self%stage = 2
         call self%velocity(self%x_pred, self%u1)
         if (allocated(self%fault)) return
         self%k2 = self%u1 - 2.0_dp * self%k1
         call step_solve(self%lu, self%pivot, self%k2)
         err = 0.5_dp * self%dt * maxval(norm2(self%k1 + self%k2, dim=1)) / implicit_tol
         if (err <= 1.0_dp) exit
         if (self%dt <= self%dt_min) exit
         self%n_rejected = self%n_rejected + 1
         if (self%jacobian_age > 0) then
            ! Most likely the Jacobian has aged: a new one, with the step it allows.
            self%want_refresh = .true.
         else
            self%dt = max(self%dt_min, self%dt * max(0.2_dp, 0.9_dp / sqrt(err)))
            self%measure_next = .true.
         end if
      end do
      if (.not. (err <= 1.0_dp)) then
         self%fault = 'implicit step: error estimate above tolerance at dt = '//real_text(self%dt)
         return
      end if
      if (self%volume_correction) v_start = enclosed_volume(self%mesh, self%positions)
      self%positions = self%positions + self%dt * (1.5_dp * self%k1 + 0.5_dp * self%k2)
      if (self%volume_correction) call restore_volume(self%mesh, self%positions, v_start, self%force)
      self%t = self%t + self%dt
      self%step = self%step + 1
      self%jacobian_age = self%jacobian_age + 1
      if (self%measure_next) then
         self%err_fresh = max(err, 1.0e-12_dp)
         self%dt_fresh = self%dt
         self%measure_next = .false.
      end if
      growth = sqrt(fresh_target / max(err, 1.0e-12_dp))
      if (growth >= 1.5_dp .and. self%dt < self%dt_max) then
         ! Well below the tolerance (the start): a longer step on the same Jacobian.
         self%dt = min(self%dt_max, min(2.0_dp, growth) * self%dt)
         self%measure_next = .true.
      else if (err > stale_error) then
         self%want_refresh = .true.
      end if
   end subroutine implicit_step

   !> A new Jacobian at the current positions (assemble_jacobian), and the step for it.
   subroutine refresh_jacobian(self)
      class(capsule_t), intent(inout) :: self
      self%x_jacobian = self%positions
      call assemble_jacobian(self)
      ! The step for the new Jacobian: the error of the first step on the last one, scaled to
      ! fresh_target (error ~ dt**2), within a factor of 2.
      if (self%err_fresh > 0.0_dp) self%dt = min(self%dt_max, self%dt_fresh * &
                                               min(2.0_dp, max(0.5_dp, sqrt(fresh_target / self%err_fresh))))
      self%want_refresh = .false.
      self%measure_next = .true.
      self%n_jacobians = self%n_jacobians + 1
      self%jacobian_age = 0
      self%lu_stale = .true.
   end subroutine refresh_jacobian

   !> J = 2/(1+lambda) (grad v_inf + (1/Ca) M K) at x_jacobian (see shear_implicit): M
   !> assembled, K = df/dx by forward differences, one load evaluation per colour and direction.
   !> A function of x_jacobian alone (every loop's iterations are independent), so that a
   !> resumed run makes the same J, bit for bit, whatever the thread count.
   subroutine assemble_jacobian(self)
      class(capsule_t), intent(inout) :: self
      integer :: c, d, j, p, m
      ! f at x, and the areas the matrix needs (load_density leaves them in self%tri_area etc.).
      call load_density(self, self%x_jacobian, self%density)
      call single_layer_matrix(self%single_layer, self%mesh, self%x_jacobian, self%tri_area, self%node_area, &
                               self%sl_matrix)
      associate (st => self%stencil)
         do c = 1, st%n_colours
            do d = 1, 3
               self%x_fd = self%x_jacobian
               do j = 1, self%mesh%n_nodes
                  if (st%colour(j) == c) self%x_fd(d, j) = self%x_fd(d, j) + jacobian_fd_step
               end do
               call load_density(self, self%x_fd, self%f_fd)
               do j = 1, self%mesh%n_nodes
                  if (st%colour(j) /= c) cycle
                  do p = st%start(j), st%start(j + 1) - 1
                     m = st%node(p)
                     st%block(:, d, p) = (self%f_fd(:, m) - self%density(:, m)) / jacobian_fd_step
                  end do
               end do
            end do
         end do
         call stencil_product(self%sl_matrix, st, 2.0_dp / ((1.0_dp + self%lambda) * self%ca), self%jacobian)
      end associate
      call add_shear_gradient(self%jacobian, 2.0_dp / (1.0_dp + self%lambda))
   end subroutine assemble_jacobian

   subroutine factorise(self)
      class(capsule_t), intent(inout) :: self
      integer :: info
      call step_matrix_lu(self%jacobian, ros2_gamma * self%dt, self%lu, self%pivot, info)
      self%dt_lu = self%dt
      self%n_factorisations = self%n_factorisations + 1
      self%lu_stale = .false.
      if (info /= 0) self%fault = 'implicit step: I - gamma dt J is singular (LAPACK dgetrf info '//int_text(info)//')'
   end subroutine factorise

   !> Volume enclosed by the closed, outward-oriented mesh.
   pure real(dp) function enclosed_volume(mesh, x) result(v)
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      integer :: t
      v = 0
      do t = 1, mesh%n_tri
         v = v + dot_product(x(:, mesh%tri(1, t)), cross(x(:, mesh%tri(2, t)), x(:, mesh%tri(3, t))))
      end do
      v = v / 6.0_dp
   end function enclosed_volume

   !> Moves the nodes along their normals, by one common distance, until the volume is v_target
   !> (two Newton steps from a step's O(dt**3) change leave round-off); the direction is
   !> remove_volume_flux's. `grad` is scratch.
   subroutine restore_volume(mesh, x, v_target, grad)
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(inout) :: x(:, :)
      real(dp), intent(in) :: v_target
      real(dp), intent(out) :: grad(:, :)
      integer :: i, iter
      real(dp) :: norm_sum, shift
      do iter = 1, 2
         norm_sum = 0
         do i = 1, mesh%n_nodes
            grad(:, i) = node_volume_gradient(mesh, x, i)
            norm_sum = norm_sum + norm2(grad(:, i))
         end do
         shift = (v_target - enclosed_volume(mesh, x)) / norm_sum
         do i = 1, mesh%n_nodes
            x(:, i) = x(:, i) + shift * grad(:, i) / norm2(grad(:, i))
         end do
      end do
   end subroutine restore_volume

   !> The shared time loop; an implicit run adds its solver counts to the message.
   subroutine run(self, opts, checkpoint_path, summary, steady_index)
      class(capsule_t), intent(inout) :: self
      type(run_options_t), intent(in) :: opts
      character(len=*), intent(in) :: checkpoint_path
      type(case_summary_t), intent(inout) :: summary
      integer, intent(out) :: steady_index
      call self%time_loop(opts, checkpoint_path, summary, steady_index)
      if (self%implicit) then
         summary%message = summary%message//' ('//int_text(self%step)//' implicit steps, '// &
                           int_text(self%n_velocity)//' velocity evaluations, '//int_text(self%n_jacobians)// &
                           ' Jacobians, '//int_text(self%n_factorisations)//' factorisations, '// &
                           int_text(self%n_rejected)//' steps redone)'
      end if
   end subroutine run

   !> Checkpoint state (capsule_model's exchange_state): the positions; at lambda /= 1 the
   !> interface solutions from which the next GMRES guesses are extrapolated; with implicit
   !> steps the step size and all that its control reads (the Jacobian's age and where it was
   !> made, the refresh and measure flags, the fresh error and its step, the LU's step) and
   !> the counts of the run's message. The Jacobian and its LU (3n squared each) are not
   !> stored: a resumed run makes them again where and with the step they were made.
   subroutine exchange_state(self, state, cursor)
      class(capsule_t), intent(inout) :: self
      real(dp), intent(inout) :: state(:)
      type(state_cursor_t), intent(inout) :: cursor
      integer :: info
      call cursor%reals(state, self%positions, size(self%positions))
      if (self%lambda /= 1.0_dp) then
         call cursor%int_value(state, self%n_stage(1))
         call cursor%int_value(state, self%n_stage(2))
         call cursor%reals(state, self%v_stage, size(self%v_stage))
      end if
      if (.not. self%implicit) return
      call cursor%real_value(state, self%dt)
      call cursor%real_value(state, self%err_fresh)
      call cursor%real_value(state, self%dt_fresh)
      call cursor%real_value(state, self%dt_lu)
      call cursor%int_value(state, self%jacobian_age)
      call cursor%flag(state, self%lu_stale)
      call cursor%flag(state, self%want_refresh)
      call cursor%flag(state, self%measure_next)
      call cursor%int_value(state, self%n_velocity)
      call cursor%int_value(state, self%n_jacobians)
      call cursor%int_value(state, self%n_factorisations)
      call cursor%int_value(state, self%n_rejected)
      call cursor%reals(state, self%x_jacobian, size(self%x_jacobian))
      ! No Jacobian before the first step (its age is then huge).
      if (cursor%restoring() .and. self%jacobian_age < jacobian_max_age) then
         call assemble_jacobian(self)
         if (.not. self%lu_stale) then
            call step_matrix_lu(self%jacobian, ros2_gamma * self%dt_lu, self%lu, self%pivot, info)
            if (info /= 0) self%fault = 'resumed implicit step: I - gamma dt J is singular (LAPACK dgetrf info '// &
                                        int_text(info)//')'
         end if
      end if
   end subroutine exchange_state

   !> Append the current diagnostics to the history.
   subroutine record(self)
      class(capsule_t), intent(inout) :: self
      type(shape_measures_t) :: m
      real(dp) :: l1, l2, stretch, energy
      integer :: t
      call shape_measures(self%mesh, self%positions, m)
      stretch = 1.0_dp
      do t = 1, self%mesh%n_tri
         call principal_stretches(self%ref, self%mesh, self%positions, t, l1, l2)
         stretch = max(stretch, l1, 1.0_dp / max(l2, 1.0e-12_dp))
      end do
      ! The force array is scratch here: velocity() recomputes it before every use.
      call membrane_nodal_forces(self%ref, self%mesh, self%law, self%positions, self%force, energy)
      if (self%bending%kb > 0.0_dp) call self%bending%add_forces(self%mesh, self%positions, self%force, energy)
      call self%next_record()
      self%history(:, self%n_rec) = [self%t, m%area, m%volume, m%d12, m%l1, m%l2, m%l3, m%theta, energy, stretch]
   end subroutine record

   function progress_text(self) result(text)
      class(capsule_t), intent(in) :: self
      character(len=:), allocatable :: text
      character(len=80) :: buf
      write (buf, '(a,f8.5,a,f8.4,a,f7.3)') 'D12 = ', self%history(h_d12, self%n_rec), '  L1/a = ', &
         self%history(h_l1, self%n_rec), '  area/4pi = ', self%history(h_area, self%n_rec) / (4 * pi)
      text = trim(buf)
      if (self%lambda /= 1.0_dp .and. self%interface%n_solves > 0) then
         write (buf, '(a,f6.2)') '  GMRES applications/solve = ', &
            real(self%interface%total_applications, dp) / real(self%interface%n_solves, dp)
         text = text//trim(buf)
      end if
   end function progress_text

   !> /mesh (reference and current nodes, triangles 0-based) and /profile (shear-plane contour).
   subroutine write_geometry(self, f, stat, errmsg)
      class(capsule_t), intent(in) :: self
      type(h5_file_t), intent(inout) :: f
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      type(shape_measures_t) :: m
      real(dp), allocatable :: y(:), z(:)
      call shape_measures(self%mesh, self%positions, m)
      call shear_plane_contour(self%mesh, self%positions, m%centroid, y, z)
      call f%write_attr('/', 'n_nodes', self%mesh%n_nodes, stat, errmsg)
      if (stat == 0) call write_surface_mesh(f, self%x_ref, self%positions, self%mesh%tri, 'a', stat, errmsg)
      if (stat == 0) call f%make_group('/profile', stat, errmsg)
      if (stat == 0) call f%write_attr('/profile', 'plane', 'x = x_centroid (shear plane yz)', stat, errmsg)
      if (stat == 0) call f%write_dataset('/profile/y', y, 'a', stat, errmsg)
      if (stat == 0) call f%write_dataset('/profile/z', z, 'a', stat, errmsg)
   end subroutine write_geometry

end module capsule_dynamics
