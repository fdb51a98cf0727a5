!> Bending stiffness of the axisymmetric membrane: the discrete Helfrich energy of
!> membrane_bending on the meridian of frusta, with ring forces as its exact gradient.
!>
!> Continuum: E = (K_B/2) int (kappa_s + kappa_phi - c0)**2 dA, c0 the reference curvature.
!> On a body of revolution made of frusta the mean curvature is concentrated: kappa_s on the
!> rings at the nodes (the meridian turns by psi_k there, a ring of length 2 pi r_k), and
!> kappa_phi = n_r / r on each frustum, whose integral over element e is exactly
!> 2 pi (z_e - z_(e+1)) (n_r = -dz/ds for a meridian running from the front pole to the rear).
!> Node k's dual cell (the frusta from the node to its elements' mid-points, the areas A_k of
!> meridian_node_areas) then carries
!>     S_k = 2 pi r_k psi_k + pi (z_(k-1) - z_(k+1))   (interior nodes),
!>     S_1 = pi (z_1 - z_2),  S_n = pi (z_(n-1) - z_n)  (poles: the cone tip has no ring),
!> the axisymmetric analogue of the 3D edge sum (1/2) sum |e| theta_e, and
!>     E = (K_B/2) sum_k (S_k - c_k A_k)**2 / A_k,   c_k = S_k / A_k of the reference meridian,
!> so the reference shape is force-free to round-off, as in 3D. On a sphere, S_k / A_k -> 2/R.
module axisymmetric_bending
   use capsim_kinds, only: dp, pi
   implicit none
   private
   public :: meridian_bending_t

   type :: meridian_bending_t
      !> Bending modulus K_B in the caller's units (k_b G_s a**2); 0: no bending.
      real(dp) :: kb = 0
      !> Reference curvature kappa_s + kappa_phi of each node's dual cell.
      real(dp), allocatable :: c0(:)
   contains
      procedure :: init => bending_init
      procedure :: add_forces
      procedure :: energy_at
   end type meridian_bending_t

contains

   subroutine bending_init(self, rz_ref, kb)
      class(meridian_bending_t), intent(inout) :: self
      real(dp), intent(in) :: rz_ref(:, :), kb
      real(dp) :: s(size(rz_ref, 2)), area(size(rz_ref, 2))
      self%kb = kb
      call curvature_sums(rz_ref, s, area)
      self%c0 = s / area
   end subroutine bending_init

   !> Integrated curvature S_k and dual-cell area A_k of every node.
   pure subroutine curvature_sums(rz, s, area)
      real(dp), intent(in) :: rz(:, :)
      real(dp), intent(out) :: s(:), area(:)
      integer :: n, k, e
      real(dp) :: d1(2), d2(2), len_e
      n = size(rz, 2)
      s(1) = pi * (rz(2, 1) - rz(2, 2))
      s(n) = pi * (rz(2, n - 1) - rz(2, n))
      do k = 2, n - 1
         d1 = rz(:, k) - rz(:, k - 1)
         d2 = rz(:, k + 1) - rz(:, k)
         s(k) = 2.0_dp * pi * rz(1, k) * turning_angle(d1, d2) + pi * (rz(2, k - 1) - rz(2, k + 1))
      end do
      area = 0
      do e = 1, n - 1
         len_e = norm2(rz(:, e + 1) - rz(:, e))
         area(e) = area(e) + 0.25_dp * pi * (3.0_dp * rz(1, e) + rz(1, e + 1)) * len_e
         area(e + 1) = area(e + 1) + 0.25_dp * pi * (rz(1, e) + 3.0_dp * rz(1, e + 1)) * len_e
      end do
   end subroutine curvature_sums

   !> Angle by which the meridian turns from direction d1 to d2, > 0 where the body is convex.
   pure real(dp) function turning_angle(d1, d2) result(psi)
      real(dp), intent(in) :: d1(2), d2(2)
      psi = atan2(d1(2) * d2(1) - d1(1) * d2(2), dot_product(d1, d2))
   end function turning_angle

   pure real(dp) function energy_at(self, rz) result(energy)
      class(meridian_bending_t), intent(in) :: self
      real(dp), intent(in) :: rz(:, :)
      real(dp) :: s(size(rz, 2)), area(size(rz, 2))
      call curvature_sums(rz, s, area)
      energy = 0.5_dp * self%kb * sum(area * (s / area - self%c0)**2)
   end function energy_at

   !> force += -dE/d(r_k, z_k) (ring forces; the poles' radial component is left out, as in
   !> meridian_forces), energy += E.
   pure subroutine add_forces(self, rz, force, energy)
      class(meridian_bending_t), intent(in) :: self
      real(dp), intent(in) :: rz(:, :)
      real(dp), intent(inout) :: force(:, :), energy
      real(dp) :: s(size(rz, 2)), area(size(rz, 2)), de_ds(size(rz, 2)), de_da(size(rz, 2))
      real(dp) :: grad(2, size(rz, 2)), u, d1(2), d2(2), x, y, q, dpsi1(2), dpsi2(2), len_e, t(2), w
      integer :: n, k, e
      n = size(rz, 2)
      call curvature_sums(rz, s, area)
      ! E_k = (K/2) A_k u**2, u = S_k/A_k - c_k: dE/dS_k = K u, dE/dA_k = -(K/2) u (u + 2 c_k).
      do k = 1, n
         u = s(k) / area(k) - self%c0(k)
         energy = energy + 0.5_dp * self%kb * area(k) * u**2
         de_ds(k) = self%kb * u
         de_da(k) = -0.5_dp * self%kb * u * (u + 2.0_dp * self%c0(k))
      end do
      grad = 0
      grad(2, 1) = grad(2, 1) + pi * de_ds(1)
      grad(2, 2) = grad(2, 2) - pi * de_ds(1)
      grad(2, n - 1) = grad(2, n - 1) + pi * de_ds(n)
      grad(2, n) = grad(2, n) - pi * de_ds(n)
      do k = 2, n - 1
         d1 = rz(:, k) - rz(:, k - 1)
         d2 = rz(:, k + 1) - rz(:, k)
         ! psi = atan2(y, x): dpsi = (x dy - y dx) / (x**2 + y**2), with dy/dd1 = (-d2_z, d2_r),
         ! dy/dd2 = (d1_z, -d1_r), dx/dd1 = d2, dx/dd2 = d1.
         y = d1(2) * d2(1) - d1(1) * d2(2)
         x = dot_product(d1, d2)
         q = 1.0_dp / (x**2 + y**2)
         dpsi1 = q * (x * [-d2(2), d2(1)] - y * d2)
         dpsi2 = q * (x * [d1(2), -d1(1)] - y * d1)
         w = 2.0_dp * pi * rz(1, k) * de_ds(k)
         grad(:, k - 1) = grad(:, k - 1) - w * dpsi1
         grad(:, k) = grad(:, k) + w * (dpsi1 - dpsi2)
         grad(:, k + 1) = grad(:, k + 1) + w * dpsi2
         grad(1, k) = grad(1, k) + 2.0_dp * pi * atan2(y, x) * de_ds(k)
         grad(2, k - 1) = grad(2, k - 1) + pi * de_ds(k)
         grad(2, k + 1) = grad(2, k + 1) - pi * de_ds(k)
      end do
      do e = 1, n - 1
         t = rz(:, e + 1) - rz(:, e)
         len_e = norm2(t)
         t = t / len_e
         ! A_e gains pi (3 r_e + r_(e+1)) L/4, A_(e+1) gains pi (r_e + 3 r_(e+1)) L/4.
         w = 0.25_dp * pi * (de_da(e) * (3.0_dp * rz(1, e) + rz(1, e + 1)) + de_da(e + 1) * (rz(1, e) + 3.0_dp * rz(1, e + 1)))
         grad(:, e + 1) = grad(:, e + 1) + w * t
         grad(:, e) = grad(:, e) - w * t
         grad(1, e) = grad(1, e) + 0.25_dp * pi * len_e * (3.0_dp * de_da(e) + de_da(e + 1))
         grad(1, e + 1) = grad(1, e + 1) + 0.25_dp * pi * len_e * (de_da(e) + 3.0_dp * de_da(e + 1))
      end do
      grad(1, 1) = 0
      grad(1, n) = 0
      force = force - grad
   end subroutine add_forces

end module axisymmetric_bending
