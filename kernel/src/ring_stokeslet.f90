!> Axisymmetric single layer: the ring Stokeslet and its integral over a straight meridian
!> segment, for the axisymmetric (centred tube) fast path.
!>
!> Normalisation (as in stokes_single_layer): J(r) = I/|r| + r r^T/|r|**3, and
!> u(x) = 1/(8 pi mu) integral_S J(x - y) . f(y) dS(y). Cylindrical (r, z), azimuth phi. For a
!> target x0 = (r0, 0, z0) (at phi = 0) and a source ring (r, z) with force density
!> f = f_r e_r(phi) + f_z e_z,
!>    M_ab(r0, z0; r, z) = integral_0^{2 pi} e_a(0) . J(x0 - y(phi)) . e_b(phi) dphi,  a, b in {r, z},
!> index 1 = r, 2 = z, so that  u_a(x0) = 1/(8 pi mu) integral_meridian M_ab f_b r ds
!> (the ring's r from dS = r dphi ds stays outside M).
!>
!> Closed form (derived here; checked against the phi quadrature of J to ~1e-15 in
!> tests/kernel/test_ring_kernel.py). With Z = z0 - z, rho**2 = (r0 - r)**2 + Z**2,
!> R**2 = (r0 + r)**2 + Z**2, m = 4 r0 r / R**2 and m1 = 1 - m = rho**2 / R**2, the change
!> phi = pi - 2t gives |x0 - y|**2 = R**2 (1 - m sin(t)**2) and cos(phi) = 2 sin(t)**2 - 1; every
!> entry is then a sum of integral_0^{pi/2} sin(t)**(2j) / Delta**(1 or 3) dt, Delta**2 = 1 - m sin**2,
!> which m sin**2 = 1 - Delta**2 reduces to K, E, B = (E - m1 K)/m and D = (K - E)/m:
!>    M_zz = 4/R [ K + Z**2 E / rho**2 ]
!>    M_rz = 4 Z/R [ (r0 - r) E / rho**2 + 2 r  D / R**2 ]
!>    M_zr = 4 Z/R [ (r0 - r) E / rho**2 - 2 r0 D / R**2 ]
!>    M_rr = 4/R [ 2 D - K + Z**2 (D / R**2 - B / rho**2) ]
!> These are the textbook combinations (Pozrikidis 1992, sec. 2.4) rearranged with
!> B - E = -m1 D and E - B = m1 D so that nothing cancels as rho -> 0 (the textbook
!> (r0 + r) E - 2 r B, for instance, loses log10(r/rho) digits), and nothing divides by r0, r or
!> m, so the axis needs no special case:
!>  - r0 = 0 (target on the axis): m = 0 and M_rr = M_rz = 0 (no radial velocity on the axis),
!>    M_zr = -2 pi Z r / R**3, M_zz = 2 pi (1/R + Z**2/R**3);
!>  - r = 0 (source ring of zero radius): M_rr = M_zr = 0 (f_r averages out over phi), and the
!>    z column is 2 pi times the point Stokeslet's: M_rz = 2 pi r0 Z / R**3, M_zz as above.
!> Reciprocity M_ab(x0; y) = M_ba(y; x0) holds (J is symmetric and even).
!>
!> Near field: as rho -> 0 along a fixed direction X/rho = (r0 - r, Z)/rho = (cos a, sin a),
!> K = ln(4/sqrt(m1)) + O(m1 ln m1) = ln(R/rho) + ln 4 + ..., D = K - 1 + ..., B, E -> 1, so
!>    M = -(2/r0) ln(rho) I + (2/r0) [ ln(8 r0) I + diag(-2, 0) + (the 2D Stokeslet's X X^T/rho**2
!>        written as [[-sin**2 a, cos a sin a], [cos a sin a, sin**2 a]]) ] + O(rho ln rho):
!> the log coefficient is A = (2/r0) I (locally the ring is a straight line force, whose
!> 2D Stokeslet is -2 ln(rho) I per unit length, on the ring's arc r0 dphi). The bounded rest
!> depends on the direction only, which is constant along a straight segment ending at x0.
!>
!> segment_integral: integral over a straight meridian segment of M . f r ds with P1 f. Off the
!> segment, Gauss-Legendre on subintervals no longer than their distance to the nearest
!> singular point of the integrand (the target; the kernel's other singular point, the target
!> mirrored through the axis, is always farther). With a target at an endpoint, the log part
!> -A ln(rho) f r is integrated exactly and the bounded rest on geometrically graded intervals.
module ring_stokeslet
   use capsim_kinds, only: dp
   use elliptic_integrals, only: elliptic_kebd_m1
   implicit none
   private
   public :: ring_kernel, ring_log_coefficient, segment_integral

   ! Gauss-Legendre on [-1, 1], the non-negative half of the symmetric nodes (n even).
   real(dp), parameter :: gl6_x(3) = [0.2386191860831969086305017_dp, 0.6612093864662645136613996_dp, &
                                      0.9324695142031520278123016_dp]
   real(dp), parameter :: gl6_w(3) = [0.4679139345726910473898703_dp, 0.3607615730481386075698335_dp, &
                                      0.1713244923791703450402961_dp]
   real(dp), parameter :: gl4_x(2) = [0.3399810435848562648026658_dp, 0.8611363115940525752239465_dp]
   real(dp), parameter :: gl4_w(2) = [0.6521451548625461426269361_dp, 0.3478548451374538573730639_dp]
   real(dp), parameter :: gl8_x(4) = [0.1834346424956498049394761_dp, 0.5255324099163289858177390_dp, &
                                      0.7966664774136267395915539_dp, 0.9602898564975362316835609_dp]
   real(dp), parameter :: gl8_w(4) = [0.3626837833783619829651504_dp, 0.3137066458778872873379622_dp, &
                                      0.2223810344533744705443560_dp, 0.1012285362903762591525314_dp]
   real(dp), parameter :: gl10_x(5) = [0.1488743389816312108848260_dp, 0.4333953941292471907992659_dp, &
                                       0.6794095682990244062343274_dp, 0.8650633666889845107320967_dp, &
                                       0.9739065285171717200779640_dp]
   real(dp), parameter :: gl10_w(5) = [0.2955242247147528701738930_dp, 0.2692667193099963550912269_dp, &
                                       0.2190863625159820439955349_dp, 0.1494513491505805931457763_dp, &
                                       0.0666713443086881375935688_dp]
   !> Subintervals of the near path are at most this many times their distance to the target:
   !> the Bernstein ellipse then has rho_B >= 4.2 and 10 points err by <~ 4.2**-20 ~ 3e-13.
   real(dp), parameter :: length_over_distance = 1.0_dp
   !> Halvings of [0, ts] towards an endpoint target. The subtracted integrand behaves like
   !> t ln t there, so the innermost interval [0, ts 2**-j] is integrated to O(4**-j ln 2**j).
   integer, parameter :: endpoint_levels = 16
   !> An endpoint target with r0 below this fraction of the segment length counts as on the axis,
   !> where the kernel times r is bounded and smooth along the segment (no log to subtract).
   real(dp), parameter :: axis_fraction = 1.0e-15_dp

   !> A segment as seen from its target: points (ra + t dr, za + t dz), t in [0, 1], the target
   !> at offset (wr, wz) from the start (so that target - point = (wr - t dr, wz - t dz) keeps
   !> full relative precision near the target), and f = fa + t df.
   type :: segment_t
      real(dp) :: r0, ra, wr, wz, dr, dz, len
      real(dp) :: fa(2), df(2)
   end type segment_t

contains

   !> Ring Stokeslet M (index 1 = r, 2 = z) at target (r0, z0) from the source ring (r, z),
   !> r0, r >= 0. At a coincident point (rho = 0) the result is large but finite (the elliptic
   !> parameter is clamped), never NaN, unless r0 = r = 0 too.
   pure subroutine ring_kernel(r0, z0, r, z, m)
      real(dp), intent(in) :: r0, z0, r, z
      real(dp), intent(out) :: m(2, 2)
      call ring_kernel_offset(r0, r, r0 - r, z0 - z, m)
   end subroutine ring_kernel

   !> ring_kernel with the offset (r0 - r, z0 - z) given directly: along a segment it is known
   !> to full relative precision even when the source is 1e-11 from a target at z0 = O(1),
   !> where z0 - (za + t dz) would carry an absolute round-off of eps |z0|.
   pure subroutine ring_kernel_offset(r0, r, dr, dz, m)
      real(dp), intent(in) :: r0, r, dr, dz
      real(dp), intent(out) :: m(2, 2)
      real(dp) :: rho2, big_r2, big_r, kk, ee, bb, dd, c, e_rho, d_big

      rho2 = dr * dr + dz * dz
      big_r2 = (r0 + r)**2 + dz * dz
      big_r = sqrt(big_r2)
      ! m1 straight from rho/R: 1 - 4 r0 r / R**2 would lose every digit near the ring.
      call elliptic_kebd_m1(rho2 / big_r2, kk, ee, bb, dd)
      c = 4.0_dp / big_r
      rho2 = max(rho2, tiny(1.0_dp))
      e_rho = ee / rho2
      d_big = dd / big_r2
      m(2, 2) = c * (kk + dz * dz * e_rho)
      m(1, 2) = c * dz * (dr * e_rho + 2.0_dp * r * d_big)
      m(2, 1) = c * dz * (dr * e_rho - 2.0_dp * r0 * d_big)
      m(1, 1) = c * (2.0_dp * dd - kk + dz * dz * (d_big - bb / rho2))
   end subroutine ring_kernel_offset

   !> Coefficient a of the logarithmic singularity M = -a ln(rho) I + bounded, a = 2/r0.
   !> On the axis (r0 = 0) the kernel has no logarithm (m = 0 identically): 0 is returned.
   elemental function ring_log_coefficient(r0) result(a)
      real(dp), intent(in) :: r0
      real(dp) :: a
      if (r0 > 0.0_dp) then
         a = 2.0_dp / r0
      else
         a = 0.0_dp
      end if
   end function ring_log_coefficient

   !> Integral over the straight meridian segment (ra, za) -> (rb, zb) of M(r0, z0; r, z) . f r ds,
   !> f linear from fa to fb (components (f_r, f_z)); multiply by 1/(8 pi mu) for a velocity.
   !> target_end = 0: the target is off the segment (it may be arbitrarily close);
   !> target_end = 1 or 2: the target is endpoint a or b, whose own coordinates are then used
   !> (r0, z0 are ignored) so that rho = t L holds exactly in the subtracted logarithm.
   !> Accuracy against adaptive quadrature (tests/kernel/test_ring_kernel.py, and a randomised
   !> sweep of ~1000 segment integrals, targets 1e-4 to 10 segment lengths away, at an endpoint, on or
   !> near the axis): typically 1e-15 relative, worst seen 2.3e-12 (targets ~0.6 lengths away,
   !> where the 10-point rule's Bernstein bound is weakest). Cost in kernel evaluations: 6 beyond
   !> 4 segment lengths, 8 beyond 2, 10 beyond 1, ~20 more per halving of the distance below
   !> that; 170 for an endpoint target, +10 per halving of r0 below L.
   pure function segment_integral(r0, z0, ra, za, rb, zb, fa, fb, target_end) result(u)
      real(dp), intent(in) :: r0, z0, ra, za, rb, zb
      real(dp), intent(in) :: fa(2), fb(2)
      integer, intent(in) :: target_end
      real(dp) :: u(2)
      type(segment_t) :: seg

      u = 0.0_dp
      select case (target_end)
      case (1)
         seg = segment_t(r0=ra, ra=ra, wr=0.0_dp, wz=0.0_dp, dr=rb - ra, dz=zb - za, len=norm_2d(rb - ra, zb - za), &
                         fa=fa, df=fb - fa)
         if (seg%len > 0.0_dp) u = endpoint_integral(seg)
      case (2)
         ! The integral does not depend on the direction of travel: start from the target.
         seg = segment_t(r0=rb, ra=rb, wr=0.0_dp, wz=0.0_dp, dr=ra - rb, dz=za - zb, len=norm_2d(rb - ra, zb - za), &
                         fa=fb, df=fa - fb)
         if (seg%len > 0.0_dp) u = endpoint_integral(seg)
      case default
         seg = segment_t(r0=r0, ra=ra, wr=r0 - ra, wz=z0 - za, dr=rb - ra, dz=zb - za, len=norm_2d(rb - ra, zb - za), &
                         fa=fa, df=fb - fa)
         if (seg%len > 0.0_dp) u = off_segment_integral(seg)
      end select
   end function segment_integral

   !> Target off the segment: one Gauss rule if it is far, else subintervals growing
   !> geometrically away from the point of the segment closest to the target.
   pure function off_segment_integral(seg) result(u)
      type(segment_t), intent(in) :: seg
      real(dp) :: u(2)
      real(dp) :: len2, t_star, d_perp, t_c, dist, x, h
      ! Floor on subinterval lengths (in units of L): only reached for a target lying on the
      ! segment's interior, which the log makes integrable anyway.
      real(dp), parameter :: h_min = 1.0e-13_dp

      u = 0.0_dp
      len2 = seg%len**2
      ! Singular points of the integrand in the complex t plane: t_star +- i d_perp (t in [0, 1]).
      t_star = (seg%wr * seg%dr + seg%wz * seg%dz) / len2
      d_perp = abs(seg%wr * seg%dz - seg%wz * seg%dr) / len2
      t_c = min(max(t_star, 0.0_dp), 1.0_dp)
      dist = norm_2d(t_star - t_c, d_perp)
      ! Gauss n-point error ~ (4 dist)**(-2n) (Bernstein ellipse through the singularity):
      ! ~1e-12 relative for 4 points at dist >= 8 and 6 points at dist >= 4.
      if (dist >= 8.0_dp) then
         u = gauss_interval(seg, 0.0_dp, 0.0_dp, 1.0_dp, 4)
      else if (dist >= 4.0_dp) then
         u = gauss_interval(seg, 0.0_dp, 0.0_dp, 1.0_dp, 6)
      else if (dist >= 2.0_dp) then
         u = gauss_interval(seg, 0.0_dp, 0.0_dp, 1.0_dp, 8)
      else if (dist >= length_over_distance) then
         u = gauss_interval(seg, 0.0_dp, 0.0_dp, 1.0_dp, 10)
      else
         ! Each subinterval is at most length_over_distance times its distance to t_star + i d_perp.
         x = t_c
         do while (x < 1.0_dp)
            h = min(1.0_dp - x, max(length_over_distance * norm_2d(x - t_star, d_perp), h_min))
            u = u + gauss_interval(seg, 0.0_dp, x, x + h, 10)
            x = x + h
         end do
         x = t_c
         do while (x > 0.0_dp)
            h = min(x, max(length_over_distance * norm_2d(x - t_star, d_perp), h_min))
            u = u + gauss_interval(seg, 0.0_dp, x - h, x, 10)
            x = x - h
         end do
      end if
   end function off_segment_integral

   !> Target at the start (t = 0) of the segment, r0 = ra.
   !> On [0, ts], ts = min(1, r0/L), where the kernel behaves like -(2/r0) ln(rho):
   !>    integral (M f r) = integral (M + A ln(t L)) f r  +  (-A) integral ln(t L) f r,
   !> the first on intervals halving towards t = 0 (its integrand is bounded, ~ t ln t), the
   !> second exactly (f r is a quadratic in t). Beyond ts (only when r0 < L: the ring is then
   !> small compared with the segment and looks like a point source from there), intervals
   !> doubling away from the target. Restricting the subtraction to [0, ts] also keeps A f r
   !> bounded (r <= r0 + ts L) when r0 is tiny.
   pure function endpoint_integral(seg) result(u)
      type(segment_t), intent(in) :: seg
      real(dp) :: u(2)
      real(dp) :: ts, a_log, c0(2), c1(2), c2(2), lo, hi, lnl
      integer :: j

      if (seg%r0 <= axis_fraction * seg%len) then
         ! On the axis M r is bounded and, along a straight segment from the target, depends
         ! on the direction only (it is 0 if the segment runs along the axis): f linear makes
         ! the integrand linear in t, which one rule integrates exactly.
         u = gauss_interval(seg, 0.0_dp, 0.0_dp, 1.0_dp, 6)
         return
      end if
      ts = min(1.0_dp, seg%r0 / seg%len)
      a_log = ring_log_coefficient(seg%r0)
      ! f(t) r(t) = c0 + c1 t + c2 t**2.
      c0 = seg%fa * seg%ra
      c1 = seg%fa * seg%dr + seg%df * seg%ra
      c2 = seg%df * seg%dr
      ! integral_0^ts t**k ln(t L) dt = ts**(k+1)/(k+1) (ln(ts L) - 1/(k+1)).
      lnl = log(ts * seg%len)
      u = -a_log * seg%len * (c0 * ts * (lnl - 1.0_dp) + c1 * ts**2 / 2 * (lnl - 0.5_dp) &
                              + c2 * ts**3 / 3 * (lnl - 1.0_dp / 3))
      hi = ts
      do j = 1, endpoint_levels
         lo = 0.5_dp * hi
         u = u + gauss_interval(seg, a_log, lo, hi, 10)
         hi = lo
      end do
      u = u + gauss_interval(seg, a_log, 0.0_dp, hi, 10)
      lo = ts
      do while (lo < 1.0_dp)
         hi = min(1.0_dp, 2.0_dp * lo)
         u = u + gauss_interval(seg, 0.0_dp, lo, hi, 10)
         lo = hi
      end do
   end function endpoint_integral

   !> sqrt(x**2 + y**2) without hypot's guard against overflow, which the meridian's lengths
   !> (0.01-10 l) never need: hypot was 8 % of a tube case's CPU time (perf).
   elemental real(dp) function norm_2d(x, y)
      real(dp), intent(in) :: x, y
      norm_2d = sqrt(x * x + y * y)
   end function norm_2d

   !> n-point Gauss-Legendre (n = 4, 6, 8 or 10) on [t0, t1] of
   !>    L (M(r0, z0; r(t), z(t)) + a_log ln(t L) I) . f(t) r(t) dt.
   pure function gauss_interval(seg, a_log, t0, t1, n) result(s)
      type(segment_t), intent(in) :: seg
      real(dp), intent(in) :: a_log, t0, t1
      integer, intent(in) :: n
      real(dp) :: s(2)
      real(dp) :: mid, half
      integer :: i

      mid = 0.5_dp * (t0 + t1)
      half = 0.5_dp * (t1 - t0)
      s = 0.0_dp
      select case (n)
      case (4)
         do i = 1, 2
            s = s + gl4_w(i) * (point(mid - half * gl4_x(i)) + point(mid + half * gl4_x(i)))
         end do
      case (6)
         do i = 1, 3
            s = s + gl6_w(i) * (point(mid - half * gl6_x(i)) + point(mid + half * gl6_x(i)))
         end do
      case (8)
         do i = 1, 4
            s = s + gl8_w(i) * (point(mid - half * gl8_x(i)) + point(mid + half * gl8_x(i)))
         end do
      case default
         do i = 1, 5
            s = s + gl10_w(i) * (point(mid - half * gl10_x(i)) + point(mid + half * gl10_x(i)))
         end do
      end select
      s = s * (half * seg%len)
   contains
      pure function point(t) result(g)
         real(dp), intent(in) :: t
         real(dp) :: g(2)
         real(dp) :: m(2, 2), r
         ! Clamped: round-off must not take a segment that ends on the axis across it.
         r = max(seg%ra + t * seg%dr, 0.0_dp)
         call ring_kernel_offset(seg%r0, r, seg%wr - t * seg%dr, seg%wz - t * seg%dz, m)
         if (a_log /= 0.0_dp) then
            m(1, 1) = m(1, 1) + a_log * log(t * seg%len)
            m(2, 2) = m(2, 2) + a_log * log(t * seg%len)
         end if
         g = matmul(m, seg%fa + t * seg%df) * r
      end function point
   end function gauss_interval

end module ring_stokeslet
