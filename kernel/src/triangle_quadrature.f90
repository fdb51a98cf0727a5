!> Quadrature rules on a flat triangle, all written as barycentric points and weights that
!> sum to one, so that  integral_T g dS ~= area(T) * sum_k w_k g(y_k).
!>
!> - Dunavant's 7-point rule (degree 5), optionally on a uniform subdivision of the triangle,
!>   for triangles near (but not touching) the target point;
!> - the Duffy (polar) rule for a 1/r singularity at vertex 1: y = x1 + u [(x2 - x1) + v (x3 - x2)]
!>   has Jacobian 2 A u, which cancels the singularity, and Gauss-Legendre in u and v
!>   integrates what is left.
module triangle_quadrature
   use capsim_kinds, only: dp
   implicit none
   private
   public :: quadrature_rule_t, dunavant7_rule, interior3_rule, edge3_rule, duffy_rule, gauss_legendre_01

   type :: quadrature_rule_t
      !> Barycentric coordinates (3, n) and weights (n), sum(weight) = 1.
      real(dp), allocatable :: bary(:, :)
      real(dp), allocatable :: weight(:)
   end type quadrature_rule_t

contains

   !> Dunavant degree-5 rule on each of the 4**levels sub-triangles of a uniform subdivision.
   pure function dunavant7_rule(levels) result(rule)
      integer, intent(in) :: levels
      type(quadrature_rule_t) :: rule
      real(dp), parameter :: a1 = 0.059715871789770_dp, b1 = 0.470142064105115_dp
      real(dp), parameter :: a2 = 0.797426985353087_dp, b2 = 0.101286507323456_dp
      real(dp), parameter :: w0 = 0.225_dp, w1 = 0.132394152788506_dp, w2 = 0.125939180544827_dp
      real(dp) :: base_bary(3, 7), base_w(7), corners(3, 3)
      integer :: n_sub, m, i, j, s, k, q
      real(dp) :: p1(3), p2(3), p3(3), h

      base_bary = reshape([1.0_dp / 3, 1.0_dp / 3, 1.0_dp / 3, &
                           a1, b1, b1, b1, a1, b1, b1, b1, a1, &
                           a2, b2, b2, b2, a2, b2, b2, b2, a2], [3, 7])
      base_w = [w0, w1, w1, w1, w2, w2, w2]
      m = 2**levels
      n_sub = m * m
      allocate (rule%bary(3, 7 * n_sub), rule%weight(7 * n_sub))
      h = 1.0_dp / m
      q = 0
      ! Sub-triangles in barycentric (s1, s2) steps of h: "upward" (i, j) and "downward" ones.
      do i = 0, m - 1
         do j = 0, m - 1 - i
            do s = 1, 2
               if (s == 2 .and. i + j == m - 1) cycle
               if (s == 1) then
                  p1 = lift(i, j)
                  p2 = lift(i + 1, j)
                  p3 = lift(i, j + 1)
               else
                  p1 = lift(i + 1, j)
                  p2 = lift(i + 1, j + 1)
                  p3 = lift(i, j + 1)
               end if
               corners(:, 1) = p1
               corners(:, 2) = p2
               corners(:, 3) = p3
               do k = 1, 7
                  q = q + 1
                  rule%bary(:, q) = matmul(corners, base_bary(:, k))
                  rule%weight(q) = base_w(k) / n_sub
               end do
            end do
         end do
      end do
   contains
      pure function lift(ii, jj) result(b)
         integer, intent(in) :: ii, jj
         real(dp) :: b(3)
         b(2) = ii * h
         b(3) = jj * h
         b(1) = 1.0_dp - b(2) - b(3)
      end function lift
   end function dunavant7_rule

   !> The interior 3-point rule of degree 2 (points (2/3, 1/6, 1/6) and permutations, weights
   !> 1/3): a degree more than the vertex rule at three points per triangle.
   pure function interior3_rule() result(rule)
      type(quadrature_rule_t) :: rule
      real(dp), parameter :: a = 2.0_dp / 3.0_dp, b = 1.0_dp / 6.0_dp
      allocate (rule%bary(3, 3), rule%weight(3))
      rule%bary = reshape([a, b, b, b, a, b, b, b, a], [3, 3])
      rule%weight = [1.0_dp, 1.0_dp, 1.0_dp] / 3.0_dp
   end function interior3_rule

   !> The edge-midpoint rule of degree 2 (point k at the midpoint of edge k, from corner k to
   !> corner k+1, weights 1/3): on a conforming mesh two triangles share each point, so a
   !> surface sum has one point per edge, half the interior rule's.
   pure function edge3_rule() result(rule)
      type(quadrature_rule_t) :: rule
      allocate (rule%bary(3, 3), rule%weight(3))
      rule%bary = reshape([0.5_dp, 0.5_dp, 0.0_dp, 0.0_dp, 0.5_dp, 0.5_dp, 0.5_dp, 0.0_dp, 0.5_dp], [3, 3])
      rule%weight = [1.0_dp, 1.0_dp, 1.0_dp] / 3.0_dp
   end function edge3_rule

   !> Duffy rule with n x n Gauss-Legendre points for a 1/r singularity at vertex `corner`.
   pure function duffy_rule(n, corner) result(rule)
      integer, intent(in) :: n, corner
      type(quadrature_rule_t) :: rule
      real(dp) :: xg(n), wg(n), b(3)
      integer :: i, j, q
      call gauss_legendre_01(n, xg, wg)
      allocate (rule%bary(3, n * n), rule%weight(n * n))
      q = 0
      do i = 1, n
         do j = 1, n
            q = q + 1
            b = [1.0_dp - xg(i), xg(i) * (1.0_dp - xg(j)), xg(i) * xg(j)]
            ! Rotate so that the singular vertex is `corner`.
            rule%bary(:, q) = cshift(b, 1 - corner)
            rule%weight(q) = 2.0_dp * xg(i) * wg(i) * wg(j)
         end do
      end do
   end function duffy_rule

   !> Gauss-Legendre nodes and weights on [0, 1] (Newton iteration on P_n).
   pure subroutine gauss_legendre_01(n, x, w)
      integer, intent(in) :: n
      real(dp), intent(out) :: x(n), w(n)
      real(dp) :: z, p0, p1, p2, dp_dz
      integer :: i, k, it
      real(dp), parameter :: pi_ = acos(-1.0_dp)
      do i = 1, n
         z = cos(pi_ * (i - 0.25_dp) / (n + 0.5_dp))
         do it = 1, 100
            p0 = 1.0_dp
            p1 = z
            do k = 2, n
               p2 = ((2 * k - 1) * z * p1 - (k - 1) * p0) / k
               p0 = p1
               p1 = p2
            end do
            if (n == 1) p0 = 1.0_dp
            dp_dz = n * (z * p1 - p0) / (z * z - 1.0_dp)
            if (abs(p1 / dp_dz) < 1.0e-15_dp) exit
            z = z - p1 / dp_dz
         end do
         x(n + 1 - i) = 0.5_dp * (1.0_dp + z)
         w(n + 1 - i) = 1.0_dp / ((1.0_dp - z * z) * dp_dz**2)
      end do
   end subroutine gauss_legendre_01

end module triangle_quadrature
