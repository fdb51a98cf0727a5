!> A steady branch of the axisymmetric tube model (capsim --branch-ca): one case file per
!> requested Ca_s, in increasing order, and a branch file with the points followed and the
!> critical Ca_s where the steady branch ends.
!>
!> Why: time stepping each case to its steady state costs ~100 implicit steps (2-7 s at 64
!> elements); along a branch the next steady shape is a few chord-Newton iterations from the
!> last (axisymmetric_continuation). Time stepping is still what picks the physical branch (at
!> small a/l Newton from the sphere lands on an unstable convex shape): the branch starts from
!> the first requested Ca_s whose time-stepped case is steady, polished and stable, and every
!> case that continuation cannot vouch for (no branch yet, or after a stability loss or a
!> corrector failure) is time-stepped as a single run would be, and may restart the branch.
!> Where the branch turns back in Ca_s (a fold) or leaves what the mesh resolves, the steady
!> shapes end: the remaining cases are continuous elongation, and the fold is the critical Ca_s.
!>
!> Files: each case file is what a single run writes (open_case_file), written as soon as its
!> case is decided; continued cases have /history of one row (the steady shape, t = 0).
!> Resume: after each case the branch state (case index, phase, the branch point's shape and
!> Ca_s, the branch log) goes to BRANCH.h5.ckpt (write_checkpoint). A rerun with the same options
!> goes on from there; as the step from a branch point depends on its shape and Ca_s only, it
!> rewrites the same results bit for bit (the files differ in their wall times only).
module tube_branch
   use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
   use capsim_kinds, only: dp, code_version, schema_version
   use file_ops, only: path_kind, path_regular, replace_file
   use hdf5_writer, only: h5_file_t
   use membrane_law, only: membrane_law_t
   use run_options, only: run_options_t, option_signature, branch_ca_values, branch_case_path
   use case_output, only: case_summary_t, close_case_file, write_checkpoint, read_checkpoint
   use capsule_model, only: num
   use text_format, only: int_text
   use tube_history, only: h_lz, h_lp, h_vc, h_volume, h_stretch
   use axisymmetric_steady, only: stable_rate_limit
   use axisymmetric_continuation, only: branch_point_t, fold_search_t, start_branch_point, continue_to_ca, &
                                        search_fold, end_none, end_fold, end_mesh_limit, end_unstable
   use axisymmetric_tube, only: axisymmetric_tube_t, meridian_stretch_limit
   implicit none
   private
   public :: run_tube_branch, start_branch_file, finish_branch_file, log_columns, branch_end_none

   !> Phases of the branch: no branch point held (cases are time-stepped), on the branch, ended.
   integer, parameter :: phase_stepping = 0, phase_on_branch = 1, phase_ended = 2
   !> Columns of the branch log: Ca_s, L_z, L_p, v_c, largest growth rate, largest stretch, and
   !> how the point was reached (source_*).
   integer, parameter :: log_columns = 7
   integer, parameter :: source_time_stepping = 0, source_requested = 1, source_arclength = 2
   character(len=*), parameter :: log_names(log_columns) = [character(len=16) :: 'Ca_s', 'L_z', 'L_p', 'v_c', &
                                                           'growth_rate', 'stretch', 'source']
   character(len=*), parameter :: log_units(log_columns) = [character(len=16) :: '1', 'l', 'l', 'V', 'V/l', '1', '1']
   !> What the source column means in the axisymmetric branch log.
   character(len=*), parameter :: axi_sources = '0 time-stepped start, 1 requested Ca_s, 2 arclength point'
   !> critical_kind of a branch that does not end within the requested Ca_s.
   character(len=*), parameter :: branch_end_none = 'none: the branch does not end within the requested Ca_s'

contains

   !> Runs the branch of `opts` (--branch-ca, --branch-summary) and writes its files.
   !> stat /= 0 with errmsg when a file cannot be written or the model cannot be set up.
   subroutine run_tube_branch(opts, threads, stat, errmsg)
      type(run_options_t), intent(in) :: opts
      integer, intent(in) :: threads
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      type(axisymmetric_tube_t) :: model
      type(branch_point_t) :: point
      type(fold_search_t) :: found
      type(run_options_t) :: case_opts
      type(case_summary_t) :: summary
      real(dp), allocatable :: values(:), branch_log(:, :), state(:), saved_rz(:, :), stuck_rz(:, :), last_rz(:, :)
      real(dp) :: critical_log_ca, wall_before, ca_from, t_unused, stuck_ca, last_ca
      integer :: k, k_done, phase, outcome, n_log, n_nodes, velocities0, jacobians0
      integer(8) :: clock_start, clock_case, clock_now, clock_rate
      character(len=:), allocatable :: signature, note, ended_text
      logical :: ok, resumed, converged, confirmed, have_last
      character(len=32) :: stepped_status

      call model%init(opts, stat, errmsg)
      if (stat /= 0) return
      call branch_ca_values(opts, values, ok)
      n_nodes = size(model%positions, 2)
      ! The state: phase, critical ln Ca_s, outcome, Ca_s and shape, and the last converged
      ! branch point kept while the cases are time-stepped (a flag, its Ca_s and shape).
      allocate (state(6 + 4 * n_nodes), branch_log(log_columns, 16), last_rz(2, n_nodes))
      have_last = .false.
      last_ca = 0
      last_rz = 0
      signature = option_signature(opts)//' branch '//trim(opts%branch_ca)
      call system_clock(clock_start, clock_rate)
      clock_now = clock_start

      ! The branch state of an interrupted run, if its case files are all there.
      k_done = 0
      n_log = 0
      call read_checkpoint(checkpoint_path(), signature, k_done, t_unused, state, branch_log, n_log, wall_before, &
                           resumed, note)
      if (resumed) then
         do k = 1, k_done
            if (path_kind(branch_case_path(opts, k)) /= path_regular) resumed = .false.
         end do
      end if
      if (resumed) then
         phase = nint(state(1))
         critical_log_ca = state(2)
         outcome = nint(state(3))
         model%ca = state(4)
         model%positions = reshape(state(5:4 + 2 * n_nodes), [2, n_nodes])
         have_last = state(5 + 2 * n_nodes) > 0.5_dp
         last_ca = state(6 + 2 * n_nodes)
         last_rz = reshape(state(7 + 2 * n_nodes:), [2, n_nodes])
         if (phase == phase_on_branch) call start_branch_point(model, point)
         if (.not. opts%quiet) write (*, '(a,i0,a,i0,a)') 'capsim: branch resumed after case ', k_done, ' of ', &
            size(values), ''
      else
         k_done = 0
         n_log = 0
         wall_before = 0
         phase = phase_stepping
         outcome = end_none
         critical_log_ca = huge(1.0_dp)
      end if

      do k = k_done + 1, size(values)
         call system_clock(clock_case)
         case_opts = opts
         case_opts%ca = values(k)
         case_opts%out = branch_case_path(opts, k)
         summary = case_summary_t()
         confirmed = .false.
         select case (phase)
         case (phase_stepping)
            call time_stepped_case(case_opts, model, point, phase, stat, errmsg, stepped_status)
            if (stat /= 0) return
            if (phase == phase_on_branch) then
               call log_point(source_time_stepping)
               have_last = .false.
            else if (have_last .and. trim(stepped_status) == 'continuous_elongation') then
               ! The branch was left at a steady case the corrector could not confirm; this case
               ! elongates: the fold search from the last converged point says where it ended.
               model%positions = last_rz
               model%ca = last_ca
               call start_branch_point(model, point)
               found = fold_search_t()
               call locate_branch_end()
               call end_at_search(last_ca)
               ! The shape written for later cases is the last converged one, as on the branch.
               model%positions = last_rz
               model%ca = last_ca
               have_last = .false.
            end if
         case (phase_on_branch)
            ca_from = exp(point%log_ca)
            allocate (saved_rz, source=point%rz)
            velocities0 = point%n_velocities
            jacobians0 = point%n_jacobians
            call continue_to_ca(model, point, opts, values(k), converged)
            found = fold_search_t()
            if (converged .and. point%stretch > meridian_stretch_limit) then
               found%outcome = end_mesh_limit
               found%critical_log_ca = point%log_ca
               converged = .false.
            else if (converged .and. point%growth_rate > stable_rate_limit) then
               found%outcome = end_unstable
               found%critical_log_ca = log(ca_from)
               converged = .false.
            end if
            if (converged) then
               call log_point(source_requested)
               summary%status = 'steady'
               summary%message = 'steady: by continuation along the steady branch from Ca_s = '//num(ca_from)// &
                                 ' (chord Newton, '//int_text(point%n_velocities - velocities0)//' velocities, '// &
                                 int_text(point%n_jacobians - jacobians0)//' Jacobians): residual '// &
                                 num(model%residual)//' V, largest growth rate '//num(point%growth_rate)//' V/l'
               call write_continued_case(case_opts, model, summary, clock_case, stat, errmsg)
               if (stat /= 0) return
            else
               ! The branch cannot vouch for this case: time stepping decides it, as a single
               ! run would. Where it is steady (and the corrector confirms it), the branch starts
               ! again from that case: the corrector's failure belonged to another part of the
               ! discrete branch (the rear of a nearly rigid capsule buckles just above Ca_s 0.01,
               ! a fold at 0.0118-0.0120 for NH a/l 0.8-1 at 64 elements, while the case at 0.02
               ! is steady). Where the case elongates, the fold search from where the corrector
               ! stopped says where the branch ended (a fold, or the mesh's limit). Searching only
               ! then saves the search wherever the case restarts the branch (8-11 CPU s after
               ! Ca_s 0.01 at NH a/l 0.8 and 1) or does not elongate (below).
               if (.not. opts%quiet) write (*, '(a)') 'capsim: continuation to Ca_s = '//num(values(k))// &
                  ' stopped at Ca_s = '//num(exp(point%log_ca))//'; time stepping decides'
               stuck_ca = model%ca
               allocate (stuck_rz, source=model%positions)
               phase = phase_stepping
               call time_stepped_case(case_opts, model, point, phase, stat, errmsg, stepped_status)
               if (stat /= 0) return
               if (phase == phase_on_branch) then
                  call log_point(source_time_stepping)
               else if (found%outcome == end_none) then
                  if (trim(stepped_status) == 'continuous_elongation') then
                     call locate_branch_end()
                     call end_at_search(ca_from)
                  else
                     ! A case the corrector cannot confirm (steady, or ended otherwise than by
                     ! elongating): the next cases are time-stepped until one restarts the
                     ! branch, and the last converged point is kept for the fold search in case
                     ! one elongates first. Searching now, towards a case that does not elongate,
                     ! cost more than the time-stepped cases it could spare (SK C = 2, a/l 0.8,
                     ! from Ca_s 0.01 to 0.02: 19 CPU s of a 31 s branch, and the case at 0.03
                     ! was time-stepped all the same).
                     have_last = .true.
                     last_rz = stuck_rz
                     last_ca = stuck_ca
                  end if
               end if
               deallocate (stuck_rz)
               if (phase /= phase_on_branch) then
                  model%positions = saved_rz
                  model%ca = ca_from
               end if
            end if
            deallocate (saved_rz)
         end select
         if (phase == phase_ended .and. .not. confirmed) then
            ended_text = end_text(outcome, critical_log_ca)
            summary%status = 'continuous_elongation'
            summary%message = 'no steady shape: '//ended_text//'; the shape written is the last steady one '// &
                              'continued, at Ca_s = '//num(model%ca)
            call write_continued_case(case_opts, model, summary, clock_case, stat, errmsg, exp(critical_log_ca))
            if (stat /= 0) return
         end if
         state(1) = phase
         state(2) = critical_log_ca
         state(3) = outcome
         state(4) = model%ca
         state(5:4 + 2 * n_nodes) = reshape(model%positions, [2 * n_nodes])
         state(5 + 2 * n_nodes) = merge(1.0_dp, 0.0_dp, have_last)
         state(6 + 2 * n_nodes) = last_ca
         state(7 + 2 * n_nodes:) = reshape(last_rz, [2 * n_nodes])
         call system_clock(clock_now)
         call write_checkpoint(checkpoint_path(), signature, k, 0.0_dp, state, branch_log, n_log, &
                               wall_before + real(clock_now - clock_start, dp) / clock_rate, stat, errmsg)
         if (stat /= 0) return
      end do
      call write_branch_file(opts, model, branch_log(:, 1:n_log), outcome, critical_log_ca, phase, threads, &
                             wall_before + real(clock_now - clock_start, dp) / clock_rate, stat, errmsg)
      if (stat /= 0) return
      open (newunit=k, file=checkpoint_path(), status='old', iostat=stat)
      if (stat == 0) close (k, status='delete')
      stat = 0

   contains

      !> After a fold search towards a case that elongates: the branch ends where the search
      !> found (a fold, or the mesh's limit), confirmed by that case; the branch ran from Ca_s = from.
      subroutine end_at_search(from)
         real(dp), intent(in) :: from
         if (found%outcome == end_fold .or. found%outcome == end_mesh_limit) then
            outcome = found%outcome
            critical_log_ca = found%critical_log_ca
            phase = phase_ended
            confirmed = .true.
         end if
         if (.not. opts%quiet) write (*, '(a)') 'capsim: the steady branch from Ca_s = '// &
            num(from)//' ends: '//search_text(found)
      end subroutine end_at_search

      !> Pseudo-arclength steps (search_fold) from where the corrector stopped, landing on the
      !> case's Ca_s (continue_to_ca) whenever they pass it, until the branch ends or reaches
      !> the case after all (converged; then nothing is confirmed): found holds how.
      subroutine locate_branch_end()
         converged = .false.
         do while (.not. converged)
            call search_fold(model, point, opts, values(k), meridian_stretch_limit, stable_rate_limit, found)
            if (found%outcome /= end_none) exit
            call log_point(source_arclength)
            call continue_to_ca(model, point, opts, values(k), converged)
         end do
      end subroutine locate_branch_end

      function checkpoint_path() result(path)
         character(len=:), allocatable :: path
         path = trim(opts%branch_summary)//'.ckpt'
      end function checkpoint_path

      !> Appends the branch point to the branch log.
      subroutine log_point(source)
         integer, intent(in) :: source
         real(dp), allocatable :: grown(:, :)
         if (n_log >= size(branch_log, 2)) then
            allocate (grown(log_columns, 2 * size(branch_log, 2)))
            grown(:, 1:n_log) = branch_log(:, 1:n_log)
            call move_alloc(grown, branch_log)
         end if
         model%n_rec = 0
         call model%record()
         n_log = n_log + 1
         branch_log(:, n_log) = [exp(point%log_ca), model%history(h_lz, 1), model%history(h_lp, 1), &
                                 model%history(h_vc, 1), point%growth_rate, point%stretch, real(source, dp)]
      end subroutine log_point

   end subroutine run_tube_branch

   !> The case at case_opts%ca time-stepped exactly as a single run (a fresh model, its own
   !> checkpoint), its case file written. If it is steady and the continuation corrector
   !> confirms its shape as a stable root (the polish may have been discarded), the branch
   !> (re)starts there: phase_on_branch, with `model` and `point` at that shape; otherwise
   !> phase is left as it was.
   subroutine time_stepped_case(case_opts, model, point, phase, stat, errmsg, status)
      type(run_options_t), intent(in) :: case_opts
      type(axisymmetric_tube_t), intent(inout) :: model
      type(branch_point_t), intent(inout) :: point
      integer, intent(inout) :: phase
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      !> The case's status (steady, continuous_elongation, ...).
      character(len=*), intent(out) :: status
      type(axisymmetric_tube_t), allocatable :: single
      type(case_summary_t) :: summary
      type(h5_file_t) :: f
      integer :: steady_index
      integer(8) :: clock_start, clock_end, clock_rate
      logical :: converged

      call system_clock(clock_start, clock_rate)
      allocate (single)
      call single%init(case_opts, stat, errmsg)
      if (stat /= 0) return
      call single%run(case_opts, trim(case_opts%out)//'.ckpt', summary, steady_index)
      if (allocated(summary%fatal)) then
         stat = 1
         errmsg = summary%fatal
         return
      end if
      call system_clock(clock_end)
      summary%wall_time_s = summary%wall_time_before_s + real(clock_end - clock_start, dp) / clock_rate
      summary%threads = case_threads()
      call single%start_case_file(case_opts, summary, steady_index, f, stat, errmsg)
      if (stat == 0) call close_case_file(f, case_opts, stat, errmsg)
      if (stat /= 0) return
      call delete_if_present(trim(case_opts%out)//'.ckpt')
      status = summary%status
      if (.not. case_opts%quiet) write (*, '(a)') 'capsim: Ca_s = '//num(case_opts%ca)//' time-stepped: '// &
         trim(summary%status)
      if (steady_index == 0) return
      ! The corrector from the time-stepped shape at this Ca_s: a tangent step of zero length.
      model%positions = single%positions
      model%ca = case_opts%ca
      call start_branch_point(model, point)
      call continue_to_ca(model, point, case_opts, case_opts%ca, converged)
      if (converged .and. carries_branch(point)) then
         phase = phase_on_branch
      end if
   end subroutine time_stepped_case

   !> The case file of a case decided by the branch: one history row (the model's shape at its
   !> Ca_s, t = 0), /steady for a steady case, and for cases past the branch's end the
   !> critical Ca_s as attribute branch_critical_Ca_s.
   subroutine write_continued_case(case_opts, model, summary, clock_case, stat, errmsg, critical_ca)
      type(run_options_t), intent(in) :: case_opts
      type(axisymmetric_tube_t), intent(inout) :: model
      type(case_summary_t), intent(inout) :: summary
      integer(8), intent(in) :: clock_case
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      real(dp), intent(in), optional :: critical_ca
      type(h5_file_t) :: f
      integer(8) :: clock_now, clock_rate
      model%n_rec = 0
      model%t = 0
      call model%record()
      summary%dt = 0
      summary%volume_change = model%history(h_volume, 1) / model%volume0 - 1.0_dp
      call system_clock(clock_now, clock_rate)
      summary%wall_time_s = real(clock_now - clock_case, dp) / clock_rate
      summary%threads = case_threads()
      call model%start_case_file(case_opts, summary, merge(1, 0, trim(summary%status) == 'steady'), f, stat, errmsg)
      if (stat == 0 .and. present(critical_ca)) call f%write_attr('/', 'branch_critical_Ca_s', critical_ca, stat, errmsg)
      if (stat == 0) call close_case_file(f, case_opts, stat, errmsg)
      if (stat == 0 .and. .not. case_opts%quiet) write (*, '(a)') 'capsim: Ca_s = '//num(case_opts%ca)//' '// &
         trim(summary%status)//' '//model%progress_text()
   end subroutine write_continued_case

   !> The branch file: the branch log as datasets under /branch, and the critical Ca_s (NaN
   !> when the branch did not end inside the requested range) with how it was found.
   subroutine write_branch_file(opts, model, branch_log, outcome, critical_log_ca, phase, threads, wall_time, &
                                stat, errmsg)
      type(run_options_t), intent(in) :: opts
      type(axisymmetric_tube_t), intent(in) :: model
      real(dp), intent(in) :: branch_log(:, :), critical_log_ca, wall_time
      integer, intent(in) :: outcome, phase, threads
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      type(h5_file_t) :: f
      real(dp) :: critical_ca
      character(len=:), allocatable :: kind
      critical_ca = ieee_value(1.0_dp, ieee_quiet_nan)
      kind = branch_end_none
      if (phase == phase_ended) then
         critical_ca = exp(critical_log_ca)
         kind = merge('fold      ', 'mesh_limit', outcome == end_fold)
         kind = trim(kind)
         call start_branch_file(opts, model%law, 'axi', branch_log, critical_ca, kind, &
                                axi_sources, threads, wall_time, &
                                f, stat, errmsg, end_text(outcome, critical_log_ca))
      else
         call start_branch_file(opts, model%law, 'axi', branch_log, critical_ca, kind, &
                                axi_sources, threads, wall_time, &
                                f, stat, errmsg)
      end if
      if (stat == 0) call f%write_attr('/', 'n_meridian', opts%n_meridian, stat, errmsg)
      call finish_branch_file(f, trim(opts%branch_summary), stat, errmsg)
   end subroutine write_branch_file

   !> The part of a branch file that the tube models share (the readers of the workflow rely
   !> on it): root attributes naming the case and the branch's end (critical_Ca_s, NaN where
   !> it did not end; critical_kind; critical_message where given), and the branch log
   !> (columns log_names) as datasets under /branch, whose attribute `source` says what the
   !> source codes mean. Written to BRANCH.tmp, left open for the model's own attributes;
   !> finish_branch_file puts it in place.
   subroutine start_branch_file(opts, law, model_name, branch_log, critical_ca, kind, source_text, threads, &
                                wall_time, f, stat, errmsg, message)
      type(run_options_t), intent(in) :: opts
      type(membrane_law_t), intent(in) :: law
      character(len=*), intent(in) :: model_name, kind, source_text
      real(dp), intent(in) :: branch_log(:, :), critical_ca, wall_time
      integer, intent(in) :: threads
      type(h5_file_t), intent(inout) :: f
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      character(len=*), intent(in), optional :: message
      integer :: c
      call f%create(trim(opts%branch_summary)//'.tmp', stat, errmsg)
      if (stat /= 0) return
      call f%write_attr('/', 'schema_version', schema_version, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'code_version', code_version, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'flow', 'tube', stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'model', model_name, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'law', law%name(), stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'nu_s', law%nu_s, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'C', law%c, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'a_over_l', opts%a_over_l, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'requested_Ca_s', trim(opts%branch_ca), stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'critical_Ca_s', critical_ca, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'critical_kind', kind, stat, errmsg)
      if (stat == 0 .and. present(message)) call f%write_attr('/', 'critical_message', message, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'wall_time_s', wall_time, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'threads', threads, stat, errmsg)
      if (stat == 0) call f%make_group('/branch', stat, errmsg)
      if (stat == 0) call f%write_attr('/branch', 'source', source_text, stat, errmsg)
      do c = 1, log_columns
         if (stat == 0) call f%write_dataset('/branch/'//trim(log_names(c)), branch_log(c, :), trim(log_units(c)), &
                                             stat, errmsg)
      end do
   end subroutine start_branch_file

   !> Closes a branch file opened by start_branch_file and, if everything was written (stat
   !> 0 on entry), renames it into place; nothing where it could not be created.
   subroutine finish_branch_file(f, path, stat, errmsg)
      type(h5_file_t), intent(inout) :: f
      character(len=*), intent(in) :: path
      integer, intent(inout) :: stat
      character(len=:), allocatable, intent(inout) :: errmsg
      integer :: ignored
      character(len=:), allocatable :: ignored_msg
      if (.not. f%is_open()) return
      if (stat == 0) then
         call f%close(stat, errmsg)
      else
         call f%close(ignored, ignored_msg)
      end if
      if (stat == 0) call replace_file(path//'.tmp', path, stat, errmsg)
   end subroutine finish_branch_file

   !> Whether the branch can go on from a converged point: linearly stable, and within what
   !> the mesh resolves.
   pure logical function carries_branch(point)
      type(branch_point_t), intent(in) :: point
      carries_branch = point%growth_rate < stable_rate_limit .and. point%stretch <= meridian_stretch_limit
   end function carries_branch

   !> What a fold search found, for progress lines.
   function search_text(found) result(text)
      type(fold_search_t), intent(in) :: found
      character(len=:), allocatable :: text
      select case (found%outcome)
      case (end_fold)
         text = 'fold at Ca_s = '//num(exp(found%critical_log_ca))
      case (end_mesh_limit)
         text = 'element stretch limit at Ca_s = '//num(exp(found%critical_log_ca))
      case (end_unstable)
         text = 'stability lost after Ca_s = '//num(exp(found%critical_log_ca))
      case default
         text = 'no convergence after '//int_text(found%n_points)//' arclength points'
      end select
   end function search_text

   !> Why the branch ended, for messages.
   function end_text(outcome, critical_log_ca) result(text)
      integer, intent(in) :: outcome
      real(dp), intent(in) :: critical_log_ca
      character(len=:), allocatable :: text
      if (outcome == end_fold) then
         text = 'the steady branch turns back at a fold at Ca_s = '//num(exp(critical_log_ca))// &
                ' (pseudo-arclength continuation)'
      else
         text = 'the steady branch leaves what the mesh resolves (element stretch '//num(meridian_stretch_limit)// &
                ') at Ca_s = '//num(exp(critical_log_ca))
      end if
   end function end_text

   integer function case_threads()
      use omp_lib, only: omp_get_max_threads
      case_threads = omp_get_max_threads()
   end function case_threads

   subroutine delete_if_present(path)
      character(len=*), intent(in) :: path
      integer :: unit, ios
      open (newunit=unit, file=path, status='old', iostat=ios)
      if (ios == 0) close (unit, status='delete')
   end subroutine delete_if_present

end module tube_branch
