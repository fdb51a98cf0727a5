!> bending_probe: measures the discrete bending energies (membrane_bending in 3D,
!> axisymmetric_bending on the meridian) and prints "key value" lines; pytest
!> (tests/kernel/test_bending.py) holds the references and tolerances. K_B = 1, reference the
!> unit sphere.
!>
!>   bending_probe fd LEVEL AMP            forces vs central differences of E on a perturbed sphere
!>   bending_probe sphere LEVEL R          unit-sphere reference scaled to radius R
!>   bending_probe spheroid LEVEL B C      energy of the spheroid (B, B, C)
!>   bending_probe axi-fd N AMP            the same three for the meridian of N elements
!>   bending_probe axi-sphere N R
!>   bending_probe axi-spheroid N B C
program bending_probe
   use capsim_kinds, only: dp, pi
   use command_args, only: int_arg, real_arg
   use vector_algebra, only: cross
   use sphere_mesh, only: surface_mesh_t, icosphere
   use membrane_bending, only: bending_t
   use axisymmetric_bending, only: meridian_bending_t
   implicit none

   character(len=64) :: command
   call get_command_argument(1, command)
   select case (command)
   case ('fd')
      call probe_fd(int_arg(2), real_arg(3))
   case ('sphere')
      call probe_sphere(int_arg(2), real_arg(3))
   case ('spheroid')
      call probe_spheroid(int_arg(2), real_arg(3), real_arg(4))
   case ('axi-fd')
      call probe_axi_fd(int_arg(2), real_arg(3))
   case ('axi-sphere')
      call probe_axi_sphere(int_arg(2), real_arg(3))
   case ('axi-spheroid')
      call probe_axi_spheroid(int_arg(2), real_arg(3), real_arg(4))
   case default
      write (*, '(a)') 'usage: bending_probe fd|sphere|spheroid|axi-fd|axi-sphere|axi-spheroid ...'
      error stop 2
   end select

contains

   subroutine unit_sphere(level, mesh, x, bend)
      integer, intent(in) :: level
      type(surface_mesh_t), intent(out) :: mesh
      real(dp), allocatable, intent(out) :: x(:, :)
      type(bending_t), intent(out) :: bend
      integer :: stat
      character(len=:), allocatable :: errmsg
      call icosphere(level, mesh, x, stat, errmsg)
      if (stat /= 0) error stop errmsg
      call bend%init(mesh, x, 1.0_dp)
   end subroutine unit_sphere

   !> Deterministic pseudo-random numbers in [-1, 1] (the test needs no real randomness).
   pure real(dp) function wobble(i, k)
      integer, intent(in) :: i, k
      wobble = 2.0_dp * (modulo(sin(12.9898_dp * i + 78.233_dp * k) * 43758.5453_dp, 1.0_dp)) - 1.0_dp
   end function wobble

   subroutine probe_fd(level, amp)
      integer, intent(in) :: level
      real(dp), intent(in) :: amp
      type(surface_mesh_t) :: mesh
      type(bending_t) :: bend
      real(dp), allocatable :: x(:, :), force(:, :), fd(:, :)
      real(dp) :: energy, ep, em, h, torque(3)
      integer :: i, k
      call unit_sphere(level, mesh, x, bend)
      do i = 1, mesh%n_nodes
         do k = 1, 3
            x(k, i) = x(k, i) * 1.1_dp + amp * wobble(i, k)
         end do
      end do
      allocate (force(3, mesh%n_nodes), fd(3, mesh%n_nodes))
      force = 0
      energy = 0
      call bend%add_forces(mesh, x, force, energy)
      h = 1.0e-6_dp
      do i = 1, mesh%n_nodes
         do k = 1, 3
            x(k, i) = x(k, i) + h
            ep = bend%energy_at(mesh, x)
            x(k, i) = x(k, i) - 2 * h
            em = bend%energy_at(mesh, x)
            x(k, i) = x(k, i) + h
            fd(k, i) = -(ep - em) / (2 * h)
         end do
      end do
      torque = 0
      do i = 1, mesh%n_nodes
         torque = torque + cross(x(:, i), force(:, i))
      end do
      write (*, '(a,es24.16)') 'energy ', energy
      write (*, '(a,es24.16)') 'energy_recomputed ', bend%energy_at(mesh, x)
      write (*, '(a,es24.16)') 'max_force ', maxval(abs(force))
      write (*, '(a,es24.16)') 'fd_max_error_rel ', maxval(abs(fd - force)) / maxval(abs(force))
      write (*, '(a,es24.16)') 'net_force_rel ', norm2(sum(force, dim=2)) / maxval(abs(force))
      write (*, '(a,es24.16)') 'net_torque_rel ', norm2(torque) / (maxval(abs(force)) * maxval(abs(x)))
   end subroutine probe_fd

   subroutine probe_sphere(level, radius)
      integer, intent(in) :: level
      real(dp), intent(in) :: radius
      type(surface_mesh_t) :: mesh
      type(bending_t) :: bend
      real(dp), allocatable :: x(:, :), force(:, :)
      real(dp) :: energy, radial, pressure, worst
      integer :: i, q
      call unit_sphere(level, mesh, x, bend)
      x = radius * x
      allocate (force(3, mesh%n_nodes))
      force = 0
      energy = 0
      call bend%add_forces(mesh, x, force, energy)
      radial = 0
      worst = 0
      ! Continuum load: p = -(dE/dR) / (4 pi R**2) = 4 (1 - R) / R**2 (outward), per node on
      ! its Voronoi area (bend's work arrays hold them at x).
      do i = 1, mesh%n_nodes
         radial = radial + dot_product(force(:, i), x(:, i)) / norm2(x(:, i))
         pressure = 0
         do q = mesh%node_tri_start(i), mesh%node_tri_start(i + 1) - 1
            pressure = pressure + bend%corner_area(mesh%node_tri_vertex(q), mesh%node_tri(q))
         end do
         pressure = dot_product(force(:, i), x(:, i)) / norm2(x(:, i)) / pressure
         worst = max(worst, abs(pressure / (4.0_dp * (1.0_dp - radius) / radius**2) - 1.0_dp))
      end do
      write (*, '(a,es24.16)') 'energy ', energy
      write (*, '(a,es24.16)') 'radial_force_sum ', radial
      write (*, '(a,es24.16)') 'pressure_max_rel_error ', worst
      write (*, '(a,es24.16)') 'max_force ', maxval(abs(force))
      write (*, '(a,es24.16)') 'c0_mean ', sum(bend%c0) / mesh%n_nodes
      write (*, '(a,es24.16)') 'c0_max_dev ', maxval(abs(bend%c0 - 2.0_dp))
   end subroutine probe_sphere

   subroutine probe_spheroid(level, b, c)
      integer, intent(in) :: level
      real(dp), intent(in) :: b, c
      type(surface_mesh_t) :: mesh
      type(bending_t) :: bend
      real(dp), allocatable :: x(:, :)
      call unit_sphere(level, mesh, x, bend)
      x(1:2, :) = b * x(1:2, :)
      x(3, :) = c * x(3, :)
      write (*, '(a,es24.16)') 'energy ', bend%energy_at(mesh, x)
   end subroutine probe_spheroid

   !> Unit-sphere meridian of n elements, poles first and last.
   subroutine meridian(n, rz, bend)
      integer, intent(in) :: n
      real(dp), allocatable, intent(out) :: rz(:, :)
      type(meridian_bending_t), intent(out) :: bend
      integer :: k
      allocate (rz(2, n + 1))
      do k = 1, n + 1
         rz(:, k) = [sin(pi * (k - 1) / n), cos(pi * (k - 1) / n)]
      end do
      rz(1, [1, n + 1]) = 0
      call bend%init(rz, 1.0_dp)
   end subroutine meridian

   subroutine probe_axi_fd(n, amp)
      integer, intent(in) :: n
      real(dp), intent(in) :: amp
      type(meridian_bending_t) :: bend
      real(dp), allocatable :: rz(:, :), force(:, :), fd(:, :)
      real(dp) :: energy, h, ep, em
      integer :: k, c
      call meridian(n, rz, bend)
      do k = 1, n + 1
         do c = 1, 2
            rz(c, k) = rz(c, k) * 1.1_dp + amp * wobble(k, c)
         end do
      end do
      rz(1, [1, n + 1]) = 0
      allocate (force(2, n + 1), fd(2, n + 1))
      force = 0
      energy = 0
      call bend%add_forces(rz, force, energy)
      h = 1.0e-6_dp
      fd = 0
      do k = 1, n + 1
         do c = 1, 2
            ! The poles stay on the axis: their radial coordinate is no degree of freedom.
            if (c == 1 .and. (k == 1 .or. k == n + 1)) cycle
            rz(c, k) = rz(c, k) + h
            ep = bend%energy_at(rz)
            rz(c, k) = rz(c, k) - 2 * h
            em = bend%energy_at(rz)
            rz(c, k) = rz(c, k) + h
            fd(c, k) = -(ep - em) / (2 * h)
         end do
      end do
      write (*, '(a,es24.16)') 'energy ', energy
      write (*, '(a,es24.16)') 'max_force ', maxval(abs(force))
      write (*, '(a,es24.16)') 'fd_max_error_rel ', maxval(abs(fd - force)) / maxval(abs(force))
      write (*, '(a,es24.16)') 'net_axial_force_rel ', abs(sum(force(2, :))) / maxval(abs(force))
   end subroutine probe_axi_fd

   subroutine probe_axi_sphere(n, radius)
      integer, intent(in) :: n
      real(dp), intent(in) :: radius
      type(meridian_bending_t) :: bend
      real(dp), allocatable :: rz(:, :), force(:, :)
      real(dp) :: energy, radial
      integer :: k
      call meridian(n, rz, bend)
      rz = radius * rz
      allocate (force(2, n + 1))
      force = 0
      energy = 0
      call bend%add_forces(rz, force, energy)
      radial = 0
      do k = 1, n + 1
         radial = radial + dot_product(force(:, k), rz(:, k)) / norm2(rz(:, k))
      end do
      write (*, '(a,es24.16)') 'energy ', energy
      write (*, '(a,es24.16)') 'radial_force_sum ', radial
      write (*, '(a,es24.16)') 'max_force ', maxval(abs(force))
      write (*, '(a,es24.16)') 'c0_max_dev ', maxval(abs(bend%c0 - 2.0_dp))
   end subroutine probe_axi_sphere

   subroutine probe_axi_spheroid(n, b, c)
      integer, intent(in) :: n
      real(dp), intent(in) :: b, c
      type(meridian_bending_t) :: bend
      real(dp), allocatable :: rz(:, :)
      call meridian(n, rz, bend)
      rz(1, :) = b * rz(1, :)
      rz(2, :) = c * rz(2, :)
      write (*, '(a,es24.16)') 'energy ', bend%energy_at(rz)
   end subroutine probe_axi_spheroid

end program bending_probe
