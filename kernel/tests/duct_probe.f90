!> duct_probe: measures the rectangular duct (duct_poiseuille, duct_wall_mesh) and prints
!> "key value" lines; tests/kernel/test_duct.py runs it and asserts, so every tolerance lives
!> there. Lengths in duct half-widths (w = 1, h = ASPECT), mean velocity 1, viscosity 1.
!>
!>   duct_probe flow ASPECT                        (series: centre, mean, walls, shear, traction)
!>   duct_probe mesh L H_FAR H_CENTRE ASPECT [EDGES] (wall mesh: topology, geometry, quality,
!>                                        grading, Poiseuille data on it, the tube wall's operator)
!>   duct_probe poiseuille L H_FAR H_CENTRE ASPECT [EDGES] (the wall alone: the wall integral
!>                                        equation for the total Poiseuille flow; traction, velocity)
!>
!> EDGES: 1 grades the lateral rings towards the long edges (build_duct_wall's grade_edges),
!> 0 or absent keeps them uniform.
program duct_probe
   use capsim_kinds, only: dp
   use command_args, only: int_arg, real_arg, put, put_int
   use vector_algebra, only: cross
   use triangle_quadrature, only: gauss_legendre_01, quadrature_rule_t, dunavant7_rule
   use tube_wall_mesh, only: tube_wall_t, build_tube_wall, wall_tag_cylinder, wall_tag_inlet, wall_tag_outlet, &
                             wall_tag_rim
   use duct_poiseuille, only: duct_flow_t, build_duct_flow
   use duct_wall_mesh, only: duct_wall_t, build_duct_wall
   use wall_single_layer, only: wall_operator_t, poiseuille_rim_jump
   use wall_mesh_quality, only: put_wall_topology, min_angle_deg, aspect_ratio, max_neighbour_size_ratio, &
                                side_edge_lengths
   implicit none

   character(len=64) :: command
   call get_command_argument(1, command)
   select case (command)
   case ('flow')
      call probe_flow(make_flow(real_arg(2)))
   case ('mesh')
      call probe_mesh(real_arg(2), real_arg(3), real_arg(4), real_arg(5), edges_graded_arg(6))
   case ('poiseuille')
      call probe_poiseuille(real_arg(2), real_arg(3), real_arg(4), real_arg(5), edges_graded_arg(6))
   case default
      write (*, '(a)') 'usage: duct_probe flow ASPECT | duct_probe mesh|poiseuille L H_FAR H_CENTRE ASPECT [EDGES]'
      error stop 2
   end select

contains

   !> The optional EDGES argument at position k: graded (1) or uniform (0, or absent).
   logical function edges_graded_arg(k)
      integer, intent(in) :: k
      edges_graded_arg = .false.
      if (command_argument_count() >= k) edges_graded_arg = int_arg(k) /= 0
   end function edges_graded_arg

   type(duct_flow_t) function make_flow(aspect) result(flow)
      real(dp), intent(in) :: aspect
      integer :: stat
      character(len=:), allocatable :: errmsg
      call build_duct_flow(1.0_dp, aspect, flow, stat, errmsg)
      if (stat /= 0) error stop errmsg
   end function make_flow

   subroutine probe_flow(flow)
      type(duct_flow_t), intent(in) :: flow
      ! Sample points as fractions of (w, h), for the test's independent series.
      real(dp), parameter :: sample(2, 6) = reshape([0.0_dp, 0.0_dp, 0.5_dp, 0.25_dp, -0.9_dp, 0.7_dp, &
                                                     0.3_dp, -0.95_dp, 0.97_dp, 0.97_dp, -0.2_dp, 0.6_dp], [2, 6])
      real(dp), parameter :: fd_step = 1.0e-5_dp
      real(dp) :: w, h, u, grad(2), bound, p(2), wall_max, q(2), shear_integral, slope_error(2), shear_max, delta
      real(dp) :: f(3), x(3)
      integer :: k, side, j, n_points, m
      character(len=32) :: key
      w = flow%half_width
      h = flow%half_height
      call put('half_width', w)
      call put('half_height', h)
      call put('pressure_gradient', flow%pressure_gradient)
      call put('mean_series_bound', flow%mean_series_bound)
      call put_int('mean_terms', flow%mean_terms)
      call put('centre_velocity', flow%centre_velocity())
      call flow%evaluate(0.0_dp, 0.0_dp, .false., u, grad, bound)
      call put('centre_velocity_bound', bound)
      ! Mean of the velocity over the cross-section by Gauss-Legendre (quadrant, symmetry).
      do m = 48, 96, 48
         call gauss_mean(flow, m)
      end do
      do k = 1, size(sample, 2)
         p = sample(:, k) * [w, h]
         write (key, '(a,i0)') 'pt', k
         call flow%evaluate(p(1), p(2), .true., u, grad, bound)
         call put(trim(key) // '_x', p(1))
         call put(trim(key) // '_y', p(2))
         call put(trim(key) // '_u', u)
         call put(trim(key) // '_dudx', grad(1))
         call put(trim(key) // '_dudy', grad(2))
         call put(trim(key) // '_dudx_fd', (flow%velocity(p(1) + fd_step, p(2)) - flow%velocity(p(1) - fd_step, p(2))) &
                  / (2 * fd_step))
         call put(trim(key) // '_dudy_fd', (flow%velocity(p(1), p(2) + fd_step) - flow%velocity(p(1), p(2) - fd_step)) &
                  / (2 * fd_step))
      end do
      ! Walls: the velocity on them, and its slope into the fluid against the wall shear.
      n_points = 50
      wall_max = 0
      shear_max = 0
      slope_error = 0
      do side = 1, 4
         do j = 1, n_points - 1
            call wall_point(w, h, side, real(j, dp) / n_points, q, p)
            wall_max = max(wall_max, abs(flow%velocity(q(1), q(2))))
            grad = flow%velocity_gradient(q(1), q(2))
            shear_max = max(shear_max, abs(dot_product(grad, p)))
            do m = 1, 2
               delta = merge(1.0e-4_dp, 1.0e-7_dp, m == 1)
               ! u(q - delta n) = -delta du/dn + O(delta^2).
               slope_error(m) = max(slope_error(m), abs(flow%velocity(q(1) - delta * p(1), q(2) - delta * p(2)) / delta &
                                                          + dot_product(grad, p)))
            end do
         end do
      end do
      call put('wall_velocity_max', wall_max)
      call put('wall_shear_max', shear_max)
      call put('slope_error_1e-4', slope_error(1))
      call put('slope_error_1e-7', slope_error(2))
      call put('corner_gradient', norm2(flow%velocity_gradient(w, h)))
      ! Force balance on a unit length of duct: wall shear around the perimeter = -G area.
      do m = 64, 128, 64
         shear_integral = perimeter_shear(flow, m)
         write (key, '(a,i0)') 'wall_shear_integral_', m
         call put(trim(key), shear_integral)
      end do
      call put('pressure_force', flow%pressure_gradient * 4 * w * h)
      ! Traction on a side wall (x = w) and on the entry section, reference pressure 0.3.
      x = [w, 0.3_dp * h, 0.7_dp]
      f = flow%traction(x, [1.0_dp, 0.0_dp, 0.0_dp], 0.3_dp)
      call put('side_traction_x', f(1))
      call put('side_traction_y', f(2))
      call put('side_traction_z', f(3))
      call put('side_slope', -flow%velocity(w - 1.0e-7_dp, 0.3_dp * h) / 1.0e-7_dp)
      call put('side_pressure', flow%pressure(0.7_dp, 0.3_dp))
      x = [0.2_dp * w, 0.4_dp * h, -2.0_dp]
      f = flow%traction(x, [0.0_dp, 0.0_dp, -1.0_dp], 0.3_dp)
      call put('inlet_traction_x', f(1))
      call put('inlet_traction_y', f(2))
      call put('inlet_traction_z', f(3))
      call put('inlet_dudx_fd', (flow%velocity(x(1) + fd_step, x(2)) - flow%velocity(x(1) - fd_step, x(2))) / (2 * fd_step))
      call put('inlet_dudy_fd', (flow%velocity(x(1), x(2) + fd_step) - flow%velocity(x(1), x(2) - fd_step)) / (2 * fd_step))
      call put('inlet_pressure', flow%pressure(-2.0_dp, 0.3_dp))

   end subroutine probe_flow

   !> Mean velocity by an m x m Gauss-Legendre rule on the quadrant, and the sum of the
   !> weighted truncation bounds.
   subroutine gauss_mean(flow, n)
      type(duct_flow_t), intent(in) :: flow
      integer, intent(in) :: n
      real(dp) :: t(n), wt(n), total, total_bound, uu, gg(2), bb
      integer :: a, b
      character(len=32) :: name
      call gauss_legendre_01(n, t, wt)
      total = 0
      total_bound = 0
      do a = 1, n
         do b = 1, n
            call flow%evaluate(t(a) * flow%half_width, t(b) * flow%half_height, .false., uu, gg, bb, tolerance=1.0e-14_dp)
            total = total + wt(a) * wt(b) * uu
            total_bound = total_bound + wt(a) * wt(b) * bb
         end do
      end do
      write (name, '(a,i0)') 'mean_gauss_', n
      call put(trim(name), total)
      write (name, '(a,i0)') 'mean_gauss_bound_', n
      call put(trim(name), total_bound)
   end subroutine gauss_mean

   !> Point at fraction s along wall side (1: x = w, 2: y = h, 3: x = -w, 4: y = -h) and its
   !> outward normal.
   subroutine wall_point(w, h, side, s, point, normal)
      integer, intent(in) :: side
      real(dp), intent(in) :: w, h, s
      real(dp), intent(out) :: point(2), normal(2)
      select case (side)
      case (1)
         point = [w, h * (2 * s - 1)]
         normal = [1.0_dp, 0.0_dp]
      case (2)
         point = [w * (2 * s - 1), h]
         normal = [0.0_dp, 1.0_dp]
      case (3)
         point = [-w, h * (2 * s - 1)]
         normal = [-1.0_dp, 0.0_dp]
      case default
         point = [w * (2 * s - 1), -h]
         normal = [0.0_dp, -1.0_dp]
      end select
   end subroutine wall_point

   !> Integral of du/dn around the perimeter, n Gauss points per side.
   real(dp) function perimeter_shear(flow, n) result(total)
      type(duct_flow_t), intent(in) :: flow
      integer, intent(in) :: n
      real(dp) :: t(n), wt(n), pt(2), nr(2), length
      integer :: sd, a
      call gauss_legendre_01(n, t, wt)
      total = 0
      do sd = 1, 4
         length = 2 * merge(flow%half_height, flow%half_width, sd == 1 .or. sd == 3)
         do a = 1, n
            call wall_point(flow%half_width, flow%half_height, sd, t(a), pt, nr)
            total = total + wt(a) * length * dot_product(flow%velocity_gradient(pt(1), pt(2)), nr)
         end do
      end do
   end function perimeter_shear

   !> Topology (closed, consistently oriented, manifold), geometry (nodes on the faces, area,
   !> volume), quality (angles and aspect ratios on the side walls and on the end sections,
   !> neighbour sizes), grading (rings against the tube's), the Poiseuille data on the mesh
   !> (flux through the sections, net force), and the tube wall's operator set up on it.
   subroutine probe_mesh(length, h_far, h_centre, aspect, edges_graded)
      real(dp), intent(in) :: length, h_far, h_centre, aspect
      logical, intent(in) :: edges_graded
      type(duct_wall_t) :: wall
      type(tube_wall_t) :: tube
      type(duct_flow_t) :: flow
      type(quadrature_rule_t) :: rule
      type(wall_operator_t) :: single_layer
      integer :: stat, t, k, i, q, inward
      character(len=:), allocatable :: errmsg
      real(dp) :: e(3), area, volume, min_angle, max_aspect, face_error, tri_area, xv(3, 3)
      real(dp) :: section_min_angle, section_max_aspect
      real(dp), allocatable :: z_duct(:), z_tube(:), centre(:)
      real(dp) :: inlet_flux, outlet_flux, net_force(3), yq(3), nrm(3)
      character(len=32) :: key
      integer :: n_ring_nodes
      call build_duct_wall(length, h_far, h_centre, wall, stat, errmsg, aspect, edges_graded)
      if (stat /= 0) error stop errmsg
      associate (mesh => wall%mesh, x => wall%x, w => wall%half_width, h => wall%half_height)
         inward = 0
         area = 0
         volume = 0
         min_angle = 180
         max_aspect = 1
         section_min_angle = 180
         section_max_aspect = 1
         do t = 1, mesh%n_tri
            xv = x(:, mesh%tri(:, t))
            e = cross(xv(:, 2) - xv(:, 1), xv(:, 3) - xv(:, 1))
            tri_area = 0.5_dp * norm2(e)
            area = area + tri_area
            ! The duct is convex and centred on the origin: an outward normal points away from it.
            if (dot_product(e, sum(xv, dim=2)) <= 0.0_dp) inward = inward + 1
            volume = volume + dot_product(xv(:, 1), e) / 6.0_dp
            if (abs(e(3)) > 0.0_dp) then
               section_min_angle = min(section_min_angle, min_angle_deg(xv))
               section_max_aspect = max(section_max_aspect, aspect_ratio(xv))
            else
               min_angle = min(min_angle, min_angle_deg(xv))
               max_aspect = max(max_aspect, aspect_ratio(xv))
            end if
         end do
         ! Every node on the duct's surface: on a side wall, or in an end plane.
         face_error = 0
         do i = 1, mesh%n_nodes
            select case (wall%tag(i))
            case (wall_tag_cylinder)
               face_error = max(face_error, min(abs(abs(x(1, i)) - w), abs(abs(x(2, i)) - h)), &
                                max(abs(x(1, i)) - w, abs(x(2, i)) - h, abs(x(3, i)) - 0.5_dp * length, 0.0_dp))
            case (wall_tag_rim)
               face_error = max(face_error, min(abs(abs(x(1, i)) - w), abs(abs(x(2, i)) - h)), &
                                abs(abs(x(3, i)) - 0.5_dp * length))
            case (wall_tag_inlet)
               face_error = max(face_error, abs(x(3, i) + 0.5_dp * length), max(abs(x(1, i)) - w, abs(x(2, i)) - h, 0.0_dp))
            case (wall_tag_outlet)
               face_error = max(face_error, abs(x(3, i) - 0.5_dp * length), max(abs(x(1, i)) - w, abs(x(2, i)) - h, 0.0_dp))
            case default
               face_error = huge(1.0_dp)
            end select
         end do
         call put_wall_topology(wall%tube_wall_t, 'n_side')
         call put_int('inward_normals', inward)
         call put('half_width', w)
         call put('half_height', h)
         call put('area', area)
         call put('volume', volume)
         call put('face_error', face_error)
         call put('side_min_angle_deg', min_angle)
         call put('side_max_aspect_ratio', max_aspect)
         call put('section_min_angle_deg', section_min_angle)
         call put('section_max_aspect_ratio', section_max_aspect)
         call put('max_neighbour_size_ratio', max_neighbour_size_ratio(mesh, x))
         ! Mean side-wall edge length over |z| < 1 (the refined centre).
         call side_edge_lengths(wall%tube_wall_t, 0.0_dp, 1.0_dp, centre)
         call put('h_centre_mean', sum(centre) / max(size(centre), 1))
         ! Rings: z and node count of each, and their largest distance from the tube's rings.
         z_duct = ring_positions(x, wall%tag)
         do k = 1, size(z_duct)
            write (key, '(a,i0)') 'ring_z_', k - 1
            call put(trim(key), z_duct(k))
            n_ring_nodes = count(abs(x(3, :) - z_duct(k)) < 1.0e-12_dp .and. &
                                 (wall%tag == wall_tag_cylinder .or. wall%tag == wall_tag_rim))
            write (key, '(a,i0)') 'ring_nodes_', k - 1
            call put_int(trim(key), n_ring_nodes)
         end do
         call build_tube_wall(length, h_far, h_centre, tube, stat, errmsg)
         if (stat /= 0) error stop errmsg
         z_tube = ring_positions(tube%x, tube%tag)
         if (size(z_tube) == size(z_duct)) then
            call put('ring_z_tube_difference', maxval(abs(z_tube - z_duct)))
         else
            call put('ring_z_tube_difference', huge(1.0_dp))
         end if
         ! Poiseuille data on the mesh (7-point rule per triangle): flux through each section,
         ! and the net force of the exact traction on the closed surface (zero for Stokes flow).
         call build_duct_flow(w, h, flow, stat, errmsg)
         if (stat /= 0) error stop errmsg
         rule = dunavant7_rule(0)
         inlet_flux = 0
         outlet_flux = 0
         net_force = 0
         do t = 1, mesh%n_tri
            e = cross(x(:, mesh%tri(2, t)) - x(:, mesh%tri(1, t)), x(:, mesh%tri(3, t)) - x(:, mesh%tri(1, t)))
            nrm = e / norm2(e)
            tri_area = 0.5_dp * norm2(e)
            do q = 1, size(rule%weight)
               yq = matmul(x(:, mesh%tri(:, t)), rule%bary(:, q))
               net_force = net_force + rule%weight(q) * tri_area * flow%traction(yq, nrm, 0.0_dp)
               if (abs(nrm(3)) > 0.5_dp) then
                  if (nrm(3) < 0) then
                     inlet_flux = inlet_flux - rule%weight(q) * tri_area * flow%velocity(yq(1), yq(2))
                  else
                     outlet_flux = outlet_flux + rule%weight(q) * tri_area * flow%velocity(yq(1), yq(2))
                  end if
               end if
            end do
         end do
         call put('inlet_flux', inlet_flux)
         call put('outlet_flux', outlet_flux)
         call put('net_force_x', net_force(1))
         call put('net_force_y', net_force(2))
         call put('net_force_z', net_force(3))
         call put('pressure_drop_force', flow%pressure_gradient * length * 4 * w * h)
         ! The wall operator on the duct: its mapped slots (rims, long edges, box corners).
         call single_layer%prepare(wall, stat, errmsg)
         if (stat /= 0) error stop errmsg
         call put('operator_area', single_layer%total_area)
         call put_int('operator_nodes', single_layer%n_nodes)
         call put_int('operator_slots', single_layer%n_rim)
      end associate
   end subroutine probe_mesh

   !> The duct wall alone (the total Poiseuille flow in the closed duct): the wall equation
   !> solved for the traction (wall_operator_t's poiseuille_rhs, with the duct's data), against
   !> the exact one on the side walls away from the ends (|z| <= L/2 - 1) and off the long
   !> edges, and the velocity it gives inside (single layer of the traction plus the sections'
   !> double layer) against the series. Errors relative to u_max and to the largest wall shear.
   subroutine probe_poiseuille(length, h_far, h_centre, aspect, edges_graded)
      real(dp), intent(in) :: length, h_far, h_centre, aspect
      logical, intent(in) :: edges_graded
      type(duct_wall_t) :: wall
      type(wall_operator_t) :: op
      real(dp), allocatable :: rhs(:, :), f(:, :), jump(:, :)
      real(dp), parameter :: fractions(2, 4) = reshape([0.0_dp, 0.0_dp, 0.5_dp, 0.3_dp, 0.8_dp, 0.0_dp, &
                                                        0.7_dp, 0.7_dp], [2, 4])
      real(dp) :: points(3, 8), u_sl(3, 8), u_dl(3, 8), n(3), g(3), shear_exact, shear_scale, shear_max, shear_sum
      real(dp) :: z, grad, vel_err, worst(3)
      real(dp), allocatable :: z_central(:), p_central(:)
      integer :: i, k, stat, n_central
      character(len=:), allocatable :: errmsg

      call build_duct_wall(length, h_far, h_centre, wall, stat, errmsg, aspect, edges_graded)
      if (stat /= 0) error stop errmsg
      call op%init(wall, '', stat, errmsg)
      if (stat /= 0) error stop errmsg
      op%mid_radius = 100.0_dp
      allocate (rhs(3, wall%mesh%n_nodes), f(3, wall%mesh%n_nodes), jump(3, wall%mesh%n_nodes))
      call poiseuille_rim_jump(wall, jump)
      call op%poiseuille_rhs(wall, rhs)
      call op%solve(rhs, f, stat, errmsg)
      if (stat /= 0) error stop errmsg

      shear_scale = maxval(abs(wall%flow%velocity_gradient(1.0_dp, 0.0_dp)))
      shear_scale = max(shear_scale, maxval(abs(wall%flow%velocity_gradient(0.0_dp, aspect))))
      shear_max = 0
      shear_sum = 0
      n_central = 0
      allocate (z_central(0), p_central(0))
      do i = 1, wall%mesh%n_nodes
         if (wall%tag(i) /= wall_tag_cylinder) cycle
         z = wall%x(3, i)
         if (abs(z) > 0.5_dp * length - 1.0_dp + 1.0e-9_dp) cycle
         ! Off the long edges, where the traction jumps.
         if (abs(abs(wall%x(1, i)) - 1.0_dp) < 1.0e-9_dp .and. abs(abs(wall%x(2, i)) - aspect) < 1.0e-9_dp) cycle
         n = wall%side_normal(wall%x(:, i))
         g = wall%undisturbed_gradient(wall%x(:, i))
         shear_exact = dot_product(g, n)
         n_central = n_central + 1
         if (abs(f(3, i) - shear_exact) > shear_max) worst = wall%x(:, i)
         shear_max = max(shear_max, abs(f(3, i) - shear_exact))
         shear_sum = shear_sum + (f(3, i) - shear_exact)**2
         z_central = [z_central, z]
         p_central = [p_central, -dot_product(f(:, i), n)]
      end do
      ! Least-squares slope dp/dz of the wall pressure -f . n over the central nodes.
      z_central = z_central - sum(z_central) / n_central
      grad = sum(z_central * p_central) / sum(z_central**2)

      do k = 1, 4
         points(:, k) = [fractions(1, k), fractions(2, k) * aspect, 0.0_dp]
         points(:, k + 4) = [-fractions(1, k), fractions(2, k) * aspect, 0.37_dp]
      end do
      call op%velocity_at(wall, f, points, u_sl, jump)
      call op%section_double_layer(wall, points, u_dl)
      vel_err = 0
      do k = 1, 8
         vel_err = max(vel_err, norm2(u_sl(:, k) + u_dl(:, k) - wall%undisturbed_velocity(points(:, k))))
      end do
      call put_int('n_nodes', wall%mesh%n_nodes)
      call put_int('n_central', n_central)
      call put('centre_velocity', wall%flow%centre_velocity())
      call put('pressure_gradient_exact', wall%flow%pressure_gradient)
      call put('pressure_gradient', -grad)
      call put('shear_scale', shear_scale)
      call put('shear_error_max', shear_max)
      call put('shear_error_rms', sqrt(shear_sum / n_central))
      call put('shear_error_max_x', worst(1))
      call put('shear_error_max_y', worst(2))
      call put('shear_error_max_z', worst(3))
      call put('velocity_error_max', vel_err)
      call put('u_centre', u_sl(3, 1) + u_dl(3, 1))
   end subroutine probe_poiseuille

   !> Sorted distinct z of the side-wall and rim nodes (the rings).
   function ring_positions(x, tag) result(z)
      real(dp), intent(in) :: x(:, :)
      integer, intent(in) :: tag(:)
      real(dp), allocatable :: z(:)
      real(dp) :: candidate(size(tag)), zmin
      integer :: n, i
      n = 0
      do i = 1, size(tag)
         if (tag(i) == wall_tag_cylinder .or. tag(i) == wall_tag_rim) then
            n = n + 1
            candidate(n) = x(3, i)
         end if
      end do
      allocate (z(0))
      zmin = -huge(1.0_dp)
      do
         if (.not. any(candidate(1:n) > zmin + 1.0e-12_dp)) exit
         zmin = minval(candidate(1:n), mask=candidate(1:n) > zmin + 1.0e-12_dp)
         z = [z, zmin]
      end do
   end function ring_positions

end program duct_probe
