!> Geometric diagnostics of a closed triangulated surface: area, enclosed volume, the
!> ellipsoid of inertia (L1, L2 in the shear plane, L3 along the vorticity axis x), the Taylor
!> parameter D12 and inclination theta, and the contour in the shear plane.
!>
!> The ellipsoid of inertia is the ellipsoid with the same volume second moments as the
!> capsule: M = integral (x - c)(x - c)^T dV = (V/5) diag(L1**2, L2**2, L3**2) in its axes.
module surface_diagnostics
   use capsim_kinds, only: dp
   use vector_algebra, only: cross
   use sphere_mesh, only: surface_mesh_t
   implicit none
   private
   public :: shape_measures_t, area_and_volume, shape_measures, shear_plane_contour

   type :: shape_measures_t
      real(dp) :: area = 0, volume = 0
      real(dp) :: centroid(3) = 0
      !> Semi-axes of the inertia ellipsoid: L1 >= L2 in the shear plane (yz), L3 along x.
      real(dp) :: l1 = 0, l2 = 0, l3 = 0
      real(dp) :: d12 = 0
      !> Angle of the L1 axis from the flow direction z towards the gradient direction y [rad].
      real(dp) :: theta = 0
   end type shape_measures_t

   interface
      subroutine dsyev(jobz, uplo, n, a, lda, w, work, lwork, info)
         import :: dp
         character, intent(in) :: jobz, uplo
         integer, intent(in) :: n, lda, lwork
         real(dp), intent(inout) :: a(lda, *)
         real(dp), intent(out) :: w(*), work(*)
         integer, intent(out) :: info
      end subroutine dsyev
   end interface

contains

   pure subroutine area_and_volume(mesh, x, area, volume)
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: area, volume
      integer :: t
      real(dp) :: p1(3), p2(3), p3(3)
      area = 0.0_dp
      volume = 0.0_dp
      do t = 1, mesh%n_tri
         p1 = x(:, mesh%tri(1, t))
         p2 = x(:, mesh%tri(2, t))
         p3 = x(:, mesh%tri(3, t))
         area = area + 0.5_dp * norm2(cross(p2 - p1, p3 - p1))
         volume = volume + dot_product(p1, cross(p2, p3)) / 6.0_dp
      end do
   end subroutine area_and_volume

   !> Volume moments from the tetrahedra (reference point, triangle); the reference point is
   !> the node mean, which keeps the second moments free of cancellation far from the origin.
   subroutine shape_measures(mesh, x, m)
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      type(shape_measures_t), intent(out) :: m
      real(dp) :: ref(3), p(3, 3), s(3), vt, first(3), second(3, 3), evec(3, 3), eval(3), work(64)
      real(dp) :: e1(3)
      integer :: t, k, info, ivort, i_a, i_b

      ref = sum(x(:, 1:mesh%n_nodes), dim=2) / mesh%n_nodes
      call area_and_volume(mesh, x, m%area, m%volume)
      first = 0.0_dp
      second = 0.0_dp
      do t = 1, mesh%n_tri
         do k = 1, 3
            p(:, k) = x(:, mesh%tri(k, t)) - ref
         end do
         vt = dot_product(p(:, 1), cross(p(:, 2), p(:, 3))) / 6.0_dp
         s = p(:, 1) + p(:, 2) + p(:, 3)
         first = first + vt * s / 4.0_dp
         ! integral_tet x x^T dV = V/20 (sum_k p_k p_k^T + s s^T), the 4th vertex being 0.
         second = second + vt / 20.0_dp * (matmul(p, transpose(p)) + spread(s, 2, 3) * spread(s, 1, 3))
      end do
      m%centroid = first / m%volume
      second = second - m%volume * spread(m%centroid, 2, 3) * spread(m%centroid, 1, 3)
      m%centroid = m%centroid + ref
      evec = second
      call dsyev('V', 'U', 3, evec, 3, eval, work, size(work), info)
      ! The axis closest to the vorticity direction x is L3; the other two lie in the shear plane.
      ivort = maxloc(abs(evec(1, :)), dim=1)
      i_a = merge(2, 1, ivort == 1)
      i_b = 6 - ivort - i_a
      if (eval(i_a) < eval(i_b)) then
         k = i_a
         i_a = i_b
         i_b = k
      end if
      m%l1 = sqrt(5.0_dp * max(eval(i_a), 0.0_dp) / m%volume)
      m%l2 = sqrt(5.0_dp * max(eval(i_b), 0.0_dp) / m%volume)
      m%l3 = sqrt(5.0_dp * max(eval(ivort), 0.0_dp) / m%volume)
      m%d12 = (m%l1 - m%l2) / (m%l1 + m%l2)
      e1 = evec(:, i_a)
      if (e1(3) < 0.0_dp) e1 = -e1
      m%theta = atan2(e1(2), e1(3))
      if (info /= 0) m%d12 = ieee_nan()
   end subroutine shape_measures

   !> Contour of the surface in the plane x = x0 (the shear plane through the centroid):
   !> one point per mesh edge that crosses the plane, ordered by angle around (y0, z0).
   subroutine shear_plane_contour(mesh, x, centre, y, z)
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :), centre(3)
      real(dp), allocatable, intent(out) :: y(:), z(:)
      real(dp), allocatable :: yy(:), zz(:), angle(:)
      integer, allocatable :: order(:)
      integer :: t, k, a, b, n, i, j, tmp
      real(dp) :: da, db, s

      allocate (yy(3 * mesh%n_tri), zz(3 * mesh%n_tri))
      n = 0
      do t = 1, mesh%n_tri
         do k = 1, 3
            a = mesh%tri(k, t)
            b = mesh%tri(mod(k, 3) + 1, t)
            ! Each edge appears in two triangles, once as a < b: take it there only.
            if (a > b) cycle
            da = x(1, a) - centre(1)
            db = x(1, b) - centre(1)
            if ((da < 0.0_dp .eqv. db < 0.0_dp) .or. da == db) cycle
            s = da / (da - db)
            n = n + 1
            yy(n) = x(2, a) + s * (x(2, b) - x(2, a))
            zz(n) = x(3, a) + s * (x(3, b) - x(3, a))
         end do
      end do
      allocate (angle(n), order(n))
      angle = atan2(yy(1:n) - centre(2), zz(1:n) - centre(3))
      order = [(i, i=1, n)]
      ! Insertion sort: a few hundred points, once per output.
      do i = 2, n
         j = i
         do while (j > 1)
            if (angle(order(j - 1)) <= angle(order(j))) exit
            tmp = order(j)
            order(j) = order(j - 1)
            order(j - 1) = tmp
            j = j - 1
         end do
      end do
      y = yy(order)
      z = zz(order)
   end subroutine shear_plane_contour

   real(dp) function ieee_nan()
      use, intrinsic :: ieee_arithmetic, only: ieee_value, ieee_quiet_nan
      ieee_nan = ieee_value(1.0_dp, ieee_quiet_nan)
   end function ieee_nan

end module surface_diagnostics
