!> tube3d_probe: measures the 3D tube model (tube_capsule) and prints "key value" lines;
!> tests/kernel/test_tube_3d.py and bench/bench_tube_3d.py run it, so tolerances live there.
!>
!>   tube3d_probe timing LEVEL A_OVER_L CA TUBE_LENGTH H_FAR H_CENTRE CACHE_DIR STEPS [SELF]
!>     wall setup (assembly + LU, or the cache load), then STEPS RK2 steps from the start shape
!>     and one velocity evaluation after them, each part timed (SELF, the membrane's own single
!>     layer: 0 the vertex rule, 1 the vertex rule with the near-field self correction
!>     tube_capsule_t%self_near_field, 2 the full 7-point rule, --self-quadrature full; absent:
!>     the model's default, full).
!>   tube3d_probe dl-outside LEVEL A FILM NEAR_RADIUS
!>     capsule double layer off the membrane (stokes_double_layer apply_outside) of a rigid-body
!>     density U + Omega x y on the level-LEVEL sphere of radius A, at the points FILM outside
!>     it over every node and every triangle centroid: exactly 0 for the polyhedron, so the
!>     result (max |w| / max |u|) is the quadrature error at that film thickness.
!>   tube3d_probe lambda-residual LEVEL A_OVER_L CA TUBE_LENGTH H_FAR H_CENTRE CACHE_DIR LAMBDA STEPS
!>     STEPS lambda = 1 RK2 steps from the start shape, then at that shape the lambda velocity
!>     and the residual of its boundary integral equation, evaluated afresh from the pieces.
!>   tube3d_probe self-quadrature LEVEL A_OVER_L CA TUBE_LENGTH H_FAR H_CENTRE CACHE_DIR T_END SELF
!>     RK2 steps to t >= T_END (SELF as for timing: 0 vertex rule, 1 with the near-field self
!>     correction, 2 full), then v_c at that shape with the full self quadrature (v_c_full,
!>     and the seconds of its self term, self_full_s, against single_layer's, self_vertex_s),
!>     and with the capsule's own single layer of single_layer
!>     alone (vertex rule beyond the second ring of triangles), with the non-touching
!>     triangles within R (and leaf_ratio diameters) integrated by the subdivided 7-point
!>     rule, R = 0.25 ... 100, and with the model's self_near_field correction (v_c_model);
!>     then the net flux of the capsule's single layer through the wall, v_c with it removed
!>     from the wall data (wall_flux_free), and v_c with the 7-point rule on every wall
!>     triangle at the membrane nodes (the tube-length experiments of README "Tube flow (3D)").
!>   tube3d_probe self-rules LEVEL A_OVER_L CA TUBE_LENGTH H_FAR H_CENTRE CACHE_DIR T_END SELF
!>     RK2 steps to t >= T_END (SELF as for timing), then at that shape v_c and the seconds of
!>     the membrane's own single layer with the vertex rule (v_c_vertex, self_s_vertex) and
!>     with self_single_layer at far rules (FAR: 7 the 7-point rule, 3 the interior 3-point
!>     rule, 1 the edge-midpoint rule) and near/subdivision ratios (v_c_FAR_NEAR_SUB,
!>     self_s_FAR_NEAR_SUB, and the largest difference of the membrane velocity from the
!>     reference's over its largest speed, max_du_FAR_NEAR_SUB); 7_6.0_6.0 is the reference;
!>     then v_c with the 7-point rule on every capsule triangle at the wall nodes too, with
!>     the full and the vertex self quadrature.
program tube3d_probe
   use omp_lib, only: omp_get_wtime, omp_get_max_threads
   use capsim_kinds, only: dp
   use command_args, only: int_arg, real_arg, string_arg, put, put_int
   use run_options, only: run_options_t
   use tube_capsule, only: tube_capsule_t, volume_gradients, remove_volume_flux
   use self_single_layer, only: far_edge
   use wall_single_layer, only: triangle_correction
   use capsim_kinds, only: pi
   use sphere_mesh, only: surface_mesh_t, icosphere
   use stokes_single_layer, only: single_layer_t
   use stokes_double_layer, only: double_layer_t
   use vector_algebra, only: cross
   implicit none

   character(len=64) :: command
   call get_command_argument(1, command)
   select case (command)
   case ('timing')
      call probe_timing()
   case ('dl-outside')
      call probe_dl_outside()
   case ('lambda-residual')
      call probe_lambda_residual()
   case ('self-quadrature')
      call probe_self_quadrature()
   case ('self-rules')
      call probe_self_rules()
   case default
      write (*, '(a)') 'usage: tube3d_probe timing LEVEL A_OVER_L CA TUBE_LENGTH H_FAR H_CENTRE CACHE_DIR STEPS'
      error stop 2
   end select

contains

   subroutine probe_self_quadrature()
      type(run_options_t) :: opts
      type(tube_capsule_t) :: model
      integer :: stat, n, i, t, p, m, ir
      character(len=:), allocatable :: errmsg
      character(len=32) :: key
      real(dp), parameter :: radii(5) = [0.25_dp, 0.5_dp, 0.75_dp, 1.0_dp, 100.0_dp]
      real(dp), allocatable :: x(:, :), u(:, :), s_base(:, :), du(:, :), grad(:, :), mgrad(:, :)
      real(dp) :: t_end, volume, moment, dvc, v_c_base, xv(3, 3), fv(3, 3), qp(3, 7), qs(3, 7), vs(3, 3), diam, corr(3)
      real(dp), parameter :: huge_dist = 1.0e30_dp
      logical, allocatable :: in_list(:)
      integer, allocatable :: list_vertex(:)

      call read_tube_case(opts)
      t_end = real_arg(9)
      call set_self_rule(opts, model, 10)
      call model%init(opts, stat, errmsg)
      if (stat /= 0) error stop errmsg
      call set_self_rule(opts, model, 10)
      call model%reset()
      do while (model%t < t_end)
         call model%advance()
      end do
      x = model%positions
      n = size(x, 2)
      allocate (u(3, n), s_base(3, n), du(3, n), grad(3, n), mgrad(3, n))
      call put('t', model%t)
      model%self_full = .true.
      model%seconds_self = 0
      call model%velocity(x, u)
      call put('v_c_full', model%v_c)
      call put('self_full_s', model%seconds_self)
      model%self_full = .false.
      model%seconds_self = 0
      call model%velocity(x, u)
      call put('self_vertex_s', model%seconds_self)
      model%self_near_field = .true.
      call model%velocity(x, u)
      call put('v_c_model', model%v_c)
      model%self_near_field = .false.
      call model%velocity(x, u)
      call put('v_c_base', model%v_c)
      v_c_base = model%v_c
      ! Net flux of the capsule's single layer through the closed wall, int_B (S f) . n dS
      ! (zero for the exact single layer: its field is divergence-free inside B), against the
      ! tube's flow rate pi; the wall's first-kind equation has no solution for such data.
      call put('wall_data_flux_over_flow_rate', -sum(model%wall_op%flux_weight * model%wall_data) / pi)
      model%wall_flux_free = .true.
      call model%velocity(x, u)
      call put('v_c_wall_flux_free', model%v_c)
      model%wall_flux_free = .false.
      ! The wall's single layer at the membrane nodes with the 7-point rule on every triangle.
      model%wall_op%mid_radius = 100.0_dp
      call model%velocity(x, u)
      call put('v_c_wall_all_7_point', model%v_c)
      model%wall_op%mid_radius = 0.5_dp
      call model%single_layer%velocity(model%mesh, x, model%density, s_base)
      allocate (in_list(model%mesh%n_tri), list_vertex(model%mesh%n_tri))
      call volume_gradients(model%mesh, x, grad, mgrad, volume, moment)
      do ir = 1, size(radii)
      du = 0.0_dp
      do i = 1, n
         in_list = .false.
         do p = model%single_layer%corr_start(i), model%single_layer%corr_start(i + 1) - 1
            in_list(model%single_layer%corr_tri(p)) = .true.
            list_vertex(model%single_layer%corr_tri(p)) = model%single_layer%corr_vertex(p)
         end do
         corr = 0.0_dp
         do t = 1, model%mesh%n_tri
            if (in_list(t)) then
               if (list_vertex(t) > 0) cycle
            end if
            xv = x(:, model%mesh%tri(:, t))
            fv = model%density(:, model%mesh%tri(:, t))
            diam = max(norm2(xv(:, 2) - xv(:, 1)), norm2(xv(:, 3) - xv(:, 2)), norm2(xv(:, 1) - xv(:, 3)))
            if (norm2(x(:, i) - sum(xv, dim=2) / 3.0_dp) >= max(radii(ir), 3.0_dp * diam)) cycle
            qp = matmul(xv, model%near_rule%bary)
            do m = 1, 7
               qs(:, m) = (model%single_layer%tri_area(t) * model%near_rule%weight(m)) * matmul(fv, model%near_rule%bary(:, m))
            end do
            vs = (model%single_layer%tri_area(t) / 3.0_dp) * fv
            ! Subdivided 7-point rule minus the vertex rule (dist 0 forces the subdivision test) ...
            corr = corr + triangle_correction(model%near_rule, x(:, i), 0.0_dp, diam, model%single_layer%tri_area(t), &
                                              xv, fv, qp, qs, vs)
            ! ... minus what the model already put there on the second ring (7-point minus vertex).
            if (in_list(t)) corr = corr - triangle_correction(model%near_rule, x(:, i), huge_dist, diam, &
                                                              model%single_layer%tri_area(t), xv, fv, qp, qs, vs)
         end do
         du(:, i) = corr / (8.0_dp * pi * model%ca)
      end do
      if (model%volume_correction) call remove_volume_flux(du, grad)
      dvc = (sum(du * mgrad) - (moment / volume) * sum(du * grad)) / volume
      write (key, '(a,f0.2)') 'v_c_refined_within_', radii(ir)
      call put(trim(key), v_c_base + dvc)
      write (key, '(a,f0.2)') 'max_du_within_', radii(ir)
      call put(trim(key), maxval(norm2(du, dim=1)) / maxval(norm2(u, dim=1)))
      end do
   end subroutine probe_self_quadrature

   subroutine probe_self_rules()
      type(run_options_t) :: opts
      type(tube_capsule_t) :: model
      integer :: stat, k
      character(len=:), allocatable :: errmsg
      character(len=32) :: key
      real(dp), allocatable :: x(:, :), u(:, :), u_ref(:, :)
      integer, parameter :: far(*) = [7, 7, 3, 3, 1, 1, 1, 1]
      real(dp), parameter :: near(*) = [6.0_dp, 3.0_dp, 3.0_dp, 3.0_dp, 3.0_dp, 3.0_dp, 4.0_dp, 2.0_dp]
      real(dp), parameter :: sub(*) = [6.0_dp, 3.0_dp, 3.0_dp, 2.0_dp, 3.0_dp, 2.0_dp, 2.0_dp, 1.5_dp]

      call read_tube_case(opts)
      call set_self_rule(opts, model, 10)
      call model%init(opts, stat, errmsg)
      if (stat /= 0) error stop errmsg
      call set_self_rule(opts, model, 10)
      call model%reset()
      do while (model%t < real_arg(9))
         call model%advance()
      end do
      x = model%positions
      allocate (u(3, size(x, 2)))
      call put('t', model%t)
      model%self_near_field = .false.
      model%self_full = .false.
      model%seconds_self = 0
      call model%velocity(x, u)
      call put('v_c_vertex', model%v_c)
      call put('self_s_vertex', model%seconds_self)
      model%self_full = .true.
      do k = 1, size(far)
         call model%self_layer%init(model%mesh, 4, far(k), near(k), sub(k))
         model%seconds_self = 0
         call model%velocity(x, u)
         write (key, '(i0,a,f0.1,a,f0.1)') far(k), '_', near(k), '_', sub(k)
         call put('v_c_'//trim(key), model%v_c)
         call put('self_s_'//trim(key), model%seconds_self)
         if (k == 1) u_ref = u
         call put('max_du_'//trim(key), maxval(norm2(u - u_ref, dim=1)) / maxval(norm2(u_ref, dim=1)))
      end do
      ! The model's own rules, with the 7-point rule on every capsule triangle at the wall
      ! nodes as well (the vertex rule beyond near_radius there is the next suspect).
      call model%self_layer%init(model%mesh, 4, far_edge, 3.0_dp, 2.0_dp)
      model%wall_near_radius = 100.0_dp
      call model%velocity(x, u)
      call put('v_c_full_capsule_at_wall_all_7_point', model%v_c)
      model%self_full = .false.
      call model%velocity(x, u)
      call put('v_c_vertex_capsule_at_wall_all_7_point', model%v_c)
   end subroutine probe_self_rules

   !> The membrane's own single layer from argument `iarg`: 0 the vertex rule, 1 with the
   !> near-field self correction, 2 the full 7-point rule (before init: the option; after:
   !> the switches).
   subroutine set_self_rule(opts, model, iarg)
      type(run_options_t), intent(inout) :: opts
      type(tube_capsule_t), intent(inout) :: model
      integer, intent(in) :: iarg
      integer :: mode
      mode = int_arg(iarg)
      opts%self_quadrature = trim(merge('full  ', 'vertex', mode == 2))
      model%self_full = mode == 2
      model%self_near_field = mode == 1
   end subroutine set_self_rule

   !> The NH 3D tube case of the command line: level, a/l, Ca_s, tube length, wall sizes and
   !> wall cache in arguments 2-8.
   subroutine read_tube_case(opts)
      type(run_options_t), intent(inout) :: opts
      opts%flow = 'tube'
      opts%model = '3d'
      opts%law = 'NH'
      opts%level = int_arg(2)
      opts%a_over_l = real_arg(3)
      opts%ca = real_arg(4)
      opts%tube_length = real_arg(5)
      opts%wall_h_far = real_arg(6)
      opts%wall_h_centre = real_arg(7)
      opts%wall_cache = string_arg(8)
      opts%quiet = .true.
   end subroutine read_tube_case

   subroutine probe_timing()
      type(run_options_t) :: opts
      type(tube_capsule_t) :: model
      integer :: stat, steps, k
      character(len=:), allocatable :: errmsg
      real(dp) :: t0, t_step, t_velocity

      call read_tube_case(opts)
      steps = int_arg(9)
      if (command_argument_count() >= 10) call set_self_rule(opts, model, 10)
      call model%init(opts, stat, errmsg)
      if (stat /= 0) error stop errmsg
      if (command_argument_count() >= 10) call set_self_rule(opts, model, 10)
      call put_int('threads', omp_get_max_threads())
      call put_int('n_nodes', model%mesh%n_nodes)
      call put_int('n_wall_nodes', model%wall%mesh%n_nodes)
      call put_int('from_cache', merge(1, 0, model%wall_op%from_cache))
      call put('wall_setup_s', model%wall_seconds)
      call put('wall_assembly_s', model%wall_op%assembly_seconds)
      call put('wall_factor_s', model%wall_op%factor_seconds)
      call put('wall_cache_s', model%wall_op%cache_seconds)
      call model%reset()
      t0 = omp_get_wtime()
      do k = 1, steps
         call model%advance()
      end do
      t_step = (omp_get_wtime() - t0) / max(steps, 1)
      model%seconds_capsule_at_wall = 0
      model%seconds_wall_solve = 0
      model%seconds_wall_at_capsule = 0
      model%seconds_self_near_field = 0
      model%seconds_self = 0
      t0 = omp_get_wtime()
      call model%velocity(model%positions, model%u0)
      t_velocity = omp_get_wtime() - t0
      call put('dt', model%dt)
      call put('rk2_step_s', t_step)
      call put('velocity_s', t_velocity)
      call put('capsule_at_wall_s', model%seconds_capsule_at_wall)
      call put('wall_solve_s', model%seconds_wall_solve)
      call put('wall_at_capsule_s', model%seconds_wall_at_capsule)
      call put('capsule_self_near_s', model%seconds_self_near_field)
      call put('capsule_self_s', model%seconds_self)
      call put('v_c', model%v_c)
      call put('max_speed', maxval(norm2(model%u0, dim=1)))
   end subroutine probe_timing

   subroutine probe_dl_outside()
      type(surface_mesh_t) :: mesh
      type(single_layer_t) :: sl
      type(double_layer_t) :: dl
      real(dp), allocatable :: x(:, :), u(:, :), p(:, :), w(:, :)
      real(dp) :: a, film, c(3)
      real(dp), parameter :: big_u(3) = [0.3_dp, -0.2_dp, 1.0_dp], omega(3) = [0.5_dp, 1.0_dp, -0.7_dp]
      integer :: stat, i, t, n
      character(len=:), allocatable :: errmsg
      a = real_arg(3)
      film = real_arg(4)
      call icosphere(int_arg(2), mesh, x, stat, errmsg)
      if (stat /= 0) error stop errmsg
      x = a * x
      n = mesh%n_nodes
      call sl%init(mesh, 4, 0)
      call dl%init(mesh, sl)
      call dl%set_geometry(mesh, x)
      allocate (u(3, n), p(3, n + mesh%n_tri), w(3, n + mesh%n_tri))
      do i = 1, n
         u(:, i) = big_u + cross(omega, x(:, i))
         p(:, i) = (a + film) * x(:, i) / norm2(x(:, i))
      end do
      do t = 1, mesh%n_tri
         c = sum(x(:, mesh%tri(:, t)), dim=2) / 3.0_dp
         p(:, n + t) = (a + film) * c / norm2(c)
      end do
      call dl%apply_outside(mesh, u, p, real_arg(5), w)
      call put_int('n_points', size(p, 2))
      call put('error_over_nodes', maxval(norm2(w(:, 1:n), dim=1)) / maxval(norm2(u, dim=1)))
      call put('error_over_centroids', maxval(norm2(w(:, n + 1:), dim=1)) / maxval(norm2(u, dim=1)))
      ! A constant density: 0 by construction (the nearest node's density is subtracted).
      u = spread(big_u, 2, n)
      call dl%apply_outside(mesh, u, p, real_arg(5), w)
      call put('constant_error', maxval(norm2(w, dim=1)) / norm2(big_u))
   end subroutine probe_dl_outside

   subroutine probe_lambda_residual()
      type(run_options_t) :: opts
      type(tube_capsule_t) :: base, model
      integer :: stat, steps, k, n
      character(len=:), allocatable :: errmsg
      real(dp), allocatable :: x(:, :), u1(:, :), ul(:, :), du(:, :), dl_wall(:, :), g(:, :), vw(:, :), res(:, :)
      real(dp) :: lambda, t0, t_base, t_lambda, flux

      call read_tube_case(opts)
      lambda = real_arg(9)
      steps = int_arg(10)
      call base%init(opts, stat, errmsg)
      if (stat /= 0) error stop errmsg
      opts%lambda = lambda
      call model%init(opts, stat, errmsg)
      if (stat /= 0) error stop errmsg
      call base%reset()
      do k = 1, steps
         call base%advance()
      end do
      x = base%positions
      n = size(x, 2)
      allocate (u1(3, n), ul(3, n), du(3, n), vw(3, n), res(3, n))
      allocate (dl_wall(3, base%wall%mesh%n_nodes), g(3, base%wall%mesh%n_nodes))
      t0 = omp_get_wtime()
      call base%velocity(x, u1)
      t_base = omp_get_wtime() - t0
      ! The right-hand side of the lambda solve: the lambda = 1 velocity, volume-corrected, lab frame.
      u1(3, :) = u1(3, :) + base%v_c
      t0 = omp_get_wtime()
      call model%velocity(x, ul)
      t_lambda = omp_get_wtime() - t0
      if (allocated(model%fault)) error stop model%fault
      ul = model%u_guess
      ! (1+lambda)/2 u - (1-lambda) D[u] - u_1 - S_wall g'/Ca, with S_wall g' = -Ca (1-lambda) D_out[u]
      ! at the wall nodes: the equation of the module header, from its pieces.
      call model%double_layer%set_geometry(model%mesh, x)
      call model%double_layer%apply(model%mesh, ul, du)
      call model%double_layer%apply_outside(model%mesh, ul, base%wall%x, 0.5_dp, dl_wall)
      dl_wall = -opts%ca * (1.0_dp - lambda) * dl_wall
      call base%wall_op%solve(dl_wall, g, stat, errmsg)
      if (stat /= 0) error stop errmsg
      call base%wall_op%velocity_at(base%wall, g, x, vw)
      res = 0.5_dp * (1.0_dp + lambda) * ul - (1.0_dp - lambda) * du - u1 - vw / opts%ca
      call put('lambda', lambda)
      call put('residual', maxval(norm2(res, dim=1)) / maxval(norm2(u1, dim=1)))
      ! The Wielandt deflation solves the equation plus (1-lambda)/2 (flux/area) n, which
      ! leaves a solution with zero flux unchanged: the discrete one carries a small flux.
      flux = model%double_layer%normal_flux(ul) / model%double_layer%area_sum
      res = res + 0.5_dp * (1.0_dp - lambda) * flux * model%double_layer%node_normal
      call put('residual_deflated', maxval(norm2(res, dim=1)) / maxval(norm2(u1, dim=1)))
      call put('mean_normal_velocity', flux / maxval(norm2(u1, dim=1)))
      call put('gmres_residual', model%interface%last_residual)
      call put_int('applications', model%interface%last_applications)
      call put('relative_change', maxval(norm2(ul - u1, dim=1)) / maxval(norm2(u1, dim=1)))
      call put('wall_dl_share', maxval(norm2(vw, dim=1)) / opts%ca / maxval(norm2(u1, dim=1)))
      ! Departure of the lab-frame velocity from its mean translation (a rigid interior at
      ! large lambda; no rotation on the axis by symmetry).
      call put('rigid_deviation', maxval(norm2(ul - spread(sum(ul, dim=2) / n, 2, n), dim=1)) / norm2(sum(ul, dim=2) / n))
      call put('v_c_base', base%v_c)
      call put('v_c_lambda', model%v_c)
      ! The polyhedron's volume against the sphere of radius a/l whose nodes it carries.
      block
         real(dp) :: grad(3, n), mgrad(3, n), volume, moment
         call volume_gradients(model%mesh, x, grad, mgrad, volume, moment)
         call put('volume_ratio', volume / (4.0_dp / 3.0_dp * pi * opts%a_over_l**3))
      end block
      call put('velocity_s_base', t_base)
      call put('velocity_s_lambda', t_lambda)
   end subroutine probe_lambda_residual

end program tube3d_probe
