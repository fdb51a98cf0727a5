!> Undisturbed flows v_inf, non-dimensional.
!>   shear: v_inf = y e_z (shear plane yz, vorticity along x), lengths in a, velocity in gamma_dot a.
module background_flow
   use capsim_kinds, only: dp
   implicit none
   private
   public :: flow_shear, flow_tube, undisturbed_velocity

   integer, parameter :: flow_shear = 1, flow_tube = 2

contains

   pure subroutine undisturbed_velocity(flow, x, v)
      integer, intent(in) :: flow
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: v(:, :)
      select case (flow)
      case (flow_shear)
         v(1, :) = 0.0_dp
         v(2, :) = 0.0_dp
         v(3, :) = x(2, :)
      case default
         v = 0.0_dp
      end select
   end subroutine undisturbed_velocity

end module background_flow
