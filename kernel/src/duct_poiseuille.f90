!> Fully developed laminar (Poiseuille) flow in a rectangular duct |x| <= w, |y| <= h, axis z:
!> v = u(x, y) e_z with mu Laplacian(u) = -G, u = 0 on the walls, G = -dp/dz. Units: mean
!> velocity U = 1 and viscosity mu = 1 (every velocity and stress scales with U mu).
!>
!> Series (White, Viscous Fluid Flow, ch. 3; Shah & London 1978, rectangular ducts): with the cosine
!> along a coordinate xi of half-extent a and the hyperbolic cosine along eta of half-extent b,
!>
!>    u = G/2 (a^2 - xi^2) - (16 a^2 G / pi^3) sum_{i odd} (-1)^((i-1)/2)
!>                            cosh(alpha_i eta) / cosh(alpha_i b) cos(alpha_i xi) / i^3,
!>    alpha_i = i pi / (2 a),
!>
!> written around the parabola of the plane channel (sum_{i odd} (-1)^((i-1)/2) cos(alpha_i xi)
!> / i^3 = pi^3 / 32 (1 - xi^2 / a^2)), so that the remaining terms fall like
!> r^i / i^3, r = exp(-pi (b - |eta|) / (2 a)): geometrically, except on the walls eta = +-b.
!> Both orientations (xi = x, a = w or xi = y, a = h) are exact; each point uses the one with
!> the smaller r, so only the corners converge slowly (where u and its gradient vanish).
!>
!> Truncation. With |cosh(alpha eta) / cosh(alpha b)| <= min(1, 2 r^i) (and the same for sinh),
!> the terms left after the last odd i < m are bounded by
!>    velocity:  (16 a^2 G / pi^3) min(2 r^m / (m^3 (1 - r^2)), 1 / (4 (m - 2)^2)),
!>    gradient:  (8 a G / pi^2)    min(2 r^m / (m^2 (1 - r^2)), 1 / (2 (m - 2))),
!> and the sum stops at the first m where the bound is below the requested absolute
!> tolerance (default 1e-13 U), or at max_terms terms (the bound is then returned as it is).
!>
!> Mean velocity (flow rate Q = 4 w h U), with s = min(w, h), l = max(w, h):
!>    U = (G s^2 / 3) [1 - (192 s / (pi^5 l)) sum_{i odd} tanh(i pi l / (2 s)) / i^5],
!> summed as lambda(5) - sum (1 - tanh) / i^5 with lambda(5) = sum_{i odd} 1/i^5 = (31/32) zeta(5):
!> 1 - tanh(x) <= 2 exp(-2 x) falls by exp(-pi l / s) <= exp(-pi) per term, so a dozen terms
!> reach rounding. G (the pressure gradient for U = 1) follows; p = p0 - G z.
!>
!> Stress and traction: sigma = -p I + mu (grad v + grad v^T) with grad v = e_z-column of
!> (du/dx, du/dy, 0), so on a surface with unit normal n (out of the fluid)
!>    f = sigma . n = -p n + (g . n) e_z + n_z g,   g = (du/dx, du/dy, 0):
!> on a side wall f = -p n + (du/dn) e_z (du/dn < 0: the wall holds the fluid back); on the
!> entry (n = -e_z) and exit (n = +e_z) sections f = -+ (-p e_z + g).
module duct_poiseuille
   use capsim_kinds, only: dp, pi
   implicit none
   private
   public :: duct_flow_t, build_duct_flow, default_series_tolerance, max_terms

   !> Absolute tolerance of the velocity and gradient series (units of U, U/w).
   real(dp), parameter :: default_series_tolerance = 1.0e-13_dp
   !> Most terms summed at one point (reached only within ~1e-5 w of a corner).
   integer, parameter :: max_terms = 200000
   !> lambda(5) = sum over odd i of 1 / i^5 = (31/32) zeta(5).
   real(dp), parameter :: lambda5 = 31.0_dp / 32.0_dp * 1.0369277551433699263313654864570_dp

   type :: duct_flow_t
      !> Half-width w (along x) and half-height h (along y).
      real(dp) :: half_width = 1, half_height = 1
      !> G = -dp/dz for U = 1, mu = 1.
      real(dp) :: pressure_gradient = 0
      !> Bound on the truncation error of the mean-velocity series, relative to U, and terms used.
      real(dp) :: mean_series_bound = 0
      integer :: mean_terms = 0
   contains
      procedure :: velocity
      procedure :: velocity_gradient
      procedure :: evaluate
      procedure :: centre_velocity
      procedure :: pressure
      procedure :: traction
   end type duct_flow_t

contains

   !> The flow of mean velocity 1 in the duct of half-width w and half-height h.
   subroutine build_duct_flow(half_width, half_height, flow, stat, errmsg)
      real(dp), intent(in) :: half_width, half_height
      type(duct_flow_t), intent(out) :: flow
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      real(dp) :: s, l, decay, tail_sum, term, bracket, bound
      ! decay = exp(-pi l / s): 1 - tanh(i pi l / (2 s)) <= 2 decay**i.
      integer :: i

      stat = 0
      errmsg = ''
      if (.not. (half_width > 0.0_dp .and. half_height > 0.0_dp .and. half_width < huge(1.0_dp) &
                 .and. half_height < huge(1.0_dp))) then
         stat = 1
         errmsg = 'duct half-width and half-height must be positive and finite'
         return
      end if
      if (max(half_width, half_height) > 100 * min(half_width, half_height)) then
         stat = 1
         errmsg = 'duct aspect ratio must lie in [0.01, 100]'
         return
      end if
      flow%half_width = half_width
      flow%half_height = half_height
      s = min(half_width, half_height)
      l = max(half_width, half_height)
      decay = exp(-pi * l / s)
      tail_sum = 0
      i = 1
      do
         ! 1 - tanh(x) = 2 exp(-2x) / (1 + exp(-2x)), without the cancellation.
         term = 2 * decay**i / ((1.0_dp + decay**i) * real(i, dp)**5)
         tail_sum = tail_sum + term
         flow%mean_terms = flow%mean_terms + 1
         ! Remaining terms: sum over odd j > i of 2 exp(-j pi l / s) / j^5.
         bound = 2 * decay**(i + 2) / (real(i + 2, dp)**5 * (1.0_dp - decay**2))
         if (bound < 1.0e-18_dp .or. flow%mean_terms >= 1000) exit
         i = i + 2
      end do
      bracket = 1.0_dp - 192.0_dp * s / (pi**5 * l) * (lambda5 - tail_sum)
      flow%mean_series_bound = 192.0_dp * s / (pi**5 * l) * bound / bracket
      ! U = G s^2 bracket / 3 = 1.
      flow%pressure_gradient = 3.0_dp / (s * s * bracket)
   end subroutine build_duct_flow

   !> u(x, y) (z-velocity) to the default tolerance; zero on and outside the walls (no slip).
   pure real(dp) function velocity(self, x, y) result(u)
      class(duct_flow_t), intent(in) :: self
      real(dp), intent(in) :: x, y
      real(dp) :: grad(2), bound
      call self%evaluate(x, y, .false., u, grad, bound)
   end function velocity

   !> (du/dx, du/dy) at (x, y) to the default tolerance, walls included.
   pure function velocity_gradient(self, x, y) result(grad)
      class(duct_flow_t), intent(in) :: self
      real(dp), intent(in) :: x, y
      real(dp) :: grad(2), u, bound
      call self%evaluate(x, y, .true., u, grad, bound)
   end function velocity_gradient

   !> u and, when want_gradient, (du/dx, du/dy) at (x, y), summed until the truncation bound
   !> of u (or of the gradient, when wanted) is below tolerance (absolute, default
   !> default_series_tolerance); bound: that bound for the values returned. u = 0 on and
   !> outside the walls; the gradient is zero at the corners (both walls hold the fluid) and
   !> outside.
   pure subroutine evaluate(self, x, y, want_gradient, u, grad, bound, tolerance)
      class(duct_flow_t), intent(in) :: self
      real(dp), intent(in) :: x, y
      logical, intent(in) :: want_gradient
      real(dp), intent(out) :: u, grad(2), bound
      real(dp), intent(in), optional :: tolerance
      logical :: inside, on_wall
      u = 0
      grad = 0
      bound = 0
      inside = abs(x) < self%half_width .and. abs(y) < self%half_height
      on_wall = abs(x) <= self%half_width .and. abs(y) <= self%half_height .and. .not. inside .and. &
                (abs(x) < self%half_width .or. abs(y) < self%half_height)
      if (inside .or. (want_gradient .and. on_wall)) &
         call oriented_series(self, x, y, want_gradient, tolerance, u, grad, bound)
      if (.not. inside) u = 0
   end subroutine evaluate

   !> The largest velocity, on the axis: u(0, 0) = u_max / U.
   pure real(dp) function centre_velocity(self)
      class(duct_flow_t), intent(in) :: self
      centre_velocity = self%velocity(0.0_dp, 0.0_dp)
   end function centre_velocity

   !> p(z) = p0 - G z.
   pure real(dp) function pressure(self, z, reference_pressure)
      class(duct_flow_t), intent(in) :: self
      real(dp), intent(in) :: z, reference_pressure
      pressure = reference_pressure - self%pressure_gradient * z
   end function pressure

   !> f = sigma . n at the point x(3) for the unit normal n (out of the fluid), p(0) = p0.
   pure function traction(self, x, normal, reference_pressure) result(f)
      class(duct_flow_t), intent(in) :: self
      real(dp), intent(in) :: x(3), normal(3), reference_pressure
      real(dp) :: f(3), g(3)
      g(1:2) = self%velocity_gradient(x(1), x(2))
      g(3) = 0
      f = -self%pressure(x(3), reference_pressure) * normal + normal(3) * g
      f(3) = f(3) + dot_product(g, normal)
   end function traction

   !> Picks the orientation with the faster decay at (x, y) and sums it; the gradient is
   !> returned in (x, y) order whatever the orientation.
   pure subroutine oriented_series(self, x, y, want_gradient, tolerance, u, grad, bound)
      class(duct_flow_t), intent(in) :: self
      real(dp), intent(in) :: x, y
      logical, intent(in) :: want_gradient
      real(dp), intent(in), optional :: tolerance
      real(dp), intent(out) :: u, grad(2), bound
      real(dp) :: tol, decay_x, decay_y, g_local(2)
      tol = default_series_tolerance
      if (present(tolerance)) tol = tolerance
      ! Decay exponents pi (b - |eta|) / (2 a) of the two orientations (cosine along x or y).
      decay_x = pi * (self%half_height - abs(y)) / (2 * self%half_width)
      decay_y = pi * (self%half_width - abs(x)) / (2 * self%half_height)
      if (decay_x >= decay_y) then
         call series(x, y, self%half_width, self%half_height, decay_x, self%pressure_gradient, want_gradient, tol, &
                     u, g_local, bound)
         grad = g_local
      else
         call series(y, x, self%half_height, self%half_width, decay_y, self%pressure_gradient, want_gradient, tol, &
                     u, g_local, bound)
         grad = g_local([2, 1])
      end if
   end subroutine oriented_series

   !> The series with the cosine along xi (half-extent a) and cosh along eta (half-extent b);
   !> decay = pi (b - |eta|) / (2 a). grad = (du/dxi, du/deta) when want_gradient, and the
   !> bound is then that of the gradient (the larger), else of u.
   pure subroutine series(xi, eta, a, b, decay, g, want_gradient, tol, u, grad, bound)
      real(dp), intent(in) :: xi, eta, a, b, decay, g, tol
      logical, intent(in) :: want_gradient
      real(dp), intent(out) :: u, grad(2), bound
      real(dp) :: r, alpha, ratio_c, ratio_s, e_eta, e_b, sgn, c_u, c_g, ci, si, sum_u, sum_gx, sum_ge
      integer :: i, k
      r = exp(-decay)
      c_u = 16.0_dp * a * a * g / pi**3
      c_g = 8.0_dp * a * g / pi**2
      sum_u = 0
      sum_gx = 0
      sum_ge = 0
      bound = huge(1.0_dp)
      do k = 0, max_terms - 1
         i = 2 * k + 1
         alpha = i * pi / (2 * a)
         ! cosh(alpha eta) / cosh(alpha b) and sinh(alpha |eta|) / cosh(alpha b), without overflow.
         e_eta = exp(-2 * alpha * abs(eta))
         e_b = exp(-2 * alpha * b)
         ratio_c = exp(alpha * (abs(eta) - b)) * (1.0_dp + e_eta) / (1.0_dp + e_b)
         ratio_s = sign(1.0_dp, eta) * exp(alpha * (abs(eta) - b)) * (1.0_dp - e_eta) / (1.0_dp + e_b)
         sgn = 1.0_dp - 2 * mod(k, 2)
         ci = cos(alpha * xi)
         sum_u = sum_u + sgn * ratio_c * ci / real(i, dp)**3
         if (want_gradient) then
            si = sin(alpha * xi)
            sum_gx = sum_gx + sgn * ratio_c * si / real(i, dp)**2
            sum_ge = sum_ge + sgn * ratio_s * ci / real(i, dp)**2
            bound = c_g * tail_bound(r, i + 2, 2)
         else
            bound = c_u * tail_bound(r, i + 2, 3)
         end if
         if (bound <= tol) exit
      end do
      u = 0.5_dp * g * (a * a - xi * xi) - c_u * sum_u
      grad = [-g * xi + c_g * sum_gx, -c_g * sum_ge]
   end subroutine series

   !> Bound on sum over odd j >= m of min(1, 2 r^j) / j^p (p = 2 or 3), m >= 3.
   pure real(dp) function tail_bound(r, m, p)
      real(dp), intent(in) :: r
      integer, intent(in) :: m, p
      real(dp) :: algebraic
      if (p == 3) then
         algebraic = 1.0_dp / (4.0_dp * real(m - 2, dp)**2)
      else
         algebraic = 1.0_dp / (2.0_dp * real(m - 2, dp))
      end if
      tail_bound = algebraic
      if (r < 1.0_dp) tail_bound = min(algebraic, 2 * r**m / (real(m, dp)**p * (1.0_dp - r * r)))
   end function tail_bound

end module duct_poiseuille
