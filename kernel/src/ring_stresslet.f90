!> Axisymmetric double layer: the ring stresslet and the double-layer operator of a P1 density
!> on a closed meridian polygon, for the viscosity ratio lambda /= 1 in the axisymmetric tube.
!>
!> Normalisation (as stokes_double_layer in 3D): for a density q on a closed surface S with
!> outward normal n,
!>    D[q](x0) = 1/(8 pi) integral_S q_i(y) T_ijk(y - x0) n_k(y) dS(y),  T_ijk(d) = -6 d_i d_j d_k/|d|**5,
!> which for a constant q is -q inside S, -q/2 on S (principal value) and 0 outside. With the
!> target x0 = (r0, 0, z0) and the source ring (r, z) with normal n_r e_r(phi) + n_z e_z and
!> density q_r e_r(phi) + q_z e_z,
!>    Q_ab(r0, z0; r, z; n) = 6 integral_0^{2 pi} (d.e_a(0)) (d.e_b(phi)) (d.n) / |d|**5 dphi,  d = x0 - y,
!> so that D[q]_a(x0) = 1/(8 pi) integral_meridian Q_ab q_b r ds (index 1 = r, 2 = z).
!>
!> Closed form (derived here; checked against the phi quadrature of T in
!> tests/kernel/test_ring_stresslet.py). With dr = r0 - r, Z = z0 - z, rho**2 = dr**2 + Z**2,
!> R**2 = (r0 + r)**2 + Z**2, m = 4 r0 r/R**2, m1 = rho**2/R**2, and phi = pi - 2t, u = cos(t)**2
!> (u = 0 at the point of the ring nearest the target), the three projections are linear in u
!> with coefficients that are plain products (nothing cancels near the ring):
!>    d.e_r(0) = dr + 2 r u,  d.e_r(phi) = dr - 2 r0 u,  d.e_z = Z,  d.n = n_r dr + n_z Z - 2 n_r r0 u,
!> and |d|**2 = R**2 (m1 + m u). Their cubic product sum_k c_k u**k gives
!>    Q_ab = 24/R**5 sum_{k=0..3} c_k H_k,   H_k = integral_0^{pi/2} cos(t)**(2k) / (1 - m sin(t)**2)**(5/2) dt,
!> and, with K, E the complete elliptic integrals of parameter m (from m1, elliptic_integrals),
!>    H_0 = (2 (2 - m) E - m1 K) / (3 m1**2),     H_1 = ((2 m - 1) E + m1 K) / (3 m m1),
!>    H_2 = ((2 + m) K - 2 (1 + m) E) / (3 m**2), H_3 = ((3 + 7 m1 - 2 m1**2) E - m1 (9 - m1) K) / (3 m**3)
!> (the weight cos**(2k) vanishes at the singular end, so each H_k carries only its own order
!> 1/m1**(2-k) or ln m1, and for m >= 1/2 no sum loses more than a factor ~40). Below m = 1/2
!> (far rings, targets near the axis) the 1/m**k quotients cancel, and the binomial series
!>    H_k = sum_j (5/2)_j / j! m**j integral_0^{pi/2} sin**(2j) cos**(2k) dt
!> is used instead (each term positive, ratio -> m: ~55 terms at m = 1/2). On the axis (r0 = 0)
!> m = 0 and Q_rr = Q_rz = 0.
!>
!> The operator. Meridian nodes rz(:, 1..n) (front pole to rear pole, P1 density), straight
!> elements, outward normal (-dz, dr)/L (the meridian turns clockwise in the (r, z) plane).
!> At a node x_k the principal value is computed with the constant-density identity,
!>    D[q](x_k) = 1/(8 pi) integral (q - q_k) T n dS - q_k / 2,
!> whose integrand is bounded (~ t ln t on the two elements that end at x_k, where the
!> weight of the far end's hat removes the log): no principal value and no log is integrated.
!> On the polygon the direct integral of a constant would give the kink's wedge value instead of
!> -1/2 (an O(h) error at every node); the identity makes D[const] = -const/2 exact, and the
!> error of D[q] is that of the P1 density on the polygon, O(h**2) (measured in the tests). Off
!> the surface, the density's value at the nearest node is subtracted the same way (the
!> constant's double layer is known there: 0 outside, -1 inside), which keeps targets close to
!> the membrane (the tube wall in the lubrication film) accurate.
module ring_stresslet
   use capsim_kinds, only: dp, pi
   use elliptic_integrals, only: elliptic_kebd_m1
   implicit none
   private
   public :: ring_stresslet_kernel, stresslet_segment, double_layer_row, element_double_layer, nearest_node

   real(dp), parameter :: gl10_x(5) = [0.1488743389816312108848260_dp, 0.4333953941292471907992659_dp, &
                                       0.6794095682990244062343274_dp, 0.8650633666889845107320967_dp, &
                                       0.9739065285171717200779640_dp]
   real(dp), parameter :: gl10_w(5) = [0.2955242247147528701738930_dp, 0.2692667193099963550912269_dp, &
                                       0.2190863625159820439955349_dp, 0.1494513491505805931457763_dp, &
                                       0.0666713443086881375935688_dp]
   !> Below this m the H_k come from their series (see the module header).
   real(dp), parameter :: series_below = 0.5_dp
   !> Halvings towards a target at a segment end: the integrand is ~ t ln t there, so the
   !> innermost interval [0, 2**-levels] contributes ~ 4**-levels ln 2**levels (1e-11 at 20).
   integer, parameter :: endpoint_levels = 20

   !> A segment seen from its target: points (ra + t dr, za + t dz), t in [0, 1]; the target at
   !> offset (wr, wz) from the start; outward normal (nr, nz).
   type :: segment_t
      real(dp) :: r0, ra, wr, wz, dr, dz, len, nr, nz
   end type segment_t

contains

   !> Ring stresslet Q (index 1 = r, 2 = z; Q(a, b): target component a, density component b)
   !> at target (r0, z0) from the ring (r, z) with unit normal (n_r, n_z) in the meridian plane.
   pure subroutine ring_stresslet_kernel(r0, z0, r, z, n_r, n_z, q)
      real(dp), intent(in) :: r0, z0, r, z, n_r, n_z
      real(dp), intent(out) :: q(2, 2)
      real(dp) :: q3(2, 3)
      call kernel_offset(r0, r, r0 - r, z0 - z, n_r, n_z, q3)
      q = q3(:, 1:2)
   end subroutine ring_stresslet_kernel

   !> ring_stresslet_kernel with the offset (dr, dz) = (r0 - r, z0 - z) given directly (full
   !> relative precision next to the target, see ring_stokeslet), and a third column: the
   !> kernel of the density e_r(phi) - e_x, e_x = e_r(0) the target's radial direction, whose
   !> projection d.(e_r(phi) - e_x) = -2 (r0 + r) u vanishes at the nearest point of the ring
   !> (the difference of the radial density and a Cartesian constant, see double_layer_row).
   pure subroutine kernel_offset(r0, r, dr, dz, n_r, n_z, q)
      real(dp), intent(in) :: r0, r, dr, dz, n_r, n_z
      real(dp), intent(out) :: q(2, 3)
      real(dp) :: big_r2, m, m1, h(0:3), e(2, 0:1), a(3, 0:1), n0, n1, c(0:3), scale
      integer :: i, j

      big_r2 = (r0 + r)**2 + dz * dz
      m1 = max((dr * dr + dz * dz) / big_r2, 1.0e-150_dp)
      m = 4.0_dp * r0 * r / big_r2
      call h_integrals(m, m1, h)
      ! Linear factors in u: target component (e), density component (a), normal (n).
      e(1, :) = [dr, 2.0_dp * r]
      e(2, :) = [dz, 0.0_dp]
      a(1, :) = [dr, -2.0_dp * r0]
      a(2, :) = [dz, 0.0_dp]
      a(3, :) = [0.0_dp, -2.0_dp * (r0 + r)]
      n0 = n_r * dr + n_z * dz
      n1 = -2.0_dp * n_r * r0
      scale = 24.0_dp / (big_r2 * big_r2 * sqrt(big_r2))
      do j = 1, 3
         do i = 1, 2
            c(0) = e(i, 0) * a(j, 0) * n0
            c(1) = e(i, 1) * a(j, 0) * n0 + e(i, 0) * a(j, 1) * n0 + e(i, 0) * a(j, 0) * n1
            c(2) = e(i, 1) * a(j, 1) * n0 + e(i, 1) * a(j, 0) * n1 + e(i, 0) * a(j, 1) * n1
            c(3) = e(i, 1) * a(j, 1) * n1
            q(i, j) = scale * sum(c * h)
         end do
      end do
      ! On the axis the radial velocity of an axisymmetric density vanishes by symmetry (not
      ! that of the Cartesian e_x in column 3). The closed form gives it as a difference of
      ! equal products (c(0) h(0) + c(1) h(1) with h(1) = h(0)/2), exactly 0 only when both
      ! round alike; with fused multiply-adds (the native build) it is ~1e-19.
      if (r0 <= 0.0_dp) q(1, 1:2) = 0.0_dp
   end subroutine kernel_offset

   !> H_k = integral_0^{pi/2} cos(t)**(2k) (1 - m sin(t)**2)**(-5/2) dt, k = 0..3.
   pure subroutine h_integrals(m, m1, h)
      real(dp), intent(in) :: m, m1
      real(dp), intent(out) :: h(0:3)
      real(dp) :: kk, ee, bb, dd, term(0:3), ratio
      integer :: j, k
      if (m >= series_below) then
         call elliptic_kebd_m1(m1, kk, ee, bb, dd)
         h(0) = (2.0_dp * (2.0_dp - m) * ee - m1 * kk) / (3.0_dp * m1 * m1)
         h(1) = ((2.0_dp * m - 1.0_dp) * ee + m1 * kk) / (3.0_dp * m * m1)
         h(2) = ((2.0_dp + m) * kk - 2.0_dp * (1.0_dp + m) * ee) / (3.0_dp * m * m)
         h(3) = ((3.0_dp + 7.0_dp * m1 - 2.0_dp * m1 * m1) * ee - m1 * (9.0_dp - m1) * kk) / (3.0_dp * m**3)
         return
      end if
      ! integral sin**0 cos**(2k) = (pi/2) (2k-1)!!/(2k)!!; each step multiplies by
      ! m (j + 5/2)/(j + 1) (binomial) and (2j + 1)/(2j + 2k + 2) (the Wallis ratio).
      term = 0.5_dp * pi * [1.0_dp, 0.5_dp, 0.375_dp, 0.3125_dp]
      h = term
      do j = 0, 400
         do k = 0, 3
            ratio = m * (j + 2.5_dp) / (j + 1) * (2 * j + 1) / real(2 * j + 2 * k + 2, dp)
            term(k) = term(k) * ratio
         end do
         h = h + term
         if (term(0) <= epsilon(1.0_dp) * 0.01_dp * h(0)) exit
      end do
   end subroutine h_integrals

   !> Weights of the segment (ra, za) -> (rb, zb) in the double layer (without 1/(8 pi)) at the
   !> target, as 2x2 blocks (target component, density component (r, z)):
   !> target_end = 0, target (r0, z0) off the segment: w(:, :, 1) = integral Q (1 - t) r ds and
   !>    w(:, :, 2) = integral Q t r ds (the P1 hats of end points a and b), w(:, :, 3) = the
   !>    weight of a Cartesian constant equal to the target's own density, c = q_r e_x + q_z e_z
   !>    (integral of the e_x kernel in its r column, of Q_.z in its z column).
   !> target_end = 1 or 2, the target is end a or b: the weights of q - c, c as above, with the
   !>    near end's weight in w(:, :, 1 or 2) and w(:, :, 3) = 0. Each integrand is then bounded
   !>    (~ t ln t): the far hat vanishes at the target, and q_r(near) (1 - t) e_r(phi) - q_r e_x
   !>    = q_r ((e_r(phi) - e_x) - t e_r(phi)).
   pure function stresslet_segment(r0, z0, ra, za, rb, zb, target_end) result(w)
      real(dp), intent(in) :: r0, z0, ra, za, rb, zb
      integer, intent(in) :: target_end
      real(dp) :: w(2, 2, 3)
      type(segment_t) :: seg
      real(dp) :: len, nr, nz, acc(2, 3, 2)
      integer :: near, far

      w = 0.0_dp
      len = hypot(rb - ra, zb - za)
      if (len <= 0.0_dp) return
      nr = -(zb - za) / len
      nz = (rb - ra) / len
      select case (target_end)
      case (1, 2)
         ! Travel from the target (the normal stays the segment's).
         if (target_end == 1) then
            seg = segment_t(r0=ra, ra=ra, wr=0.0_dp, wz=0.0_dp, dr=rb - ra, dz=zb - za, len=len, nr=nr, nz=nz)
         else
            seg = segment_t(r0=rb, ra=rb, wr=0.0_dp, wz=0.0_dp, dr=ra - rb, dz=za - zb, len=len, nr=nr, nz=nz)
         end if
         near = target_end
         far = 3 - target_end
         acc = endpoint_integral(seg)
         ! acc(:, column, hat) with hats (1 - t, t) in the travel variable t from the target.
         w(:, :, far) = acc(:, 1:2, 2)
         w(:, 1, near) = acc(:, 3, 1) + acc(:, 3, 2) - acc(:, 1, 2)
         w(:, 2, near) = -acc(:, 2, 2)
      case default
         seg = segment_t(r0=r0, ra=ra, wr=r0 - ra, wz=z0 - za, dr=rb - ra, dz=zb - za, len=len, nr=nr, nz=nz)
         acc = off_segment(seg)
         w(:, :, 1) = acc(:, 1:2, 1)
         w(:, :, 2) = acc(:, 1:2, 2)
         w(:, 1, 3) = acc(:, 1, 1) + acc(:, 1, 2) - acc(:, 3, 1) - acc(:, 3, 2)
         w(:, 2, 3) = acc(:, 2, 1) + acc(:, 2, 2)
      end select
   end function stresslet_segment

   !> Target off the segment: one 10-point rule when the nearest singular point of the
   !> integrand is a segment length or more away, else subintervals no longer than their
   !> distance to it (the rule of ring_stokeslet's off_segment_integral).
   pure function off_segment(seg) result(acc)
      type(segment_t), intent(in) :: seg
      real(dp) :: acc(2, 3, 2)
      real(dp) :: len2, t_star, d_perp, t_c, dist, x, h
      real(dp), parameter :: h_min = 1.0e-13_dp
      len2 = seg%len**2
      t_star = (seg%wr * seg%dr + seg%wz * seg%dz) / len2
      d_perp = abs(seg%wr * seg%dz - seg%wz * seg%dr) / len2
      t_c = min(max(t_star, 0.0_dp), 1.0_dp)
      dist = hypot(t_star - t_c, d_perp)
      if (dist >= 1.0_dp) then
         acc = gauss10(seg, 0.0_dp, 1.0_dp)
         return
      end if
      acc = 0.0_dp
      x = t_c
      do while (x < 1.0_dp)
         h = min(1.0_dp - x, max(hypot(x - t_star, d_perp), h_min))
         acc = acc + gauss10(seg, x, x + h)
         x = x + h
      end do
      x = t_c
      do while (x > 0.0_dp)
         h = min(x, max(hypot(x - t_star, d_perp), h_min))
         acc = acc + gauss10(seg, x - h, x)
         x = x - h
      end do
   end function off_segment

   !> Target at t = 0: intervals halving towards the target.
   pure function endpoint_integral(seg) result(acc)
      type(segment_t), intent(in) :: seg
      real(dp) :: acc(2, 3, 2)
      real(dp) :: hi
      integer :: j
      acc = 0.0_dp
      hi = 1.0_dp
      do j = 1, endpoint_levels
         acc = acc + gauss10(seg, 0.5_dp * hi, hi)
         hi = 0.5_dp * hi
      end do
      acc = acc + gauss10(seg, 0.0_dp, hi)
   end function endpoint_integral

   !> 10-point Gauss-Legendre on [t0, t1] of L Q(t) r(t) (the three columns of kernel_offset)
   !> times the hats (1 - t, t).
   pure function gauss10(seg, t0, t1) result(acc)
      type(segment_t), intent(in) :: seg
      real(dp), intent(in) :: t0, t1
      real(dp) :: acc(2, 3, 2)
      real(dp) :: mid, half, t, r, q(2, 3), s
      integer :: i, side
      mid = 0.5_dp * (t0 + t1)
      half = 0.5_dp * (t1 - t0)
      acc = 0.0_dp
      do i = 1, 5
         do side = -1, 1, 2
            t = mid + side * half * gl10_x(i)
            r = max(seg%ra + t * seg%dr, 0.0_dp)
            call kernel_offset(seg%r0, r, seg%wr - t * seg%dr, seg%wz - t * seg%dz, seg%nr, seg%nz, q)
            s = gl10_w(i) * r
            acc(:, :, 1) = acc(:, :, 1) + (s * (1.0_dp - t)) * q
            acc(:, :, 2) = acc(:, :, 2) + (s * t) * q
         end do
      end do
      acc = acc * (half * seg%len)
   end function gauss10

   !> One block row of the double-layer operator: row(:, 2j-1:2j) is the 2x2 weight of node j's
   !> density in D[q](x) (including 1/(8 pi)), for a closed meridian rz (poles on the axis).
   !> node > 0: x is that meridian node (principal value). node = 0: x is off the surface, outside
   !> (inside = .false.) or inside it. In both cases the Cartesian constant c = q_r(ref) e_x +
   !> q_z(ref) e_z of a reference node (x itself, or the node nearest x) is subtracted from the
   !> density and its double layer added back from the identity (-c/2 on the surface, 0 outside,
   !> -c inside).
   pure subroutine double_layer_row(rz, x, node, inside, row)
      real(dp), intent(in) :: rz(:, :), x(2)
      integer, intent(in) :: node
      logical, intent(in) :: inside
      real(dp), intent(out) :: row(:, :)
      real(dp) :: w(2, 2, 3), constant
      integer :: n, e, ref, end_flag, j

      n = size(rz, 2)
      row = 0.0_dp
      if (node > 0) then
         ref = node
         constant = -0.5_dp
      else
         ref = nearest_node(rz, x)
         constant = 0.0_dp
         if (inside) constant = -1.0_dp
      end if
      do e = 1, n - 1
         end_flag = 0
         if (node == e) end_flag = 1
         if (node == e + 1) end_flag = 2
         w = stresslet_segment(x(1), x(2), rz(1, e), rz(2, e), rz(1, e + 1), rz(2, e + 1), end_flag)
         row(:, 2 * e - 1:2 * e) = row(:, 2 * e - 1:2 * e) + w(:, :, 1)
         row(:, 2 * e + 1:2 * e + 2) = row(:, 2 * e + 1:2 * e + 2) + w(:, :, 2)
         row(:, 2 * ref - 1:2 * ref) = row(:, 2 * ref - 1:2 * ref) - w(:, :, 3)
      end do
      row = row / (8.0_dp * pi)
      do j = 1, 2
         row(j, 2 * ref - 2 + j) = row(j, 2 * ref - 2 + j) + constant
      end do
   end subroutine double_layer_row

   !> The meridian node nearest to x (the reference node of an off-surface target).
   pure integer function nearest_node(rz, x) result(ref)
      real(dp), intent(in) :: rz(:, :), x(2)
      ref = minloc((rz(1, :) - x(1))**2 + (rz(2, :) - x(2))**2, dim=1)
   end function nearest_node

   !> Element e's part of the double layer at x of the density q(:, 1..n) (nodes rz), with the
   !> Cartesian constant of node ref's density subtracted (see double_layer_row, whose row
   !> applied to q is the sum of these over e plus -q_ref/2 on the surface (node = ref > 0),
   !> 0 outside or -q_ref inside). node > 0: x is that node.
   pure function element_double_layer(rz, q, x, e, node, ref) result(v)
      real(dp), intent(in) :: rz(:, :), q(:, :), x(2)
      integer, intent(in) :: e, node, ref
      real(dp) :: v(2)
      real(dp) :: w(2, 2, 3)
      integer :: end_flag
      end_flag = 0
      if (node == e) end_flag = 1
      if (node == e + 1) end_flag = 2
      w = stresslet_segment(x(1), x(2), rz(1, e), rz(2, e), rz(1, e + 1), rz(2, e + 1), end_flag)
      v = (matmul(w(:, :, 1), q(:, e)) + matmul(w(:, :, 2), q(:, e + 1)) - matmul(w(:, :, 3), q(:, ref))) &
          / (8.0_dp * pi)
   end function element_double_layer

end module ring_stresslet
