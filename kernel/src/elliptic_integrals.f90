!> Complete elliptic integrals of the first and second kind, parameter m = k**2:
!>   K(m) = integral_0^{pi/2} dt / sqrt(1 - m sin(t)**2),   E(m) = integral_0^{pi/2} sqrt(1 - m sin(t)**2) dt,
!> and the two combinations that the ring Stokeslet needs without cancellation,
!>   B(m) = (E - (1 - m) K) / m = integral cos(t)**2 / sqrt(1 - m sin(t)**2) dt  (= K - D),
!>   D(m) = (K - E) / m         = integral sin(t)**2 / sqrt(1 - m sin(t)**2) dt,
!> (B(0) = D(0) = pi/4, where the quotients themselves would be 0/0).
!>
!> Near m = 1 the argument m1 = 1 - m should be passed directly (the *_m1 forms): for a ring
!> source close to the target, m1 = rho**2/R**2 is known accurately while 1 - m is not.
!>
!> Fast path (elliptic_kebd_m1, used by the ring kernels): B and D in Cody's form,
!>   D = P_D(m1) + ln(m1) Q_D(m1),   B = P_B(m1) + ln(m1) m1 Q_B(m1),
!> polynomials of degree 10 (scripts/fit_elliptic_coefficients.py: a least-squares fit of the
!> relative error in 90-digit arithmetic; fit error 7e-17 for D, 3e-17 for B, over m1 in (0, 1]).
!> The logarithm carries the singularity at m -> 1 exactly, and the constant terms are the exact
!> limits (D = ln 4 - 1 - ln(m1)/2 + ..., B = 1 + m1 ln(m1)/4 + ...), so the relative error stays
!> at a few ulps for every m1 down to the underflow. Then K = B + D and E = B + m1 D add positive
!> numbers: no digit is lost anywhere, and no branch depends on m. Why not the AGM: it costs
!> 3 to 11 dependent square roots and divisions, and was 44 % of a tube case's instructions;
!> this form is one logarithm and four independent Horner chains (bench/bench_elliptic.py and
!> docs/validation/performance.md give the measured ratio).
!>
!> Reference (elliptic_kebd_agm_m1): Bulirsch's "cel" (Numer. Math. 7, 1965; 13, 1969), i.e.
!> the arithmetic-geometric mean of 1 and kc = sqrt(1 - m) carried along with two linear sums.
!> For p = 1 and non-negative (a, b) every operation adds positive numbers, so K, E, B and D all
!> come out to a few ulps for every m1 > 0, including m1 > 1 (m < 0). It converges
!> quadratically: 3 steps at m = 0.1, 6 at 1 - m = 1e-8, 11 at 1 - m = 1e-300. The kernel probe
!> checks the fast path against it (tests/kernel/test_ring_kernel.py: 1e-14, measured 1.1e-15,
!> the sum of both rounding errors).
module elliptic_integrals
   use capsim_kinds, only: dp, pi
   implicit none
   private
   public :: elliptic_k, elliptic_e, elliptic_k_m1, elliptic_e_m1, elliptic_kebd_m1, elliptic_kebd_agm_m1

   ! Coefficients in ascending powers of m1 (scripts/fit_elliptic_coefficients.py).
   real(dp), parameter :: d_p(0:10) = [ &
      3.862943611198906188345e-1_dp, 3.97207708867036245448e-2_dp, 1.380078723083256002986e-2_dp, &
      6.919012405531580583289e-3_dp, 4.702745190378717667032e-3_dp, 1.180751201712430403188e-2_dp, &
      5.567316553305520592225e-2_dp, 1.255878282525316464845e-1_dp, 1.086465319113301912253e-1_dp, &
      3.047226732068659592174e-2_dp, 1.77318152938325116028e-3_dp]
   real(dp), parameter :: d_q(0:10) = [ &
      -5.0e-1_dp, -3.749999999948907189305e-1_dp, -3.515624898724729070325e-1_dp, &
      -3.41794345135451330367e-1_dp, -3.362959072754074810444e-1_dp, -3.29609362709040558384e-1_dp, &
      -3.002261672676226775494e-1_dp, -2.07599007138012808224e-1_dp, -8.023091720953604103028e-2_dp, &
      -1.206736978544819231327e-2_dp, -3.749357349739299120617e-4_dp]
   real(dp), parameter :: b_p(0:10) = [ &
      1.0_dp, 5.685281943972779898336e-2_dp, 1.708441700942199751102e-2_dp, &
      8.028818352985118915774e-3_dp, 4.497344374267148861565e-3_dp, -2.78427248501760411272e-4_dp, &
      -2.605382478826330213498e-2_dp, -9.263593932256288094038e-2_dp, -1.210586880963710889294e-1_dp, &
      -5.482081989844676784664e-2_dp, -6.217536424807960335962e-3_dp]
   real(dp), parameter :: b_q(0:10) = [ &
      2.5e-1_dp, 2.812499993436907005279e-1_dp, 2.929684065980376702058e-1_dp, &
      2.990371660045378460339e-1_dp, 3.016963954242155618365e-1_dp, 2.91730776036609085255e-1_dp, &
      2.345199192753340400127e-1_dp, 1.190874194804805999636e-1_dp, 2.706171015705057088523e-2_dp, &
      1.585934574996390961326e-3_dp, -1.107499913478992680656e-5_dp]

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

   !> K, E, B = (E - m1 K)/m and D = (K - E)/m from m1 = 1 - m in (0, 1] (Cody's form, above).
   !> m1 <= 0 (m >= 1, where K is infinite) is clamped to tiny(1.0_dp): K is then about 355,
   !> large but finite, so that a caller evaluating at a coincident point gets no NaN or Inf.
   !> m1 > 1 (negative m) is outside the fit: use elliptic_kebd_agm_m1 there.
   elemental subroutine elliptic_kebd_m1(m1, k, e, b, d)
      real(dp), intent(in) :: m1
      real(dp), intent(out) :: k, e, b, d
      real(dp) :: x, log_x
      x = max(m1, tiny(1.0_dp))
      log_x = log(x)
      d = horner(d_p, x) + log_x * horner(d_q, x)
      b = horner(b_p, x) + log_x * x * horner(b_q, x)
      k = b + d
      e = b + x * d
   end subroutine elliptic_kebd_m1

   !> sum_i c(i) x**i.
   pure function horner(c, x) result(s)
      real(dp), intent(in) :: c(0:), x
      real(dp) :: s
      integer :: i
      s = c(ubound(c, 1))
      do i = ubound(c, 1) - 1, 0, -1
         s = s * x + c(i)
      end do
   end function horner

   !> K, E, B, D by Bulirsch's AGM (the reference, see the header), from m1 = 1 - m, any m1 > 0;
   !> m1 <= 0 is clamped to tiny(1.0_dp) as in elliptic_kebd_m1.
   elemental subroutine elliptic_kebd_agm_m1(m1, k, e, b, d)
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
   end subroutine elliptic_kebd_agm_m1

end module elliptic_integrals
