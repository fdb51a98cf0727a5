!> Complete elliptic integrals of the first and second kind, parameter m = k**2:
!>   K(m) = integral_0^{pi/2} dt / sqrt(1 - m sin(t)**2),   E(m) = integral_0^{pi/2} sqrt(1 - m sin(t)**2) dt,
!> and the two combinations that the ring Stokeslet needs without cancellation,
!>   B(m) = (E - (1 - m) K) / m = integral cos(t)**2 / sqrt(1 - m sin(t)**2) dt  (= K - D),
!>   D(m) = (K - E) / m         = integral sin(t)**2 / sqrt(1 - m sin(t)**2) dt,
!> (B(0) = D(0) = pi/4, where the quotients themselves would be 0/0).
!>
!> Algorithm: Bulirsch's "cel" (Numer. Math. 7, 1965; 13, 1969), i.e. the arithmetic-geometric
!> mean of 1 and kc = sqrt(1 - m) carried along with two linear sums. For p = 1 and
!> non-negative (a, b) every operation adds positive numbers, so K, E, B and D all come out to
!> a few ulps for every m in [0, 1), including m -> 1 where K ~ ln(4/kc) and a formula such as
!> E = K - m D would lose log10(K) digits. The iteration converges quadratically: 3 steps at
!> m = 0.1, 6 at 1 - m = 1e-8, 11 at 1 - m = 1e-300.
!>
!> Near m = 1 the argument m1 = 1 - m should be passed directly (the *_m1 forms): for a ring
!> source close to the target, m1 = rho**2/R**2 is known accurately while 1 - m is not.
module elliptic_integrals
   use capsim_kinds, only: dp, pi
   implicit none
   private
   public :: elliptic_k, elliptic_e, elliptic_k_m1, elliptic_e_m1, elliptic_kebd_m1

contains

   !> K(m), m in [0, 1).
   elemental function elliptic_k(m) result(k)
      real(dp), intent(in) :: m
      real(dp) :: k
      k = elliptic_k_m1(1.0_dp - m)
   end function elliptic_k

   !> E(m), m in [0, 1].
   elemental function elliptic_e(m) result(e)
      real(dp), intent(in) :: m
      real(dp) :: e
      e = elliptic_e_m1(1.0_dp - m)
   end function elliptic_e

   !> K as a function of the complementary parameter m1 = 1 - m, m1 in (0, 1].
   elemental function elliptic_k_m1(m1) result(k)
      real(dp), intent(in) :: m1
      real(dp) :: k, e, b, d
      call elliptic_kebd_m1(m1, k, e, b, d)
   end function elliptic_k_m1

   !> E as a function of the complementary parameter m1 = 1 - m, m1 in [0, 1].
   elemental function elliptic_e_m1(m1) result(e)
      real(dp), intent(in) :: m1
      real(dp) :: k, e, b, d
      if (m1 <= 0.0_dp) then
         e = 1.0_dp
         return
      end if
      call elliptic_kebd_m1(m1, k, e, b, d)
   end function elliptic_e_m1

   !> K, E, B = (E - m1 K)/m and D = (K - E)/m in one AGM pass, from m1 = 1 - m.
   !> m1 <= 0 (m >= 1, where K is infinite) is clamped to tiny(1.0_dp): K is then about 356,
   !> large but finite, so that a caller evaluating at a coincident point gets no NaN or Inf.
   !> m1 > 1 (negative m) is also valid (Bulirsch's algorithm accepts any kc > 0).
   elemental subroutine elliptic_kebd_m1(m1, k, e, b, d)
      real(dp), intent(in) :: m1
      real(dp), intent(out) :: k, e, b, d
      ! Relative stopping tolerance on the AGM gap: the error after the last step is its square.
      real(dp), parameter :: ca = 1.5e-8_dp
      integer, parameter :: max_iter = 64
      real(dp) :: kc, qc, ee, em, p, g
      real(dp) :: sa(4), sb(4), f(4)
      integer :: it

      kc = sqrt(max(m1, tiny(1.0_dp)))
      ! cel(kc, 1, a, b) for (a, b) = (1, 1) -> K, (1, kc**2) -> E, (1, 0) -> B, (0, 1) -> D.
      ! The AGM sequence (qc, em, p) does not depend on (a, b): carry the four sums together.
      sa = [1.0_dp, 1.0_dp, 1.0_dp, 0.0_dp]
      sb = [1.0_dp, kc * kc, 0.0_dp, 1.0_dp]
      qc = kc
      ee = kc
      em = 1.0_dp
      p = 1.0_dp
      do it = 1, max_iter
         f = sa
         g = 1.0_dp / p
         sa = sa + sb * g
         g = ee * g
         sb = 2.0_dp * (sb + f * g)
         p = g + p
         g = em
         em = qc + em
         if (abs(g - qc) <= g * ca) exit
         qc = 2.0_dp * sqrt(ee)
         ee = qc * em
      end do
      f = 0.5_dp * pi * (sb + sa * em) / (em * (em + p))
      k = f(1)
      e = f(2)
      b = f(3)
      d = f(4)
   end subroutine elliptic_kebd_m1

end module elliptic_integrals
