!> Positional command-line arguments of the probe programs (kernel/tests), read by number,
!> and their output: one "key value" line per measured quantity. The probes are test drivers: a malformed argument is a bug in the calling test, so it
!> stops the program with a message rather than returning an error.
module command_args
   use capsim_kinds, only: dp
   implicit none
   private
   public :: int_arg, real_arg, string_arg, put, put_int

contains

   integer function int_arg(k)
      integer, intent(in) :: k
      character(len=:), allocatable :: text
      integer :: ios
      text = string_arg(k)
      read (text, *, iostat=ios) int_arg
      if (ios /= 0) error stop 'probe: an argument is not an integer'
   end function int_arg

   real(dp) function real_arg(k)
      integer, intent(in) :: k
      character(len=:), allocatable :: text
      integer :: ios
      text = string_arg(k)
      read (text, *, iostat=ios) real_arg
      if (ios /= 0) error stop 'probe: an argument is not a number'
   end function real_arg

   function string_arg(k) result(s)
      integer, intent(in) :: k
      character(len=:), allocatable :: s
      character(len=1024) :: buffer
      call get_command_argument(k, buffer)
      s = trim(buffer)
   end function string_arg

   !> One "key value" output line, full precision.
   subroutine put(key, value)
      character(len=*), intent(in) :: key
      real(dp), intent(in) :: value
      write (*, '(a,1x,es24.16)') key, value
   end subroutine put

   subroutine put_int(key, value)
      character(len=*), intent(in) :: key
      integer, intent(in) :: value
      write (*, '(a,1x,i0)') key, value
   end subroutine put_int

end module command_args
