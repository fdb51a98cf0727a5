!> kernel_probe: measures one numerical property of a kernel module and prints it as
!> "key value" lines. pytest (tests/kernel) runs it and asserts the physics, so every
!> tolerance lives in one visible place.
!>
!>   kernel_probe mesh LEVEL
!>   kernel_probe uniaxial LAW NU_S C LAMBDA1
!>   kernel_probe fd-forces LAW NU_S C LEVEL
!>   kernel_probe laplace LAW NU_S C LAMBDA LEVEL
!>   kernel_probe translate LEVEL DUFFY_ORDER NEAR_LEVELS
!>   kernel_probe axi-fd LAW NU_S C N_ELEMENTS
!>   kernel_probe axi-laplace LAW NU_S C LAMBDA N_ELEMENTS
!>   kernel_probe tube-jacobian A_OVER_L CA [KB]   (incremental vs brute-force Jacobian)
!>   kernel_probe bench LEVEL REPEATS      (seconds per velocity evaluation and per RK2 step)
!>   kernel_probe rest LAW NU_S C ALPHA LEVEL STEPS   (pre-stressed capsule, no outer flow)
program kernel_probe
   use capsim_kinds, only: dp, pi
   use command_args, only: int_arg, real_arg, string_arg
   use sphere_mesh, only: surface_mesh_t, icosphere
   use membrane_law, only: membrane_law_t, make_membrane_law
   use membrane_forces, only: membrane_reference_t, membrane_nodal_forces
   use stokes_single_layer, only: single_layer_t, triangle_areas, node_areas
   use surface_diagnostics, only: area_and_volume
   implicit none

   character(len=64) :: command
   call get_command_argument(1, command)
   select case (command)
   case ('mesh')
      call probe_mesh(int_arg(2))
   case ('uniaxial')
      call probe_uniaxial(law_arg(2), real_arg(5))
   case ('fd-forces')
      call probe_fd_forces(law_arg(2), int_arg(5))
   case ('laplace')
      call probe_laplace(law_arg(2), real_arg(5), int_arg(6))
   case ('axi-fd')
      call probe_axi_fd(law_arg(2), int_arg(5))
   case ('axi-laplace')
      call probe_axi_laplace(law_arg(2), real_arg(5), int_arg(6))
   case ('tube-jacobian')
      call probe_tube_jacobian(real_arg(2), real_arg(3))
   case ('bench')
      call probe_bench(int_arg(2), int_arg(3))
   case ('translate')
      call probe_translate(int_arg(2), int_arg(3), int_arg(4))
   case ('rest')
      call probe_rest(real_arg(5), int_arg(6), int_arg(7))
   case default
      write (*, '(a)') 'usage: kernel_probe mesh|uniaxial|fd-forces|laplace|translate ...'
      error stop 2
   end select

contains



   type(membrane_law_t) function law_arg(k)
      integer, intent(in) :: k
      character(len=64) :: s
      integer :: stat
      character(len=:), allocatable :: errmsg
      call get_command_argument(k, s)
      call make_membrane_law(trim(s), real_arg(k + 1), real_arg(k + 2), law_arg, stat, errmsg)
      if (stat /= 0) error stop errmsg
   end function law_arg

   subroutine sphere(level, mesh, x)
      integer, intent(in) :: level
      type(surface_mesh_t), intent(out) :: mesh
      real(dp), allocatable, intent(out) :: x(:, :)
      integer :: stat
      character(len=:), allocatable :: errmsg
      call icosphere(level, mesh, x, stat, errmsg)
      if (stat /= 0) error stop errmsg
   end subroutine sphere

   subroutine probe_mesh(level)
      integer, intent(in) :: level
      type(surface_mesh_t) :: mesh
      real(dp), allocatable :: x(:, :)
      integer :: t, k, a, b, unmatched
      real(dp) :: area, volume, hmin, hmax, h
      integer, allocatable :: directed(:, :)
      call sphere(level, mesh, x)
      call area_and_volume(mesh, x, area, volume)
      ! Closed, consistently oriented 2-manifold: every directed edge (a,b) has exactly one (b,a).
      allocate (directed(2, 3 * mesh%n_tri))
      hmin = huge(1.0_dp)
      hmax = 0
      do t = 1, mesh%n_tri
         do k = 1, 3
            a = mesh%tri(k, t)
            b = mesh%tri(mod(k, 3) + 1, t)
            directed(:, 3 * (t - 1) + k) = [a, b]
            h = norm2(x(:, a) - x(:, b))
            hmin = min(hmin, h)
            hmax = max(hmax, h)
         end do
      end do
      unmatched = 0
      do k = 1, size(directed, 2)
         if (count(directed(1, :) == directed(2, k) .and. directed(2, :) == directed(1, k)) /= 1) &
            unmatched = unmatched + 1
      end do
      write (*, '(a,i0)') 'n_nodes ', mesh%n_nodes
      write (*, '(a,i0)') 'n_tri ', mesh%n_tri
      write (*, '(a,i0)') 'unmatched_edges ', unmatched
      write (*, '(a,es24.16)') 'area ', area
      write (*, '(a,es24.16)') 'volume ', volume
      write (*, '(a,es24.16)') 'h_min ', hmin
      write (*, '(a,es24.16)') 'h_max ', hmax
      write (*, '(a,es24.16)') 'max_radius_error ', maxval(abs(norm2(x, dim=1) - 1.0_dp))
   end subroutine probe_mesh

   !> One triangle under uniform in-plane stretch x = diag(lambda1, lambda2) X. The tension is
   !> measured from the element's nodal forces by virtual work, T1 = -(1/(A0 lambda2)) sum F.dx/dlambda1,
   !> and lambda2 is found by bisection so that T2 = 0 (uniaxial tension).
   subroutine probe_uniaxial(law, lambda1)
      type(membrane_law_t), intent(in) :: law
      real(dp), intent(in) :: lambda1
      real(dp) :: lo, hi, mid, t1, t2, t1_law, t2_law
      integer :: it
      lo = 0.2_dp
      hi = 1.5_dp
      do it = 1, 200
         mid = 0.5_dp * (lo + hi)
         call fe_tensions(law, lambda1, mid, t1, t2)
         if (t2 > 0.0_dp) then
            hi = mid
         else
            lo = mid
         end if
      end do
      call fe_tensions(law, lambda1, mid, t1, t2)
      call law%tensions(lambda1, mid, t1_law, t2_law)
      write (*, '(a,es24.16)') 'lambda2 ', mid
      write (*, '(a,es24.16)') 't1 ', t1
      write (*, '(a,es24.16)') 't2 ', t2
      write (*, '(a,es24.16)') 't1_law ', t1_law
      write (*, '(a,es24.16)') 't2_law ', t2_law
   end subroutine probe_uniaxial

   subroutine fe_tensions(law, l1, l2, t1, t2)
      type(membrane_law_t), intent(in) :: law
      real(dp), intent(in) :: l1, l2
      real(dp), intent(out) :: t1, t2
      type(surface_mesh_t) :: mesh
      type(membrane_reference_t) :: ref
      real(dp) :: xr(3, 3), x(3, 3), force(3, 3), energy
      mesh%n_nodes = 3
      mesh%n_tri = 1
      mesh%tri = reshape([1, 2, 3], [3, 1])
      call mesh%build_adjacency()
      ! A generic (not axis-aligned) triangle, so that the test does not rely on symmetry.
      xr = reshape([0.0_dp, 0.0_dp, 0.0_dp, 1.0_dp, 0.2_dp, 0.0_dp, 0.3_dp, 0.9_dp, 0.0_dp], [3, 3])
      call ref%init(mesh, xr)
      x = xr
      x(1, :) = l1 * xr(1, :)
      x(2, :) = l2 * xr(2, :)
      call membrane_nodal_forces(ref, mesh, law, x, force, energy)
      t1 = -sum(force(1, :) * xr(1, :)) / (ref%area0(1) * l2)
      t2 = -sum(force(2, :) * xr(2, :)) / (ref%area0(1) * l1)
   end subroutine fe_tensions

   !> Forces against central finite differences of the energy, and invariance under rigid motion.
   subroutine probe_fd_forces(law, level)
      type(membrane_law_t), intent(in) :: law
      integer, intent(in) :: level
      type(surface_mesh_t) :: mesh
      type(membrane_reference_t) :: ref
      real(dp), allocatable :: xr(:, :), x(:, :), force(:, :), f2(:, :), xp(:, :), noise(:, :)
      real(dp) :: energy, ep, em, fd, err, scale, eps, rot(3, 3), c, s, torque(3)
      integer :: i, k, sample
      call sphere(level, mesh, xr)
      call ref%init(mesh, xr)
      allocate (noise(3, mesh%n_nodes), force(3, mesh%n_nodes), f2(3, mesh%n_nodes))
      call random_seed_fixed()
      call random_number(noise)
      ! A large, non-uniform deformation: stretch along z, shear, plus nodal noise.
      x = xr
      x(3, :) = 1.4_dp * xr(3, :) + 0.3_dp * xr(2, :)
      x(1, :) = 0.8_dp * xr(1, :)
      x = x + 0.05_dp * (noise - 0.5_dp)
      call membrane_nodal_forces(ref, mesh, law, x, force, energy)
      scale = maxval(abs(force))
      eps = 1.0e-6_dp
      err = 0
      xp = x
      do sample = 1, min(mesh%n_nodes, 40)
         i = 1 + mod(37 * sample, mesh%n_nodes)
         do k = 1, 3
            xp(k, i) = x(k, i) + eps
            call membrane_nodal_forces(ref, mesh, law, xp, f2, ep)
            xp(k, i) = x(k, i) - eps
            call membrane_nodal_forces(ref, mesh, law, xp, f2, em)
            xp(k, i) = x(k, i)
            fd = -(ep - em) / (2 * eps)
            err = max(err, abs(fd - force(k, i)))
         end do
      end do
      write (*, '(a,es24.16)') 'fd_max_error_rel ', err / scale
      torque = 0
      do i = 1, mesh%n_nodes
         torque = torque + [x(2, i) * force(3, i) - x(3, i) * force(2, i), &
                            x(3, i) * force(1, i) - x(1, i) * force(3, i), &
                            x(1, i) * force(2, i) - x(2, i) * force(1, i)]
      end do
      write (*, '(a,es24.16)') 'net_force_rel ', norm2(sum(force, dim=2)) / scale
      write (*, '(a,es24.16)') 'net_torque_rel ', norm2(torque) / scale
      ! Rigid motion of the reference state: zero force.
      c = cos(0.7_dp)
      s = sin(0.7_dp)
      rot = reshape([c, s, 0.0_dp, -s * c, c * c, s, s * s, -s * c, c], [3, 3])
      x = matmul(rot, xr)
      do i = 1, mesh%n_nodes
         x(:, i) = x(:, i) + [0.3_dp, -1.2_dp, 2.0_dp]
      end do
      call membrane_nodal_forces(ref, mesh, law, x, force, energy)
      write (*, '(a,es24.16)') 'rigid_max_force ', maxval(abs(force))
      write (*, '(a,es24.16)') 'rigid_energy ', energy
   end subroutine probe_fd_forces

   !> Sphere of reference radius 1 inflated to radius lambda: the force density must be the
   !> Laplace pressure 2 T / R along the inward normal, T the isotropic tension of the law.
   subroutine probe_laplace(law, lambda, level)
      type(membrane_law_t), intent(in) :: law
      real(dp), intent(in) :: lambda
      integer, intent(in) :: level
      type(surface_mesh_t) :: mesh
      type(membrane_reference_t) :: ref
      real(dp), allocatable :: xr(:, :), x(:, :), force(:, :), tri_area(:), area(:), fn(:), ft(:)
      real(dp) :: energy, t1, t2, pressure
      integer :: i
      call sphere(level, mesh, xr)
      call ref%init(mesh, xr)
      x = lambda * xr
      allocate (force(3, mesh%n_nodes), tri_area(mesh%n_tri), area(mesh%n_nodes))
      allocate (fn(mesh%n_nodes), ft(mesh%n_nodes))
      call membrane_nodal_forces(ref, mesh, law, x, force, energy)
      call triangle_areas(mesh, x, tri_area)
      call node_areas(mesh, tri_area, area)
      call law%tensions(lambda, lambda, t1, t2)
      pressure = 2.0_dp * t1 / lambda
      do i = 1, mesh%n_nodes
         fn(i) = -dot_product(force(:, i), xr(:, i)) / area(i)
         ft(i) = norm2(force(:, i) + fn(i) * area(i) * xr(:, i)) / area(i)
      end do
      write (*, '(a,es24.16)') 'pressure_exact ', pressure
      write (*, '(a,es24.16)') 'pressure_mean ', sum(fn * area) / sum(area)
      write (*, '(a,es24.16)') 'pressure_max_rel_error ', maxval(abs(fn / pressure - 1.0_dp))
      write (*, '(a,es24.16)') 'pressure_rms_rel_error ', sqrt(sum(area * (fn / pressure - 1.0_dp)**2) / sum(area))
      write (*, '(a,es24.16)') 'tangential_max_rel ', maxval(ft) / pressure
   end subroutine probe_laplace

   !> Unit sphere with uniform force density f = e_z: translates at U = 2/3 (mu = a = 1).
   subroutine probe_translate(level, duffy_order, near_levels)
      integer, intent(in) :: level, duffy_order, near_levels
      type(surface_mesh_t) :: mesh
      type(single_layer_t) :: sl
      real(dp), allocatable :: x(:, :), f(:, :), u(:, :)
      real(dp) :: exact
      call sphere(level, mesh, x)
      call sl%init(mesh, duffy_order, near_levels)
      allocate (f(3, mesh%n_nodes), u(3, mesh%n_nodes))
      f = 0
      f(3, :) = 1
      call sl%velocity(mesh, x, f, u)
      exact = 2.0_dp / 3.0_dp
      write (*, '(a,es24.16)') 'u_exact ', exact
      write (*, '(a,es24.16)') 'u_mean ', sum(u(3, :)) / mesh%n_nodes
      write (*, '(a,es24.16)') 'max_rel_error ', maxval(norm2(u - spread([0.0_dp, 0.0_dp, exact], 2, mesh%n_nodes), &
                                                          dim=1)) / exact
      write (*, '(a,es24.16)') 'pi_check ', pi
   end subroutine probe_translate

   !> A capsule pre-stressed by alpha (--prestress) in a quiescent fluid: the load is the Laplace
   !> pressure of the pre-tension, which drives no flow, so the capsule must stay at rest.
   !> Prints the pressure against 2 T(1 + alpha)/a, the largest membrane velocity in units of
   !> the pre-tension's velocity scale T/mu, and the largest radial drift after STEPS RK2 steps.
   subroutine probe_rest(alpha, level, steps)
      use capsule_dynamics, only: capsule_t
      use run_options, only: run_options_t
      real(dp), intent(in) :: alpha
      integer, intent(in) :: level, steps
      type(capsule_t) :: cap
      type(run_options_t) :: opts
      type(membrane_law_t) :: law
      integer :: k, stat
      character(len=:), allocatable :: errmsg
      real(dp), allocatable :: u(:, :)
      real(dp) :: t1, t2, pressure
      character(len=64) :: name
      call get_command_argument(2, name)
      opts%flow = 'shear'
      opts%law = trim(name)
      opts%nu_s = real_arg(3)
      opts%c = real_arg(4)
      opts%prestress = alpha
      opts%ca = 1.0_dp
      opts%level = level
      call cap%init(opts, stat, errmsg)
      if (stat /= 0) error stop errmsg
      cap%flow = 0   ! no outer flow
      law = cap%law
      allocate (u(3, cap%mesh%n_nodes))
      call cap%velocity(cap%positions, u)
      call law%tensions(1.0_dp + alpha, 1.0_dp + alpha, t1, t2)
      ! Tensions per current length are in G_s; u/Ca is in G_s/mu, the pressure in G_s/a.
      pressure = 2.0_dp * t1
      write (*, '(a,es24.16)') 'tension ', t1
      write (*, '(a,es24.16)') 'pressure_exact ', pressure
      write (*, '(a,es24.16)') 'pressure_mean ', -sum(sum(cap%density * cap%positions, dim=1) * cap%node_area) / sum(cap%node_area)
      write (*, '(a,es24.16)') 'max_velocity ', maxval(norm2(u, dim=1))
      if (t1 > 0.0_dp) write (*, '(a,es24.16)') 'max_velocity_over_tension ', maxval(norm2(u, dim=1)) / t1
      do k = 1, steps
         call cap%advance()
      end do
      write (*, '(a,es24.16)') 'time ', cap%t
      write (*, '(a,es24.16)') 'max_radius_drift ', maxval(abs(norm2(cap%positions, dim=1) - 1.0_dp))
   end subroutine probe_rest

   !> Timing of the hot path on a sheared capsule: one velocity evaluation (forces, single
   !> layer, volume-flux correction) and one RK2 step, on the current OpenMP thread count.
   subroutine probe_bench(level, repeats)
      use omp_lib, only: omp_get_wtime, omp_get_max_threads
      use capsule_dynamics, only: capsule_t
      use run_options, only: run_options_t
      integer, intent(in) :: level, repeats
      type(capsule_t) :: cap
      type(run_options_t) :: opts
      integer :: k, stat
      character(len=:), allocatable :: errmsg
      real(dp) :: t0, t_velocity, t_step, c0, c1
      real(dp), allocatable :: u(:, :)
      opts%flow = 'shear'
      opts%law = 'NH'
      opts%ca = 0.1_dp
      opts%level = level
      call cap%init(opts, stat, errmsg)
      if (stat /= 0) error stop errmsg
      allocate (u(3, cap%mesh%n_nodes))
      ! A deformed state: a few steps first.
      do k = 1, 3
         call cap%advance()
      end do
      t0 = omp_get_wtime()
      call cpu_time(c0)
      do k = 1, repeats
         call cap%velocity(cap%positions, u)
      end do
      call cpu_time(c1)
      t_velocity = (omp_get_wtime() - t0) / repeats
      t0 = omp_get_wtime()
      do k = 1, repeats
         call cap%advance()
      end do
      t_step = (omp_get_wtime() - t0) / repeats
      write (*, '(a,i0)') 'threads ', omp_get_max_threads()
      write (*, '(a,i0)') 'n_nodes ', cap%mesh%n_nodes
      write (*, '(a,es24.16)') 'velocity_s ', t_velocity
      ! CPU seconds of the process (all threads): on one thread, immune to a loaded machine.
      write (*, '(a,es24.16)') 'velocity_cpu_s ', (c1 - c0) / repeats
      write (*, '(a,es24.16)') 'rk2_step_s ', t_step
   end subroutine probe_bench

   !> Unit-sphere meridian with n elements, equal steps in polar angle, front pole first.
   function sphere_meridian(n) result(rz)
      integer, intent(in) :: n
      real(dp) :: rz(2, n + 1)
      integer :: k
      do k = 0, n
         rz(:, k + 1) = [sin(pi * k / n), cos(pi * k / n)]
      end do
      rz(1, 1) = 0.0_dp
      rz(1, n + 1) = 0.0_dp
   end function sphere_meridian

   !> Axisymmetric ring forces against finite differences of the energy, rigid axial
   !> translation, and the volume gradient against finite differences of the volume.
   subroutine probe_axi_fd(law, n)
      use axisymmetric_membrane, only: meridian_reference_t, meridian_forces, meridian_area_volume, &
                                       meridian_volume_gradient
      type(membrane_law_t), intent(in) :: law
      integer, intent(in) :: n
      type(meridian_reference_t) :: ref
      real(dp) :: rz0(2, n + 1), rz(2, n + 1), xp(2, n + 1), force(2, n + 1), f2(2, n + 1), grad(2, n + 1)
      real(dp) :: noise(2, n + 1), energy, ep, em, err, err_v, eps, a, v, vp, vm, scale
      integer :: k, c
      rz0 = sphere_meridian(n)
      call ref%init(rz0)
      call random_seed_fixed()
      call random_number(noise)
      rz(1, :) = 0.8_dp * rz0(1, :)
      rz(2, :) = 1.5_dp * rz0(2, :) + 0.2_dp * rz0(1, :)**2
      rz = rz + 0.02_dp * (noise - 0.5_dp)
      rz(1, 1) = 0.0_dp
      rz(1, n + 1) = 0.0_dp
      call meridian_forces(ref, law, rz, force, energy)
      call meridian_volume_gradient(rz, grad)
      scale = maxval(abs(force))
      eps = 1.0e-6_dp
      err = 0
      err_v = 0
      do k = 1, n + 1
         do c = 1, 2
            if (c == 1 .and. (k == 1 .or. k == n + 1)) cycle     ! poles stay on the axis
            xp = rz
            xp(c, k) = rz(c, k) + eps
            call meridian_forces(ref, law, xp, f2, ep)
            call meridian_area_volume(xp, a, vp)
            xp(c, k) = rz(c, k) - eps
            call meridian_forces(ref, law, xp, f2, em)
            call meridian_area_volume(xp, a, vm)
            err = max(err, abs(-(ep - em) / (2 * eps) - force(c, k)))
            err_v = max(err_v, abs((vp - vm) / (2 * eps) - grad(c, k)))
         end do
      end do
      write (*, '(a,es24.16)') 'fd_max_error_rel ', err / scale
      write (*, '(a,es24.16)') 'volume_gradient_error ', err_v
      write (*, '(a,es24.16)') 'net_axial_force_rel ', abs(sum(force(2, :))) / scale
      xp = rz0
      xp(2, :) = xp(2, :) + 0.7_dp
      call meridian_forces(ref, law, xp, f2, energy)
      write (*, '(a,es24.16)') 'rigid_max_force ', maxval(abs(f2))
      call meridian_area_volume(rz0, a, v)
      write (*, '(a,es24.16)') 'sphere_area ', a
      write (*, '(a,es24.16)') 'sphere_volume ', v
   end subroutine probe_axi_fd

   !> Inflated sphere, axisymmetric: force density F_k/A_k against the Laplace pressure 2T/R.
   subroutine probe_axi_laplace(law, lambda, n)
      use axisymmetric_membrane, only: meridian_reference_t, meridian_forces, meridian_node_areas
      type(membrane_law_t), intent(in) :: law
      real(dp), intent(in) :: lambda
      integer, intent(in) :: n
      type(meridian_reference_t) :: ref
      real(dp) :: rz0(2, n + 1), force(2, n + 1), area(n + 1), fn(n + 1), energy, t1, t2, pressure
      integer :: k
      rz0 = sphere_meridian(n)
      call ref%init(rz0)
      call meridian_forces(ref, law, lambda * rz0, force, energy)
      call meridian_node_areas(lambda * rz0, area)
      call law%tensions(lambda, lambda, t1, t2)
      pressure = 2.0_dp * t1 / lambda
      do k = 1, n + 1
         fn(k) = -dot_product(force(:, k), rz0(:, k)) / area(k)
      end do
      ! Poles: only the axial component exists; it is the normal one there.
      write (*, '(a,es24.16)') 'pressure_max_rel_error_interior ', maxval(abs(fn(2:n) / pressure - 1.0_dp))
      write (*, '(a,es24.16)') 'pressure_rel_error_pole ', abs(fn(1) / pressure - 1.0_dp)
   end subroutine probe_axi_laplace

   !> The Newton solver's incremental finite-difference Jacobian against columns computed by
   !> full velocity evaluations, on a capsule deformed by a few RK2 steps.
   subroutine probe_tube_jacobian(a_over_l, ca)
      use omp_lib, only: omp_get_wtime
      use axisymmetric_tube, only: axisymmetric_tube_t
      use axisymmetric_operator, only: velocity_jacobian, pack_dofs
      use run_options, only: run_options_t
      real(dp), intent(in) :: a_over_l, ca
      type(axisymmetric_tube_t) :: tube
      type(run_options_t) :: opts
      integer :: stat, k, m, j, node
      character(len=:), allocatable :: errmsg
      real(dp), allocatable :: jac(:, :), u0(:, :), u1(:, :), p0(:), p1(:), rz1(:, :)
      real(dp) :: err, scale, t0, t_incremental, t_brute
      opts%flow = 'tube'
      opts%law = 'NH'
      opts%ca = ca
      opts%a_over_l = a_over_l
      opts%integrator = 'rk2'
      if (command_argument_count() >= 4) opts%kb = real_arg(4)
      call tube%init(opts, stat, errmsg)
      if (stat /= 0) error stop errmsg
      do k = 1, 20
         call tube%advance()
      end do
      m = 2 * size(tube%positions, 2) - 2
      allocate (jac(m, m), u0(2, size(tube%positions, 2)), u1(2, size(tube%positions, 2)), p0(m), p1(m))
      t0 = omp_get_wtime()
      call velocity_jacobian(tube, tube%positions, 1.0e-6_dp, jac)
      t_incremental = omp_get_wtime() - t0
      call tube%velocity(tube%positions, u0)
      call pack_dofs(u0, p0)
      scale = maxval(abs(jac))
      err = 0
      t0 = omp_get_wtime()
      ! Brute force on a sample of columns: poles, a node near each pole, the equator.
      do j = 1, m
         node = 2 + (j - 2) / 2
         if (.not. (j <= 5 .or. j >= m - 4 .or. abs(node - size(tube%positions, 2) / 2) <= 1)) cycle
         rz1 = tube%positions
         if (j == 1) then
            rz1(2, 1) = rz1(2, 1) + 1.0e-6_dp
         else if (j == m) then
            rz1(2, size(rz1, 2)) = rz1(2, size(rz1, 2)) + 1.0e-6_dp
         else
            rz1(1 + mod(j - 2, 2), node) = rz1(1 + mod(j - 2, 2), node) + 1.0e-6_dp
         end if
         call tube%velocity(rz1, u1)
         call pack_dofs(u1, p1)
         err = max(err, maxval(abs((p1 - p0) / 1.0e-6_dp - jac(:, j))))
      end do
      t_brute = omp_get_wtime() - t0
      write (*, '(a,es24.16)') 'max_rel_difference ', err / scale
      write (*, '(a,es24.16)') 'jacobian_scale ', scale
      write (*, '(a,es24.16)') 'incremental_s ', t_incremental
      write (*, '(a,es24.16)') 'one_velocity_s ', t_brute / 12
   end subroutine probe_tube_jacobian

   subroutine random_seed_fixed()
      integer :: n
      integer, allocatable :: seed(:)
      call random_seed(size=n)
      allocate (seed(n))
      seed = 20261122
      call random_seed(put=seed)
   end subroutine random_seed_fixed

end program kernel_probe
