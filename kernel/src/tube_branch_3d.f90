!> A steady branch of the 3D tube and duct models (capsim --branch-ca with --model 3d
!> --integrator newton): one case file per requested Ca_s, in increasing order, and a branch
!> file laid out as the axisymmetric model's (tube_branch: start_branch_file), with the points
!> followed and the bracket of Ca_s where the steady branch ends.
!>
!> Why: a single 3D case sets up its wall (assembly and LU, or the cache load), solves the
!> axisymmetric model for its guess and takes Newton-Krylov from that guess, which is a shape
!> of another model and mesh. Along a branch the wall is set up once and the previous steady
!> 3D shape, moved by the secant through the last two (linear in Ca_s), is a far better guess.
!>
!> The first case (and any case while no steady point is held) is solved as a single run
!> would (tube_steady_3d's run: the axisymmetric guess, warm-ups after failed attempts). From
!> a steady point the next Ca_s is reached by one Newton attempt per trial; where a trial
!> fails, the interval between the last steady Ca_s and the failed one is bisected
!> (intermediate steady points are logged, source 2); a failed Ca_s that the bisection comes
!> within fold_resolution (relative) of is tried once more from there (it may have failed only
!> for starting too far), and continuation goes on to the requested Ca_s if it converges. A
!> trial that fails within fold_resolution of the last steady Ca_s ends the branch. Its end
!> is recorded as the bracket (last steady Ca_s, first failed Ca_s) and the bracket's
!> midpoint as critical_Ca_s; every later case file is the last steady shape with status
!> continuous_elongation, as in the axisymmetric branch.
!> A steady shape flagged not stable (tube_steady_3d's growth-rate estimate above its limit)
!> does not carry the branch, as in the axisymmetric branch (carries_branch): a continued
!> trial that converges to one counts as failed, so that the bisection brackets the loss of
!> stability as it brackets a fold, and the branch ends there with critical_kind `unstable`;
!> a case solved as a single one (no steady point held) that is flagged is written as solved
!> and not kept, so that the next Ca_s is solved as a single case again.
!> A failed trial is a Newton attempt that found no root near the predicted shape: past a
!> fold there is none, but a bisection that still fails within fold_resolution is also what a
!> root that Newton cannot reach would give; the message says how the end was found.
!>
!> No resume: an interrupted 3D branch reruns from its first Ca_s.
module tube_branch_3d
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
   use capsim_kinds, only: dp
   use hdf5_writer, only: h5_file_t
   use run_options, only: run_options_t, branch_ca_values, branch_case_path
   use case_output, only: case_summary_t, close_case_file
   use capsule_model, only: num
   use text_format, only: int_text
   use tube_history, only: h_lz, h_lp, h_vc, h_stretch
   use tube_branch, only: start_branch_file, finish_branch_file, log_columns, branch_end_none
   use tube_steady_3d, only: tube_steady_capsule_t, stability
   implicit none
   private
   public :: run_tube_branch_3d

   !> The branch ends when a failed Ca_s lies within this fraction of the last steady Ca_s:
   !> about the level-3 mesh's own error in the lengths (docs/validation/kernel-tube.md).
   real(dp), parameter :: fold_resolution = 1.0e-2_dp
   !> The secant predictor extrapolates at most this many times the last step: after a
   !> bisection step the last two shapes are close, and their difference carries Newton's noise.
   real(dp), parameter :: max_extrapolation = 2.0_dp
   integer, parameter :: source_single = 0, source_requested = 1, source_bisection = 2
   character(len=*), parameter :: source_text = '0 solved as a single case (axisymmetric guess), '// &
                                                '1 requested Ca_s by continuation, 2 intermediate point of a bisection'

   !> A steady point of the branch: Ca_s, the shape, and the solver's figures written with it.
   type :: steady_point_t
      real(dp) :: ca = 0, growth_rate = 0, growth_residual = 0, residual = 0, residual_full = 0
      real(dp), allocatable :: x(:, :)
   end type steady_point_t

contains

   !> Runs the branch of `opts` (--branch-ca, --branch-summary, --model 3d --integrator newton)
   !> and writes its files. stat /= 0 with errmsg when a file cannot be written or the model
   !> cannot be set up.
   subroutine run_tube_branch_3d(opts, threads, stat, errmsg)
      type(run_options_t), intent(in) :: opts
      integer, intent(in) :: threads
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      type(tube_steady_capsule_t) :: model
      type(run_options_t) :: case_opts
      type(case_summary_t) :: summary
      type(steady_point_t) :: last, before
      real(dp), allocatable :: values(:), branch_log(:, :)
      !> The first failed Ca_s of the branch's end; where the current case's continuation started.
      real(dp) :: failed_ca, from_ca
      !> Whether the trial that failed at failed_ca converged to a shape flagged not stable (its
      !> growth rate), rather than finding no steady shape.
      logical :: failed_unstable
      real(dp) :: failed_growth
      integer :: k, n_known, n_log, steady_index, case_evaluations, case_products, case_newton, trials
      integer(8) :: clock_start, clock_case, clock_now, clock_rate
      logical :: ok, ended
      character(len=:), allocatable :: how

      call system_clock(clock_start, clock_rate)
      call model%init(opts, stat, errmsg)
      if (stat /= 0) return
      call branch_ca_values(opts, values, ok)
      allocate (branch_log(log_columns, 16))
      n_log = 0
      n_known = 0
      ended = .false.
      failed_ca = 0
      failed_unstable = .false.
      failed_growth = 0
      clock_case = clock_start
      do k = 1, size(values)
         case_opts = opts
         case_opts%ca = values(k)
         case_opts%out = branch_case_path(opts, k)
         summary = case_summary_t()
         case_evaluations = 0
         case_products = 0
         case_newton = 0
         trials = 0
         if (ended) then
            call write_past_end()
            if (stat /= 0) return
         else if (n_known == 0) then
            ! No steady point held: the case as a single run solves it (the wall is kept; the
            ! axisymmetric guess's checkpoint goes beside the branch file and is removed).
            model%ca = values(k)
            call model%run(case_opts, trim(opts%branch_summary)//'.ckpt', summary, steady_index)
            call count_solve()
            if (steady_index > 0 .and. stability(model) /= 0) then
               call keep_point()
               call log_point(source_single)
            end if
            call write_case(steady_index)
            if (stat /= 0) return
         else
            call continue_to(values(k), ok)
            if (ok) then
               summary%message = 'continued along the steady branch from Ca_s = '//num(from_ca)//' ('// &
                                 int_text(trials)//' Newton attempts, '//int_text(case_evaluations)// &
                                 ' velocity evaluations in all): '//summary%message
               call log_point(source_requested)
               call write_case(model%n_rec)
            else
               ended = .true.
               call write_past_end()
            end if
            if (stat /= 0) return
         end if
         call system_clock(clock_case)
      end do
      call system_clock(clock_now)
      call write_branch_3d(opts, model, branch_log(:, 1:n_log), ended, last%ca, failed_ca, failed_unstable, &
                           failed_growth, threads, real(clock_now - clock_start, dp) / clock_rate, stat, errmsg)

   contains

      !> From the last steady point to Ca_s = target by trials of one Newton attempt each,
      !> bisecting after a failure (see the module header). ok: the model is steady at
      !> target; otherwise the branch ends between last%ca and failed_ca.
      subroutine continue_to(target, ok)
         real(dp), intent(in) :: target
         logical, intent(out) :: ok
         real(dp) :: step, ca
         logical :: unstable
         from_ca = last%ca
         step = target - last%ca
         do
            ca = last%ca + step
            if (ca >= target * (1.0_dp - 1.0e-12_dp)) ca = target
            call trial(ca, ok, unstable)
            if (ok) then
               if (ca == target) return
               call log_point(source_bisection)
               ! Bisection towards the failed Ca_s; once within the resolution, that Ca_s again
               ! from here: it may have failed only for starting too far. Past it (the retry
               ! converged), on to the target.
               if (ca >= failed_ca) then
                  step = target - last%ca
               else if (failed_ca - last%ca <= fold_resolution * last%ca) then
                  step = failed_ca - last%ca
               else
                  step = 0.5_dp * (failed_ca - last%ca)
               end if
            else
               failed_ca = ca
               failed_unstable = unstable
               if (unstable) failed_growth = model%growth_rate
               if (ca - last%ca <= fold_resolution * last%ca) then
                  how = branch_end_text(last%ca, failed_ca, failed_unstable, failed_growth)
                  if (.not. opts%quiet) write (*, '(a)') 'capsim: '//how
                  return
               end if
               step = 0.5_dp * (ca - last%ca)
            end if
         end do
      end subroutine continue_to

      !> One Newton attempt at Ca_s = ca from the secant predictor through the last two steady
      !> points (the last one alone when there is one); a converged trial whose shape is not
      !> flagged not stable becomes the last point (converged), a flagged one does not
      !> (unstable).
      subroutine trial(ca, converged, unstable)
         real(dp), intent(in) :: ca
         logical, intent(out) :: converged, unstable
         real(dp) :: ratio
         type(run_options_t) :: trial_opts
         model%ca = ca
         model%positions = last%x
         model%guess_source = 'previous branch point (Ca_s = '//num(last%ca)//')'
         if (n_known >= 2) then
            ratio = min((ca - last%ca) / (last%ca - before%ca), max_extrapolation)
            model%positions = last%x + ratio * (last%x - before%x)
            model%guess_source = 'previous branch points (Ca_s = '//num(before%ca)//' and '//num(last%ca)// &
                                 ', secant predictor)'
         end if
         model%seconds_guess = 0
         trial_opts = opts
         trial_opts%ca = ca
         if (.not. opts%quiet) write (*, '(a)') 'capsim: branch trial at Ca_s = '//num(ca)//' from the '// &
            model%guess_source
         call model%solve(trial_opts, .false., summary, steady_index)
         call count_solve()
         trials = trials + 1
         converged = steady_index > 0
         unstable = converged .and. stability(model) == 0
         if (unstable) then
            converged = .false.
            if (.not. opts%quiet) write (*, '(a)') 'capsim: the steady shape at Ca_s = '//num(ca)// &
               ' is flagged not stable (growth rate '//num(model%growth_rate)//' V/l): it does not carry the branch'
         end if
         if (converged) call keep_point()
      end subroutine trial

      subroutine count_solve()
         case_evaluations = case_evaluations + model%velocity_evaluations
         case_products = case_products + model%gmres_products
         case_newton = case_newton + model%newton_iterations
      end subroutine count_solve

      !> The model's steady shape becomes the last point, the last one the one before.
      subroutine keep_point()
         if (n_known > 0) call move_alloc(last%x, before%x)
         before%ca = last%ca
         last%ca = model%ca
         last%x = model%positions
         last%growth_rate = model%growth_rate
         last%growth_residual = model%growth_residual
         last%residual = model%residual
         last%residual_full = model%residual_full
         n_known = min(n_known + 1, 2)
      end subroutine keep_point

      !> The case file of the model's state (one history row) with the case's solver totals.
      subroutine write_case(steady_index)
         integer, intent(in) :: steady_index
         type(h5_file_t) :: f
         call system_clock(clock_now)
         summary%wall_time_s = real(clock_now - clock_case, dp) / clock_rate
         summary%threads = threads
         model%velocity_evaluations = case_evaluations
         model%gmres_products = case_products
         model%newton_iterations = case_newton
         call model%start_case_file(case_opts, summary, steady_index, f, stat, errmsg)
         if (stat == 0 .and. ended) call f%write_attr('/', 'branch_critical_Ca_s', 0.5_dp * (last%ca + failed_ca), &
                                                      stat, errmsg)
         if (stat == 0) call close_case_file(f, case_opts, stat, errmsg)
         if (stat == 0 .and. .not. opts%quiet) write (*, '(a)') 'capsim: Ca_s = '//num(values(k))//' '// &
            trim(summary%status)//' '//model%progress_text()
      end subroutine write_case

      !> A case past the branch's end: the last steady shape, at its Ca_s, as the axisymmetric
      !> branch writes it.
      subroutine write_past_end()
         model%ca = last%ca
         model%positions = last%x
         model%growth_rate = last%growth_rate
         model%growth_residual = last%growth_residual
         model%residual = last%residual
         model%residual_full = last%residual_full
         model%guess_source = 'previous branch point (Ca_s = '//num(last%ca)//')'
         model%t = 0
         model%n_rec = 0
         call model%record()
         summary%status = 'continuous_elongation'
         summary%message = trim(merge('no stable steady shape: ', 'no steady shape:        ', failed_unstable))// &
                           ' '//how//'; the shape written is the last steady one, at Ca_s = '//num(last%ca)
         call write_case(0)
      end subroutine write_past_end

      !> Appends the model's steady point (its history row) to the branch log.
      subroutine log_point(source)
         integer, intent(in) :: source
         real(dp), allocatable :: grown(:, :)
         real(dp) :: growth
         if (n_log >= size(branch_log, 2)) then
            allocate (grown(log_columns, 2 * size(branch_log, 2)))
            grown(:, 1:n_log) = branch_log(:, 1:n_log)
            call move_alloc(grown, branch_log)
         end if
         growth = model%growth_rate
         if (growth == huge(1.0_dp)) growth = ieee_value(1.0_dp, ieee_quiet_nan)
         n_log = n_log + 1
         branch_log(:, n_log) = [model%ca, model%history(h_lz, 1), model%history(h_lp, 1), model%history(h_vc, 1), &
                                 growth, model%history(h_stretch, 1), real(source, dp)]
      end subroutine log_point

   end subroutine run_tube_branch_3d

   !> The branch file: the axisymmetric layout (start_branch_file), critical_Ca_s the midpoint
   !> of the bracket where the branch ended (NaN if it did not), and the bracket, its
   !> resolution and the 3D mesh as attributes of their own.
   subroutine write_branch_3d(opts, model, branch_log, ended, last_ca, failed_ca, failed_unstable, failed_growth, &
                              threads, wall_time, stat, errmsg)
      type(run_options_t), intent(in) :: opts
      type(tube_steady_capsule_t), intent(in) :: model
      real(dp), intent(in) :: branch_log(:, :), last_ca, failed_ca, failed_growth, wall_time
      logical, intent(in) :: ended, failed_unstable
      integer, intent(in) :: threads
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      type(h5_file_t) :: f
      real(dp) :: nan
      nan = ieee_value(1.0_dp, ieee_quiet_nan)
      if (ended) then
         call start_branch_file(opts, model%law, '3d', branch_log, 0.5_dp * (last_ca + failed_ca), &
                                trim(merge('unstable', 'fold    ', failed_unstable)), source_text, threads, wall_time, &
                                f, stat, errmsg, branch_end_text(last_ca, failed_ca, failed_unstable, failed_growth))
         if (stat == 0) call f%write_attr('/', 'critical_Ca_s_last_steady', last_ca, stat, errmsg)
         if (stat == 0) call f%write_attr('/', 'critical_Ca_s_first_failed', failed_ca, stat, errmsg)
      else
         call start_branch_file(opts, model%law, '3d', branch_log, nan, branch_end_none, source_text, threads, &
                                wall_time, f, stat, errmsg)
         if (stat == 0) call f%write_attr('/', 'critical_Ca_s_last_steady', nan, stat, errmsg)
         if (stat == 0) call f%write_attr('/', 'critical_Ca_s_first_failed', nan, stat, errmsg)
      end if
      if (stat == 0) call f%write_attr('/', 'critical_Ca_s_resolution_rel', fold_resolution, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'n_meridian', opts%n_meridian, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'mesh_level', opts%level, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'channel', trim(opts%channel), stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'aspect', opts%aspect, stat, errmsg)
      call finish_branch_file(f, trim(opts%branch_summary), stat, errmsg)
   end subroutine write_branch_3d

   !> How the branch ended, between its last steady (and not unstable) Ca_s and the first failed
   !> one, for messages and critical_message: no steady shape found there (a fold), or a steady
   !> shape flagged not stable (its growth rate).
   function branch_end_text(last_ca, failed_ca, unstable, growth) result(text)
      real(dp), intent(in) :: last_ca, failed_ca, growth
      logical, intent(in) :: unstable
      character(len=:), allocatable :: text
      if (unstable) then
         text = 'the steady branch loses stability between Ca_s = '//num(last_ca)//' (the last steady point not '// &
                'flagged) and '//num(failed_ca)//' (steady, flagged not stable: largest growth rate '//num(growth)// &
                ' V/l; bisected down to '//num(fold_resolution)//' relative): critical Ca_s taken at the midpoint '// &
                num(0.5_dp * (last_ca + failed_ca))
      else
         text = 'the steady branch ends between Ca_s = '//num(last_ca)//' (the last steady point) and '// &
                num(failed_ca)//' (Newton-Krylov from the branch found no steady shape; bisected '// &
                'down to '//num(fold_resolution)//' relative): critical Ca_s taken at the midpoint '// &
                num(0.5_dp * (last_ca + failed_ca))
      end if
   end function branch_end_text

end module tube_branch_3d
