!> axi_probe: measures one property of the axisymmetric single-layer machinery
!> (elliptic_integrals, ring_stokeslet) and prints it as "key value" lines; pytest
!> (tests/kernel/test_ring_kernel.py) holds the references and the tolerances.
!>
!>   axi_probe ellip M1                     K, E, B, D from the complementary parameter m1 = 1 - m
!>   axi_probe ellip-m M                    K(m), E(m)
!>   axi_probe ellip-sweep                  largest relative deviation of the fast K, E, B, D
!>                                          from the AGM reference over a dense grid (see below)
!>   axi_probe ellip-bench N REPEATS        seconds per call, fast form and AGM, interleaved
!>   axi_probe kernel R0 Z0 R Z             ring Stokeslet M (m_rr m_rz m_zr m_zz)
!>   axi_probe log-coefficient R0           a in M = -a ln(rho) I + bounded
!>   axi_probe segment R0 Z0 RA ZA RB ZB FAR FAZ FBR FBZ END    segment integral (u_r u_z)
!>   axi_probe sphere N translate|pressure  unit sphere, N straight meridian segments: max error
!>   axi_probe bench N REPEATS              seconds per sphere velocity and per segment integral
!>   axi_probe stresslet R0 Z0 R Z NR NZ    ring stresslet Q (q_rr q_rz q_zr q_zz), ring_stresslet
!>   axi_probe dl-sphere N                  double layer on the unit sphere, N straight segments:
!>                                          identities and the Green's identity error (see below)
!>   axi_probe velocity A_OVER_L CA N LAMBDA  node velocities (u_r_K u_z_K) of the tube model (NH)
!>                                          at its starting shape
!>   axi_probe jacobian A_OVER_L CA N T [LAMBDA]  eigenvalues of the tube model's velocity Jacobian
!>                                          (NH, N meridian elements) after RK2 to time T, and its
!>                                          largest difference from brute-force differences of the velocity
program axi_probe
   use capsim_kinds, only: dp, pi
   use command_args, only: int_arg, real_arg, string_arg
   use elliptic_integrals, only: elliptic_k, elliptic_e, elliptic_kebd_m1, elliptic_kebd_agm_m1
   use ring_stokeslet, only: ring_kernel, ring_log_coefficient, segment_integral
   use ring_stresslet, only: ring_stresslet_kernel, stresslet_segment, double_layer_row
   use run_options, only: run_options_t
   use axisymmetric_tube, only: axisymmetric_tube_t
   use axisymmetric_operator, only: velocity_jacobian, largest_growth_rate, pack_dofs, unpack_dofs
   implicit none

   character(len=64) :: command
   call get_command_argument(1, command)
   select case (command)
   case ('ellip')
      call probe_ellip(real_arg(2))
   case ('ellip-m')
      write (*, '(a,es24.16)') 'k ', elliptic_k(real_arg(2))
      write (*, '(a,es24.16)') 'e ', elliptic_e(real_arg(2))
   case ('ellip-sweep')
      call probe_ellip_sweep()
   case ('ellip-bench')
      call probe_ellip_bench(int_arg(2), int_arg(3))
   case ('kernel')
      call probe_kernel(real_arg(2), real_arg(3), real_arg(4), real_arg(5))
   case ('log-coefficient')
      write (*, '(a,es24.16)') 'a ', ring_log_coefficient(real_arg(2))
   case ('segment')
      call probe_segment()
   case ('sphere')
      call probe_sphere(int_arg(2), string_arg(3))
   case ('bench')
      call probe_bench(int_arg(2), int_arg(3))
   case ('stresslet')
      call probe_stresslet()
   case ('dl-sphere')
      call probe_dl_sphere(int_arg(2))
   case ('velocity')
      call probe_velocity(real_arg(2), real_arg(3), int_arg(4), real_arg(5))
   case ('jacobian')
      call probe_jacobian(real_arg(2), real_arg(3), int_arg(4), real_arg(5))
   case default
      write (*, '(a)') 'usage: axi_probe ellip|ellip-m|ellip-sweep|ellip-bench|kernel|log-coefficient|segment|sphere|bench ...'
      error stop 2
   end select

contains

   subroutine probe_velocity(a_over_l, ca, n_meridian, lambda)
      real(dp), intent(in) :: a_over_l, ca, lambda
      integer, intent(in) :: n_meridian
      type(run_options_t) :: opts
      type(axisymmetric_tube_t) :: model
      real(dp), allocatable :: u(:, :)
      integer :: stat, k
      character(len=:), allocatable :: errmsg
      opts%flow = 'tube'
      opts%law = 'NH'
      opts%a_over_l = a_over_l
      opts%ca = ca
      opts%n_meridian = n_meridian
      opts%lambda = lambda
      call model%init(opts, stat, errmsg)
      if (stat /= 0) error stop 'init failed'
      allocate (u, mold=model%positions)
      call model%velocity(model%positions, u)
      do k = 1, size(u, 2)
         write (*, '(a,i0,es25.16)') 'u_r_', k, u(1, k)
         write (*, '(a,i0,es25.16)') 'u_z_', k, u(2, k)
      end do
      write (*, '(a,es25.16)') 'v_c ', model%v_c
   end subroutine probe_velocity

   !> Largest and smallest real parts of the Jacobian's eigenvalues (the model's LAPACK dgeev).
   subroutine probe_jacobian(a_over_l, ca, n_meridian, t_end)
      real(dp), intent(in) :: a_over_l, ca, t_end
      integer, intent(in) :: n_meridian
      type(run_options_t) :: opts
      type(axisymmetric_tube_t) :: model
      real(dp), allocatable :: jac(:, :)
      real(dp) :: largest
      integer :: stat
      character(len=:), allocatable :: errmsg
      opts%flow = 'tube'
      opts%law = 'NH'
      opts%a_over_l = a_over_l
      opts%ca = ca
      opts%n_meridian = n_meridian
      opts%integrator = 'rk2'
      if (command_argument_count() >= 6) opts%lambda = real_arg(6)
      call model%init(opts, stat, errmsg)
      if (stat /= 0) error stop 'init failed'
      do while (model%t < t_end - 0.5_dp * model%dt)
         call model%advance()
      end do
      allocate (jac(2 * n_meridian, 2 * n_meridian))
      call velocity_jacobian(model, model%positions, 1.0e-5_dp * a_over_l, jac)
      largest = largest_growth_rate(model, jac)
      write (*, '(a,es12.4)') 't ', model%t
      write (*, '(a,es12.4)') 'largest_real ', largest
      write (*, '(a,es12.4)') 'smallest_real ', minval(model%eig_re)
      block
         real(dp), allocatable :: rz1(:, :), u0(:, :), u1(:, :), q0(:), q1(:), col(:)
         real(dp) :: worst, h
         integer :: j, n
         n = size(model%positions, 2)
         h = 1.0e-5_dp * a_over_l
         allocate (rz1, source=model%positions)
         allocate (u0(2, n), u1(2, n), q0(2 * n - 2), q1(2 * n - 2), col(2 * n - 2))
         call model%velocity(model%positions, u0)
         call pack_dofs(u0, q0)
         worst = 0.0_dp
         do j = 1, 2 * n - 2
            call pack_dofs(model%positions, col)
            col(j) = col(j) + h
            call unpack_dofs(col, rz1)
            call model%velocity(rz1, u1)
            call pack_dofs(u1, q1)
            if (maxval(abs((q1 - q0) / h - jac(:, j))) > 0.1_dp * worst .and. command_argument_count() >= 7) &
               write (*, '(a,i0,a,i0,2es12.4)') 'column_', j, '_row_', maxloc(abs((q1 - q0) / h - jac(:, j))), &
               maxval(abs((q1 - q0) / h - jac(:, j))), maxval(abs(jac(:, j)))
            worst = max(worst, maxval(abs((q1 - q0) / h - jac(:, j))))
         end do
         write (*, '(a,es12.4)') 'brute_force_difference ', worst
         write (*, '(a,es12.4)') 'jacobian_max ', maxval(abs(jac))
         write (*, '(a,es12.4)') 'velocity_max ', maxval(abs(u0))
      end block
   end subroutine probe_jacobian




   subroutine probe_ellip(m1)
      real(dp), intent(in) :: m1
      real(dp) :: k, e, b, d
      call elliptic_kebd_m1(m1, k, e, b, d)
      write (*, '(a,es24.16)') 'k ', k
      write (*, '(a,es24.16)') 'e ', e
      write (*, '(a,es24.16)') 'b ', b
      write (*, '(a,es24.16)') 'd ', d
   end subroutine probe_ellip

   !> The fast K, E, B, D (elliptic_kebd_m1 and the m-forms) against Bulirsch's AGM, as the
   !> largest relative deviation over: m = i/100000 on [0, 1) and m = 1 - 10**(-j/8) up to
   !> m = 1 - 1e-15 (K(m), E(m) from m, m_k m_e); m1 = 10**(-j/10) from 1 down to 1e-300 and
   !> m1 = i/100000 on (0, 1] (all four from m1, m1_k m1_e m1_b m1_d).
   subroutine probe_ellip_sweep()
      integer, parameter :: n_uniform = 100000
      real(dp) :: m, dev(2), dev1(4), k, e, b, d, kr, er, br, dr
      integer :: i, j
      dev = 0.0_dp
      do i = 0, n_uniform + 120
         if (i < n_uniform) then
            m = real(i, dp) / n_uniform
         else
            m = 1.0_dp - 10.0_dp**(-real(i - n_uniform, dp) / 8)
         end if
         call elliptic_kebd_agm_m1(1.0_dp - m, kr, er, br, dr)
         dev = max(dev, abs([elliptic_k(m) / kr, elliptic_e(m) / er] - 1.0_dp))
      end do
      dev1 = 0.0_dp
      do j = 0, 3000 + n_uniform
         if (j <= 3000) then
            m = 10.0_dp**(-real(j, dp) / 10)
         else
            m = real(j - 3000, dp) / n_uniform
         end if
         call elliptic_kebd_m1(m, k, e, b, d)
         call elliptic_kebd_agm_m1(m, kr, er, br, dr)
         dev1 = max(dev1, abs([k / kr, e / er, b / br, d / dr] - 1.0_dp))
      end do
      write (*, '(a,es12.4)') 'm_k ', dev(1)
      write (*, '(a,es12.4)') 'm_e ', dev(2)
      write (*, '(a,es12.4)') 'm1_k ', dev1(1)
      write (*, '(a,es12.4)') 'm1_e ', dev1(2)
      write (*, '(a,es12.4)') 'm1_b ', dev1(3)
      write (*, '(a,es12.4)') 'm1_d ', dev1(4)
   end subroutine probe_ellip_sweep

   !> CPU seconds per call (the process's, so that a loaded machine does not count) of the fast
   !> form and of the AGM on the same N arguments, timed alternately REPEATS times (lines fast_s_I and agm_s_I; the caller takes medians). The
   !> arguments: m1 log-uniform on [1e-12, 1], the range a ring kernel sees from a target 1e-6
   !> ring radii to several radii away (rho/R = sqrt(m1)).
   subroutine probe_ellip_bench(n, repeats)
      integer, intent(in) :: n, repeats
      real(dp) :: m1(n), k(n), e(n), b(n), d(n), kr(n), er(n), br(n), dr(n), t0, t1
      integer :: i, r
      character(len=32) :: key
      m1 = [(10.0_dp**(-12.0_dp * modulo(0.6180339887498949_dp * i, 1.0_dp)), i = 1, n)]
      do r = 1, repeats
         call cpu_time(t0)
         call elliptic_kebd_m1(m1, k, e, b, d)
         write (key, '(a,i0)') 'fast_s_', r
         call cpu_time(t1)
         write (*, '(a,1x,es24.16)') trim(key), (t1 - t0) / n
         call cpu_time(t0)
         call elliptic_kebd_agm_m1(m1, kr, er, br, dr)
         write (key, '(a,i0)') 'agm_s_', r
         call cpu_time(t1)
         write (*, '(a,1x,es24.16)') trim(key), (t1 - t0) / n
      end do
      ! The results are used (so neither call is optimised away) and agree to rounding.
      write (*, '(a,es12.4)') 'max_rel_diff ', maxval(abs([k / kr, e / er, b / br, d / dr] - 1.0_dp))
   end subroutine probe_ellip_bench

   subroutine probe_kernel(r0, z0, r, z)
      real(dp), intent(in) :: r0, z0, r, z
      real(dp) :: m(2, 2)
      call ring_kernel(r0, z0, r, z, m)
      write (*, '(a,es24.16)') 'm_rr ', m(1, 1)
      write (*, '(a,es24.16)') 'm_rz ', m(1, 2)
      write (*, '(a,es24.16)') 'm_zr ', m(2, 1)
      write (*, '(a,es24.16)') 'm_zz ', m(2, 2)
   end subroutine probe_kernel

   subroutine probe_segment()
      real(dp) :: u(2)
      u = segment_integral(real_arg(2), real_arg(3), real_arg(4), real_arg(5), real_arg(6), &
                           real_arg(7), [real_arg(8), real_arg(9)], [real_arg(10), real_arg(11)], &
                           int_arg(12))
      write (*, '(a,es24.16)') 'u_r ', u(1)
      write (*, '(a,es24.16)') 'u_z ', u(2)
   end subroutine probe_segment

   !> Nodes on the unit sphere equally spaced in polar angle, P1 force density at the nodes.
   subroutine sphere_nodes(n, mode, r, z, f)
      integer, intent(in) :: n
      character(len=*), intent(in) :: mode
      real(dp), intent(out) :: r(0:n), z(0:n), f(2, 0:n)
      integer :: i
      do i = 0, n
         r(i) = sin(pi * i / n)
         z(i) = cos(pi * i / n)
      end do
      ! The poles exactly on the axis (sin(pi) is 1.2e-16, not 0).
      r(0) = 0.0_dp
      r(n) = 0.0_dp
      select case (mode)
      case ('translate')
         f(1, :) = 0.0_dp           ! uniform Cartesian f = e_z
         f(2, :) = 1.0_dp
      case ('pressure')
         f(1, :) = r                ! f = n, the outward normal of the exact sphere
         f(2, :) = z
      case default
         error stop 'axi_probe sphere: mode is translate or pressure'
      end select
   end subroutine sphere_nodes

   !> u at every node = 1/(8 pi) sum over segments, segment j from node j-1 to node j.
   subroutine sphere_velocity(n, r, z, f, u)
      integer, intent(in) :: n
      real(dp), intent(in) :: r(0:n), z(0:n), f(2, 0:n)
      real(dp), intent(out) :: u(2, 0:n)
      integer :: i, j, target_end
      !$omp parallel do default(none) shared(n, r, z, f, u) private(i, j, target_end) schedule(static)
      do i = 0, n
         u(:, i) = 0.0_dp
         do j = 1, n
            target_end = 0
            if (i == j - 1) target_end = 1
            if (i == j) target_end = 2
            u(:, i) = u(:, i) + segment_integral(r(i), z(i), r(j - 1), z(j - 1), r(j), z(j), &
                                                 f(:, j - 1), f(:, j), target_end)
         end do
         u(:, i) = u(:, i) / (8.0_dp * pi)
      end do
      !$omp end parallel do
   end subroutine sphere_velocity

   subroutine probe_sphere(n, mode)
      integer, intent(in) :: n
      character(len=*), intent(in) :: mode
      real(dp) :: r(0:n), z(0:n), f(2, 0:n), u(2, 0:n), exact(2)
      integer :: i
      real(dp) :: err
      call sphere_nodes(n, trim(mode), r, z, f)
      call sphere_velocity(n, r, z, f, u)
      ! U = 2 a f / (3 mu) for the translating sphere; a pressure on a closed surface drives no flow.
      exact = 0.0_dp
      if (trim(mode) == 'translate') exact = [0.0_dp, 2.0_dp / 3.0_dp]
      err = 0.0_dp
      do i = 0, n
         err = max(err, norm2(u(:, i) - exact))
      end do
      write (*, '(a,i0)') 'n_segments ', n
      write (*, '(a,es24.16)') 'max_error ', err
      write (*, '(a,es24.16)') 'u_z_pole ', u(2, 0)
      write (*, '(a,es24.16)') 'u_z_equator ', u(2, n / 2)
   end subroutine probe_sphere

   subroutine probe_bench(n, repeats)
      use omp_lib, only: omp_get_wtime, omp_get_max_threads
      integer, intent(in) :: n, repeats
      real(dp) :: r(0:n), z(0:n), f(2, 0:n), u(2, 0:n), t0, t_eval
      integer :: k
      call sphere_nodes(n, 'pressure', r, z, f)
      t0 = omp_get_wtime()
      do k = 1, repeats
         call sphere_velocity(n, r, z, f, u)
      end do
      t_eval = (omp_get_wtime() - t0) / repeats
      write (*, '(a,i0)') 'threads ', omp_get_max_threads()
      write (*, '(a,i0)') 'n_segments ', n
      write (*, '(a,es24.16)') 'velocity_s ', t_eval
      write (*, '(a,es24.16)') 'segment_integral_s ', t_eval / (real(n + 1, dp) * n)
      write (*, '(a,es24.16)') 'checksum ', sum(abs(u))
   end subroutine probe_bench

   subroutine probe_stresslet()
      real(dp) :: q(2, 2)
      call ring_stresslet_kernel(real_arg(2), real_arg(3), real_arg(4), real_arg(5), real_arg(6), real_arg(7), q)
      write (*, '(a,es24.16)') 'q_rr ', q(1, 1)
      write (*, '(a,es24.16)') 'q_rz ', q(1, 2)
      write (*, '(a,es24.16)') 'q_zr ', q(2, 1)
      write (*, '(a,es24.16)') 'q_zz ', q(2, 2)
   end subroutine probe_stresslet

   !> Double layer on the unit sphere (n straight meridian segments), printed as largest errors:
   !>  midpoint_identity: D[c] = -c/2 at element mid-points (smooth points of the closed
   !>    polygonal surface, where it holds exactly), as the mean of the two one-sided values
   !>    integrated directly (no subtraction) 1e-4 element lengths inside and outside;
   !>  inside_identity / outside_identity: D[c] = -c inside (a rigid translation reproduced by its
   !>    own double layer, v = -D[v]) and 0 outside, integrated directly at a few points;
   !>  green_error: the Green's identity D[v](x_k) + v/2 = 1/(8 pi) SL[sigma.n](x_k) at the nodes
   !>    for the straining flow v = (-r/2, z), sigma.n = (-n_r, 2 n_z) (mu = 1), with the operator
   !>    of double_layer_row and the single layer of ring_stokeslet: the discretisation error of
   !>    a P1 density on the polygon, O(h**2).
   subroutine probe_dl_sphere(n)
      integer, intent(in) :: n
      real(dp) :: rz(2, n + 1), acc(2, 2), x(2), row(2, 2 * (n + 1)), v(2 * (n + 1))
      real(dp) :: f(2, 0:n), rr(0:n), zz(0:n), u(2, 0:n), dv(2), err
      real(dp), parameter :: inner(2, 3) = reshape([0.0_dp, 0.0_dp, 0.5_dp, 0.3_dp, 0.2_dp, -0.9_dp], [2, 3])
      real(dp), parameter :: outer(2, 3) = reshape([1.5_dp, 0.2_dp, 0.3_dp, 1.2_dp, 0.0_dp, -1.05_dp], [2, 3])
      integer :: e, k, j
      do k = 1, n + 1
         rz(:, k) = [sin(pi * (k - 1) / n), cos(pi * (k - 1) / n)]
      end do
      rz(1, [1, n + 1]) = 0.0_dp
      err = 0.0_dp
      do e = 1, n
         x = 0.5_dp * (rz(:, e) + rz(:, e + 1))
         dv = 1.0e-4_dp * [rz(2, e + 1) - rz(2, e), rz(1, e) - rz(1, e + 1)]
         acc = 0.5_dp * (raw_constant(rz, x + dv) + raw_constant(rz, x - dv))
         err = max(err, maxval(abs(acc + 0.5_dp * identity2())))
      end do
      write (*, '(a,es24.16)') 'midpoint_identity ', err
      err = 0.0_dp
      do j = 1, 3
         err = max(err, maxval(abs(raw_constant(rz, inner(:, j)) + identity2())))
      end do
      write (*, '(a,es24.16)') 'inside_identity ', err
      err = 0.0_dp
      do j = 1, 3
         err = max(err, maxval(abs(raw_constant(rz, outer(:, j)))))
      end do
      write (*, '(a,es24.16)') 'outside_identity ', err
      ! Green's identity for the straining flow.
      do k = 1, n + 1
         v(2 * k - 1:2 * k) = [-0.5_dp * rz(1, k), rz(2, k)]
      end do
      rr = rz(1, :)
      zz = rz(2, :)
      f(1, :) = -rr
      f(2, :) = 2.0_dp * zz
      call sphere_velocity(n, rr, zz, f, u)
      err = 0.0_dp
      do k = 1, n + 1
         call double_layer_row(rz, rz(:, k), k, .false., row)
         dv = matmul(row, v) + 0.5_dp * v(2 * k - 1:2 * k)
         err = max(err, maxval(abs(dv - u(:, k - 1))))
      end do
      write (*, '(a,i0)') 'n_segments ', n
      write (*, '(a,es24.16)') 'green_error ', err
   end subroutine probe_dl_sphere

   pure function identity2() result(i2)
      real(dp) :: i2(2, 2)
      i2 = reshape([1.0_dp, 0.0_dp, 0.0_dp, 1.0_dp], [2, 2])
   end function identity2

   !> D[c] / c at xt for the Cartesian constants c = e_x (column 1, x at phi = 0) and e_z (column 2),
   !> summed directly over all elements of rz (no subtraction).
   function raw_constant(rz, xt) result(d)
      real(dp), intent(in) :: rz(:, :), xt(2)
      real(dp) :: d(2, 2), w(2, 2, 3)
      integer :: e
      d = 0.0_dp
      do e = 1, size(rz, 2) - 1
         w = stresslet_segment(xt(1), xt(2), rz(1, e), rz(2, e), rz(1, e + 1), rz(2, e + 1), 0)
         d = d + w(:, :, 3)
      end do
      d = d / (8.0_dp * pi)
   end function raw_constant

end program axi_probe
