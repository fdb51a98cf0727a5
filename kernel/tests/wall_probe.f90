!> wall_probe: measures the tube wall (tube_wall_mesh, wall_single_layer) and prints "key value"
!> lines; tests/kernel/test_tube_wall.py runs it and asserts, so every tolerance lives there.
!>
!>   wall_probe mesh L H_FAR H_CENTRE
!>   wall_probe matrix L H_FAR H_CENTRE DUFFY_ORDER    (null vectors; matrix rows = limit of velocity_at)
!>   wall_probe quadrature L H_FAR H_CENTRE MID_RADIUS (velocity_at against a brute-force rule)
!>   wall_probe poiseuille L H_FAR H_CENTRE DUFFY_ORDER GAUGE(0|1) MID_RADIUS [CACHE_DIR]
!>   wall_probe pointforce L H_FAR H_CENTRE MID_RADIUS (disturbance of a point force: exact integrals)
program wall_probe
   use omp_lib, only: omp_get_wtime, omp_get_max_threads
   use capsim_kinds, only: dp, pi
   use command_args, only: int_arg, real_arg, string_arg, put, put_int
   use vector_algebra, only: cross
   use triangle_quadrature, only: quadrature_rule_t, dunavant7_rule
   use tube_wall_mesh, only: tube_wall_t, build_tube_wall, wall_tag_cylinder, wall_tag_inlet, wall_tag_outlet, &
                             wall_tag_rim
   use wall_single_layer, only: wall_operator_t, poiseuille_velocity, poiseuille_rim_jump, corner_map
   use wall_mesh_quality, only: put_wall_topology, min_angle_deg, max_neighbour_size_ratio, side_edge_lengths
   implicit none

   character(len=64) :: command
   call get_command_argument(1, command)
   select case (command)
   case ('mesh')
      call probe_mesh(make_wall())
   case ('matrix')
      call probe_matrix(make_wall(), int_arg(5))
   case ('quadrature')
      call probe_quadrature(make_wall(), real_arg(5))
   case ('poiseuille')
      call probe_poiseuille(make_wall(), int_arg(5), int_arg(6) /= 0, real_arg(7), string_arg(8))
   case ('pointforce')
      call probe_point_force(make_wall(), real_arg(5))
   case default
      write (*, '(a)') 'usage: wall_probe mesh|matrix|quadrature|poiseuille|pointforce L H_FAR H_CENTRE ...'
      error stop 2
   end select

contains




   type(tube_wall_t) function make_wall() result(wall)
      integer :: stat
      character(len=:), allocatable :: errmsg
      call build_tube_wall(real_arg(2), real_arg(3), real_arg(4), wall, stat, errmsg)
      if (stat /= 0) error stop errmsg
   end function make_wall


   !> Topology (closed, consistently oriented, manifold), orientation, geometry, sizes.
   subroutine probe_mesh(wall)
      type(tube_wall_t), intent(in) :: wall
      integer :: t, i
      real(dp) :: volume, area, e(3), min_angle, radius_error, disk_error
      real(dp), allocatable :: centre(:), far(:)
      associate (mesh => wall%mesh, x => wall%x)
         volume = 0
         area = 0
         min_angle = 180
         do t = 1, mesh%n_tri
            e = cross(x(:, mesh%tri(2, t)) - x(:, mesh%tri(1, t)), x(:, mesh%tri(3, t)) - x(:, mesh%tri(1, t)))
            area = area + 0.5_dp * norm2(e)
            volume = volume + dot_product(x(:, mesh%tri(1, t)), e) / 6.0_dp
            min_angle = min(min_angle, min_angle_deg(x(:, mesh%tri(:, t))))
         end do
         ! Edge lengths on the cylinder in the centre (|z| < 1) and far (|z| > 2.2).
         call side_edge_lengths(wall, 0.0_dp, 1.0_dp, centre)
         call side_edge_lengths(wall, 2.2_dp, huge(1.0_dp), far)
         radius_error = 0
         disk_error = 0
         do i = 1, mesh%n_nodes
            select case (wall%tag(i))
            case (wall_tag_cylinder, wall_tag_rim)
               radius_error = max(radius_error, abs(norm2(x(1:2, i)) - 1.0_dp))
            case default
               disk_error = max(disk_error, abs(abs(x(3, i)) - 0.5_dp * wall%length))
            end select
            if (wall%tag(i) == wall_tag_rim) disk_error = max(disk_error, abs(abs(x(3, i)) - 0.5_dp * wall%length))
            if (wall%tag(i) == wall_tag_inlet .and. x(3, i) > 0) disk_error = huge(1.0_dp)
            if (wall%tag(i) == wall_tag_outlet .and. x(3, i) < 0) disk_error = huge(1.0_dp)
         end do
         call put_wall_topology(wall, 'n_cylinder')
         call put('volume', volume)
         call put('volume_exact', pi * wall%length)
         call put('area', area)
         call put('area_exact', 2 * pi * wall%length + 2 * pi)
         call put('radius_error', radius_error)
         call put('disk_plane_error', disk_error)
         call put('min_angle_deg', min_angle)
         call put('max_neighbour_size_ratio', max_neighbour_size_ratio(mesh, x))
         call put('h_centre_mean', sum(centre) / max(size(centre), 1))
         call put('h_centre_min', minval(centre))
         call put('h_centre_max', maxval(centre))
         if (size(far) > 0) then
            call put('h_far_mean', sum(far) / size(far))
            call put('h_far_min', minval(far))
            call put('h_far_max', maxval(far))
         end if
      end associate
   end subroutine probe_mesh

   !> A smooth, non-symmetric traction field for the consistency checks (any values at the
   !> rims: the disk side follows through the corner map in both routines compared).
   function smooth_traction(wall) result(f)
      type(tube_wall_t), intent(in) :: wall
      real(dp) :: f(3, wall%mesh%n_nodes)
      integer :: i
      do i = 1, wall%mesh%n_nodes
         associate (x => wall%x(:, i))
            f(:, i) = [sin(x(1) + 0.7_dp * x(3)), cos(2 * x(2)) * x(3), 1.0_dp + x(1) * x(2) - 0.3_dp * x(3)]
         end associate
      end do
   end function smooth_traction

   !> The assembled matrix: its two null vectors on the closed wall (a uniform pressure moves
   !> nothing; a single-layer velocity has no net flux through the wall), and each row against
   !> the limit of the off-wall evaluation (velocity_at, adaptive quadrature) at points
   !> approaching the node from inside: the single layer is continuous across the wall.
   subroutine probe_matrix(wall, duffy_order)
      type(tube_wall_t), intent(in) :: wall
      integer, intent(in) :: duffy_order
      type(wall_operator_t) :: op
      real(dp), allocatable :: at(:, :), rim_disk(:, :), f(:, :), u(:, :), un(:, :)
      real(dp), parameter :: depth(3) = [0.04_dp, 0.02_dp, 0.01_dp]
      integer, parameter :: n_samples = 6
      integer :: n, stat, sample(n_samples), s, k, i
      real(dp) :: t0, t_assembly, inward(3), points(3, 1), u_off(3, 1), err(size(depth))
      character(len=:), allocatable :: errmsg
      character(len=32) :: key
      n = wall%mesh%n_nodes
      call op%prepare(wall, stat, errmsg, duffy_order=duffy_order)
      if (stat /= 0) error stop errmsg
      allocate (at(3 * n, 3 * n), rim_disk(3 * op%n_rim, 3 * n), u(3, n), un(3, n))
      t0 = omp_get_wtime()
      call op%assemble(wall, at, rim_disk)
      t_assembly = omp_get_wtime() - t0
      f = smooth_traction(wall)
      u = reshape(matmul(reshape(f, [3 * n]), at), [3, n])
      un = reshape(matmul(reshape(op%node_normal, [3 * n]), at), [3, n])
      call put_int('n_nodes', n)
      call put_int('n_rim', op%n_rim)
      call put('assembly_s', t_assembly)
      call put('normal_traction_velocity_rel', maxval(abs(un)) / maxval(abs(u)))
      call put('flux_of_single_layer_rel', abs(sum(op%flux_weight * u)) / (op%total_area * maxval(abs(u))))
      ! Sample nodes: cylinder centre, cylinder next to a rim, disk centre, disk near the rim.
      sample = [nearest_node(wall, [1.0_dp, 0.0_dp, 0.0_dp]), &
                nearest_node(wall, [0.0_dp, 1.0_dp, 0.5_dp * wall%length - 0.3_dp]), &
                nearest_node(wall, [0.0_dp, 0.0_dp, -0.5_dp * wall%length]), &
                nearest_node(wall, [0.8_dp, 0.2_dp, 0.5_dp * wall%length]), &
                nearest_node(wall, [-0.7_dp, 0.7_dp, 0.0_dp]), &
                nearest_node(wall, [0.3_dp, -0.5_dp, -0.5_dp * wall%length])]
      err = 0
      do s = 1, n_samples
         i = sample(s)
         inward = -op%node_normal(:, i)
         do k = 1, size(depth)
            points(:, 1) = wall%x(:, i) + depth(k) * wall%h_centre * inward
            call op%velocity_at(wall, f, points, u_off)
            err(k) = max(err(k), norm2(u_off(:, 1) - u(:, i)) / maxval(abs(u)))
         end do
      end do
      do k = 1, size(depth)
         write (key, '(a,f4.2,a)') 'row_vs_limit_', depth(k), 'h'
         call put(trim(key), err(k))
      end do
      ! The single layer is Lipschitz across the wall: remove the O(depth) term.
      call put('row_vs_limit_extrapolated', abs(2 * err(3) - err(2)))
   end subroutine probe_matrix

   !> Vertex values of the P1 traction f on triangle t: the disk side of the rim nodes through
   !> the corner map (no rim jump).
   function triangle_traction(wall, op, f, t) result(fv)
      type(tube_wall_t), intent(in) :: wall
      type(wall_operator_t), intent(in) :: op
      real(dp), intent(in) :: f(:, :)
      integer, intent(in) :: t
      real(dp) :: fv(3, 3)
      integer :: m, k
      do m = 1, 3
         k = wall%mesh%tri(m, t)
         fv(:, m) = f(:, k)
         if (op%disk_tri(t) .and. wall%tag(k) == wall_tag_rim) fv(:, m) = matmul(corner_map(wall%x(:, k)), f(:, k))
      end do
   end function triangle_traction

   !> The node nearest to `target` that is not on a rim (rims have no single inward normal).
   integer function nearest_node(wall, target)
      type(tube_wall_t), intent(in) :: wall
      real(dp), intent(in) :: target(3)
      integer :: j
      real(dp) :: best
      best = huge(1.0_dp)
      nearest_node = 1
      do j = 1, wall%mesh%n_nodes
         if (wall%tag(j) == wall_tag_rim) cycle
         if (norm2(wall%x(:, j) - target) < best) then
            best = norm2(wall%x(:, j) - target)
            nearest_node = j
         end if
      end do
   end function nearest_node

   !> velocity_at (vertex rule beyond mid_radius, 7-point rule within) against a brute-force rule (the
   !> 7-point rule on 4**6 sub-triangles near the point, 4**3 elsewhere), for a smooth traction,
   !> at points 1, 0.5, 0.2, 0.1 and 0.05 wall-element sizes inside the wall.
   subroutine probe_quadrature(wall, mid_radius)
      type(tube_wall_t), intent(in) :: wall
      real(dp), intent(in) :: mid_radius
      type(wall_operator_t) :: op
      type(quadrature_rule_t) :: fine, coarse
      real(dp), parameter :: depth(5) = [1.0_dp, 0.5_dp, 0.2_dp, 0.1_dp, 0.05_dp]
      real(dp) :: points(3, size(depth)), u(3, size(depth)), ref(3), err, h
      real(dp), allocatable :: f(:, :)
      integer :: k, stat
      character(len=:), allocatable :: errmsg
      character(len=32) :: key
      call op%prepare(wall, stat, errmsg)
      if (stat /= 0) error stop errmsg
      op%mid_radius = mid_radius
      fine = dunavant7_rule(6)
      coarse = dunavant7_rule(3)
      f = smooth_traction(wall)
      h = wall%h_centre
      do k = 1, size(depth)
         points(:, k) = (1.0_dp - depth(k) * h) * [cos(0.37_dp), sin(0.37_dp), 0.0_dp] + [0.0_dp, 0.0_dp, 0.11_dp]
      end do
      call op%velocity_at(wall, f, points, u)
      err = 0
      do k = 1, size(depth)
         ref = brute_force(wall, op, f, fine, coarse, points(:, k))
         write (key, '(a,f4.2,a)') 'quadrature_error_', depth(k), 'h'
         call put(trim(key), norm2(u(:, k) - ref) / norm2(ref))
         err = max(err, norm2(u(:, k) - ref) / norm2(ref))
      end do
      call put('quadrature_error_max', err)
   end subroutine probe_quadrature

   !> 1/(8 pi) int_B J(p - y) . f dS with `fine` on triangles within 0.5 of p, `coarse` elsewhere
   !> (disk side of the rims through the corner map, as in velocity_at).
   function brute_force(wall, op, f, fine, coarse, p) result(acc)
      type(tube_wall_t), intent(in) :: wall
      type(wall_operator_t), intent(in) :: op
      real(dp), intent(in) :: f(:, :), p(3)
      type(quadrature_rule_t), intent(in) :: fine, coarse
      real(dp) :: acc(3), xv(3, 3), fv(3, 3), area
      integer :: t
      acc = 0
      do t = 1, wall%mesh%n_tri
         xv = wall%x(:, wall%mesh%tri(:, t))
         fv = triangle_traction(wall, op, f, t)
         area = 0.5_dp * norm2(cross(xv(:, 2) - xv(:, 1), xv(:, 3) - xv(:, 1)))
         if (norm2(p - sum(xv, dim=2) / 3) < 0.5_dp) then
            acc = acc + area * rule_sum(fine, p, xv, fv)
         else
            acc = acc + area * rule_sum(coarse, p, xv, fv)
         end if
      end do
      acc = acc / (8 * pi)
   end function brute_force

   !> sum_q w_q J(p - y_q) . f(y_q) over a barycentric rule on the triangle (xv, fv).
   function rule_sum(rule, p, xv, fv) result(w)
      type(quadrature_rule_t), intent(in) :: rule
      real(dp), intent(in) :: p(3), xv(3, 3), fv(3, 3)
      real(dp) :: w(3), g(3), r(3)
      integer :: q
      w = 0
      do q = 1, size(rule%weight)
         g = matmul(fv, rule%bary(:, q))
         r = p - matmul(xv, rule%bary(:, q))
         w = w + rule%weight(q) * (g / norm2(r) + r * dot_product(r, g) / norm2(r)**3)
      end do
   end function rule_sum

   !> Tube wall alone: total Poiseuille flow in the closed tube. Solve the wall equation for the
   !> traction, compare it with the Poiseuille wall stress, and evaluate the velocity inside.
   subroutine probe_poiseuille(wall, duffy_order, gauge, mid_radius, cache_dir)
      type(tube_wall_t), intent(in) :: wall
      integer, intent(in) :: duffy_order
      logical, intent(in) :: gauge
      real(dp), intent(in) :: mid_radius
      character(len=*), intent(in) :: cache_dir
      type(wall_operator_t) :: op
      real(dp), allocatable :: rhs(:, :), f(:, :), jump(:, :)
      real(dp), parameter :: radii(3) = [0.0_dp, 0.5_dp, 0.8_dp]
      real(dp) :: points(3, 6), u_sl(3, 6), u_dl(3, 6), er(3), ephi(3), z, p_num, t0, t_rhs, t_solve, t_points
      real(dp) :: shear_max, shear_sum, pres_max, azim_max, sz, szz, sp, szp, cnt, grad, offset, fit_max, vel_err
      real(dp) :: shear_all_max, centre_err(2), ex(3)
      integer :: i, k, stat, n_central
      character(len=:), allocatable :: errmsg
      character(len=32) :: key

      call op%init(wall, cache_dir, stat, errmsg, duffy_order=duffy_order, pressure_gauge=gauge)
      if (stat /= 0) error stop errmsg
      op%mid_radius = mid_radius
      allocate (rhs(3, wall%mesh%n_nodes), f(3, wall%mesh%n_nodes), jump(3, wall%mesh%n_nodes))
      call poiseuille_rim_jump(wall, jump)
      t0 = omp_get_wtime()
      call op%poiseuille_rhs(wall, rhs)
      t_rhs = omp_get_wtime() - t0
      t0 = omp_get_wtime()
      call op%solve(rhs, f, stat, errmsg)
      if (stat /= 0) error stop errmsg
      t_solve = omp_get_wtime() - t0

      ! Cylinder away from the ends (|z| <= L/2 - 1): f = -p e_r - 4 e_z with p = -8 z.
      shear_max = 0
      shear_sum = 0
      shear_all_max = 0
      pres_max = 0
      azim_max = 0
      n_central = 0
      sz = 0
      szz = 0
      sp = 0
      szp = 0
      do i = 1, wall%mesh%n_nodes
         if (wall%tag(i) /= wall_tag_cylinder) cycle
         er = [wall%x(1, i), wall%x(2, i), 0.0_dp] / norm2(wall%x(1:2, i))
         ephi = [-er(2), er(1), 0.0_dp]
         z = wall%x(3, i)
         shear_all_max = max(shear_all_max, abs(f(3, i) + 4.0_dp))
         if (abs(z) > 0.5_dp * wall%length - 1.0_dp + 1.0e-9_dp) cycle
         n_central = n_central + 1
         p_num = -dot_product(f(:, i), er)
         shear_max = max(shear_max, abs(f(3, i) + 4.0_dp))
         shear_sum = shear_sum + (f(3, i) + 4.0_dp)**2
         pres_max = max(pres_max, abs(p_num + 8.0_dp * z))
         azim_max = max(azim_max, abs(dot_product(f(:, i), ephi)))
         sz = sz + z
         szz = szz + z * z
         sp = sp + p_num
         szp = szp + z * p_num
      end do
      cnt = n_central
      grad = (cnt * szp - sz * sp) / (cnt * szz - sz * sz)
      offset = (sp - grad * sz) / cnt
      fit_max = 0
      do i = 1, wall%mesh%n_nodes
         if (wall%tag(i) /= wall_tag_cylinder) cycle
         z = wall%x(3, i)
         if (abs(z) > 0.5_dp * wall%length - 1.0_dp + 1.0e-9_dp) cycle
         er = [wall%x(1, i), wall%x(2, i), 0.0_dp] / norm2(wall%x(1:2, i))
         fit_max = max(fit_max, abs(-dot_product(f(:, i), er) - (offset + grad * z)))
      end do
      ! Disk centres: f = +p e_z (entry), -p e_z (exit), p = -8 z.
      centre_err = 0
      do i = 1, wall%mesh%n_nodes
         if (norm2(wall%x(1:2, i)) > 1.0e-12_dp) cycle
         z = wall%x(3, i)
         ex = [0.0_dp, 0.0_dp, -8.0_dp * z * merge(1.0_dp, -1.0_dp, wall%tag(i) == wall_tag_inlet)]
         centre_err(merge(1, 2, wall%tag(i) == wall_tag_inlet)) = norm2(f(:, i) - ex)
      end do

      ! Interior velocity at z = 0 (and z = 0.37) for r = 0, 0.5, 0.8.
      do k = 1, 3
         points(:, k) = [radii(k) * cos(0.3_dp), radii(k) * sin(0.3_dp), 0.0_dp]
         points(:, k + 3) = [radii(k) * cos(1.9_dp), radii(k) * sin(1.9_dp), 0.37_dp]
      end do
      t0 = omp_get_wtime()
      call op%velocity_at(wall, f, points, u_sl, jump)
      t_points = omp_get_wtime() - t0
      call op%section_double_layer(wall, points, u_dl)
      vel_err = 0

      call put_int('n_nodes', wall%mesh%n_nodes)
      call put_int('matrix_order', 3 * wall%mesh%n_nodes)
      call put('matrix_mb', 8.0_dp * (3.0_dp * wall%mesh%n_nodes)**2 / 2.0_dp**20)
      call put_int('threads', omp_get_max_threads())
      call put_int('from_cache', merge(1, 0, op%from_cache))
      write (*, '(a,1x,a)') 'cache_message', op%cache_message
      call put('assembly_s', op%assembly_seconds)
      call put('factor_s', op%factor_seconds)
      call put('cache_s', op%cache_seconds)
      call put('rhs_s', t_rhs)
      call put('solve_s', t_solve)
      call put('points_s', t_points)
      call put('rcond', op%rcond)
      call put('mean_normal_traction', sum(op%flux_weight * f) / op%total_area)
      call put_int('n_central', n_central)
      call put('shear_error_max', shear_max)
      call put('shear_error_rms', sqrt(shear_sum / cnt))
      call put('shear_error_max_whole_cylinder', shear_all_max)
      call put('pressure_error_max', pres_max)
      call put('pressure_gradient', grad)
      call put('pressure_offset', offset)
      call put('pressure_fit_residual_max', fit_max)
      call put('azimuthal_traction_max', azim_max)
      call put('inlet_centre_traction_error', centre_err(1))
      call put('outlet_centre_traction_error', centre_err(2))
      do k = 1, 6
         ex = poiseuille_velocity(points(:, k))
         write (key, '(a,f3.1,a,i0)') 'velocity_error_r', radii(mod(k - 1, 3) + 1), '_', (k - 1) / 3
         call put(trim(key), norm2(u_sl(:, k) + u_dl(:, k) - ex))
         vel_err = max(vel_err, norm2(u_sl(:, k) + u_dl(:, k) - ex))
      end do
      call put('velocity_error_max', vel_err)
      call put('u_axis', u_sl(3, 1) + u_dl(3, 1))
      call put('double_layer_axis', u_dl(3, 1))
   end subroutine probe_poiseuille

   !> The paper's formulation with a point force F at x0 inside the tube (a stand-in for the
   !> capsule): the wall traction f+ cancels the Stokeslet's velocity on the whole wall,
   !> f+ = solve(-u_stokeslet). Exact for any closed tube: force balance int_B f+ dS = -F, torque
   !> int_B (y - x0) x f+ dS = 0, and (reciprocal theorem with Poiseuille flow in the same tube)
   !> int_disks v_inf . f+ dS = -F . v_inf(x0): the point force raises the pressure ahead of it
   !> by 2 F_z v_inf(x0)/(2 pi) and the cylinder carries +F_z (axial force on the axis).
   subroutine probe_point_force(wall, mid_radius)
      type(tube_wall_t), intent(in) :: wall
      real(dp), intent(in) :: mid_radius
      type(wall_operator_t) :: op
      real(dp), parameter :: x0(3) = [0.3_dp, -0.2_dp, 0.1_dp], force(3) = [0.4_dp, -0.3_dp, 1.0_dp]
      real(dp), allocatable :: u(:, :), f(:, :)
      real(dp) :: total(3), torque(3), flux_work, cyl_z, xv(3, 3), fv(3, 3), y(3), g(3), w
      real(dp) :: points(3, 4), u_ref(3, 4), u_mid(3, 4), t0, t_mid, t_ref, r(3)
      integer :: i, t, q, stat
      character(len=:), allocatable :: errmsg
      type(quadrature_rule_t) :: rule
      call op%init(wall, '', stat, errmsg)
      if (stat /= 0) error stop errmsg
      allocate (u(3, wall%mesh%n_nodes), f(3, wall%mesh%n_nodes))
      do i = 1, wall%mesh%n_nodes
         r = wall%x(:, i) - x0
         u(:, i) = -(force / norm2(r) + r * dot_product(r, force) / norm2(r)**3) / (8 * pi)
      end do
      call op%solve(u, f, stat, errmsg)
      if (stat /= 0) error stop errmsg
      ! Integrals of the P1 traction (disk side of the rims through the corner map), 7-point rule.
      rule = dunavant7_rule(0)
      total = 0
      torque = 0
      flux_work = 0
      cyl_z = 0
      do t = 1, wall%mesh%n_tri
         xv = wall%x(:, wall%mesh%tri(:, t))
         fv = triangle_traction(wall, op, f, t)
         do q = 1, size(rule%weight)
            y = matmul(xv, rule%bary(:, q))
            g = matmul(fv, rule%bary(:, q))
            w = op%tri_area(t) * rule%weight(q)
            total = total + w * g
            torque = torque + w * cross(y - x0, g)
            if (op%disk_tri(t)) then
               flux_work = flux_work + w * dot_product(poiseuille_velocity(y), g)
            else
               cyl_z = cyl_z + w * g(3)
            end if
         end do
      end do
      call put_int('n_nodes', wall%mesh%n_nodes)
      call put('force_balance_error', norm2(total + force) / norm2(force))
      call put('torque_error', norm2(torque) / norm2(force))
      call put('disk_work', flux_work)
      call put('disk_work_exact', -dot_product(force, poiseuille_velocity(x0)))
      call put('disk_work_rel_error', abs(flux_work + dot_product(force, poiseuille_velocity(x0))) &
               / abs(dot_product(force, poiseuille_velocity(x0))))
      call put('cylinder_axial_force', cyl_z)
      ! Disturbance velocity at interior points: velocity_at with mid_radius against all 7-point.
      points = reshape([0.0_dp, 0.0_dp, 0.6_dp, 0.9_dp, 0.0_dp, 0.0_dp, 0.0_dp, 0.7_dp, -0.5_dp, &
                        -0.5_dp, 0.5_dp, 1.2_dp], [3, 4])
      op%mid_radius = mid_radius
      t0 = omp_get_wtime()
      call op%velocity_at(wall, f, points, u_mid)
      t_mid = omp_get_wtime() - t0
      op%mid_radius = 1.0e6_dp
      t0 = omp_get_wtime()
      call op%velocity_at(wall, f, points, u_ref)
      t_ref = omp_get_wtime() - t0
      call put('velocity_at_vs_all_7_point', maxval(norm2(u_mid - u_ref, dim=1)) / maxval(norm2(u_ref, dim=1)))
      call put('velocity_at_s_per_point', t_mid / size(points, 2))
      call put('all_7_point_s_per_point', t_ref / size(points, 2))
   end subroutine probe_point_force

end program wall_probe
