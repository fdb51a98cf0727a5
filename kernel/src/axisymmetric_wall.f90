!> The tube boundary of the axisymmetric model (axisymmetric_operator): its elements (inlet
!> disk, cylinder, outlet disk; end points (r, z)), the ring single layer of a constant traction
!> on one element, the wall matrix W (traction -> velocity at the element mid-points) and its
!> LU, and W's left null vector (a uniform pressure on the closed boundary moves no fluid).
module axisymmetric_wall
   use capsim_kinds, only: dp
   use lapack_interfaces, only: dgetrf, dgetrs
   use ring_stokeslet, only: segment_integral
   implicit none
   private
   public :: tube_wall_elements, wall_element_velocity, wall_single_layer, factorise_wall, wall_left_null_vector, &
             remove_wall_flux

   !> Wall element sizes: fine over |z| < 2, growing geometrically (ratio wall_growth) to
   !> coarse_size towards the end sections (the tube length is a run option).
   real(dp), parameter :: fine_size = 0.04_dp, coarse_size = 0.3_dp, wall_growth = 1.2_dp
   integer, parameter :: disk_elements = 10

contains

   !> Wall elements of the tube boundary, inlet disk, cylinder, outlet disk (end points (r, z)).
   subroutine tube_wall_elements(tube_half_length, wall_a, wall_b)
      real(dp), intent(in) :: tube_half_length
      real(dp), allocatable, intent(out) :: wall_a(:, :), wall_b(:, :)
      real(dp), allocatable :: z_half(:), z(:)
      real(dp) :: h, zc
      integer :: k, nz, nh, m
      ! Half-cylinder node positions from z = 0 outwards.
      allocate (z_half(1000))
      nh = 1
      z_half(1) = 0.0_dp
      h = fine_size
      do while (z_half(nh) < tube_half_length - 1.0e-12_dp)
         zc = z_half(nh)
         if (zc >= 2.0_dp) h = min(h * wall_growth, coarse_size)
         nh = nh + 1
         z_half(nh) = min(zc + h, tube_half_length)
         ! Avoid a sliver at the end.
         if (tube_half_length - z_half(nh) < 0.3_dp * h) z_half(nh) = tube_half_length
      end do
      nz = 2 * nh - 1
      allocate (z(nz))
      z(nh:nz) = z_half(1:nh)
      z(1:nh - 1) = -z_half(nh:2:-1)
      m = disk_elements + (nz - 1) + disk_elements
      allocate (wall_a(2, m), wall_b(2, m))
      do k = 1, disk_elements
         wall_a(:, k) = [real(k - 1, dp) / disk_elements, -tube_half_length]
         wall_b(:, k) = [real(k, dp) / disk_elements, -tube_half_length]
      end do
      do k = 1, nz - 1
         wall_a(:, disk_elements + k) = [1.0_dp, z(k)]
         wall_b(:, disk_elements + k) = [1.0_dp, z(k + 1)]
      end do
      do k = 1, disk_elements
         wall_a(:, disk_elements + nz - 1 + k) = [1.0_dp - real(k - 1, dp) / disk_elements, tube_half_length]
         wall_b(:, disk_elements + nz - 1 + k) = [1.0_dp - real(k, dp) / disk_elements, tube_half_length]
      end do
   end subroutine tube_wall_elements

   !> Single layer of a constant traction g on wall element j at point (r0, z0); an element
   !> that contains the point (its own mid-point) is split there so that the log singularity
   !> sits at a segment end.
   pure function wall_element_velocity(wa, wb, g, r0, z0, own) result(u)
      real(dp), intent(in) :: wa(2), wb(2), g(2), r0, z0
      logical, intent(in) :: own
      real(dp) :: u(2), mid(2)
      if (own) then
         mid = 0.5_dp * (wa + wb)
         u = segment_integral(r0, z0, wa(1), wa(2), mid(1), mid(2), g, g, 2) + &
             segment_integral(r0, z0, mid(1), mid(2), wb(1), wb(2), g, g, 1)
      else
         u = segment_integral(r0, z0, wa(1), wa(2), wb(1), wb(2), g, g, 0)
      end if
   end function wall_element_velocity

   !> W (2 n_wall square: the single layer of a unit traction on element j at the mid-point of
   !> element i) for the elements wall_a -> wall_b with mid-points wall_mid, LU-factorised.
   subroutine factorise_wall(wall_a, wall_b, wall_mid, wall_lu, wall_pivot, stat, errmsg)
      real(dp), intent(in) :: wall_a(:, :), wall_b(:, :), wall_mid(:, :)
      real(dp), allocatable, intent(out) :: wall_lu(:, :)
      integer, allocatable, intent(out) :: wall_pivot(:)
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: i, j, m, n_wall, info
      n_wall = size(wall_a, 2)
      m = 2 * n_wall
      allocate (wall_lu(m, m), wall_pivot(m))
      !$omp parallel do default(none) shared(wall_a, wall_b, wall_mid, wall_lu, n_wall) private(i, j) schedule(dynamic)
      do j = 1, n_wall
         do i = 1, n_wall
            wall_lu(2 * i - 1:2 * i, 2 * j - 1) = wall_element_velocity(wall_a(:, j), wall_b(:, j), [1.0_dp, 0.0_dp], &
                                                                        wall_mid(1, i), wall_mid(2, i), i == j)
            wall_lu(2 * i - 1:2 * i, 2 * j) = wall_element_velocity(wall_a(:, j), wall_b(:, j), [0.0_dp, 1.0_dp], &
                                                                    wall_mid(1, i), wall_mid(2, i), i == j)
         end do
      end do
      !$omp end parallel do
      call dgetrf(m, m, wall_lu, m, wall_pivot, info)
      stat = info
      errmsg = ''
      if (info /= 0) errmsg = 'tube wall matrix is singular (LAPACK dgetrf info /= 0)'
   end subroutine factorise_wall

   !> Wall single layer (without 1/(8 pi)) of the wall traction g at point x.
   pure function wall_single_layer(wall_a, wall_b, g, x) result(acc)
      real(dp), intent(in) :: wall_a(:, :), wall_b(:, :), g(:), x(2)
      real(dp) :: acc(2)
      integer :: i
      acc = 0.0_dp
      do i = 1, size(wall_a, 2)
         acc = acc + wall_element_velocity(wall_a(:, i), wall_b(:, i), g(2 * i - 1:2 * i), x(1), x(2), .false.)
      end do
   end function wall_single_layer

   !> W is singular along a uniform pressure on B (it moves no fluid inside: W's smallest
   !> singular value is ~1e-11 of its largest), so W g = b needs b without a component along
   !> W's left null vector (the flux of b through B). The single layers have none (to the
   !> quadrature error), but the double layer of U carries the flux of U through the membrane,
   !> dV/dt, which the physical U lacks and the discrete one has at the discretisation error:
   !> W**-1 turned it, and the quadrature noise, into tractions of 1e7 whose velocity at the
   !> nodes was noise. Removing that component from the right-hand sides b(:, j) solves for
   !> the flux-free part of the double layer, which is the whole of it for the physical U.
   subroutine remove_wall_flux(wall_null, b)
      real(dp), intent(in) :: wall_null(:)
      real(dp), intent(inout) :: b(:, :)
      integer :: j
      do j = 1, size(b, 2)
         b(:, j) = b(:, j) - dot_product(wall_null, b(:, j)) * wall_null
      end do
   end subroutine remove_wall_flux

   !> W's left null vector (unit norm) by inverse iteration on W**T with the LU of W.
   subroutine wall_left_null_vector(wall_lu, wall_pivot, wall_null)
      real(dp), intent(in) :: wall_lu(:, :)
      integer, intent(in) :: wall_pivot(:)
      real(dp), intent(out) :: wall_null(:)
      real(dp) :: x(size(wall_null), 1)
      integer :: it, m, info
      m = size(wall_null)
      x = 1.0_dp
      do it = 1, 4
         call dgetrs('T', m, 1, wall_lu, m, wall_pivot, x, m, info)
         x = x / norm2(x)
      end do
      wall_null = x(:, 1)
   end subroutine wall_left_null_vector

end module axisymmetric_wall
