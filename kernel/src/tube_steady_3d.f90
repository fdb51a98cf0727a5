!> Steady shapes of the 3D tube (and duct) model without time stepping (`--model 3d
!> --integrator newton`): the root of the membrane velocity in the capsule's frame, u(x) = 0,
!> by Jacobian-free Newton-Krylov, from the axisymmetric model's steady shape at the same
!> a/l, Ca_s and law mapped onto the 3D mesh's material points.
!>
!> Why: the explicit steps of tube_capsule are bound to dt ~ Ca_s h (the membrane's stiffest
!> modes), so a level-3 case needs thousands of velocity evaluations to reach its steady
!> shape, while the steady shape itself is the root of one function. Newton's linear systems
!> are solved by GMRES with the Jacobian applied as a directional difference of `velocity`
!> (one evaluation per product), right-preconditioned by the membrane's stiffness seen
!> through the free-space single layer (build_preconditioner), which takes the stiff modes
!> off GMRES's hands.
!>
!> Null directions: u carries no volume flux (the volume correction), the capsule frame
!> removes the axial translation, and the tube is invariant under rotation about its axis.
!> Newton's step is therefore taken in the complement of five directions at x (the volume
!> gradient, the three uniform translations, the rotation about the axis), with the residual
!> projected likewise (the axisymmetric model's bordered system, in projected form); after
!> each step the volume is put back to the start's (the time-stepped run conserves it). The
!> centroid is not put back after a step: a step that keeps the node mean still moves the
!> volume centroid at first order, and re-centring then spoiled every line search at level 2
!> (stalled at 2e-4 V); the written shape is re-centred.
!>
!> Where an attempt from the guess fails (a mapped shape far from the 3D mesh's own, or one
!> whose short waves spoil the line search), the guess is time-stepped by the run's own RK2 in
!> short warm-ups, with a Newton attempt after each; every attempt and the whole solve have a
!> budget of velocity evaluations, and a solve that spends it ends `failed` saying so.
!>
!> Stability: after convergence, the rightmost eigenvalue of the linearised time-stepped
!> dynamics at the steady shape, by a Jacobi-Davidson iteration preconditioned by the stiffness
!> preconditioner (estimate_growth_rate); a shape whose rightmost eigenvalue has a real part
!> above stable_rate_limit_3d is written with stable = 0 and its message says NOT STABLE.
module tube_steady_3d
   use capsim_kinds, only: dp, pi
   use omp_lib, only: omp_get_wtime
   use lapack_interfaces, only: dgeev, dgetrf, dgetrs, dgesv
   use hdf5_writer, only: h5_file_t
   use file_ops, only: delete_file
   use run_options, only: run_options_t
   use case_output, only: case_summary_t
   use capsule_model, only: num
   use text_format, only: int_text
   use vector_algebra, only: cross
   use sphere_mesh, only: surface_mesh_t
   use surface_diagnostics, only: area_and_volume
   use membrane_forces, only: membrane_nodal_forces
   use stokes_single_layer, only: triangle_areas, node_areas
   use axisymmetric_tube, only: axisymmetric_tube_t
   use tube_capsule, only: tube_capsule_t, volume_gradients, recentre, volume_centroid
   implicit none
   private
   public :: tube_steady_capsule_t, stability

   !> Largest projected membrane velocity (V) at which Newton stops: a twentieth of the
   !> time-stepped run's steady criterion (lengths and v_c settled to 1e-3 per l/V). The
   !> velocity is smooth in the nodes only to ~1e-5 V: the near-field quadratures switch rules
   !> at distance thresholds, so a step of 1e-5 l can jump the residual by that much (level 2,
   !> a/l 0.8, Ca_s 0.05: the line search stalls at 1.2e-5 V). Where it stalls below
   !> noise_tol, the shape is accepted as the root to that noise (the message says so).
   real(dp), parameter :: newton_tol_3d = 5.0e-5_dp, noise_tol = 1.0e-4_dp
   !> Directional differences move the nodes by at most this (l). Small, because the rule
   !> switches of the quadratures (above) spoil every difference that crosses one: at level 2
   !> (a/l 0.8, Ca_s 0.05) 1e-8, 1e-7 and 1e-6 reached the noise (~1.2e-5 V) within 108-112
   !> velocity evaluations, while 1e-5 stalled at 6e-3 V and 1e-4 at 2e-3 V.
   real(dp), parameter :: fd_size = 1.0e-7_dp
   !> Krylov vectors per GMRES cycle and GMRES products per Newton step at most.
   integer, parameter :: krylov_dim = 120, max_products = 600
   integer, parameter :: max_newton = 20
   !> Velocity evaluations at most: for each Newton attempt, and for the whole solve (warm-ups
   !> included). A level-3 case converges from the axisymmetric guess in ~150.
   integer, parameter :: attempt_evaluations = 400, max_evaluations = 3000
   !> Residual (V) below which an attempt is not cut at attempt_evaluations: from there Newton
   !> converged within a few steps wherever it got there (level 2, a/l 0.4-0.9).
   real(dp), parameter :: near_root = 1.0e-3_dp
   !> The preconditioner is rebuilt at the current shape after a Newton step whose GMRES
   !> needed more products than this (it was built at a shape that no longer resembles x).
   integer, parameter :: rebuild_products = 60
   !> Time-stepped warm-ups (l/V of the run's own RK2, continued from the guess) between failed
   !> Newton attempts: they damp the membrane's short waves that the mapped guess excites, and
   !> bring a guess far from the 3D mesh's own shape nearer; warm_up_time each, up to
   !> max_warm_up_time in all.
   real(dp), parameter :: warm_up_time = 0.5_dp, max_warm_up_time = 3.0_dp
   !> Largest node displacement of one Newton step, in capsule radii.
   real(dp), parameter :: max_step = 0.05_dp
   !> A steady shape is flagged as not stable when its growth rate (estimate_growth_rate)
   !> exceeds this (V/l). Set when the estimate (Ritz values of Newton's GMRES cycle) carried
   !> the velocity's noise, up to +0.026 V/l at level 2 on shapes that time stepping reaches;
   !> the estimate's error is now within growth_tol (0.01), and a level-2 shape with a rate of
   !> +0.075 V/l confirmed by time stepping (a/l 0.8, Ca_s 0.06, small wall) passes unflagged.
   !> The instabilities the axisymmetric model met (the buckling rear pole, ~ +9 V/l) are far
   !> above.
   real(dp), parameter :: stable_rate_limit_3d = 0.1_dp
   !> Number of constraint directions (volume, three translations, rotation about the axis).
   integer, parameter :: n_constraints = 5
   !> The growth-rate estimate (estimate_growth_rate): a Ritz pair counts as converged when
   !> its residual |A u - theta u| (|u| = 1) is below growth_tol max(1, |theta|) V/l, a
   !> tenth of stable_rate_limit_3d, so that the flag is decided by the eigenvalue and not by
   !> the estimate's error. The search space starts from growth_start vectors smoothed by
   !> growth_smoothing applications of the preconditioner (M^-1 damps the stiff membrane
   !> modes, leaving the slow ones that decide the sign), holds at most growth_basis vectors
   !> (then restarted on the growth_keep rightmost Ritz vectors), and spends at most
   !> growth_budget velocity evaluations (two or three per product).
   real(dp), parameter :: growth_tol = 1.0e-2_dp
   integer, parameter :: growth_start = 4, growth_smoothing = 2, growth_basis = 40, growth_keep = 10, &
                         growth_budget = 300
   !> Ritz values this small (V/l) belong to exact null directions (Newton's J_P had them at
   !> level 2, a/l 0.8, Ca_s 0.06: -1.7e-10 and -3.6e-14, residuals ~1e-10); the constraints
   !> of the estimate's operator remove them, and this keeps any left out of the choice.
   real(dp), parameter :: null_rate = 1.0e-8_dp

   type, extends(tube_capsule_t) :: tube_steady_capsule_t
      !> The start's polyhedron volume, which the time-stepped run conserves.
      real(dp) :: volume0 = 0
      integer :: newton_iterations = 0, gmres_products = 0, velocity_evaluations = 0
      !> Real part of the rightmost eigenvalue of the linearised time-stepped dynamics (V/l;
      !> huge where the estimate did not converge), its imaginary part, the residual of its
      !> Ritz pair, the velocity evaluations the estimate spent, and its eigenvector (the real
      !> part, |.| = 1; not allocated where the estimate did not converge).
      real(dp) :: growth_rate = huge(1.0_dp), growth_frequency = 0, growth_residual = huge(1.0_dp)
      integer :: growth_evaluations = 0
      real(dp), allocatable :: growth_mode(:, :)
      !> Largest membrane velocity without the projection (V).
      real(dp) :: residual_full = huge(1.0_dp)
      real(dp) :: seconds_guess = 0
      character(len=:), allocatable :: guess_source
      real(dp), allocatable :: basis(:, :, :)
      !> LU of the preconditioner (build_preconditioner) and the number of its builds.
      real(dp), allocatable :: precond_lu(:, :)
      integer, allocatable :: precond_pivot(:)
      integer :: precond_builds = 0
      real(dp) :: seconds_preconditioner = 0
      !> Newton stopped below noise_tol where the line search found no descent.
      logical :: stalled = .false.
   contains
      procedure :: run => steady_run
      procedure :: solve => steady_solve
      procedure :: write_geometry => steady_write_geometry
   end type tube_steady_capsule_t

contains

   !> Newton-Krylov from the axisymmetric guess; one history row, the steady shape at t = 0.
   subroutine steady_run(self, opts, checkpoint_path, summary, steady_index)
      class(tube_steady_capsule_t), intent(inout) :: self
      type(run_options_t), intent(in) :: opts
      character(len=*), intent(in) :: checkpoint_path
      type(case_summary_t), intent(inout) :: summary
      integer, intent(out) :: steady_index
      real(dp) :: t0
      t0 = omp_get_wtime()
      call axisymmetric_guess(self, opts, checkpoint_path)
      self%seconds_guess = omp_get_wtime() - t0
      call steady_solve(self, opts, .true., summary, steady_index)
   end subroutine steady_run

   !> Newton-Krylov from the current positions (the guess, named by guess_source) at the
   !> model's Ca_s; with `warm_ups`, failed attempts are followed by RK2 warm-ups and new
   !> attempts (steady_run), without, one attempt decides (a branch step, which bisects
   !> instead). The solver's counters are this solve's; one history row, the shape at t = 0.
   subroutine steady_solve(self, opts, warm_ups, summary, steady_index)
      class(tube_steady_capsule_t), intent(inout) :: self
      type(run_options_t), intent(in) :: opts
      logical, intent(in) :: warm_ups
      type(case_summary_t), intent(inout) :: summary
      integer, intent(out) :: steady_index
      real(dp) :: area, warmed
      real(dp), allocatable :: warm(:, :)
      character(len=:), allocatable :: source
      logical :: converged
      character(len=:), allocatable :: how, first_attempt

      steady_index = 0
      summary%dt = 0
      if (.not. allocated(self%basis)) then
         call area_and_volume(self%mesh, self%start_positions, area, self%volume0)
         allocate (self%basis(3, self%mesh%n_nodes, n_constraints))
      end if
      self%newton_iterations = 0
      self%gmres_products = 0
      self%velocity_evaluations = 0
      self%precond_builds = 0
      self%seconds_preconditioner = 0
      self%stalled = .false.
      warm = self%positions
      source = self%guess_source
      first_attempt = ''
      call newton_krylov(self, newton_tol_3d, attempt_evaluations, opts%quiet, converged, how)
      warmed = 0
      do while (warm_ups .and. .not. converged .and. self%velocity_evaluations < max_evaluations .and. &
                warmed < max_warm_up_time)
         ! Another attempt from the guess time-stepped warm_up_time further.
         if (warmed == 0) first_attempt = '; the first attempt, from the '//source//' shape, stopped: '//how
         self%positions = warm
         call rk2_warm_up(self, warm_up_time, opts%quiet)
         warm = self%positions
         warmed = warmed + warm_up_time
         self%guess_source = 'warmed-up ('//source//', then '//num(warmed)//' l/V of RK2)'
         call newton_krylov(self, newton_tol_3d, min(self%velocity_evaluations + attempt_evaluations, max_evaluations), &
                            opts%quiet, converged, how)
      end do
      if (.not. converged .and. warmed > 0) how = how//' (the last of '//int_text(nint(warmed / warm_up_time) + 1)// &
                                                  ' attempts; the budget: '//int_text(max_evaluations)// &
                                                  ' velocity evaluations, '//num(max_warm_up_time)//' l/V of warm-up)'
      self%growth_rate = huge(1.0_dp)
      self%growth_evaluations = 0
      if (converged) call estimate_growth_rate(self, opts%quiet)
      ! Mid-tube, on the axis, as the time-stepped run keeps it (the velocity barely notices).
      call recentre(self%mesh, self%positions, axial_only=.false.)
      self%t = 0
      self%step = self%newton_iterations
      self%n_rec = 0
      call self%record()
      if (converged) then
         summary%status = 'steady'
         summary%message = ''
         if (stability(self) == 0) summary%message = 'NOT STABLE (a growth rate above '//num(stable_rate_limit_3d)// &
                                                     ' V/l): '
         summary%message = summary%message//'Newton-Krylov from the '//self%guess_source//' shape, '// &
                           int_text(self%newton_iterations)//' Newton steps, '//int_text(self%gmres_products)// &
                           ' GMRES products, '//int_text(self%velocity_evaluations)// &
                           ' velocity evaluations: residual (largest projected membrane velocity) '// &
                           num(self%residual)//' V (unprojected '//num(self%residual_full)//')'
         if (self%stalled) summary%message = summary%message//', where the quadrature noise stopped the line search'
         if (stability(self) < 0) then
            summary%message = summary%message//'; growth rate unknown (the rightmost Ritz value did not converge in '// &
                              int_text(self%growth_evaluations)//' velocity evaluations: residual '// &
                              num(self%growth_residual)//' V/l)'
         else
            summary%message = summary%message//'; largest growth rate '//num(self%growth_rate)//' V/l'
            if (self%growth_frequency /= 0.0_dp) summary%message = summary%message//' (a pair, frequency '// &
                                                                   num(abs(self%growth_frequency))//' V/l)'
            summary%message = summary%message//' ('//int_text(self%growth_evaluations)//' of the evaluations)'
         end if
         summary%message = summary%message//first_attempt
         steady_index = self%n_rec
      else
         summary%status = 'failed'
         summary%message = 'Newton-Krylov from the '//self%guess_source//' shape did not converge: '//how// &
                           ' (residual '//num(self%residual)//' V after '//int_text(self%newton_iterations)// &
                           ' Newton steps and '//int_text(self%velocity_evaluations)//' velocity evaluations)'// &
                           first_attempt
      end if
      summary%volume_change = 0
   end subroutine steady_solve

   !> The case file's geometry, and the solver's figures as root attributes.
   subroutine steady_write_geometry(self, f, stat, errmsg)
      class(tube_steady_capsule_t), intent(in) :: self
      type(h5_file_t), intent(inout) :: f
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      call self%tube_capsule_t%write_geometry(f, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'steady_solver', 'newton-krylov', stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'newton_residual', self%residual, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'newton_residual_unprojected', self%residual_full, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'newton_iterations', self%newton_iterations, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'gmres_products', self%gmres_products, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'velocity_evaluations', self%velocity_evaluations, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'growth_rate', self%growth_rate, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'growth_rate_residual', self%growth_residual, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'growth_rate_evaluations', self%growth_evaluations, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'stable', stability(self), stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'initial_guess', self%guess_source, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'initial_guess_s', self%seconds_guess, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'preconditioner_s', self%seconds_preconditioner, stat, errmsg)
   end subroutine steady_write_geometry

   !> 1: stable, 0: not stable (growth rate above stable_rate_limit_3d), -1: unknown (the
   !> estimate did not converge).
   pure integer function stability(self)
      class(tube_steady_capsule_t), intent(in) :: self
      if (self%growth_rate == huge(1.0_dp)) then
         stability = -1
      else
         stability = merge(1, 0, self%growth_rate <= stable_rate_limit_3d)
      end if
   end function stability

   !> The axisymmetric model's steady meridian at the same a/l, Ca_s, law (its default solver
   !> and meridian), mapped onto the 3D nodes by their material polar angle (linear in the
   !> angle between meridian nodes) and azimuth; the start shape if that model is not steady.
   !> In a duct the circular tube of radius the half-width stands in.
   subroutine axisymmetric_guess(self, opts, checkpoint_path)
      class(tube_steady_capsule_t), intent(inout) :: self
      type(run_options_t), intent(in) :: opts
      character(len=*), intent(in) :: checkpoint_path
      type(axisymmetric_tube_t) :: axi
      type(run_options_t) :: axi_opts
      type(case_summary_t) :: axi_summary
      character(len=:), allocatable :: errmsg, axi_checkpoint
      real(dp) :: theta, phi, s, w, r, z, rho
      integer :: stat, steady_index, i, k, n_m

      self%positions = self%start_positions
      self%guess_source = 'start (sphere)'
      axi_opts = opts
      axi_opts%model = 'axi'
      axi_opts%integrator = 'auto'
      axi_opts%channel = 'tube'
      axi_opts%aspect = 1.0_dp
      axi_opts%quiet = .true.
      axi_opts%dt = 0.0_dp
      axi_opts%checkpoint_every = huge(1.0_dp)
      axi_checkpoint = checkpoint_path//'.axisymmetric'
      call axi%init(axi_opts, stat, errmsg)
      if (stat /= 0) return
      call axi%run(axi_opts, axi_checkpoint, axi_summary, steady_index)
      call delete_file(axi_checkpoint)
      if (steady_index == 0) return
      n_m = size(axi%positions, 2)
      do i = 1, self%mesh%n_nodes
         rho = norm2(self%x_ref(:, i))
         theta = acos(max(-1.0_dp, min(1.0_dp, self%x_ref(3, i) / rho)))
         phi = atan2(self%x_ref(2, i), self%x_ref(1, i))
         ! Meridian node k sits at the material angle pi (k - 1) / (n_m - 1), front first.
         s = theta / pi * (n_m - 1)
         k = min(int(s) + 1, n_m - 1)
         w = s - (k - 1)
         r = (1.0_dp - w) * axi%positions(1, k) + w * axi%positions(1, k + 1)
         z = (1.0_dp - w) * axi%positions(2, k) + w * axi%positions(2, k + 1)
         self%positions(:, i) = [r * cos(phi), r * sin(phi), z]
      end do
      self%guess_source = 'axisymmetric'
   end subroutine axisymmetric_guess

   !> The run's own RK2 steps (tube_capsule's, at its dt) for `duration` l/V from the current
   !> positions.
   subroutine rk2_warm_up(self, duration, quiet)
      class(tube_steady_capsule_t), intent(inout) :: self
      real(dp), intent(in) :: duration
      logical, intent(in) :: quiet
      integer :: k, n_steps
      n_steps = ceiling(duration / self%dt)
      if (.not. quiet) write (*, '(a,i0,a)') 'capsim: Newton attempt failed; ', n_steps, ' RK2 steps of warm-up'
      do k = 1, n_steps
         call self%advance()
         self%velocity_evaluations = self%velocity_evaluations + 2
      end do
   end subroutine rk2_warm_up

   !> Newton's iterations on P u(x) = 0 (P the projection off the constraint directions at x),
   !> until the run has spent `evaluation_budget` velocity evaluations in all.
   subroutine newton_krylov(self, tol, evaluation_budget, quiet, converged, how)
      class(tube_steady_capsule_t), intent(inout) :: self
      real(dp), intent(in) :: tol
      integer, intent(in) :: evaluation_budget
      logical, intent(in) :: quiet
      logical, intent(out) :: converged
      character(len=:), allocatable, intent(out) :: how
      real(dp), allocatable :: x(:, :), r(:, :), pr(:, :), delta(:, :), x_try(:, :), r_try(:, :), pr_try(:, :)
      real(dp) :: res2, res2_try, res2_prev, alpha, eta
      integer :: n, products, steps
      logical :: solved

      converged = .false.
      steps = 0
      how = 'no Newton step taken'
      n = self%mesh%n_nodes
      allocate (x(3, n), r(3, n), pr(3, n), delta(3, n), x_try(3, n), r_try(3, n), pr_try(3, n))
      x = self%positions
      call restore_volume_and_centre(self, x, .true.)
      call residual_at(self, x, r, pr, res2)
      res2_prev = res2
      call build_preconditioner(self, x)
      do
         self%residual = maxval(abs(pr))
         self%residual_full = maxval(abs(r))
         self%positions = x
         if (.not. quiet) write (*, '(a,i0,a,es10.3,a,es10.3,a,i0,a)') 'capsim: Newton step ', self%newton_iterations, &
            ': residual ', self%residual, ' V (unprojected ', self%residual_full, ' V), ', self%velocity_evaluations, &
            ' velocity evaluations'
         if (self%residual < tol) then
            converged = .true.
            return
         end if
         if (steps >= max_newton) then
            how = 'no convergence in '//int_text(max_newton)//' Newton steps'
            return
         end if
         ! An attempt that is near the root goes on, to the solve's whole budget.
         if (self%velocity_evaluations >= max_evaluations .or. &
             (self%velocity_evaluations >= evaluation_budget .and. self%residual > near_root)) then
            how = 'the budget of '//int_text(min(evaluation_budget, max_evaluations))//' velocity evaluations was spent'
            return
         end if
         ! Eisenstat-Walker forcing: loose far from the root, tighter as Newton converges.
         eta = 0.1_dp
         if (self%newton_iterations > 0) eta = min(0.1_dp, max(1.0e-3_dp, 0.9_dp * (res2 / res2_prev)**2))
         call gmres(self, x, r, -pr, max(eta * res2, 0.1_dp * tol), &
                    min(max_products, max_evaluations - self%velocity_evaluations), delta, products, solved)
         self%gmres_products = self%gmres_products + products
         ! A step larger than max_step a is along a direction the Jacobian barely sees (GMRES's
         ! loose first solve at a/l 0.4, Ca_s 0.05 moved nodes by 0.86 l): cut to that length.
         if (maxval(abs(delta)) > max_step * self%a) delta = (max_step * self%a / maxval(abs(delta))) * delta
         alpha = 1.0_dp
         do
            x_try = x + alpha * delta
            call restore_volume_and_centre(self, x_try, .false.)
            call residual_at(self, x_try, r_try, pr_try, res2_try)
            if (res2_try < (1.0_dp - 1.0e-4_dp * alpha) * res2) exit
            alpha = 0.5_dp * alpha
            if (alpha < 1.0_dp / 32) then
               call constraint_basis(self, x)
               if (self%residual < noise_tol) then
                  converged = .true.
                  self%stalled = .true.
               else
                  how = 'the line search found no descent (GMRES '//trim(merge('converged    ', 'did not reach', solved))// &
                        ' its tolerance)'
               end if
               return
            end if
         end do
         x = x_try
         r = r_try
         pr = pr_try
         res2_prev = res2
         res2 = res2_try
         self%newton_iterations = self%newton_iterations + 1
         steps = steps + 1
         if (products > rebuild_products) call build_preconditioner(self, x)
      end do
   end subroutine newton_krylov

   !> Right-preconditioned GMRES(krylov_dim) on J_P delta = b from delta = 0, with
   !> J_P v = P (u(x + e v) - u(x)) / e and delta = P M^-1 y (M the stiffness preconditioner),
   !> until |b - J_P delta| <= tol_abs or product_limit products.
   subroutine gmres(self, x, r, b, tol_abs, product_limit, delta, products, solved)
      class(tube_steady_capsule_t), intent(inout) :: self
      real(dp), intent(in) :: x(:, :), r(:, :), b(:, :), tol_abs
      integer, intent(in) :: product_limit
      real(dp), intent(out) :: delta(:, :)
      integer, intent(out) :: products
      logical, intent(out) :: solved
      real(dp), allocatable :: v(:, :, :), z(:, :, :), w(:, :), resid(:, :)
      real(dp) :: h(krylov_dim + 1, krylov_dim), cs(krylov_dim), sn(krylov_dim)
      real(dp) :: g(krylov_dim + 1), y(krylov_dim), beta, c, temp, subdiagonal
      integer :: n, i, j, k, pass

      n = size(x, 2)
      allocate (v(3, n, krylov_dim + 1), z(3, n, krylov_dim), w(3, n), resid(3, n))
      delta = 0.0_dp
      resid = b
      products = 0
      solved = .false.
      do
         beta = norm2(resid)
         if (beta <= tol_abs) then
            solved = .true.
            return
         end if
         v(:, :, 1) = resid / beta
         g = 0.0_dp
         g(1) = beta
         h = 0.0_dp
         k = 0
         do j = 1, krylov_dim
            z(:, :, j) = v(:, :, j)
            call apply_preconditioner(self, z(:, :, j))
            call jacobian_product(self, x, r, z(:, :, j), w)
            products = products + 1
            ! Modified Gram-Schmidt, twice: the basis stays orthogonal to rounding over a
            ! 120-vector cycle.
            do pass = 1, 2
               do i = 1, j
                  c = sum(w * v(:, :, i))
                  h(i, j) = h(i, j) + c
                  w = w - c * v(:, :, i)
               end do
            end do
            h(j + 1, j) = norm2(w)
            subdiagonal = h(j + 1, j)
            if (h(j + 1, j) > 0.0_dp) v(:, :, j + 1) = w / h(j + 1, j)
            do i = 1, j - 1
               temp = cs(i) * h(i, j) + sn(i) * h(i + 1, j)
               h(i + 1, j) = -sn(i) * h(i, j) + cs(i) * h(i + 1, j)
               h(i, j) = temp
            end do
            temp = hypot(h(j, j), h(j + 1, j))
            cs(j) = h(j, j) / temp
            sn(j) = h(j + 1, j) / temp
            h(j, j) = temp
            h(j + 1, j) = 0.0_dp
            g(j + 1) = -sn(j) * g(j)
            g(j) = cs(j) * g(j)
            k = j
            if (abs(g(j + 1)) <= tol_abs .or. products >= product_limit .or. subdiagonal == 0.0_dp) exit
         end do
         do i = k, 1, -1
            y(i) = (g(i) - dot_product(h(i, i + 1:k), y(i + 1:k))) / h(i, i)
         end do
         do i = 1, k
            delta = delta + y(i) * z(:, :, i)
         end do
         if (abs(g(k + 1)) <= tol_abs) then
            solved = .true.
            return
         end if
         if (products >= product_limit) return
         ! Restart from the true residual.
         call jacobian_product(self, x, r, delta, w)
         products = products + 1
         resid = b - w
      end do
   end subroutine gmres

   !> The rightmost eigenvalue of the linearised time-stepped dynamics at the steady shape
   !> (positions): A = Pi J on the shapes that keep the constraints, J the velocity's Jacobian
   !> (directional differences, as Newton's), Pi the projection that the time-stepped run
   !> applies (dynamics_projector: the volume centroid held on the axis and mid-tube, the
   !> volume and the rotation about the axis fixed). By Jacobi-Davidson with the stiffness
   !> preconditioner M (Sleijpen & van der Vorst's one-step approximation of the correction
   !> equation): Rayleigh-Ritz of A on an orthonormal search space Q (W = A Q, one velocity
   !> evaluation per vector), the Ritz pair (theta, u) of largest real part, and the space
   !> expanded by t = Pi (M^-1 res - eps M^-1 u), eps = (u . M^-1 res) / (u . M^-1 u), and by
   !> res = A u - theta u itself (a complex pair: M^-1 of the real and imaginary parts of
   !> res), until the residual is below growth_tol max(1, |theta|) and a fresh product along
   !> the Ritz vector confirms it. The correction alone stagnated where M, which knows the
   !> membrane and not the walls, is a poor inverse on the slow modes (level 2, a/l 0.8, Ca_s
   !> 0.1 from the axisymmetric guess: residual 0.62 V/l after 200 evaluations); with the
   !> residual, converged in 179 (+0.090 V/l).
   !> Not Newton's J_P: its orthogonal projection removes the node mean of a lateral
   !> displacement where the run recentres the volume centroid, and as a lateral shift of the
   !> capsule is no symmetry of the tube (the shifted capsule's velocity is no shift of the
   !> centred one's), the two operators have other spectra: at level 2, a/l 0.8, Ca_s 0.06,
   !> J_P's rightmost Ritz value converged to +0.40 V/l where time stepping along its vector
   !> grew at +0.03 V/l.
   !> Why: the spectrum of J_P spans the stiff membrane modes (rates ~ -1/(Ca h), hundreds of
   !> V/l) and the slow ones (|rate| < 1 V/l) whose sign decides stability; Krylov vectors of
   !> J_P itself resolve the stiff end first, and a GMRES cycle built for Newton's step (the
   !> estimate used before) left the rightmost Ritz value unconverged on deep parachutes. M
   !> takes the stiff modes off (M^-1 amplifies the slow ones), so each expansion adds what
   !> the rightmost pair still lacks, and the residual test decides convergence at this shape.
   !> Sets growth_rate (huge where it did not converge within growth_budget),
   !> growth_frequency, growth_residual, growth_mode and growth_evaluations; the positions are
   !> left as they are.
   subroutine estimate_growth_rate(self, quiet)
      class(tube_steady_capsule_t), intent(inout) :: self
      logical, intent(in) :: quiet
      real(dp), allocatable :: x(:, :), r(:, :), pr(:, :), q(:, :, :), w(:, :, :), t(:, :), u_re(:, :), u_im(:, :), &
                               res_re(:, :), res_im(:, :), mu(:, :), keep(:, :), q_new(:, :, :), w_new(:, :, :)
      real(dp) :: hs(growth_basis, growth_basis), a(growth_basis, growth_basis), wr(growth_basis), wi(growth_basis), &
                  vr(growth_basis, growth_basis), work(8 * growth_basis), vl(1, 1), c_re(growth_basis), c_im(growth_basis)
      real(dp) :: res2, theta, freq, scale, residual, eps
      real(dp), allocatable :: removed(:, :, :), normals(:, :, :)
      real(dp) :: coupling(n_constraints, n_constraints)
      integer :: n, m, i, j, k, info, pick, n_keep, evaluations0
      logical :: added, added_residual

      evaluations0 = self%velocity_evaluations
      self%growth_rate = huge(1.0_dp)
      self%growth_frequency = 0
      self%growth_residual = huge(1.0_dp)
      if (allocated(self%growth_mode)) deallocate (self%growth_mode)
      n = self%mesh%n_nodes
      allocate (x(3, n), r(3, n), pr(3, n), q(3, n, growth_basis), w(3, n, growth_basis), t(3, n), u_re(3, n), &
                u_im(3, n), res_re(3, n), res_im(3, n), mu(3, n))
      x = self%positions
      call residual_at(self, x, r, pr, res2)
      if (.not. allocated(self%precond_lu)) call build_preconditioner(self, x)
      call dynamics_projector(self%mesh, x, removed, normals, coupling)
      m = 0
      hs = 0.0_dp
      do k = 1, growth_start
         ! Deterministic, uncorrelated start vectors (a run is repeatable bit for bit).
         do i = 1, n
            do j = 1, 3
               t(j, i) = sin(1.0e3_dp * real(k, dp) + 12.9898_dp * real(3 * i + j, dp) * real(k, dp))
            end do
         end do
         do i = 1, growth_smoothing
            call apply_preconditioner(self, t)
            t = t / norm2(t)
         end do
         call constrain(t)
         call add_vector(t, added)
      end do
      do
         ! Rayleigh-Ritz: the pair of largest real part, past the exact null directions.
         a(1:m, 1:m) = hs(1:m, 1:m)
         call dgeev('N', 'V', m, a, growth_basis, wr, wi, vl, 1, vr, growth_basis, work, size(work), info)
         if (info /= 0) exit
         pick = rightmost(m)
         if (pick == 0) exit
         call ritz_pair(pick, m)
         self%growth_residual = residual
         if (.not. quiet) write (*, '(a,i0,a,es11.3,a,es10.3,a,es10.3,a)') 'capsim: growth rate, ', m, &
            ' vectors: rightmost Ritz value ', theta, ' V/l (frequency ', freq, ', residual ', residual, ')'
         if (residual <= growth_tol * max(1.0_dp, hypot(theta, freq))) then
            ! Confirmed by a fresh product along the Ritz vector's real part, A u_re =
            ! theta u_re - freq u_im: the pair is an eigenpair of the operator, not of the
            ! columns of W alone.
            call dynamics_product(u_re, t)
            residual = max(residual, norm2(t - (theta * u_re - freq * u_im)) / norm2(u_re))
            self%growth_residual = residual
            if (.not. quiet) write (*, '(a,es10.3,a)') 'capsim: growth rate, fresh product: residual ', residual, ' V/l'
            if (residual <= growth_tol * max(1.0_dp, hypot(theta, freq))) then
               self%growth_rate = theta
               self%growth_frequency = freq
               self%growth_mode = u_re / norm2(u_re)
               exit
            end if
         end if
         if (self%velocity_evaluations - evaluations0 >= growth_budget) exit
         if (m + 2 > growth_basis) call thick_restart()
         ! The expansion: the correction equation's one-step approximation with M.
         if (freq == 0.0_dp) then
            t = res_re
            call apply_preconditioner(self, t)
            mu = u_re
            call apply_preconditioner(self, mu)
            eps = sum(u_re * t) / sum(u_re * mu)
            t = t - eps * mu
            call constrain(t)
            call add_vector(t, added)
            ! The residual too: the space then holds the Krylov space of A around u, which
            ! goes on where M's correction stagnates (M knows the membrane, not the walls).
            t = res_re
            call add_vector(t, added_residual)
            added = added .or. added_residual
         else
            t = res_re
            call apply_preconditioner(self, t)
            call constrain(t)
            call add_vector(t, added)
            t = res_im
            call apply_preconditioner(self, t)
            call constrain(t)
            call add_vector(t, added)
         end if
         if (.not. added) then
            ! M^-1 res lies in the space already: the residual itself goes in.
            t = res_re + res_im
            call add_vector(t, added)
            if (.not. added) exit
         end if
      end do
      self%growth_evaluations = self%velocity_evaluations - evaluations0

   contains

      !> v <- Pi v: v - removed coupling^-1 (normals . v).
      subroutine constrain(v)
         real(dp), intent(inout) :: v(:, :)
         real(dp) :: a(n_constraints)
         integer :: j
         do j = 1, n_constraints
            a(j) = sum(normals(:, :, j) * v)
         end do
         a = matmul(coupling, a)
         do j = 1, n_constraints
            v = v - a(j) * removed(:, :, j)
         end do
      end subroutine constrain

      !> w = A v = Pi J v by differences that no switch of the quadrature rules spoils. A
      !> Newton root sits where the residual's noise stopped the line search, often within a
      !> difference step of a rule switch (the velocity jumps by ~1e-5 V there: level 2, a/l
      !> 0.8, Ca_s 0.06, 17 of 30 one-sided products were off by 5-80 % of their size), and
      !> a jump over a step e adds jump/e to the product. The forward and backward
      !> differences agree to the step's second order where neither crosses a switch: then
      !> their mean (a central difference); where they do not, the forward one counts if the
      !> forward difference over 2e agrees with it (a jump would be halved), the backward
      !> one otherwise. Two or three velocity evaluations per product.
      subroutine dynamics_product(v, w)
         real(dp), intent(in) :: v(:, :)
         real(dp), intent(out) :: w(:, :)
         !> Relative disagreement of two differences above which one has crossed a switch:
         !> far above the second-order term (~1e-5 relative at a step of 1e-7 l) and far below
         !> a jump's (jump / e, of the product's own size or more).
         real(dp), parameter :: agree = 1.0e-3_dp
         real(dp), allocatable :: forward(:, :), backward(:, :), far(:, :)
         real(dp) :: e
         allocate (forward(3, n), backward(3, n), far(3, n))
         e = fd_size / maxval(abs(v))
         call evaluate(self, x + e * v, forward)
         forward = (forward - r) / e
         call evaluate(self, x - e * v, backward)
         backward = (r - backward) / e
         if (norm2(forward - backward) <= agree * max(norm2(forward), norm2(backward))) then
            w = 0.5_dp * (forward + backward)
         else
            call evaluate(self, x + 2.0_dp * e * v, far)
            far = (far - r) / (2.0_dp * e)
            if (norm2(far - forward) <= agree * max(norm2(far), norm2(forward))) then
               w = forward
            else
               w = backward
            end if
         end if
         call constrain(w)
      end subroutine dynamics_product

      !> Orthonormalises v against Q (modified Gram-Schmidt, twice) and appends it with A v.
      subroutine add_vector(v, added)
         real(dp), intent(inout) :: v(:, :)
         logical, intent(out) :: added
         real(dp) :: norm0, c
         integer :: pass, i
         added = .false.
         norm0 = norm2(v)
         if (norm0 == 0.0_dp .or. m >= growth_basis) return
         do pass = 1, 2
            do i = 1, m
               c = sum(v * q(:, :, i))
               v = v - c * q(:, :, i)
            end do
         end do
         if (norm2(v) <= 1.0e-8_dp * norm0) return
         m = m + 1
         q(:, :, m) = v / norm2(v)
         call dynamics_product(q(:, :, m), w(:, :, m))
         do i = 1, m
            hs(i, m) = sum(q(:, :, i) * w(:, :, m))
            hs(m, i) = sum(q(:, :, m) * w(:, :, i))
         end do
         added = .true.
      end subroutine add_vector

      !> Index of the Ritz value of largest real part (the first of a complex pair) among
      !> those off the null directions; 0 if none.
      integer function rightmost(m)
         integer, intent(in) :: m
         integer :: j
         rightmost = 0
         do j = 1, m
            if (wi(j) < 0.0_dp .or. hypot(wr(j), wi(j)) <= null_rate) cycle
            if (rightmost == 0) then
               rightmost = j
            else if (wr(j) > wr(rightmost)) then
               rightmost = j
            end if
         end do
      end function rightmost

      !> The Ritz pair at index j (theta + i freq, u_re + i u_im, |u| = 1), its residual
      !> res_re + i res_im = J_P u - (theta + i freq) u and its norm.
      subroutine ritz_pair(j, m)
         integer, intent(in) :: j, m
         integer :: i
         theta = wr(j)
         freq = wi(j)
         c_re(1:m) = vr(1:m, j)
         c_im(1:m) = 0.0_dp
         if (freq /= 0.0_dp) c_im(1:m) = vr(1:m, j + 1)
         scale = sqrt(sum(c_re(1:m)**2) + sum(c_im(1:m)**2))
         c_re(1:m) = c_re(1:m) / scale
         c_im(1:m) = c_im(1:m) / scale
         u_re = 0.0_dp
         u_im = 0.0_dp
         res_re = 0.0_dp
         res_im = 0.0_dp
         do i = 1, m
            u_re = u_re + c_re(i) * q(:, :, i)
            u_im = u_im + c_im(i) * q(:, :, i)
            res_re = res_re + c_re(i) * w(:, :, i)
            res_im = res_im + c_im(i) * w(:, :, i)
         end do
         res_re = res_re - (theta * u_re - freq * u_im)
         res_im = res_im - (theta * u_im + freq * u_re)
         residual = sqrt(sum(res_re**2) + sum(res_im**2))
      end subroutine ritz_pair

      !> The search space cut to the growth_keep rightmost Ritz vectors (real and imaginary
      !> parts of a pair), orthonormalised; W follows without new products.
      subroutine thick_restart()
         real(dp) :: order(growth_basis), c
         integer :: j, i, l, best
         logical :: taken(growth_basis)
         allocate (keep(m, growth_keep + 1))
         n_keep = 0
         taken = .false.
         order(1:m) = wr(1:m)
         do while (n_keep < growth_keep)
            best = 0
            do j = 1, m
               if (taken(j) .or. wi(j) < 0.0_dp) cycle
               if (best == 0) then
                  best = j
               else if (order(j) > order(best)) then
                  best = j
               end if
            end do
            if (best == 0) exit
            taken(best) = .true.
            n_keep = n_keep + 1
            keep(:, n_keep) = vr(1:m, best)
            if (wi(best) > 0.0_dp) then
               n_keep = n_keep + 1
               keep(:, n_keep) = vr(1:m, best + 1)
            end if
         end do
         ! Orthonormal in R^m, so that Q keep stays orthonormal.
         l = 0
         do j = 1, n_keep
            do i = 1, l
               c = dot_product(keep(:, i), keep(:, j))
               keep(:, j) = keep(:, j) - c * keep(:, i)
            end do
            c = norm2(keep(:, j))
            if (c <= 1.0e-8_dp) cycle
            l = l + 1
            keep(:, l) = keep(:, j) / c
         end do
         allocate (q_new(3, n, l), w_new(3, n, l))
         q_new = 0.0_dp
         w_new = 0.0_dp
         do j = 1, l
            do i = 1, m
               q_new(:, :, j) = q_new(:, :, j) + keep(i, j) * q(:, :, i)
               w_new(:, :, j) = w_new(:, :, j) + keep(i, j) * w(:, :, i)
            end do
         end do
         m = l
         q(:, :, 1:m) = q_new
         w(:, :, 1:m) = w_new
         do j = 1, m
            do i = 1, m
               hs(i, j) = sum(q(:, :, i) * w(:, :, j))
            end do
         end do
         deallocate (keep, q_new, w_new)
      end subroutine thick_restart

   end subroutine estimate_growth_rate

   !> The projection Pi = I - R C^-1 N^T of the time-stepped run's constraints at x, as
   !> `removed` R (the uniform translations along x, y, z, the volume gradient, the rotation
   !> about the axis), `normals` N (the gradients of the volume centroid's coordinates, which
   !> the run holds on the axis and mid-tube by translating; the volume gradient, as the
   !> velocity carries no volume flux; the rotation, a symmetry of the tube) and `coupling`
   !> C^-1 (C = N^T R). Pi R = 0 and N^T Pi = 0: Pi keeps what the run's recentring keeps.
   subroutine dynamics_projector(mesh, x, removed, normals, coupling)
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      real(dp), allocatable, intent(out) :: removed(:, :, :), normals(:, :, :)
      real(dp), intent(out) :: coupling(n_constraints, n_constraints)
      real(dp), allocatable :: grad_volume(:, :), grad_moment(:, :, :)
      real(dp) :: dvol(3, 3), vol, s(3), volume, moment(3), c(3), ident(n_constraints, n_constraints)
      integer :: t, corner, k, i, j, info, pivot(n_constraints)
      integer :: node(3)
      allocate (removed(3, size(x, 2), n_constraints), normals(3, size(x, 2), n_constraints))
      allocate (grad_volume(3, size(x, 2)), grad_moment(3, size(x, 2), 3))
      grad_volume = 0.0_dp
      grad_moment = 0.0_dp
      volume = 0.0_dp
      moment = 0.0_dp
      ! V = sum of a . (b x c) / 6 over the triangles, V c = sum of V_t (a + b + c) / 4.
      do t = 1, mesh%n_tri
         node = mesh%tri(:, t)
         vol = dot_product(x(:, node(1)), cross(x(:, node(2)), x(:, node(3)))) / 6.0_dp
         s = x(:, node(1)) + x(:, node(2)) + x(:, node(3))
         dvol(:, 1) = cross(x(:, node(2)), x(:, node(3))) / 6.0_dp
         dvol(:, 2) = cross(x(:, node(3)), x(:, node(1))) / 6.0_dp
         dvol(:, 3) = cross(x(:, node(1)), x(:, node(2))) / 6.0_dp
         volume = volume + vol
         moment = moment + vol * s / 4.0_dp
         do corner = 1, 3
            grad_volume(:, node(corner)) = grad_volume(:, node(corner)) + dvol(:, corner)
            do k = 1, 3
               grad_moment(:, node(corner), k) = grad_moment(:, node(corner), k) + s(k) / 4.0_dp * dvol(:, corner)
               grad_moment(k, node(corner), k) = grad_moment(k, node(corner), k) + vol / 4.0_dp
            end do
         end do
      end do
      c = moment / volume
      removed = 0.0_dp
      do k = 1, 3
         removed(k, :, k) = 1.0_dp
         normals(:, :, k) = (grad_moment(:, :, k) - c(k) * grad_volume) / volume
      end do
      removed(:, :, 4) = grad_volume / norm2(grad_volume)
      normals(:, :, 4) = removed(:, :, 4)
      removed(1, :, 5) = -x(2, :)
      removed(2, :, 5) = x(1, :)
      removed(3, :, 5) = 0.0_dp
      removed(:, :, 5) = removed(:, :, 5) / norm2(removed(:, :, 5))
      normals(:, :, 5) = removed(:, :, 5)
      do j = 1, n_constraints
         do i = 1, n_constraints
            coupling(i, j) = sum(normals(:, :, i) * removed(:, :, j))
         end do
      end do
      ident = 0.0_dp
      do i = 1, n_constraints
         ident(i, i) = 1.0_dp
      end do
      call dgesv(n_constraints, n_constraints, coupling, n_constraints, pivot, ident, n_constraints, info)
      if (info /= 0) error stop 'tube_steady_3d: the constraint directions are dependent'
      coupling = ident
   end subroutine dynamics_projector


   !> The preconditioner M ~ S K / Ca at x, LU-factorised: K = dF/dx the membrane's nodal
   !> force Jacobian (directional differences, one node coordinate at a time: the forces are
   !> local and cheap), S the free-space single layer from nodal forces to nodal velocities
   !> (vertex rule; a node's own patch as a flat disk of its area: R/(8A) (3 (I - nn) + 2 nn)),
   !> K shifted by -shift_fraction of its largest diagonal entry so that M is regular along
   !> the rigid motions. M is what makes the Jacobian stiff (the membrane's short waves,
   !> rates ~ 1/(Ca h)); the walls, the inflow and the volume and frame corrections are left
   !> to GMRES.
   subroutine build_preconditioner(self, x)
      class(tube_steady_capsule_t), intent(inout) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), parameter :: step = 1.0e-7_dp, shift_fraction = 1.0e-3_dp
      real(dp), allocatable :: s(:, :), k_col(:), xp(:, :), f0(:, :), f1(:, :), tri_area(:), area(:), normal(:, :)
      real(dp) :: d(3), r2, radius, shift, volume, moment, t0
      integer :: n, m, i, j, a, b, col, info, q
      integer, allocatable :: rows(:)

      t0 = omp_get_wtime()
      n = self%mesh%n_nodes
      m = 3 * n
      if (.not. allocated(self%precond_lu)) allocate (self%precond_lu(m, m), self%precond_pivot(m))
      allocate (s(m, m), k_col(m), xp(3, n), f0(3, n), f1(3, n), tri_area(self%mesh%n_tri), area(n), normal(3, n))
      allocate (rows(m))
      call triangle_areas(self%mesh, x, tri_area)
      call node_areas(self%mesh, tri_area, area)
      call volume_gradients(self%mesh, x, normal, self%moment_grad, volume, moment)
      !$omp parallel do default(none) shared(s, x, area, normal, n) private(i, j, a, b, d, r2, radius) schedule(static)
      do j = 1, n
         do i = 1, n
            if (i == j) then
               radius = sqrt(area(j) / pi)
               d = normal(:, j) / norm2(normal(:, j))
               do b = 1, 3
                  do a = 1, 3
                     s(3 * (i - 1) + a, 3 * (j - 1) + b) = radius / (8.0_dp * area(j)) * &
                                                           (merge(3.0_dp, 0.0_dp, a == b) - d(a) * d(b))
                  end do
               end do
            else
               d = x(:, i) - x(:, j)
               r2 = sum(d * d)
               do b = 1, 3
                  do a = 1, 3
                     s(3 * (i - 1) + a, 3 * (j - 1) + b) = (merge(1.0_dp, 0.0_dp, a == b) / sqrt(r2) + &
                                                           d(a) * d(b) / (r2 * sqrt(r2))) / (8.0_dp * pi)
                  end do
               end do
            end if
         end do
      end do
      !$omp end parallel do
      call force_at(self, x, f0)
      shift = 0.0_dp
      self%precond_lu = 0.0_dp
      do col = 1, m
         xp = x
         j = (col - 1) / 3 + 1
         a = col - 3 * (j - 1)
         xp(a, j) = xp(a, j) + step
         call force_at(self, xp, f1)
         k_col = reshape((f1 - f0) / step, [m])
         shift = max(shift, abs(k_col(col)))
         ! Column col of S K: S times the few nonzero entries of K's column.
         q = 0
         do i = 1, m
            if (k_col(i) /= 0.0_dp) then
               q = q + 1
               rows(q) = i
            end if
         end do
         self%precond_lu(:, col) = matmul(s(:, rows(1:q)), k_col(rows(1:q)))
      end do
      ! M = S (K - shift I) / Ca.
      self%precond_lu = (self%precond_lu - shift_fraction * shift * s) / self%ca
      call dgetrf(m, m, self%precond_lu, m, self%precond_pivot, info)
      if (info /= 0) deallocate (self%precond_lu, self%precond_pivot)
      self%precond_builds = self%precond_builds + 1
      self%seconds_preconditioner = self%seconds_preconditioner + (omp_get_wtime() - t0)
   end subroutine build_preconditioner

   !> Nodal membrane forces (elastic and bending) at x.
   subroutine force_at(self, x, force)
      class(tube_steady_capsule_t), intent(inout) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: force(:, :)
      real(dp) :: energy
      call membrane_nodal_forces(self%ref, self%mesh, self%law, x, force, energy)
      if (self%bending%kb > 0.0_dp) call self%bending%add_forces(self%mesh, x, force, energy)
   end subroutine force_at

   !> z <- P M^-1 z (M^-1 = identity where the factorisation failed).
   subroutine apply_preconditioner(self, z)
      class(tube_steady_capsule_t), intent(in) :: self
      real(dp), intent(inout) :: z(:, :)
      real(dp) :: col(size(z), 1)
      integer :: info, m
      if (allocated(self%precond_lu)) then
         m = size(z)
         col(:, 1) = reshape(z, [m])
         call dgetrs('N', m, 1, self%precond_lu, m, self%precond_pivot, col, m, info)
         z = reshape(col(:, 1), shape(z))
      end if
      call project(self, z)
   end subroutine apply_preconditioner

   !> w = P (u(x + e v) - r) / e with r = u(x), the step e moving no node by more than fd_size.
   subroutine jacobian_product(self, x, r, v, w)
      class(tube_steady_capsule_t), intent(inout) :: self
      real(dp), intent(in) :: x(:, :), r(:, :), v(:, :)
      real(dp), intent(out) :: w(:, :)
      real(dp) :: e, size_v
      size_v = maxval(abs(v))
      if (size_v == 0.0_dp) then
         w = 0.0_dp
         return
      end if
      e = fd_size / size_v
      call evaluate(self, x + e * v, w)
      w = (w - r) / e
      call project(self, w)
   end subroutine jacobian_product

   !> The velocity r at x, the constraint directions there, and the projected residual pr = P r
   !> with its norm: what each Newton iterate and each line-search trial is judged by.
   subroutine residual_at(self, x, r, pr, res2)
      class(tube_steady_capsule_t), intent(inout) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: r(:, :), pr(:, :), res2
      call evaluate(self, x, r)
      call constraint_basis(self, x)
      pr = r
      call project(self, pr)
      res2 = norm2(pr)
   end subroutine residual_at

   subroutine evaluate(self, x, u)
      class(tube_steady_capsule_t), intent(inout) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: u(:, :)
      call self%velocity(x, u)
      self%velocity_evaluations = self%velocity_evaluations + 1
   end subroutine evaluate

   !> The constraint directions at x, orthonormal (modified Gram-Schmidt): the volume gradient,
   !> the uniform translations along x, y, z, and the rotation about the axis.
   subroutine constraint_basis(self, x)
      class(tube_steady_capsule_t), intent(inout) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp) :: volume, moment
      integer :: k, j
      call volume_gradients(self%mesh, x, self%basis(:, :, 1), self%moment_grad, volume, moment)
      do k = 1, 3
         self%basis(:, :, k + 1) = 0.0_dp
         self%basis(k, :, k + 1) = 1.0_dp
      end do
      self%basis(1, :, 5) = -x(2, :)
      self%basis(2, :, 5) = x(1, :)
      self%basis(3, :, 5) = 0.0_dp
      do k = 1, n_constraints
         do j = 1, k - 1
            self%basis(:, :, k) = self%basis(:, :, k) - sum(self%basis(:, :, k) * self%basis(:, :, j)) * self%basis(:, :, j)
         end do
         self%basis(:, :, k) = self%basis(:, :, k) / norm2(self%basis(:, :, k))
      end do
   end subroutine constraint_basis

   !> u <- P u, the part of u orthogonal to the constraint directions.
   subroutine project(self, u)
      class(tube_steady_capsule_t), intent(in) :: self
      real(dp), intent(inout) :: u(:, :)
      integer :: k
      do k = 1, n_constraints
         u = u - sum(u * self%basis(:, :, k)) * self%basis(:, :, k)
      end do
   end subroutine project

   !> Scale x about its centroid to the start's volume, then, when `centre`, put the centroid
   !> at the origin (not after a Newton step: see the module header).
   subroutine restore_volume_and_centre(self, x, centre)
      class(tube_steady_capsule_t), intent(in) :: self
      real(dp), intent(inout) :: x(:, :)
      logical, intent(in) :: centre
      real(dp) :: area, volume, c(3), s
      integer :: i
      call area_and_volume(self%mesh, x, area, volume)
      c = volume_centroid(self%mesh, x)
      s = (self%volume0 / volume)**(1.0_dp / 3.0_dp)
      do i = 1, size(x, 2)
         x(:, i) = c + s * (x(:, i) - c)
      end do
      if (centre) call recentre(self%mesh, x, axial_only=.false.)
   end subroutine restore_volume_and_centre

end module tube_steady_3d
