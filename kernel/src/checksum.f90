!> CRC-32 (the IEEE 802.3 / zlib polynomial, reflected, 0xEDB88320) over the bytes of values
!> as they are written to an unformatted stream file, so that a checkpoint's checksum can be
!> computed while writing and checked by reading the file's bytes back (Python: zlib.crc32).
!> It detects every single-bit flip and every burst of up to 32 bits. The arithmetic stays
!> within 0..2**32-1 in 64-bit integers: no overflow.
module checksum
   use, intrinsic :: iso_fortran_env, only: int8, int32, int64
   use capsim_kinds, only: dp
   implicit none
   private
   public :: crc32_t

   type :: crc32_t
      integer(int64) :: state = int(z'FFFFFFFF', int64)
      integer(int64) :: table(0:255) = 0
      logical :: ready = .false.
   contains
      procedure :: add_bytes, add_int, add_real, add_reals, add_text
      procedure :: value => crc_value
   end type crc32_t

contains

   subroutine add_bytes(self, bytes)
      class(crc32_t), intent(inout) :: self
      integer(int8), intent(in) :: bytes(:)
      integer(int64), parameter :: low_byte = 255_int64
      integer :: k
      if (.not. self%ready) call make_table(self)
      do k = 1, size(bytes)
         self%state = ieor(self%table(iand(ieor(self%state, int(bytes(k), int64)), low_byte)), shiftr(self%state, 8))
      end do
   end subroutine add_bytes

   subroutine add_int(self, i)
      class(crc32_t), intent(inout) :: self
      integer, intent(in) :: i
      call self%add_bytes(transfer(i, [0_int8]))
   end subroutine add_int

   subroutine add_real(self, x)
      class(crc32_t), intent(inout) :: self
      real(dp), intent(in) :: x
      call self%add_bytes(transfer(x, [0_int8]))
   end subroutine add_real

   !> The elements of `x` in order (a contiguous array, as a stream write lays them out).
   subroutine add_reals(self, x)
      class(crc32_t), intent(inout) :: self
      real(dp), intent(in) :: x(:)
      integer :: k
      do k = 1, size(x)
         call self%add_bytes(transfer(x(k), [0_int8]))
      end do
   end subroutine add_reals

   subroutine add_text(self, s)
      class(crc32_t), intent(inout) :: self
      character(len=*), intent(in) :: s
      integer :: k
      do k = 1, len(s)
         call self%add_bytes([int(ichar(s(k:k)), int8)])
      end do
   end subroutine add_text

   !> The CRC-32 of everything added, as a 32-bit integer (its bit pattern).
   integer(int32) function crc_value(self)
      class(crc32_t), intent(in) :: self
      integer(int64) :: v
      v = ieor(self%state, int(z'FFFFFFFF', int64))
      if (v >= 2_int64**31) v = v - 2_int64**32
      crc_value = int(v, int32)
   end function crc_value

   subroutine make_table(self)
      class(crc32_t), intent(inout) :: self
      integer(int64), parameter :: poly = int(z'EDB88320', int64)
      integer(int64) :: c
      integer :: n, k
      do n = 0, 255
         c = n
         do k = 1, 8
            if (iand(c, 1_int64) /= 0) then
               c = ieor(poly, shiftr(c, 1))
            else
               c = shiftr(c, 1)
            end if
         end do
         self%table(n) = c
      end do
      self%ready = .true.
   end subroutine make_table

end module checksum
