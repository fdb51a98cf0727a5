!> capsim: one capsule in Stokes flow (BIM-FEM), from the command line to an HDF5 case file.
!> This is the program's edge: errors from the modules become one line on stderr and exit 2.
program capsim
   use, intrinsic :: iso_fortran_env, only: error_unit, output_unit
   use, intrinsic :: iso_c_binding, only: c_int
   use file_ops, only: delete_file
   use omp_lib, only: omp_set_num_threads, omp_get_max_threads
   use blas_threads, only: match_blas_threads
   use capsim_kinds, only: dp, code_version
   use hdf5_writer, only: h5_file_t
   use run_options, only: run_options_t, parse_command_line, write_help, step_count_problem
   use case_output, only: case_summary_t, close_case_file
   use capsule_model, only: capsule_model_t
   use capsule_dynamics, only: capsule_t
   use axisymmetric_tube, only: axisymmetric_tube_t
   use tube_capsule, only: tube_capsule_t
   use tube_steady_3d, only: tube_steady_capsule_t
   use tube_branch, only: run_tube_branch
   use tube_branch_3d, only: run_tube_branch_3d
   implicit none

   type(run_options_t) :: opts
   class(capsule_model_t), allocatable :: model
   type(case_summary_t) :: summary
   type(h5_file_t) :: f
   character(len=:), allocatable :: errmsg, checkpoint_path
   integer :: stat, steady_index, unit, ios, close_stat
   character(len=:), allocatable :: close_errmsg

   interface
      !> POSIX _exit: ends the process without the exit handlers (see case_file_failed).
      subroutine c_exit(status) bind(c, name='_exit')
         import :: c_int
         integer(c_int), value :: status
      end subroutine c_exit
   end interface
   integer(8) :: clock_start, clock_end, clock_rate

   call parse_command_line(opts, stat, errmsg)
   if (opts%show_help) then
      call write_help(output_unit)
      stop
   end if
   if (opts%show_version) then
      write (output_unit, '(a)') 'capsim '//code_version
      stop
   end if
   if (stat /= 0) call die('capsim: error: '//errmsg, 2)
   if (opts%threads > 0) call omp_set_num_threads(opts%threads)
   call match_blas_threads(omp_get_max_threads())
   if (len_trim(opts%branch_ca) > 0) then
      ! A steady branch: its own case files and branch file (tube_branch, tube_branch_3d).
      if (trim(opts%model) == '3d') then
         call run_tube_branch_3d(opts, omp_get_max_threads(), stat, errmsg)
      else
         call run_tube_branch(opts, omp_get_max_threads(), stat, errmsg)
      end if
      if (stat /= 0) call die('capsim: error: '//errmsg, 1)
      ! Quiet: a plain STOP reports the IEEE flags that the quadratures raise on the way (a
      ! single run, which ends at END PROGRAM, does not).
      stop 0, quiet = .true.
   end if
   call system_clock(clock_start, clock_rate)

   if (trim(opts%flow) == 'tube' .and. trim(opts%model) == '3d' .and. trim(opts%integrator) == 'newton') then
      allocate (tube_steady_capsule_t :: model)
   else if (trim(opts%flow) == 'tube' .and. trim(opts%model) == '3d') then
      allocate (tube_capsule_t :: model)
   else if (trim(opts%flow) == 'tube') then
      allocate (axisymmetric_tube_t :: model)
   else
      allocate (capsule_t :: model)
   end if
   select type (model)
   type is (capsule_t)
      call model%init(opts, stat, errmsg)
   type is (axisymmetric_tube_t)
      call model%init(opts, stat, errmsg)
   class is (tube_capsule_t)
      call model%init(opts, stat, errmsg)
   end select
   if (stat /= 0) call die('capsim: error: '//errmsg, 2)
   ! The automatic step is known only now (it follows the mesh): bounded like a given one.
   if (len(step_count_problem(opts%t_max, model%dt)) > 0) &
      call die('capsim: error: --dt-factor: '//step_count_problem(opts%t_max, model%dt), 2)
   if (.not. opts%quiet) then
      write (*, '(a,i0,a,es9.2,a,i0,a)') 'capsim: ', size(model%positions), ' degrees of freedom, dt = ', model%dt, &
         ', ', omp_get_max_threads(), ' threads'
   end if
   checkpoint_path = trim(opts%out)//'.ckpt'
   call model%run(opts, checkpoint_path, summary, steady_index)
   if (allocated(summary%fatal)) call die('capsim: error: '//summary%fatal, 1)
   call system_clock(clock_end)
   summary%wall_time_s = summary%wall_time_before_s + real(clock_end - clock_start, dp) / clock_rate
   summary%threads = omp_get_max_threads()

   call model%start_case_file(opts, summary, steady_index, f, stat, errmsg)
   if (stat == 0) call close_case_file(f, opts, stat, errmsg)
   if (stat /= 0) call case_file_failed('capsim: error: writing the case file: '//errmsg)
   ! The case file is complete: the checkpoint has served its purpose.
   open (newunit=unit, file=checkpoint_path, status='old', iostat=ios)
   if (ios == 0) close (unit, status='delete')
   if (.not. opts%quiet) then
      write (*, '(a)') 'capsim: '//trim(summary%status)//': '//summary%message
      write (*, '(a,f0.2,a)') 'capsim: wrote '//trim(opts%out)//' (', summary%wall_time_s, ' s)'
   end if

contains

   !> The case file could not be written (a full disk): OUT.tmp is removed and the program
   !> exits 1 with one line. HDF5's exit handler would flush the failed file again and crash
   !> (exit 139), so the process ends by _exit, after flushing its own output.
   subroutine case_file_failed(message)
      character(len=*), intent(in) :: message
      call f%close(close_stat, close_errmsg)
      call delete_file(trim(opts%out)//'.tmp')
      write (error_unit, '(a)') message
      flush (error_unit)
      flush (output_unit)
      call c_exit(1_c_int)
   end subroutine case_file_failed

   subroutine die(message, code)
      character(len=*), intent(in) :: message
      integer, intent(in) :: code
      write (error_unit, '(a)') message
      ! STOP, not ERROR STOP: gfortran prints a backtrace for ERROR STOP even when quiet.
      if (code == 2) then
         stop 2, quiet = .true.
      else
         stop 1, quiet = .true.
      end if
   end subroutine die

end program capsim
