!> The time loop shared by every capsule model (3D in shear, axisymmetric in a tube):
!> checkpoint and resume, periodic records, progress lines, and the classification of the
!> run (steady, continuous elongation, mesh breakdown, failed, time limit).
!>
!> A model extends capsule_model_t: it advances its state by one time step, appends one row
!> of diagnostics to `history`, and says which history columns hold the time, area, volume,
!> a length (for elongation), the largest element stretch (for breakdown) and the shape
!> measures that must settle for a steady state.
module capsule_model
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
   use, intrinsic :: iso_fortran_env, only: error_unit
   use capsim_kinds, only: dp
   use hdf5_writer, only: h5_file_t
   use membrane_law, only: membrane_law_t
   use run_options, only: run_options_t, option_signature
   use case_output, only: case_summary_t, write_checkpoint, read_checkpoint, open_case_file
   use file_ops, only: keep_aside
   use state_vector, only: state_cursor_t, state_counting, state_storing, state_restoring
   implicit none
   private
   public :: capsule_model_t, t_min_steady, max_element_stretch, num, limit_estimate

   !> A steady state is not declared before this time: the first units hold the start-up.
   real(dp), parameter :: t_min_steady = 2.0_dp
   !> Largest principal stretch (or inverse) an element may reach before the mesh no longer
   !> represents the membrane. 15 was too late: the NH capsule at a/l = 0.85, Ca_s = 0.15
   !> (96 meridian elements) elongated from L_z = 2.1 to 3.2 l over 30 l/V while its rim
   !> elements stretched to 14.96 and then stalled there; RK2 crossed 15 and reported the
   !> elongation, the implicit path peaked just below it and ran into the time limit.
   real(dp), parameter :: max_element_stretch = 10.0_dp

   type, abstract :: capsule_model_t
      type(membrane_law_t) :: law
      real(dp) :: t = 0, dt = 0
      !> The state advanced in time: node positions, (3, n) in 3D or (r, z) x n on a meridian,
      !> and the positions a run starts from.
      real(dp), allocatable :: positions(:, :), start_positions(:, :)
      !> Names and units of the history columns, as written to the case file.
      character(len=16), allocatable :: history_names(:), history_units(:)
      integer :: step = 0
      !> Rows 1:n_rec of `history` hold the records; its columns double when full
      !> (next_record), so that memory follows the records taken, not t_max.
      real(dp), allocatable :: history(:, :)
      integer :: n_rec = 0
      !> The most records the steady Newton continuation (axisymmetric tube) takes.
      integer :: record_limit = huge(1)
      !> History columns read by the classification.
      integer :: col_t = 1, col_area = 2, col_volume = 3, col_length = 0, col_stretch = 0
      integer, allocatable :: col_shape(:)
      !> Area scale of the steady criterion (4 pi a**2) and elongation limit of col_length.
      real(dp) :: area_scale = 1, length_limit = huge(1.0_dp)
      !> Largest element stretch (or inverse) the mesh resolves (default max_element_stretch).
      real(dp) :: stretch_limit = max_element_stretch
      !> A shape measure has settled when it varies over one time unit by less than
      !> shape_rel_tol * |value| + shape_abs_tol.
      real(dp) :: shape_rel_tol = 5.0e-3_dp, shape_abs_tol = 1.0e-4_dp
      !> History column whose long-time limit is estimated (limit_estimate) before a steady
      !> state is declared, 0 for none: the steady state then also needs the estimated
      !> remaining change below limit_rel_tol * |value|, and the case file records it.
      integer :: col_limit = 0
      real(dp) :: limit_rel_tol = 5.0e-4_dp
      !> Largest membrane velocity in the capsule frame (steady solvers report it).
      real(dp) :: residual = huge(1.0_dp)
      !> Set by `advance` when a step could not be computed (an inner solver failed): the run
      !> then ends as failed with this reason.
      character(len=:), allocatable :: fault
   contains
      procedure(advance_iface), deferred :: advance
      procedure(advance_iface), deferred :: record
      procedure :: reset
      procedure :: state_size
      procedure :: get_state
      procedure :: set_state
      procedure :: exchange_state
      procedure(progress_iface), deferred :: progress_text
      procedure(geometry_iface), deferred :: write_geometry
      !> `run` is what the program calls; models with their own solver override it and may
      !> still call `time_loop`, the shared explicit loop.
      procedure :: run => time_loop
      procedure :: time_loop
      procedure :: allocate_history
      procedure :: next_record
      procedure :: start_case_file
   end type capsule_model_t

   abstract interface
      subroutine advance_iface(self)
         import :: capsule_model_t
         class(capsule_model_t), intent(inout) :: self
      end subroutine advance_iface
      function progress_iface(self) result(text)
         import :: capsule_model_t
         class(capsule_model_t), intent(in) :: self
         character(len=:), allocatable :: text
      end function progress_iface
      !> Writes /mesh and /profile into the open case file.
      subroutine geometry_iface(self, f, stat, errmsg)
         import :: capsule_model_t, h5_file_t
         class(capsule_model_t), intent(in) :: self
         type(h5_file_t), intent(inout) :: f
         integer, intent(out) :: stat
         character(len=:), allocatable, intent(out) :: errmsg
      end subroutine geometry_iface
   end interface

contains

   subroutine reset(self)
      class(capsule_model_t), intent(inout) :: self
      self%positions = self%start_positions
   end subroutine reset

   !> Entries of the checkpoint state (exchange_state).
   integer function state_size(self)
      class(capsule_model_t), intent(inout) :: self
      type(state_cursor_t) :: cursor
      real(dp) :: none(0)
      cursor%mode = state_counting
      call self%exchange_state(none, cursor)
      state_size = cursor%at
   end function state_size

   !> The checkpoint state (exchange_state) into `state`.
   subroutine get_state(self, state)
      class(capsule_model_t), intent(inout) :: self
      real(dp), intent(inout) :: state(:)
      type(state_cursor_t) :: cursor
      cursor%mode = state_storing
      call self%exchange_state(state, cursor)
   end subroutine get_state

   !> The checkpoint state back from `state` (a resumed run).
   subroutine set_state(self, state)
      class(capsule_model_t), intent(inout) :: self
      real(dp), intent(inout) :: state(:)
      type(state_cursor_t) :: cursor
      cursor%mode = state_restoring
      call self%exchange_state(state, cursor)
   end subroutine set_state

   !> The parts of the checkpoint state, in order, through `cursor`: everything the next step
   !> depends on, so that a resumed run goes on bit for bit as the uninterrupted one. Here the
   !> positions; models whose steps carry more (step size control, Jacobians, initial guesses
   !> of iterative solves) extend it, and rebuild what they do not store when restoring.
   subroutine exchange_state(self, state, cursor)
      class(capsule_model_t), intent(inout) :: self
      real(dp), intent(inout) :: state(:)
      type(state_cursor_t), intent(inout) :: cursor
      call cursor%reals(state, self%positions, size(self%positions))
   end subroutine exchange_state

   !> An empty history of these columns. It starts small and grows (next_record); t_max and
   !> record_every give only `record_limit`, the records the run would take at most (in
   !> real arithmetic, capped: t_max may be 1e9).
   subroutine allocate_history(self, names, units, t_max, record_every)
      class(capsule_model_t), intent(inout) :: self
      character(len=*), intent(in) :: names(:), units(:)
      real(dp), intent(in) :: t_max, record_every
      integer, parameter :: initial_records = 256
      self%history_names = names
      self%history_units = units
      self%record_limit = int(min(t_max / max(record_every, self%dt) + 17.0_dp, 0.5_dp * real(huge(1), dp)))
      if (allocated(self%history)) deallocate (self%history)
      allocate (self%history(size(names), initial_records))
      self%history = 0
      self%n_rec = 0
   end subroutine allocate_history

   !> Makes room for one more record and counts it: the caller then fills history(:, n_rec).
   !> A full history doubles its columns.
   subroutine next_record(self)
      class(capsule_model_t), intent(inout) :: self
      real(dp), allocatable :: grown(:, :)
      if (self%n_rec >= size(self%history, 2)) then
         allocate (grown(size(self%history, 1), max(16, 2 * size(self%history, 2))))
         grown = 0
         grown(:, 1:self%n_rec) = self%history(:, 1:self%n_rec)
         call move_alloc(grown, self%history)
      end if
      self%n_rec = self%n_rec + 1
   end subroutine next_record

   !> Advance until a final status; checkpoints to `checkpoint_path` every
   !> opts%checkpoint_every wall seconds and resumes from it if it matches the options.
   subroutine time_loop(self, opts, checkpoint_path, summary, steady_index)
      class(capsule_model_t), intent(inout) :: self
      type(run_options_t), intent(in) :: opts
      character(len=*), intent(in) :: checkpoint_path
      type(case_summary_t), intent(inout) :: summary
      integer, intent(out) :: steady_index
      integer(8) :: clock_start, clock_now, clock_rate, clock_ckpt, clock_print
      real(dp) :: t_next_record, v0
      real(dp), allocatable :: state(:)
      character(len=:), allocatable :: signature, errmsg, note, kept
      logical :: resumed, decided
      integer :: stat

      steady_index = 0
      summary%dt = self%dt
      signature = option_signature(opts)
      allocate (state(self%state_size()))
      call read_checkpoint(checkpoint_path, signature, self%step, self%t, state, self%history, self%n_rec, &
                           summary%wall_time_before_s, resumed, note)
      if (len(note) > 0) then
         ! A whole checkpoint of other options is another run's work: kept, not overwritten by
         ! this run's first checkpoint, so that rerunning with the first options resumes it.
         if (index(note, 'signature differs') > 0) then
            kept = keep_aside(checkpoint_path, 'other-options')
            if (len(kept) > 0) note = note//'; kept as "'//kept//'"'
         end if
         write (error_unit, '(a)') 'capsim: warning: checkpoint "'//checkpoint_path//'" not used: '//note// &
            '; starting afresh'
         ! Said before any work: a run killed later must not lose this line in a buffer.
         flush (error_unit)
      end if
      if (resumed) then
         call self%set_state(state)
         if (.not. opts%quiet) write (*, '(a,f0.3)') 'capsim: resumed from checkpoint at t = ', self%t
      else
         call self%reset()
         self%t = 0
         self%step = 0
         self%n_rec = 0
         call self%record()
      end if
      v0 = self%history(self%col_volume, 1)
      t_next_record = next_record_time(self%history(self%col_t, self%n_rec), opts%record_every)
      call system_clock(clock_start, clock_rate)
      clock_ckpt = clock_start
      clock_print = clock_start
      decided = .false.
      do while (self%t < opts%t_max - 0.5_dp * self%dt)
         call self%advance()
         if (allocated(self%fault)) then
            summary%status = 'failed'
            summary%message = self%fault//' at t = '//num(self%t)
            decided = .true.
            exit
         end if
         call self%get_state(state)
         if (.not. all(ieee_is_finite(state))) then
            summary%status = 'failed'
            summary%message = 'non-finite node positions at t = '//num(self%t)//' (time step too large?)'
            decided = .true.
            exit
         end if
         if (self%t >= t_next_record - 1.0e-9_dp) then
            call self%record()
            t_next_record = next_record_time(self%t, opts%record_every)
            call classify(self, opts, summary, decided)
            if (decided) exit
         end if
         call system_clock(clock_now)
         if (real(clock_now - clock_ckpt, dp) / clock_rate >= opts%checkpoint_every) then
            call write_checkpoint(checkpoint_path, signature, self%step, self%t, state, self%history, &
                                  self%n_rec, summary%wall_time_before_s + real(clock_now - clock_start, dp) / clock_rate, &
                                  stat, errmsg)
            if (stat /= 0) then
               ! The previous checkpoint is left in place; going on would risk hours unsaved.
               summary%status = 'failed'
               summary%message = errmsg
               summary%fatal = errmsg
               decided = .true.
               exit
            end if
            clock_ckpt = clock_now
         end if
         if (.not. opts%quiet .and. real(clock_now - clock_print, dp) / clock_rate >= 2.0_dp) then
            ! Exponent form for a t_max that fixed notation would write with hundreds of digits.
            if (opts%t_max < 1.0e6_dp) then
               write (*, '(a,f9.3,a,f0.1,a)') 'capsim: t = ', self%t, ' / ', opts%t_max, '  '//self%progress_text()
            else
               write (*, '(a,es11.3e3,a,es11.3e3,a)') 'capsim: t = ', self%t, ' / ', opts%t_max, '  '//self%progress_text()
            end if
            flush (6)
            clock_print = clock_now
         end if
      end do
      if (.not. decided) then
         ! The final state always closes the history.
         if (self%history(self%col_t, self%n_rec) < self%t - 1.0e-12_dp) call self%record()
         call classify_at_time_limit(self, opts, summary)
      end if
      if (trim(summary%status) == 'steady') steady_index = self%n_rec
      summary%volume_change = self%history(self%col_volume, self%n_rec) / v0 - 1.0_dp
   end subroutine time_loop

   !> Creates the case file (opts%out, as OUT.tmp) with the run's attributes, the history rows
   !> 1:n_rec, /steady from row steady_index when it is > 0, and the model's geometry. The caller
   !> may add attributes, then closes it (close_case_file), or removes it when stat /= 0.
   subroutine start_case_file(self, opts, summary, steady_index, f, stat, errmsg)
      class(capsule_model_t), intent(in) :: self
      type(run_options_t), intent(in) :: opts
      type(case_summary_t), intent(in) :: summary
      integer, intent(in) :: steady_index
      type(h5_file_t), intent(inout) :: f
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      if (steady_index > 0) then
         call open_case_file(opts, self%law, summary, self%history_names, self%history_units, &
                             self%history(:, 1:self%n_rec), f, stat, errmsg, self%history(:, steady_index))
      else
         call open_case_file(opts, self%law, summary, self%history_names, self%history_units, &
                             self%history(:, 1:self%n_rec), f, stat, errmsg)
      end if
      if (stat == 0) call self%write_geometry(f, stat, errmsg)
   end subroutine start_case_file

   !> Steady, continuous elongation or mesh breakdown, from the history so far.
   subroutine classify(self, opts, summary, decided)
      class(capsule_model_t), intent(in) :: self
      type(run_options_t), intent(in) :: opts
      type(case_summary_t), intent(inout) :: summary
      logical, intent(out) :: decided
      integer :: first, n, k, c
      real(dp) :: t_now, area_var, shape_var, growth, creep_growth, value, remaining, limit
      logical :: still_growing, known
      character(len=:), allocatable :: detail

      decided = .false.
      n = self%n_rec
      t_now = self%history(self%col_t, n)
      if (self%history(self%col_length, n) > self%length_limit) then
         summary%status = 'continuous_elongation'
         summary%message = 'the capsule length exceeded '//num(self%length_limit)//' at t = '//num(t_now)// &
                           ': it elongates without reaching a steady shape'
         decided = .true.
         return
      end if
      first = window_start(self, t_now - 1.0_dp)
      if (self%history(self%col_stretch, n) > self%stretch_limit) then
         growth = self%history(self%col_length, n) - self%history(self%col_length, first)
         still_growing = creeping(self, creep_growth)
         if (growth > 0.01_dp .or. still_growing) then
            summary%status = 'continuous_elongation'
            summary%message = 'an element stretched beyond '//num(self%stretch_limit)//' (what the mesh resolves) at t = '// &
                              num(t_now)//' while the capsule kept elongating (by '// &
                              num(max(growth, creep_growth))//' over the last time units): no steady shape'
         else
            summary%status = 'failed'
            summary%message = 'mesh breakdown at t = '//num(t_now)//' (element stretch above '// &
                              num(self%stretch_limit)//')'
         end if
         decided = .true.
         return
      end if
      if (t_now < t_min_steady .or. self%history(self%col_t, 1) > t_now - 1.0_dp) return
      area_var = maxval(self%history(self%col_area, first:n)) - minval(self%history(self%col_area, first:n))
      if (area_var >= opts%steady_tol * self%area_scale) return
      detail = ''
      do k = 1, size(self%col_shape)
         c = self%col_shape(k)
         shape_var = maxval(self%history(c, first:n)) - minval(self%history(c, first:n))
         if (shape_var >= self%shape_rel_tol * abs(self%history(c, n)) + self%shape_abs_tol) return
         detail = detail//', '//num(shape_var)
      end do
      if (self%col_limit > 0) then
         value = self%history(self%col_limit, n)
         call limit_estimate(self%history(self%col_t, 1:n), self%history(self%col_limit, 1:n), &
                             self%limit_rel_tol * abs(value), remaining, limit, known)
         ! A measure that ripples without settling (the node-scale mode of small Ca_s at
         ! levels 3-4, issue 23) never passes: such a run ends at t_max, not steady.
         if (.not. known .or. remaining >= self%limit_rel_tol * abs(value)) return
         summary%time_error = remaining / max(abs(value), tiny(1.0_dp))
         summary%time_error_measure = trim(self%history_names(self%col_limit))
         detail = detail//'; estimated limit of '//summary%time_error_measure//' '//num(limit)// &
                  ', remaining change '//num(summary%time_error)//' relative'
      end if
      summary%status = 'steady'
      summary%message = 'over the last time unit the area varied by '//num(area_var / self%area_scale)// &
                        ' of 4 pi a^2 and the shape measures by '//detail(3:)
      decided = .true.
   end subroutine classify

   !> The long-time limit of a measure y(t) that settles after a start-up (shear: D12 after
   !> its overshoot), and how far the last value y(n) is from it. y is averaged over the last
   !> three time units (means m1, m2, m3), which smooths the mesh's periodic ripple as the
   !> membrane tank-treads; the differences d1 = m2 - m1, d2 = m3 - m2 are taken as a
   !> geometric series of ratio rho = d2/d1, whose tail adds d2 rho/(1 - rho) to m3
   !> (Aitken's extrapolation). rho is taken at least 0.5, so a decay faster than that is
   !> over- not under-estimated; the estimate is unknown while the means turn (d1, d2 of
   !> opposite sign: the overshoot is inside the windows) or settle slowly (rho >= 0.9).
   !> Where both differences are below a quarter of the caller's tolerance `tol` on
   !> `remaining`, the means no longer move: the limit is m3 and the tail the larger difference.
   !> remaining = |limit - y(n)|: the tail plus the ripple of the last value about m3.
   !> Measured on NH shear runs to t = 20-30 (level 2: Ca_s 0.05-1 and GH nu_s 0 at 0.3;
   !> level 3: 0.3, 0.6): stopped at remaining < 5e-4 |y|, the true distance to the mean of
   !> the second half of the long run was 0.03-0.8 of `remaining` (tests/kernel/test_shear.py).
   pure subroutine limit_estimate(t, y, tol, remaining, limit, known)
      real(dp), intent(in) :: t(:), y(:), tol
      real(dp), intent(out) :: remaining, limit
      logical, intent(out) :: known
      real(dp), parameter :: window = 1.0_dp, rho_min = 0.5_dp, rho_max = 0.9_dp
      real(dp) :: means(3), d1, d2, rho, t_end, upper
      integer :: n, k, i, count
      n = size(t)
      known = .false.
      remaining = huge(1.0_dp)
      limit = y(n)
      t_end = t(n)
      if (t_end - 3 * window < t(1) - 1.0e-9_dp) return
      do k = 1, 3
         ! Window k is (upper - window, upper], the last one ending at t_end.
         upper = t_end - (3 - k) * window + 1.0e-9_dp
         means(k) = 0
         count = 0
         do i = n, 1, -1
            if (t(i) <= upper - window) exit
            if (t(i) <= upper) then
               means(k) = means(k) + y(i)
               count = count + 1
            end if
         end do
         if (count == 0) return
         means(k) = means(k) / count
      end do
      d1 = means(2) - means(1)
      d2 = means(3) - means(2)
      if (abs(d1) < 0.25_dp * tol .and. abs(d2) < 0.25_dp * tol) then
         limit = means(3)
         remaining = abs(limit - y(n)) + max(abs(d1), abs(d2))
         known = .true.
         return
      end if
      if (d1 * d2 <= 0.0_dp) return
      rho = d2 / d1
      if (rho >= rho_max) return
      rho = max(rho, rho_min)
      limit = means(3) + d2 * rho / (1.0_dp - rho)
      remaining = abs(limit - y(n))
      known = .true.
   end subroutine limit_estimate

   !> At t_max: continuous elongation if the capsule is creeping (see `creeping`); otherwise
   !> the time limit.
   subroutine classify_at_time_limit(self, opts, summary)
      class(capsule_model_t), intent(in) :: self
      type(run_options_t), intent(in) :: opts
      type(case_summary_t), intent(inout) :: summary
      real(dp) :: total
      if (creeping(self, total)) then
         summary%status = 'continuous_elongation'
         summary%message = 'the capsule length grew in each of the last 5 time units up to t_max = '// &
                           num(opts%t_max)//' (by '//num(total)//' in all): no steady shape'
      else
         summary%status = 'max_time'
         summary%message = 'no steady state by t_max = '//num(opts%t_max)
      end if
   end subroutine classify_at_time_limit

   !> True if the length grew, by more than the steady tolerance, in every one of the last
   !> `creep_units` time units (capsules creep in bursts, so the rate itself need not hold);
   !> `total` is the growth over those units.
   logical function creeping(self, total)
      class(capsule_model_t), intent(in) :: self
      real(dp), intent(out) :: total
      integer, parameter :: creep_units = 5
      integer :: last, k, newer, older
      real(dp) :: t_now, growth, threshold
      last = self%n_rec
      t_now = self%history(self%col_t, last)
      creeping = t_now >= creep_units
      total = 0.0_dp
      do k = 1, creep_units
         if (.not. creeping) exit
         newer = window_start(self, t_now - (k - 1))
         if (k == 1) newer = last
         older = window_start(self, t_now - k)
         growth = self%history(self%col_length, newer) - self%history(self%col_length, older)
         threshold = self%shape_rel_tol * abs(self%history(self%col_length, newer)) + self%shape_abs_tol
         creeping = growth > threshold
         total = total + growth
      end do
   end function creeping

   !> Records fall on the first step at or after each multiple of `every`; computed from the
   !> last record alone, so that a resumed run records at the same steps as an uninterrupted one.
   pure real(dp) function next_record_time(t_last, every)
      real(dp), intent(in) :: t_last, every
      next_record_time = (floor(t_last / every + 1.0e-6_dp) + 1) * every
   end function next_record_time

   pure integer function window_start(self, t_from)
      class(capsule_model_t), intent(in) :: self
      real(dp), intent(in) :: t_from
      integer :: k
      window_start = 1
      do k = self%n_rec, 1, -1
         if (self%history(self%col_t, k) < t_from - 1.0e-9_dp) then
            window_start = k + 1
            exit
         end if
      end do
      window_start = min(window_start, self%n_rec)
   end function window_start

   !> A number as short text for messages.
   pure function num(x) result(s)
      real(dp), intent(in) :: x
      character(len=:), allocatable :: s
      character(len=32) :: buf
      write (buf, '(es10.3)') x
      s = trim(adjustl(buf))
   end function num

end module capsule_model
