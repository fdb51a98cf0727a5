!> capsim: one capsule in Stokes flow (BIM-FEM), from the command line to an HDF5 case file.
!> This is the program's edge: errors from the modules become one line on stderr and exit 2.
program capsim
   use, intrinsic :: iso_fortran_env, only: error_unit
   use omp_lib, only: omp_set_num_threads, omp_get_max_threads
   use capsim_kinds, only: dp
   use run_options, only: run_options_t, parse_command_line, usage_text
   use case_output, only: case_summary_t, write_case_file
   use capsule_dynamics, only: capsule_t
   use surface_diagnostics, only: shape_measures_t, shape_measures, shear_plane_contour
   implicit none

   type(run_options_t) :: opts
   type(capsule_t) :: capsule
   type(case_summary_t) :: summary
   type(shape_measures_t) :: final_shape
   character(len=:), allocatable :: errmsg, checkpoint_path
   real(dp), allocatable :: profile_y(:), profile_z(:)
   integer :: stat, steady_index, unit, ios
   integer(8) :: clock_start, clock_end, clock_rate

   call parse_command_line(opts, stat, errmsg)
   if (opts%show_help) then
      write (*, '(a)') usage_text
      stop
   end if
   if (stat /= 0) call die('capsim: error: '//errmsg, 2)
   if (opts%threads > 0) call omp_set_num_threads(opts%threads)
   call system_clock(clock_start, clock_rate)

   call capsule%init(opts, stat, errmsg)
   if (stat /= 0) call die('capsim: error: '//errmsg, 2)
   if (.not. opts%quiet) then
      write (*, '(a,i0,a,i0,a,es9.2,a,i0,a)') 'capsim: ', capsule%mesh%n_nodes, ' nodes, ', capsule%mesh%n_tri, &
         ' triangles, dt = ', capsule%dt, ', ', omp_get_max_threads(), ' threads'
   end if
   checkpoint_path = trim(opts%out)//'.ckpt'
   call capsule%run(opts, checkpoint_path, summary, steady_index)
   call system_clock(clock_end)
   summary%wall_time_s = real(clock_end - clock_start, dp) / clock_rate
   summary%threads = omp_get_max_threads()

   call shape_measures(capsule%mesh, capsule%x, final_shape)
   call shear_plane_contour(capsule%mesh, capsule%x, final_shape%centroid, profile_y, profile_z)
   if (steady_index > 0) then
      call write_case_file(opts, capsule%law, summary, capsule%mesh, capsule%x_ref, capsule%x, &
                           capsule%history(:, 1:capsule%n_rec), profile_y, profile_z, &
                           capsule%history(:, steady_index), stat=stat, errmsg=errmsg)
   else
      call write_case_file(opts, capsule%law, summary, capsule%mesh, capsule%x_ref, capsule%x, &
                           capsule%history(:, 1:capsule%n_rec), profile_y, profile_z, stat=stat, errmsg=errmsg)
   end if
   if (stat /= 0) call die('capsim: error: writing the case file: '//errmsg, 1)
   ! The case file is complete: the checkpoint has served its purpose.
   open (newunit=unit, file=checkpoint_path, status='old', iostat=ios)
   if (ios == 0) close (unit, status='delete')
   if (.not. opts%quiet) then
      write (*, '(a)') 'capsim: '//trim(summary%status)//': '//summary%message
      write (*, '(a,f0.2,a)') 'capsim: wrote '//trim(opts%out)//' (', summary%wall_time_s, ' s)'
   end if

contains

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
