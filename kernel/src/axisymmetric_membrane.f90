!> Axisymmetric membrane: frustum (conical ring) elements on the meridian, with nodal ring
!> forces as the exact gradient of the discrete strain energy.
!>
!> The meridian runs from the front pole (node 1, on the axis) to the rear pole (node n, on
!> the axis); element e joins nodes e and e+1. With reference length S0_e and mean reference
!> radius R0_e, each element carries the energy 2 pi R0_e S0_e w_s(I1, I2) with the
!> meridional stretch lambda_s = S_e/S0_e and the azimuthal stretch lambda_phi = r_e/R0_e
!> at its mid-point (one-point rule, O(h**2) like the 3D P1 elements). The same membrane_law
!> supplies w_s, so the 3D and axisymmetric models share their constitutive code.
module axisymmetric_membrane
   use capsim_kinds, only: dp, pi
   use membrane_law, only: membrane_law_t
   implicit none
   private
   public :: meridian_reference_t, meridian_forces, meridian_node_areas, meridian_area_volume, &
             meridian_volume_gradient

   type :: meridian_reference_t
      integer :: n_nodes = 0
      !> Reference (stress-free) element lengths and mean radii.
      real(dp), allocatable :: length0(:), radius0(:)
   contains
      procedure :: init => reference_init
   end type meridian_reference_t

contains

   !> `rz_ref(2, n)`: reference meridian (r, z), poles first and last.
   subroutine reference_init(self, rz_ref)
      class(meridian_reference_t), intent(inout) :: self
      real(dp), intent(in) :: rz_ref(:, :)
      integer :: e, n
      n = size(rz_ref, 2)
      self%n_nodes = n
      allocate (self%length0(n - 1), self%radius0(n - 1))
      do e = 1, n - 1
         self%length0(e) = norm2(rz_ref(:, e + 1) - rz_ref(:, e))
         self%radius0(e) = 0.5_dp * (rz_ref(1, e) + rz_ref(1, e + 1))
      end do
   end subroutine reference_init

   !> Ring forces F_k = -dE/d(r_k, z_k) (total force on the ring, units G_s l) and energy E.
   pure subroutine meridian_forces(ref, law, rz, force, energy)
      type(meridian_reference_t), intent(in) :: ref
      type(membrane_law_t), intent(in) :: law
      real(dp), intent(in) :: rz(:, :)
      real(dp), intent(out) :: force(:, :)
      real(dp), intent(out) :: energy
      integer :: e
      real(dp) :: d(2), s, lam_s, lam_p, w1, w2, dw_ds, dw_dp, weight, t(2)
      force = 0.0_dp
      energy = 0.0_dp
      do e = 1, ref%n_nodes - 1
         d = rz(:, e + 1) - rz(:, e)
         s = norm2(d)
         t = d / s
         lam_s = s / ref%length0(e)
         lam_p = 0.5_dp * (rz(1, e) + rz(1, e + 1)) / ref%radius0(e)
         call law%derivatives(lam_s**2 + lam_p**2 - 2.0_dp, (lam_s * lam_p)**2 - 1.0_dp, w1, w2)
         weight = 2.0_dp * pi * ref%radius0(e) * ref%length0(e)
         energy = energy + weight * law%energy(lam_s**2 + lam_p**2 - 2.0_dp, (lam_s * lam_p)**2 - 1.0_dp)
         ! dw/dlambda from dI1/dlambda = 2 lambda, dI2/dlambda_s = 2 lambda_s lambda_phi**2, ...
         dw_ds = 2.0_dp * lam_s * (w1 + w2 * lam_p**2)
         dw_dp = 2.0_dp * lam_p * (w1 + w2 * lam_s**2)
         ! dlambda_s/dx_(e+1) = t / S0, dlambda_phi/dr_e = dlambda_phi/dr_(e+1) = 1/(2 R0).
         force(:, e + 1) = force(:, e + 1) - weight * dw_ds * t / ref%length0(e)
         force(:, e) = force(:, e) + weight * dw_ds * t / ref%length0(e)
         force(1, e) = force(1, e) - weight * dw_dp / (2.0_dp * ref%radius0(e))
         force(1, e + 1) = force(1, e + 1) - weight * dw_dp / (2.0_dp * ref%radius0(e))
      end do
      ! The poles stay on the axis: their radial force is carried by the symmetry.
      force(1, 1) = 0.0_dp
      force(1, ref%n_nodes) = 0.0_dp
   end subroutine meridian_forces

   !> Area attached to each node: the frusta from the node to the mid-points of its elements
   !> (the dual cell). Unlike the hat-function area, this gives the Laplace pressure at the
   !> poles too (the hat-function area is 3/4 of the polar cap the pole's force acts on), and
   !> sum_k A_k f_k is the total force for f_k = F_k / A_k.
   pure subroutine meridian_node_areas(rz, area)
      real(dp), intent(in) :: rz(:, :)
      real(dp), intent(out) :: area(:)
      integer :: e
      real(dp) :: half, r_mid
      area = 0.0_dp
      do e = 1, size(rz, 2) - 1
         half = 0.5_dp * norm2(rz(:, e + 1) - rz(:, e))
         r_mid = 0.5_dp * (rz(1, e) + rz(1, e + 1))
         area(e) = area(e) + pi * (rz(1, e) + r_mid) * half
         area(e + 1) = area(e + 1) + pi * (rz(1, e + 1) + r_mid) * half
      end do
   end subroutine meridian_node_areas

   !> Surface area and enclosed volume of the body of revolution (frusta, exact).
   pure subroutine meridian_area_volume(rz, area, volume)
      real(dp), intent(in) :: rz(:, :)
      real(dp), intent(out) :: area, volume
      integer :: e
      real(dp) :: ra, rb
      area = 0.0_dp
      volume = 0.0_dp
      do e = 1, size(rz, 2) - 1
         ra = rz(1, e)
         rb = rz(1, e + 1)
         area = area + pi * (ra + rb) * norm2(rz(:, e + 1) - rz(:, e))
         ! Meridian from the front (high z) to the rear: z decreases, hence the sign.
         volume = volume - pi * (rz(2, e + 1) - rz(2, e)) * (ra * ra + ra * rb + rb * rb) / 3.0_dp
      end do
   end subroutine meridian_area_volume

   !> dV/d(r_k, z_k) of the frustum volume above.
   pure subroutine meridian_volume_gradient(rz, grad)
      real(dp), intent(in) :: rz(:, :)
      real(dp), intent(out) :: grad(:, :)
      integer :: e
      real(dp) :: ra, rb, dz, q
      grad = 0.0_dp
      do e = 1, size(rz, 2) - 1
         ra = rz(1, e)
         rb = rz(1, e + 1)
         dz = rz(2, e + 1) - rz(2, e)
         q = pi * (ra * ra + ra * rb + rb * rb) / 3.0_dp
         grad(2, e) = grad(2, e) + q
         grad(2, e + 1) = grad(2, e + 1) - q
         grad(1, e) = grad(1, e) - pi * dz * (2.0_dp * ra + rb) / 3.0_dp
         grad(1, e + 1) = grad(1, e + 1) - pi * dz * (ra + 2.0_dp * rb) / 3.0_dp
      end do
   end subroutine meridian_volume_gradient

end module axisymmetric_membrane
