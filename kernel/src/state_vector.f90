!> A model's checkpoint state as one vector of reals (case_output writes it whole, under its
!> checksum). A cursor walks the vector in one direction, storing the model's values into it,
!> restoring them from it, or only counting them, so that one list of the state's parts (the
!> model's exchange_state) serves all three and cannot fall out of step. Integers and flags
!> are stored as reals, exactly (|i| < 2**53).
module state_vector
   use capsim_kinds, only: dp
   implicit none
   private
   public :: state_cursor_t, state_counting, state_storing, state_restoring

   integer, parameter :: state_counting = 0, state_storing = 1, state_restoring = 2

   type :: state_cursor_t
      !> state_counting, state_storing or state_restoring.
      integer :: mode = state_counting
      !> Entries of the vector passed so far.
      integer :: at = 0
   contains
      procedure :: reals
      procedure :: real_value
      procedure :: int_value
      procedure :: flag
      procedure :: restoring
   end type state_cursor_t

contains

   !> n contiguous values (an array of any rank, by sequence association: no copy is made).
   subroutine reals(self, state, values, n)
      class(state_cursor_t), intent(inout) :: self
      real(dp), intent(inout) :: state(:)
      integer, intent(in) :: n
      real(dp), intent(inout) :: values(n)
      select case (self%mode)
      case (state_storing)
         state(self%at + 1:self%at + n) = values
      case (state_restoring)
         values = state(self%at + 1:self%at + n)
      end select
      self%at = self%at + n
   end subroutine reals

   subroutine real_value(self, state, value)
      class(state_cursor_t), intent(inout) :: self
      real(dp), intent(inout) :: state(:)
      real(dp), intent(inout) :: value
      select case (self%mode)
      case (state_storing)
         state(self%at + 1) = value
      case (state_restoring)
         value = state(self%at + 1)
      end select
      self%at = self%at + 1
   end subroutine real_value

   subroutine int_value(self, state, value)
      class(state_cursor_t), intent(inout) :: self
      real(dp), intent(inout) :: state(:)
      integer, intent(inout) :: value
      select case (self%mode)
      case (state_storing)
         state(self%at + 1) = real(value, dp)
      case (state_restoring)
         value = nint(state(self%at + 1))
      end select
      self%at = self%at + 1
   end subroutine int_value

   subroutine flag(self, state, value)
      class(state_cursor_t), intent(inout) :: self
      real(dp), intent(inout) :: state(:)
      logical, intent(inout) :: value
      select case (self%mode)
      case (state_storing)
         state(self%at + 1) = merge(1.0_dp, 0.0_dp, value)
      case (state_restoring)
         value = state(self%at + 1) /= 0.0_dp
      end select
      self%at = self%at + 1
   end subroutine flag

   pure logical function restoring(self)
      class(state_cursor_t), intent(in) :: self
      restoring = self%mode == state_restoring
   end function restoring

end module state_vector
