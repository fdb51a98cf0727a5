!> Numbers as text for messages (errors, progress): one place for the formats, so that every
!> module's messages print values alike.
module text_format
   use capsim_kinds, only: dp
   implicit none
   private
   public :: real_text, int_text

contains

   !> A real with 6 significant digits, no padding.
   function real_text(x) result(s)
      real(dp), intent(in) :: x
      character(len=:), allocatable :: s
      character(len=32) :: buf
      write (buf, '(g0.6)') x
      s = trim(adjustl(buf))
   end function real_text

   !> An integer, no padding.
   pure function int_text(i) result(s)
      integer, intent(in) :: i
      character(len=:), allocatable :: s
      character(len=16) :: buf
      write (buf, '(i0)') i
      s = trim(buf)
   end function int_text

end module text_format
