!> Numbers read from text strictly: the whole token must be the number. List-directed READ
!> stops at a blank, comma or slash and accepts NaN and Infinity, so "0.05 junk", "0.05,7" and
!> "0.05/" read as 0.05; here they are refused, as is every non-finite value.
module text_parse
   use capsim_kinds, only: dp
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
   implicit none
   private
   public :: parse_real, parse_int

contains

   !> A decimal real: [sign] digits [. [digits]] or [sign] . digits, then optionally an exponent
   !> e|E|d|D [sign] digits; blanks only before and after. `ok` is false for anything else, for
   !> NaN and Infinity, and for a value that overflows.
   subroutine parse_real(text, x, ok)
      character(len=*), intent(in) :: text
      real(dp), intent(out) :: x
      logical, intent(out) :: ok
      character(len=:), allocatable :: s
      integer :: i, n, mantissa_digits, ios
      x = 0
      ok = .false.
      s = trim(adjustl(text))
      n = len(s)
      if (n == 0) return
      i = 1
      if (s(i:i) == '+' .or. s(i:i) == '-') i = i + 1
      mantissa_digits = count_digits(s, i)
      if (i <= n) then
         if (s(i:i) == '.') then
            i = i + 1
            mantissa_digits = mantissa_digits + count_digits(s, i)
         end if
      end if
      if (mantissa_digits == 0) return
      if (i <= n) then
         if (index('eEdD', s(i:i)) == 0) return
         i = i + 1
         if (i <= n) then
            if (s(i:i) == '+' .or. s(i:i) == '-') i = i + 1
         end if
         if (count_digits(s, i) == 0) return
      end if
      if (i <= n) return
      read (s, *, iostat=ios) x
      ok = ios == 0 .and. ieee_is_finite(x)
   end subroutine parse_real

   !> A decimal integer: [sign] digits, blanks only before and after, within the default kind.
   subroutine parse_int(text, k, ok)
      character(len=*), intent(in) :: text
      integer, intent(out) :: k
      logical, intent(out) :: ok
      character(len=:), allocatable :: s
      integer :: i, ios
      k = 0
      ok = .false.
      s = trim(adjustl(text))
      if (len(s) == 0) return
      i = 1
      if (s(1:1) == '+' .or. s(1:1) == '-') i = 2
      if (count_digits(s, i) == 0 .or. i <= len(s)) return
      read (s, *, iostat=ios) k
      ok = ios == 0
   end subroutine parse_int

   !> Number of decimal digits from s(i:) on; advances i past them.
   integer function count_digits(s, i) result(n)
      character(len=*), intent(in) :: s
      integer, intent(inout) :: i
      n = 0
      do while (i <= len(s))
         if (index('0123456789', s(i:i)) == 0) exit
         i = i + 1
         n = n + 1
      end do
   end function count_digits

end module text_parse
