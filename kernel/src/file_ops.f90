!> File-system operations the Fortran standard lacks.
module file_ops
   use, intrinsic :: iso_c_binding, only: c_char, c_int, c_null_char
   implicit none
   private
   public :: replace_file

   interface
      integer(c_int) function c_rename(old, new) bind(c, name='rename')
         import :: c_char, c_int
         character(kind=c_char), intent(in) :: old(*), new(*)
      end function c_rename
   end interface

contains

   !> Atomic replacement (POSIX rename): readers see the old file or the new one, never half.
   subroutine replace_file(from, to, stat, errmsg)
      character(len=*), intent(in) :: from, to
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      stat = 0
      errmsg = ''
      if (c_rename(from//c_null_char, to//c_null_char) /= 0) then
         stat = 1
         errmsg = 'cannot rename "'//from//'" to "'//to//'"'
      end if
   end subroutine replace_file

end module file_ops
