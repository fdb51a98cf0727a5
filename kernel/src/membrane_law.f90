!> Hyperelastic membrane laws w_s(I1, I2), per unit undeformed area, in units of G_s.
!>
!> I1 = lambda1**2 + lambda2**2 - 2, I2 = lambda1**2 * lambda2**2 - 1 (paper eqs 2.1, 2.4-2.6):
!>   GH(nu_s): 1/4 (2 I1 - 2 I2 + I1**2 / (1 - nu_s))       K_s/G_s = (1 + nu_s)/(1 - nu_s)
!>   NH:       1/2 (I1 - 1 + 1/(I2 + 1))                       K_s/G_s = 3
!>   SK(C):    1/4 (I1**2 + 2 I1 - 2 I2 + C I2**2)             K_s/G_s = 1 + 2 C
!> One derived type with a law tag rather than a class hierarchy: the derivatives are
!> evaluated inside the hottest membrane loop, where a select case on an integer keeps the
!> routines pure and inlinable.
module membrane_law
   use capsim_kinds, only: dp
   implicit none
   private
   public :: membrane_law_t, law_nh, law_sk, law_gh, make_membrane_law

   integer, parameter :: law_nh = 1, law_sk = 2, law_gh = 3

   type :: membrane_law_t
      integer :: id = law_nh
      real(dp) :: nu_s = 0.5_dp
      real(dp) :: c = 1.0_dp
   contains
      procedure :: energy
      procedure :: derivatives
      procedure :: tensions
      procedure :: dilation_modulus
      procedure :: name
   end type membrane_law_t

contains

   !> Law from its name ('NH', 'SK', 'GH'); nu_s is used by GH, C by SK.
   subroutine make_membrane_law(law_name, nu_s, c, law, stat, errmsg)
      character(len=*), intent(in) :: law_name
      real(dp), intent(in) :: nu_s, c
      type(membrane_law_t), intent(out) :: law
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      stat = 0
      select case (law_name)
      case ('NH')
         law%id = law_nh
      case ('SK')
         law%id = law_sk
      case ('GH')
         law%id = law_gh
      case default
         stat = 1
         errmsg = 'unknown membrane law "'//trim(law_name)//'" (expected NH, SK or GH)'
         return
      end select
      if (.not. (nu_s > -1.0_dp .and. nu_s < 1.0_dp)) then
         stat = 1
         errmsg = 'nu_s must lie in (-1, 1)'
         return
      end if
      if (.not. (c > -0.5_dp)) then
         stat = 1
         errmsg = 'C must be > -0.5 (K_s = (1 + 2C) G_s > 0)'
         return
      end if
      law%nu_s = nu_s
      law%c = c
   end subroutine make_membrane_law

   elemental real(dp) function energy(self, i1, i2)
      class(membrane_law_t), intent(in) :: self
      real(dp), intent(in) :: i1, i2
      select case (self%id)
      case (law_nh)
         energy = 0.5_dp * (i1 - 1.0_dp + 1.0_dp / (i2 + 1.0_dp))
      case (law_sk)
         energy = 0.25_dp * (i1**2 + 2.0_dp * i1 - 2.0_dp * i2 + self%c * i2**2)
      case default
         energy = 0.25_dp * (2.0_dp * i1 - 2.0_dp * i2 + i1**2 / (1.0_dp - self%nu_s))
      end select
   end function energy

   !> dw/dI1 and dw/dI2.
   elemental subroutine derivatives(self, i1, i2, w1, w2)
      class(membrane_law_t), intent(in) :: self
      real(dp), intent(in) :: i1, i2
      real(dp), intent(out) :: w1, w2
      select case (self%id)
      case (law_nh)
         w1 = 0.5_dp
         w2 = -0.5_dp / (i2 + 1.0_dp)**2
      case (law_sk)
         w1 = 0.5_dp * (i1 + 1.0_dp)
         w2 = 0.5_dp * (self%c * i2 - 1.0_dp)
      case default
         w1 = 0.5_dp * (1.0_dp + i1 / (1.0_dp - self%nu_s))
         w2 = -0.5_dp
      end select
   end subroutine derivatives

   !> Principal Cauchy tensions T_k = (1/(lambda1 lambda2)) lambda_k dw/dlambda_k [G_s].
   elemental subroutine tensions(self, lambda1, lambda2, t1, t2)
      class(membrane_law_t), intent(in) :: self
      real(dp), intent(in) :: lambda1, lambda2
      real(dp), intent(out) :: t1, t2
      real(dp) :: w1, w2
      call self%derivatives(lambda1**2 + lambda2**2 - 2.0_dp, (lambda1 * lambda2)**2 - 1.0_dp, w1, w2)
      t1 = 2.0_dp * lambda1 / lambda2 * (w1 + w2 * lambda2**2)
      t2 = 2.0_dp * lambda2 / lambda1 * (w1 + w2 * lambda1**2)
   end subroutine tensions

   !> Area dilation modulus K_s/G_s.
   elemental real(dp) function dilation_modulus(self)
      class(membrane_law_t), intent(in) :: self
      select case (self%id)
      case (law_nh)
         dilation_modulus = 3.0_dp
      case (law_sk)
         dilation_modulus = 1.0_dp + 2.0_dp * self%c
      case default
         dilation_modulus = (1.0_dp + self%nu_s) / (1.0_dp - self%nu_s)
      end select
   end function dilation_modulus

   pure function name(self) result(label)
      class(membrane_law_t), intent(in) :: self
      character(len=:), allocatable :: label
      select case (self%id)
      case (law_nh)
         label = 'NH'
      case (law_sk)
         label = 'SK'
      case default
         label = 'GH'
      end select
   end function name

end module membrane_law
