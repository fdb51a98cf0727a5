!> A centred capsule in Poiseuille flow in a circular tube, axisymmetric (the fast path for
!> tube databases): the model the program runs. Its velocity is axisymmetric_operator's; it is
!> advanced by RK2 or linearly implicit steps (axisymmetric_integrators) or solved for its
!> steady shape by Newton continuation (axisymmetric_steady); this module chooses the solver,
!> records the history and writes the geometry.
module axisymmetric_tube
   use capsim_kinds, only: dp, pi
   use hdf5_writer, only: h5_file_t
   use axisymmetric_membrane, only: meridian_area_volume
   use run_options, only: run_options_t
   use text_format, only: int_text
   use tube_history, only: h_volume, h_lz, h_lp, h_vc, h_stretch, tube_history_names, tube_history_units, tube_progress_text
   use case_output, only: case_summary_t
   use axisymmetric_operator, only: axisymmetric_operator_t
   use axisymmetric_integrators, only: implicit_state_t, rk2_step, implicit_step, exchange_implicit_state, implicit_dt
   use state_vector, only: state_cursor_t
   use axisymmetric_steady, only: newton_state_t, newton_run, polish_steady_shape
   implicit none
   private
   public :: axisymmetric_tube_t, meridian_stretch_limit

   !> The automatic solver choice uses Newton below this Ca and RK2 time stepping above (see run).
   real(dp), parameter :: newton_max_ca = 0.005_dp
   !> Element stretch beyond which the meridian no longer resolves the parachute rim. Steady
   !> shapes of the development grid (64 elements) have stretches below 2.9, except three NH
   !> shapes at the end of the steady branch (5.4 to 9.3, reached after creeping for 30 l/V)
   !> which finer meridians do not have: at a/l = 0.85, Ca_s = 0.15, 96 elements elongate past
   !> 10 while 64 stall at 9. A capsule still elongating when its rim passes 4 is therefore
   !> continuous elongation (the paper's NH result at that point).
   real(dp), parameter :: meridian_stretch_limit = 4.0_dp
   integer, parameter :: solver_newton = 1, solver_implicit = 2, solver_rk2 = 3

   type, extends(axisymmetric_operator_t) :: axisymmetric_tube_t
      !> Steady solver (Newton with continuation in Ca), linearly implicit Euler steps, or
      !> Heun's RK2 (explicit, dt ~ Ca h).
      integer :: solver = solver_implicit
      type(implicit_state_t) :: implicit
      type(newton_state_t) :: newton
   contains
      procedure :: init
      procedure :: advance
      procedure :: record
      procedure :: exchange_state
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
      integer :: n

      call self%init_operator(opts, stat, errmsg)
      if (stat /= 0) return
      n = size(self%positions, 2)
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
      call self%newton%init(n)
      call self%implicit%init(n, self%dt)
      self%dt_max = self%dt
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

   !> One time step: linearly implicit (implicit_step), or Heun's RK2 in the capsule frame.
   subroutine advance(self)
      class(axisymmetric_tube_t), intent(inout) :: self
      if (self%solver == solver_implicit) then
         call implicit_step(self, self%implicit)
      else
         call rk2_step(self)
      end if
   end subroutine advance

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
         call newton_run(self, self%newton, opts, summary, steady_index)
         summary%volume_change = self%history(h_volume, self%n_rec) / self%history(h_volume, 1) - 1.0_dp
         if (trim(summary%status) /= 'failed' .or. trim(opts%integrator) /= 'auto') return
         ! Newton from the sphere is fragile at fine meshes (a/l = 0.6, Ca_s = 0.004, 64
         ! elements: no convergence at Ca_s = 1e-3); `auto` then falls back on time stepping.
         newton_failure = summary%message
         ! newton_run leaves Ca where its continuation stopped (the nearly rigid start, 1e-3):
         ! the time steps must run at the requested Ca.
         self%ca = opts%ca
         self%solver = solver_implicit
         self%dt = implicit_dt
         self%dt_max = implicit_dt
         self%implicit%dt_limit = implicit_dt
         self%n_rec = 0
         call self%time_loop(opts, checkpoint_path, summary, steady_index)
         summary%message = summary%message//' (implicit steps after: '//newton_failure//')'
         if (steady_index > 0) call polish_steady_shape(self, self%newton, opts, summary, steady_index)
      else
         call self%time_loop(opts, checkpoint_path, summary, steady_index)
         if (self%solver == solver_implicit) then
            summary%message = summary%message//' ('//int_text(self%step)//' implicit steps, '// &
                              int_text(self%implicit%n_jacobians)//' Jacobians, '// &
                              int_text(self%implicit%n_rejected)//' steps redone)'
         end if
         if (steady_index > 0) call polish_steady_shape(self, self%newton, opts, summary, steady_index)
      end if
   end subroutine run

   !> Checkpoint state: the positions (an RK2 step depends on nothing else) and, for implicit
   !> steps, their state (exchange_implicit_state). Newton continuation writes no checkpoint:
   !> a killed run starts it afresh and, being deterministic, ends as the uninterrupted one.
   subroutine exchange_state(self, state, cursor)
      class(axisymmetric_tube_t), intent(inout) :: self
      real(dp), intent(inout) :: state(:)
      type(state_cursor_t), intent(inout) :: cursor
      call cursor%reals(state, self%positions, size(self%positions))
      if (self%solver == solver_implicit) call exchange_implicit_state(self, self%implicit, state, cursor)
   end subroutine exchange_state

   !> Append diagnostics: L_z (front to rear), L_p (rear pole to the rear-most point: the
   !> parachute depth, 0 for a convex rear), v_c/V, film-side radius r_max.
   subroutine record(self)
      class(axisymmetric_tube_t), intent(inout) :: self
      real(dp) :: area, volume, l_z, l_p, stretch, lam_s, lam_p
      integer :: n, e
      n = size(self%positions, 2)
      call self%velocity_here(self%positions, self%u0)
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
