!> Positional command-line arguments of the probe programs (kernel/tests), read by number.
!> The probes are test drivers: a malformed argument is a bug in the calling test, so it
!> stops the program with a message rather than returning an error.
module command_args
   use capsim_kinds, only: dp
   implicit none
   private
   public :: int_arg, real_arg, string_arg

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

end module command_args
