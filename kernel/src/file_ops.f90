!> File-system operations the Fortran standard lacks.
module file_ops
   use, intrinsic :: iso_c_binding, only: c_char, c_int, c_null_char, c_int16_t, c_int32_t, c_int8_t
   implicit none
   private
   public :: replace_file, path_kind, path_absent, path_regular, path_directory, path_other, folder_of, &
             folder_writable, delete_file, keep_aside

   !> What a path names (path_kind): nothing, a regular file, a directory, or anything else (a
   !> device, FIFO or socket, which must not be replaced by a regular file).
   integer, parameter :: path_absent = 0, path_regular = 1, path_directory = 2, path_other = 3

   interface
      integer(c_int) function c_rename(old, new) bind(c, name='rename')
         import :: c_char, c_int
         character(kind=c_char), intent(in) :: old(*), new(*)
      end function c_rename
      integer(c_int) function c_access(path, mode) bind(c, name='access')
         import :: c_char, c_int
         character(kind=c_char), intent(in) :: path(*)
         integer(c_int), value :: mode
      end function c_access
      !> Linux statx(2): its struct statx has the same layout on every architecture (256
      !> bytes; the file mode is the 16-bit field at byte offset 28), unlike struct stat.
      integer(c_int) function c_statx(dirfd, path, flags, mask, buf) bind(c, name='statx')
         import :: c_char, c_int, c_int8_t
         integer(c_int), value :: dirfd, flags, mask
         character(kind=c_char), intent(in) :: path(*)
         integer(c_int8_t), intent(out) :: buf(256)
      end function c_statx
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

   !> Renames the file at `path` to the first free `path.SUFFIX`, `path.SUFFIX-2`, ... (up to 99)
   !> and returns that name; '' when none was free or the rename failed (the file is left).
   function keep_aside(path, suffix) result(kept)
      character(len=*), intent(in) :: path, suffix
      character(len=:), allocatable :: kept, errmsg
      character(len=8) :: number
      integer :: n, stat
      do n = 1, 99
         number = ''
         if (n > 1) write (number, '(a,i0)') '-', n
         kept = path//'.'//suffix//trim(number)
         if (path_kind(kept) /= path_absent) cycle
         call replace_file(path, kept, stat, errmsg)
         if (stat == 0) return
         exit
      end do
      kept = ''
   end function keep_aside

   !> path_absent, path_regular, path_directory or path_other for what `path` names (links
   !> followed); a path that cannot be examined (a missing folder on the way) is absent.
   integer function path_kind(path)
      character(len=*), intent(in) :: path
      integer(c_int), parameter :: at_fdcwd = -100, statx_type = 1
      integer(c_int8_t) :: buf(256)
      integer(c_int16_t) :: mode
      integer(c_int32_t) :: file_type
      path_kind = path_absent
      if (len(path) == 0) return
      buf = 0
      if (c_statx(at_fdcwd, path//c_null_char, 0_c_int, statx_type, buf) /= 0) return
      mode = transfer(buf(29:30), mode)
      file_type = iand(int(mode, c_int32_t), int(o'170000', c_int32_t))
      if (file_type == int(o'100000', c_int32_t)) then
         path_kind = path_regular
      else if (file_type == int(o'040000', c_int32_t)) then
         path_kind = path_directory
      else
         path_kind = path_other
      end if
   end function path_kind

   !> The folder part of a path ('.' for a bare name, '/' for a name in the root).
   function folder_of(path) result(folder)
      character(len=*), intent(in) :: path
      character(len=:), allocatable :: folder
      integer :: slash
      slash = index(path, '/', back=.true.)
      if (slash == 0) then
         folder = '.'
      else if (slash == 1) then
         folder = '/'
      else
         folder = path(:slash - 1)
      end if
   end function folder_of

   !> True if this process may create files in `folder` (POSIX access W_OK | X_OK).
   logical function folder_writable(folder)
      character(len=*), intent(in) :: folder
      integer(c_int), parameter :: w_ok = 2, x_ok = 1
      folder_writable = c_access(folder//c_null_char, ior(w_ok, x_ok)) == 0
   end function folder_writable

   !> Removes a regular file if there is one; quiet otherwise.
   subroutine delete_file(path)
      character(len=*), intent(in) :: path
      integer :: unit, ios
      if (path_kind(path) /= path_regular) return
      open (newunit=unit, file=path, status='old', iostat=ios)
      if (ios == 0) close (unit, status='delete', iostat=ios)
   end subroutine delete_file

end module file_ops
