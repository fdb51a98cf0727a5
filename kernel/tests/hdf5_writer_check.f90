!> Writes a small case-like file through hdf5_writer so that tests/kernel/test_hdf5_writer.py
!> can pin, from the Python side, the layout the kernel relies on (attribute types, the
!> Fortran (3,n) -> h5py (n,3) convention, scalar datasets, units, gzip on large datasets).
!>
!> Usage: hdf5_writer_check OUTPUT.h5
program hdf5_writer_check
   use, intrinsic :: iso_fortran_env, only: error_unit, output_unit
   use capsim_kinds, only: dp, schema_version
   use hdf5_writer, only: h5_file_t
   implicit none

   type(h5_file_t) :: f
   integer :: stat, i, j, k, path_len
   character(len=:), allocatable :: errmsg, out_path
   real(dp) :: nodes(3, 5)
   real(dp) :: t(100)
   integer :: triangles(3, 2)

   if (command_argument_count() /= 1) then
      write (error_unit, '(a)') 'usage: hdf5_writer_check OUTPUT.h5'
      error stop 2
   end if
   call get_command_argument(1, length=path_len)
   allocate (character(len=path_len) :: out_path)
   call get_command_argument(1, out_path)

   do j = 1, size(nodes, 2)
      do i = 1, size(nodes, 1)
         nodes(i, j) = real(10*j + i, dp)
      end do
   end do
   triangles = reshape([0, 1, 2, 2, 3, 4], [3, 2])
   t = [(0.1_dp*k, k=1, size(t))]

   call f%create(out_path, stat, errmsg)
   call check('create')
   call f%write_attr('/', 'schema_version', schema_version, stat, errmsg)
   call check('schema_version')
   call f%write_attr('/', 'flow', 'shear', stat, errmsg)
   call check('flow')
   call f%write_attr('/', 'Ca_s', 0.05_dp, stat, errmsg)
   call check('Ca_s')

   call f%make_group('/mesh', stat, errmsg)
   call check('/mesh')
   call f%write_dataset('/mesh/nodes', nodes, 'a', stat, errmsg)
   call check('/mesh/nodes')
   call f%write_dataset('/mesh/triangles', triangles, '1', stat, errmsg)
   call check('/mesh/triangles')

   call f%make_group('/steady', stat, errmsg)
   call check('/steady')
   call f%write_dataset('/steady/D12', 0.25_dp, '1', stat, errmsg)
   call check('/steady/D12')

   call f%make_group('/history', stat, errmsg)
   call check('/history')
   call f%write_dataset('/history/t', t, '1/gamma_dot', stat, errmsg)
   call check('/history/t')

   ! The parent group does not exist: the writer must report it, not abort or print.
   call f%write_dataset('/nosuch/x', t, '1', stat, errmsg)
   if (stat /= 0 .and. len(errmsg) > 0 .and. index(errmsg, '/nosuch/x') > 0) then
      write (output_unit, '(a)') 'error_path_ok 1'
   else
      write (error_unit, '(a,i0,3a)') 'error path not reported: stat=', stat, ', errmsg="', errmsg, '"'
      error stop 1
   end if

   call f%close(stat, errmsg)
   call check('close')
   write (output_unit, '(a)') 'ok'

contains

   subroutine check(step)
      character(len=*), intent(in) :: step
      if (stat /= 0) then
         write (error_unit, '(a)') 'hdf5_writer_check: ' // step // ': ' // errmsg
         error stop 1
      end if
   end subroutine check

end program hdf5_writer_check
