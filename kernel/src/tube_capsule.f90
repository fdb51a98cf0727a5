!> A capsule on the axis of a circular tube, 3D (the full solver behind `--model 3d`; the
!> axisymmetric model of axisymmetric_tube is the fast path it cross-checks).
!>
!> Non-dimensional as axisymmetric_tube: lengths in l (tube radius), velocities in V (mean
!> velocity), time in l/V, forces in G_s, Ca_s = mu V / G_s, v_inf = 2 (1 - x**2 - y**2) e_z.
!> The paper's disturbance formulation: single layers on the membrane (known force density f
!> = F/A_node, P1) and on the closed tube boundary B (tube_wall_mesh: cylinder and end disks;
!> unknown disturbance traction g, P1, wall_single_layer's sign convention: the force per
!> unit area that the wall exerts on the fluid). The disturbance vanishes on the whole of B
!> (no-slip on the cylinder, undisturbed Poiseuille on the end sections), so
!>     S_wall g = -S_capsule f   at the wall nodes
!> (no double layer: the disturbance velocity on B is zero), solved with the factorised
!> wall matrix (LAPACK LU, cached on disk), and the membrane moves with
!>     v = v_inf + (S_capsule f + S_wall g) / Ca,   S = 1/(8 pi) int J . (density) dS.
!> The capsule is kept centred: velocities are taken in the frame of its volume centroid
!> (v_c, the centroid's axial velocity, is subtracted and recorded), and after each step
!> the centroid is translated back to the origin, in the middle of the tube, on its axis.
!> An off-centre capsule (--offset) starts with its centroid at x = offset and is put back
!> to mid-tube axially only: it drifts radially as the flow moves it (history column r_c),
!> and L_p and /profile are measured along its own axis (parallel to the tube's, through the
!> centroid).
!> In a rectangular duct (--channel square|rect, duct_wall_mesh) the same holds with the duct's
!> wall and Poiseuille flow; lengths are then in the duct's half-width w.
!>
!> Viscosity ratio lambda /= 1 (inner/outer): the membrane velocity u solves
!>     (1+lambda)/2 u - (1-lambda) D[u] = v_inf + (S_capsule f + S_wall g)/Ca
!> (D the capsule's principal-value double layer of stokes_double_layer), and the disturbance
!> at the wall nodes now includes the capsule's double layer (off the membrane, apply_outside):
!>     S_wall g = -S_capsule f - Ca (1-lambda) D_out[u].
!> g is linear in u: g = g_1 - Ca (1-lambda) W^-1 D_out[u] (g_1 that of lambda = 1, W the
!> factorised wall matrix), so with u_1 the lambda = 1 velocity
!>     (1+lambda)/2 u - (1-lambda) (D[u] - V_wall W^-1 D_out[u]) = u_1,
!> V_wall the wall single layer at the membrane nodes: interface_equation's equation with the
!> wall reflection as its operator term (GMRES, Wielandt deflation of the normal mode: the
!> wall single layer carries no flux through the membrane, so n stays a left eigenvector).
!> D[c] = -c/2 and D_out[c] = 0 hold exactly for a constant c (singularity and nearest-node
!> subtraction), and the flux of c through the polyhedron is exactly 0, so a rigid
!> translation u_1 = c is mapped onto itself: at steady translation the shape equations are
!> those of lambda = 1 (the inner fluid moves rigidly). As in axisymmetric_tube, u_1 gets the
!> volume correction before the solve as well as after it. At lambda = 1 none of this runs.
module tube_capsule
   use, intrinsic :: iso_c_binding, only: c_char, c_int, c_null_char
   use omp_lib, only: omp_get_wtime
   use capsim_kinds, only: dp, pi
   use vector_algebra, only: cross
   use hdf5_writer, only: h5_file_t
   use sphere_mesh, only: surface_mesh_t, icosphere
   use membrane_law, only: make_membrane_law
   use membrane_forces, only: membrane_reference_t, membrane_nodal_forces, principal_stretches
   use membrane_bending, only: bending_t
   use stokes_single_layer, only: single_layer_t, add_stokeslets, triangle_areas, node_areas
   use self_single_layer, only: self_single_layer_t, far_edge
   use triangle_quadrature, only: quadrature_rule_t, dunavant7_rule
   use surface_diagnostics, only: area_and_volume, shear_plane_contour
   use tube_wall_mesh, only: tube_wall_t, build_tube_wall
   use duct_wall_mesh, only: duct_wall_t, build_duct_wall
   use triangle_cells, only: triangle_cells_t
   use wall_single_layer, only: wall_operator_t, leaf_ratio, leaf_strengths, triangle_correction
   use run_options, only: run_options_t
   use case_output, only: write_surface_mesh
   use tube_history, only: h_t, h_area, h_volume, h_lz, h_lp, h_vc, h_rmax, h_energy, h_stretch, &
                           tube3d_history_names, tube3d_history_units, tube_progress_text
   use capsule_model, only: capsule_model_t
   use state_vector, only: state_cursor_t
   use stokes_double_layer, only: double_layer_t
   use interface_equation, only: interface_equation_t, operator_term_t
   implicit none
   private
   public :: tube_capsule_t, default_cache_dir, volume_gradients, remove_volume_flux, recentre, volume_centroid

   !> Pre-deformation of large capsules, as in axisymmetric_tube: from a/l = 0.9 the run
   !> starts from the spheroid of equatorial radius 0.8 and the same volume; stresses are
   !> measured from the sphere of radius a.
   real(dp), parameter :: predeform_from = 0.9_dp, predeform_radius = 0.8_dp
   !> The capsule's single layer at a wall node replaces the vertex rule by the 7-point rule
   !> (subdivided near the node) on the capsule triangles whose centroid is nearer than
   !> near_radius (tube radii), or than leaf_ratio of their diameters: the wall's own
   !> velocity_at criterion (wall_single_layer, default_mid_radius).
   real(dp), parameter :: near_radius = 0.5_dp
   !> --self-quadrature full (self_single_layer): the far rule's points per triangle, and
   !> the near and subdivision ratios (diameters); tube3d_probe self-rules measured them.
   integer, parameter :: self_far_kind = far_edge
   real(dp), parameter :: self_near_ratio = 3.0_dp, self_sub_ratio = 2.0_dp

   type, extends(capsule_model_t) :: tube_capsule_t
      type(surface_mesh_t) :: mesh
      type(membrane_reference_t) :: ref
      !> Bending stiffness (--kb); set up only when k_b > 0.
      type(bending_t) :: bending
      type(single_layer_t) :: single_layer
      !> The channel's closed boundary: the circular tube's, or the rectangular duct's
      !> (duct_wall_t, --channel square|rect), whose shape the wall operator asks of it.
      class(tube_wall_t), allocatable :: wall
      type(wall_operator_t) :: wall_op
      type(quadrature_rule_t) :: near_rule
      real(dp) :: a = 0, ca = 0, h_min = 0, energy = 0, v_c = 0
      !> Initial radial position of the centroid (l); 0: centred, re-centred in all directions.
      real(dp) :: offset = 0
      !> Put the centroid back to (offset, 0) after every step instead of letting it drift.
      logical :: hold_offset = .false.
      logical :: volume_correction = .true.
      !> Wall setup time (assembly and LU, or the cache load) [s], and the time spent so far in
      !> the three parts of the velocity that involve the wall (bench/bench_tube_3d.py).
      real(dp) :: wall_seconds = 0
      real(dp) :: seconds_capsule_at_wall = 0, seconds_wall_solve = 0, seconds_wall_at_capsule = 0
      real(dp) :: seconds_self_near_field = 0
      !> Reference (stress-free) sphere of radius a.
      real(dp), allocatable :: x_ref(:, :)
      ! Work arrays allocated once by init: the time loop allocates nothing.
      real(dp), allocatable :: x_pred(:, :), u0(:, :), u1(:, :), force(:, :), density(:, :), u_wall(:, :)
      real(dp), allocatable :: wall_data(:, :), wall_traction(:, :), grad(:, :), moment_grad(:, :)
      !> Per-step quadrature data of the capsule triangles: centroid, diameter, corner
      !> positions and densities, 7-point points and strengths, vertex-rule strengths.
      real(dp), allocatable :: tri_centroid(:, :), tri_diameter(:), tri_x(:, :, :), tri_f(:, :, :)
      real(dp), allocatable :: quad_point(:, :, :), quad_strength(:, :, :), vertex_strength(:, :, :)
      !> The capsule triangles by cell of their centroid, rebuilt per call of
      !> capsule_single_layer_at: a wall node visits only the triangles around it.
      type(triangle_cells_t) :: cells
      !> The membrane's own single layer at its nodes: single_layer (vertex rule beyond the
      !> second ring), plus, when self_near_field, self_corrections (the subdivided 7-point
      !> rule on the capsule triangles within near_radius or leaf_ratio diameters of the
      !> node). Off by default (the model of the case files); README "Tube flow (3D)" has
      !> what it changes: the vertex rule's O(h) mid-field error is most of the 3D model's
      !> first-order v_c/V error at a/l = 0.8 (tube3d_probe self-quadrature).
      logical :: self_near_field = .false.
      !> --self-quadrature: 'full' (default) takes the membrane's own single layer from
      !> self_layer (7-point rule on every triangle, subdivided within leaf_ratio diameters,
      !> Duffy on the touching ones); 'vertex' from single_layer (and self_near_field), the
      !> model before it. README "Tube flow (3D)" has what it changes.
      logical :: self_full = .true.
      type(self_single_layer_t) :: self_layer
      real(dp) :: seconds_self = 0
      !> Experiment (tube3d_probe self-quadrature): remove the net flux of the capsule's single
      !> layer through the wall from the wall data, along the node normals, before the solve.
      logical :: wall_flux_free = .false.
      !> Experiment (tube3d_probe self-rules): the radius within which the capsule's single
      !> layer at the wall nodes replaces the vertex rule (near_radius in the model).
      real(dp) :: wall_near_radius = near_radius
      !> Viscosity ratio; the double layer, its equation and their work arrays are set up only
      !> when lambda /= 1.
      real(dp) :: lambda = 1
      type(double_layer_t) :: double_layer
      type(interface_equation_t) :: interface
      !> Last solution (lab frame), the initial guess of the next solve; time spent in solves.
      real(dp), allocatable :: u_guess(:, :), rhs(:, :), wall_dl(:, :), wall_dl_traction(:, :), u_wall_dl(:, :)
      logical :: have_guess = .false.
      real(dp) :: seconds_lambda = 0
   contains
      procedure :: init
      procedure :: velocity
      procedure :: capsule_single_layer_at
      procedure :: interface_velocity
      procedure :: advance => rk2_step
      procedure :: record
      procedure :: exchange_state
      procedure :: progress_text
      procedure :: write_geometry
   end type tube_capsule_t

   !> The walls' reflection of the capsule's double layer, -V_wall W^-1 D_out[u], as
   !> interface_equation's operator term; `capsule` is associated during a velocity call only.
   type, extends(operator_term_t) :: wall_reflection_t
      type(tube_capsule_t), pointer :: capsule => null()
   contains
      procedure :: add => add_wall_reflection
   end type wall_reflection_t

   interface
      integer(c_int) function c_mkdir(path, mode) bind(c, name='mkdir')
         import :: c_char, c_int
         character(kind=c_char), intent(in) :: path(*)
         integer(c_int), value :: mode
      end function c_mkdir
   end interface

contains

   subroutine init(self, opts, stat, errmsg)
      class(tube_capsule_t), intent(inout) :: self
      type(run_options_t), intent(in) :: opts
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      real(dp), allocatable :: x_unit(:, :)
      character(len=:), allocatable :: cache_dir
      real(dp) :: c_axis, t0, h
      integer :: n, nt, t, k

      call make_membrane_law(trim(opts%law), opts%nu_s, opts%c, self%law, stat, errmsg)
      if (stat /= 0) return
      call icosphere(opts%level, self%mesh, x_unit, stat, errmsg)
      if (stat /= 0) return
      self%a = opts%a_over_l
      self%ca = opts%ca
      self%volume_correction = opts%volume_correction
      n = self%mesh%n_nodes
      nt = self%mesh%n_tri
      self%x_ref = self%a * x_unit
      self%start_positions = self%x_ref
      if (self%a >= predeform_from) then
         c_axis = self%a**3 / predeform_radius**2
         self%start_positions(1:2, :) = (predeform_radius / self%a) * self%x_ref(1:2, :)
         self%start_positions(3, :) = (c_axis / self%a) * self%x_ref(3, :)
      end if
      self%offset = opts%offset
      self%hold_offset = trim(opts%offset_mode) == 'held'
      self%start_positions(1, :) = self%start_positions(1, :) + self%offset
      self%positions = self%start_positions
      ! Strains are measured from the stress-free sphere of radius a/(1 + alpha).
      call self%ref%init(self%mesh, self%x_ref / (1.0_dp + opts%prestress))
      ! Bending from the sphere at rest; K_B = k_b G_s a**2 is k_b (a/l)**2 in units G_s l**2.
      if (opts%kb > 0.0_dp) call self%bending%init(self%mesh, self%x_ref, opts%kb * self%a**2)
      ! As capsule_dynamics: Duffy 4x4 on touching triangles, 7-point rule on the next ring.
      call self%single_layer%init(self%mesh, 4, 0)
      self%self_full = trim(opts%self_quadrature) /= 'vertex'
      ! Also for 'vertex': tube3d_probe compares both rules at one shape.
      call self%self_layer%init(self%mesh, 4, self_far_kind, self_near_ratio, self_sub_ratio)
      self%near_rule = dunavant7_rule(0)
      self%h_min = huge(1.0_dp)
      do t = 1, nt
         do k = 1, 3
            h = norm2(self%x_ref(:, self%mesh%tri(k, t)) - self%x_ref(:, self%mesh%tri(mod(k, 3) + 1, t)))
            self%h_min = min(self%h_min, h)
         end do
      end do

      if (maxval(abs(self%positions(3, :))) > 0.5_dp * opts%tube_length - 1.0_dp) then
         stat = 2
         errmsg = '--tube-length: the tube must reach at least 1 l beyond the capsule on both sides'
         return
      end if
      if (trim(opts%channel) == 'tube') then
         allocate (tube_wall_t :: self%wall)
      else
         allocate (duct_wall_t :: self%wall)
      end if
      select type (wall => self%wall)
      type is (duct_wall_t)
         call build_duct_wall(opts%tube_length, opts%wall_h_far, opts%wall_h_centre, wall, stat, errmsg, opts%aspect)
      type is (tube_wall_t)
         call build_tube_wall(opts%tube_length, opts%wall_h_far, opts%wall_h_centre, wall, stat, errmsg)
      end select
      if (stat /= 0) then
         errmsg = '--wall-h-far/--wall-h-centre: '//errmsg
         stat = 2
         return
      end if
      if (3 * self%wall%mesh%n_nodes > 40000) then
         stat = 2
         errmsg = '--wall-h-centre: the wall mesh has too many nodes for the dense wall solver (at most 13333; '// &
                  'use larger --wall-h-centre/--wall-h-far or a shorter --tube-length)'
         return
      end if
      cache_dir = ''
      if (trim(opts%wall_cache) /= 'none') then
         if (len_trim(opts%wall_cache) > 0) then
            cache_dir = trim(opts%wall_cache)
         else
            cache_dir = default_cache_dir()
         end if
      end if
      t0 = omp_get_wtime()
      call self%wall_op%init(self%wall, cache_dir, stat, errmsg)
      if (stat /= 0) return
      self%wall_seconds = omp_get_wtime() - t0
      if (.not. opts%quiet) write (*, '(a,i0,a,f0.2,a)') 'capsim: '//self%wall%channel_name()//' wall of ', &
         self%wall%mesh%n_nodes, &
         ' nodes ready in ', self%wall_seconds, ' s (cache: '//self%wall_op%cache_message//')'

      allocate (self%x_pred(3, n), self%u0(3, n), self%u1(3, n), self%force(3, n), self%density(3, n))
      allocate (self%u_wall(3, n), self%grad(3, n), self%moment_grad(3, n))
      allocate (self%wall_data(3, self%wall%mesh%n_nodes), self%wall_traction(3, self%wall%mesh%n_nodes))
      allocate (self%tri_centroid(3, nt), self%tri_diameter(nt), self%tri_x(3, 3, nt), self%tri_f(3, 3, nt))
      allocate (self%quad_point(3, size(self%near_rule%weight), nt), self%quad_strength(3, size(self%near_rule%weight), nt))
      allocate (self%vertex_strength(3, 3, nt))
      self%wall_traction = 0.0_dp
      self%lambda = opts%lambda
      if (self%lambda /= 1.0_dp) then
         call self%double_layer%init(self%mesh, self%single_layer)
         call self%interface%init(n, self%lambda)
         allocate (self%u_guess(3, n), self%rhs(3, n), self%u_wall_dl(3, n))
         allocate (self%wall_dl(3, self%wall%mesh%n_nodes), self%wall_dl_traction(3, self%wall%mesh%n_nodes))
      end if
      ! Explicit membrane stiffness: stable for dt < O(Ca h); 0.01 l/V bounds the advection error.
      if (opts%dt > 0) then
         self%dt = opts%dt
      else
         self%dt = min(opts%dt_factor * opts%ca * self%h_min, 0.01_dp)
         ! A less viscous interior lets short membrane waves relax up to 2/(1+lambda) times
         ! faster: the shear solver's margin (capsule_dynamics).
         if (self%lambda < 1.0_dp) self%dt = min(opts%dt_factor * opts%ca * self%h_min * (0.5_dp * (1.0_dp + self%lambda)), &
                                                 0.01_dp)
      end if
      ! Bending limit as capsule_dynamics, with K_B = k_b a**2 in units G_s l**2.
      if (opts%dt <= 0 .and. opts%kb > 0.0_dp) &
         self%dt = min(self%dt, opts%dt_factor * opts%ca * self%h_min**3 / (opts%kb * self%a**2))
      call self%allocate_history(tube3d_history_names, tube3d_history_units, opts%t_max, opts%record_every)
      ! The axisymmetric model's steady criteria (lengths and v_c settle to 1e-3 per time unit).
      self%col_length = h_lz
      self%col_stretch = h_stretch
      self%col_shape = [h_lz, h_lp, h_vc]
      self%area_scale = 4 * pi * self%a**2
      self%length_limit = 2 * opts%max_length * self%a
      self%shape_rel_tol = 0.0_dp
      self%shape_abs_tol = 1.0e-3_dp
   end subroutine init

   !> $XDG_CACHE_HOME/capsmech, else $HOME/.cache/capsmech, created if missing; '' (no
   !> cache) when neither variable is set.
   function default_cache_dir() result(dir)
      character(len=:), allocatable :: dir
      character(len=4096) :: base
      integer :: length, status, ignored
      call get_environment_variable('XDG_CACHE_HOME', base, length, status)
      if (status /= 0 .or. length == 0) then
         call get_environment_variable('HOME', base, length, status)
         if (status /= 0 .or. length == 0) then
            dir = ''
            return
         end if
         base = base(:length)//'/.cache'
         ignored = c_mkdir(trim(base)//c_null_char, int(o'755', c_int))
      end if
      dir = trim(base)//'/capsmech'
      ! An existing directory (EEXIST) is fine; any other failure shows when the cache is written.
      ignored = c_mkdir(dir//c_null_char, int(o'755', c_int))
   end function default_cache_dir

   !> Membrane velocity at positions x in the frame of the capsule's centroid; sets v_c.
   subroutine velocity(self, x, u)
      class(tube_capsule_t), intent(inout), target :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: u(:, :)
      integer :: i, n, stat
      real(dp) :: volume, moment, t0, t1, t2, t3
      character(len=:), allocatable :: errmsg

      n = self%mesh%n_nodes
      call membrane_nodal_forces(self%ref, self%mesh, self%law, x, self%force, self%energy)
      if (self%bending%kb > 0.0_dp) call self%bending%add_forces(self%mesh, x, self%force, self%energy)
      ! single_layer%velocity leaves the triangle and node areas, and the node Stokeslets
      ! (positions, strengths f A), in its work arrays: capsule_single_layer_at uses them.
      call triangle_areas(self%mesh, x, self%single_layer%tri_area)
      call node_areas(self%mesh, self%single_layer%tri_area, self%single_layer%node_area)
      do i = 1, n
         self%density(:, i) = self%force(:, i) / self%single_layer%node_area(i)
      end do
      t0 = omp_get_wtime()
      if (self%self_full) then
         ! capsule_single_layer_at needs single_layer's node Stokeslets, not its pair sum.
         self%single_layer%xs = x(1, 1:n)
         self%single_layer%ys = x(2, 1:n)
         self%single_layer%zs = x(3, 1:n)
         self%single_layer%qx = self%density(1, 1:n) * self%single_layer%node_area
         self%single_layer%qy = self%density(2, 1:n) * self%single_layer%node_area
         self%single_layer%qz = self%density(3, 1:n) * self%single_layer%node_area
         call self%self_layer%velocity(self%mesh, x, self%density, self%single_layer%tri_area, u)
      else
         call self%single_layer%velocity(self%mesh, x, self%density, u)
      end if
      self%seconds_self = self%seconds_self + (omp_get_wtime() - t0)
      t0 = omp_get_wtime()
      call self%capsule_single_layer_at(x, self%wall%x, self%wall_data)
      self%wall_data = -self%wall_data
      if (self%wall_flux_free) self%wall_data = self%wall_data - (sum(self%wall_op%flux_weight * self%wall_data) &
                                                                  / sum(self%wall_op%flux_weight * self%wall_op%node_normal)) &
                                                                 * self%wall_op%node_normal
      t1 = omp_get_wtime()
      call self%wall_op%solve(self%wall_data, self%wall_traction, stat, errmsg)
      if (stat /= 0) error stop 'tube_capsule: wall solve failed (the operator was initialised)'
      t2 = omp_get_wtime()
      call self%wall_op%velocity_at(self%wall, self%wall_traction, x, self%u_wall)
      t3 = omp_get_wtime()
      self%seconds_capsule_at_wall = self%seconds_capsule_at_wall + (t1 - t0)
      self%seconds_wall_solve = self%seconds_wall_solve + (t2 - t1)
      self%seconds_wall_at_capsule = self%seconds_wall_at_capsule + (t3 - t2)
      ! Uses the triangle data and cells that capsule_single_layer_at has set up for x.
      if (self%self_near_field .and. .not. self%self_full) then
         call self_corrections(self, x, u)
         self%seconds_self_near_field = self%seconds_self_near_field + (omp_get_wtime() - t3)
      end if
      do i = 1, n
         u(:, i) = self%wall%undisturbed_velocity(x(:, i)) + (u(:, i) + self%u_wall(:, i)) / self%ca
      end do
      if (self%lambda /= 1.0_dp) call self%interface_velocity(x, u)
      call volume_gradients(self%mesh, x, self%grad, self%moment_grad, volume, moment)
      if (self%volume_correction) call remove_volume_flux(u, self%grad)
      ! d(V z_c)/dt = sum_i u_i . d(V z_c)/dx_i, dV/dt = sum_i u_i . dV/dx_i: exact for the
      ! polyhedron, so that v_c is the velocity of the centroid that record() reports.
      self%v_c = (sum(u * self%moment_grad) - (moment / volume) * sum(u * self%grad)) / volume
      u(3, :) = u(3, :) - self%v_c
   end subroutine velocity

   !> lambda /= 1: on entry u = u_1, the lambda = 1 velocity (lab frame); on exit the solution
   !> of (1+lambda)/2 u - (1-lambda) (D[u] - V_wall W^-1 D_out[u]) = u_1 (module header).
   subroutine interface_velocity(self, x, u)
      class(tube_capsule_t), intent(inout), target :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(inout) :: u(:, :)
      type(wall_reflection_t) :: term
      real(dp) :: volume, moment, t0
      integer :: stat
      character(len=:), allocatable :: errmsg
      t0 = omp_get_wtime()
      if (self%volume_correction) then
         call volume_gradients(self%mesh, x, self%grad, self%moment_grad, volume, moment)
         call remove_volume_flux(u, self%grad)
      end if
      self%rhs = (2.0_dp / (1.0_dp + self%lambda)) * u
      call self%double_layer%set_geometry(self%mesh, x)
      ! From the last solution (the previous stage or step), else from the right-hand side.
      if (self%have_guess) then
         u = self%u_guess
      else
         u = self%rhs
      end if
      term%capsule => self
      call self%interface%solve(self%double_layer, self%mesh, self%rhs, u, stat, errmsg, term)
      if (stat /= 0 .and. .not. allocated(self%fault)) self%fault = errmsg
      self%u_guess = u
      self%have_guess = .true.
      self%seconds_lambda = self%seconds_lambda + (omp_get_wtime() - t0)
   end subroutine interface_velocity

   !> w <- w - V_wall W^-1 D_out[u]: the wall traction that cancels the capsule's double layer
   !> of u at the wall nodes, and its single layer at the membrane nodes (positions of the
   !> double layer's last set_geometry).
   subroutine add_wall_reflection(self, u, w)
      class(wall_reflection_t), intent(inout) :: self
      real(dp), intent(in) :: u(:, :)
      real(dp), intent(inout) :: w(:, :)
      integer :: stat
      character(len=:), allocatable :: errmsg
      associate (c => self%capsule)
         call c%double_layer%apply_outside(c%mesh, u, c%wall%x, near_radius, c%wall_dl)
         call c%wall_op%solve(c%wall_dl, c%wall_dl_traction, stat, errmsg)
         if (stat /= 0) error stop 'tube_capsule: wall solve failed (the operator was initialised)'
         call c%wall_op%velocity_at(c%wall, c%wall_dl_traction, c%double_layer%x, c%u_wall_dl)
         w = w - c%u_wall_dl
      end associate
   end subroutine add_wall_reflection

   !> Capsule single layer (1/(8 pi) included) at points off the membrane (the wall nodes):
   !> one Stokeslet per capsule node (the vertex rule, from the node Stokeslets that
   !> single_layer%velocity has just set up for positions x), with the vertex rule replaced on
   !> the capsule triangles near the point by the 7-point rule, subdivided within leaf_ratio
   !> of their diameters (near_triangle_correction): a wall node 0.05 l from the membrane
   !> then sees the membrane's P1 density integrated to the accuracy of the wall's own rules.
   !> Per-step routine: no allocation.
   subroutine capsule_single_layer_at(self, x, points, u)
      class(tube_capsule_t), intent(inout) :: self
      real(dp), intent(in) :: x(:, :), points(:, :)
      real(dp), intent(out) :: u(:, :)
      integer :: n, nt, k, t
      real(dp) :: p(3), acc(3), z_lo, z_hi, r_hi, reach

      n = self%mesh%n_nodes
      nt = self%mesh%n_tri
      !$omp parallel do default(none) shared(self, x, nt) private(t) schedule(static)
      do t = 1, nt
         self%tri_x(:, :, t) = x(:, self%mesh%tri(:, t))
         self%tri_f(:, :, t) = self%density(:, self%mesh%tri(:, t))
         self%tri_centroid(:, t) = sum(self%tri_x(:, :, t), dim=2) / 3.0_dp
         self%tri_diameter(t) = max(norm2(self%tri_x(:, 2, t) - self%tri_x(:, 1, t)), &
                                    norm2(self%tri_x(:, 3, t) - self%tri_x(:, 2, t)), &
                                    norm2(self%tri_x(:, 1, t) - self%tri_x(:, 3, t)))
         self%quad_point(:, :, t) = matmul(self%tri_x(:, :, t), self%near_rule%bary)
         call leaf_strengths(self%near_rule, self%single_layer%tri_area(t), self%tri_f(:, :, t), &
                             self%quad_strength(:, :, t), self%vertex_strength(:, :, t))
      end do
      !$omp end parallel do
      call self%cells%build(self%tri_centroid, self%tri_diameter, self%wall_near_radius, leaf_ratio, &
                            max(0.5_dp * self%wall_near_radius, maxval(self%tri_diameter)))
      ! Points farther than `reach` from the capsule's bounding cylinder need no correction.
      reach = self%cells%max_reach + maxval(self%tri_diameter)
      z_lo = minval(x(3, 1:n)) - reach
      z_hi = maxval(x(3, 1:n)) + reach
      r_hi = sqrt(maxval(x(1, 1:n)**2 + x(2, 1:n)**2)) + reach
      !$omp parallel do default(none) shared(self, points, u, n, z_lo, z_hi, r_hi) &
      !$omp private(k, p, acc) schedule(dynamic, 16)
      do k = 1, size(points, 2)
         p = points(:, k)
         acc = 0.0_dp
         call add_stokeslets(n, self%single_layer%xs, self%single_layer%ys, self%single_layer%zs, &
                             self%single_layer%qx, self%single_layer%qy, self%single_layer%qz, p, 1, n, acc)
         if (p(3) > z_lo .and. p(3) < z_hi .and. p(1)**2 + p(2)**2 < r_hi**2) acc = acc + capsule_corrections(self, p)
         u(:, k) = acc / (8.0_dp * pi)
      end do
      !$omp end parallel do
   end subroutine capsule_single_layer_at

   !> u <- u + the membrane's own single layer, accurate minus single_layer's rules, at every
   !> node: on the capsule triangles within near_radius or leaf_ratio diameters of the node
   !> (the rule of the single layer at the wall nodes) that do not touch it, the subdivided
   !> 7-point rule replaces the vertex rule (beyond the second ring) or the plain 7-point
   !> rule (on the second ring, where single_layer uses it). Needs the triangle data and cells
   !> of capsule_single_layer_at for positions x.
   subroutine self_corrections(self, x, u)
      class(tube_capsule_t), intent(in) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(inout) :: u(:, :)
      integer :: i
      !$omp parallel do default(none) shared(self, x, u) private(i) schedule(dynamic, 16)
      do i = 1, self%mesh%n_nodes
         u(:, i) = u(:, i) + self_correction_at(self, x(:, i), i) / (8.0_dp * pi)
      end do
      !$omp end parallel do
   end subroutine self_corrections

   function self_correction_at(self, p, i) result(corr)
      class(tube_capsule_t), intent(in) :: self
      real(dp), intent(in) :: p(3)
      integer, intent(in) :: i
      real(dp) :: corr(3)
      real(dp), parameter :: forced_near = 0.0_dp, forced_leaf = huge(1.0_dp)
      integer :: list(self%cells%n_tri), m, j, t, q, first, last
      real(dp) :: dist(self%cells%n_tri)
      logical :: second_ring, touching
      call self%cells%near(p, list, dist, m)
      first = self%single_layer%corr_start(i)
      last = self%single_layer%corr_start(i + 1) - 1
      corr = 0.0_dp
      do j = 1, m
         t = list(j)
         touching = .false.
         second_ring = .false.
         do q = first, last
            if (self%single_layer%corr_tri(q) == t) then
               touching = self%single_layer%corr_vertex(q) > 0
               second_ring = .not. touching
               exit
            end if
         end do
         if (touching) cycle
         associate (d => self%tri_diameter(t), a => self%single_layer%tri_area(t), xv => self%tri_x(:, :, t), &
                    fv => self%tri_f(:, :, t), qp => self%quad_point(:, :, t), qs => self%quad_strength(:, :, t), &
                    vs => self%vertex_strength(:, :, t))
            if (second_ring) then
               if (dist(j) > leaf_ratio * d) cycle
               corr = corr + triangle_correction(self%near_rule, p, forced_near, d, a, xv, fv, qp, qs, vs) &
                      - triangle_correction(self%near_rule, p, forced_leaf, d, a, xv, fv, qp, qs, vs)
            else
               corr = corr + triangle_correction(self%near_rule, p, dist(j), d, a, xv, fv, qp, qs, vs)
            end if
         end associate
      end do
   end function self_correction_at

   !> Sum of triangle_correction over the capsule triangles that need more than the vertex
   !> rule at p (found by the cell index of capsule_single_layer_at).
   function capsule_corrections(self, p) result(corr)
      class(tube_capsule_t), intent(in) :: self
      real(dp), intent(in) :: p(3)
      real(dp) :: corr(3)
      integer :: list(self%cells%n_tri), m, j, t
      real(dp) :: dist(self%cells%n_tri)
      call self%cells%near(p, list, dist, m)
      corr = 0.0_dp
      do j = 1, m
         t = list(j)
         corr = corr + triangle_correction(self%near_rule, p, dist(j), self%tri_diameter(t), &
                                           self%single_layer%tri_area(t), self%tri_x(:, :, t), &
                                           self%tri_f(:, :, t), self%quad_point(:, :, t), self%quad_strength(:, :, t), &
                                           self%vertex_strength(:, :, t))
      end do
   end function capsule_corrections

   !> dV/dx_i and d(int z dV)/dx_i at every node, the volume V and the moment int z dV, from
   !> the tetrahedra (origin, triangle): V_t = p1 . (p2 x p3) / 6, z-moment V_t (z1+z2+z3)/4.
   pure subroutine volume_gradients(mesh, x, grad, moment_grad, volume, moment)
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: grad(:, :), moment_grad(:, :), volume, moment
      integer :: t, k, i, j, l
      real(dp) :: g(3), vol_t, zbar
      grad = 0.0_dp
      moment_grad = 0.0_dp
      volume = 0.0_dp
      moment = 0.0_dp
      do t = 1, mesh%n_tri
         vol_t = dot_product(x(:, mesh%tri(1, t)), cross(x(:, mesh%tri(2, t)), x(:, mesh%tri(3, t)))) / 6.0_dp
         zbar = sum(x(3, mesh%tri(:, t))) / 4.0_dp
         volume = volume + vol_t
         moment = moment + vol_t * zbar
         do k = 1, 3
            i = mesh%tri(k, t)
            j = mesh%tri(mod(k, 3) + 1, t)
            l = mesh%tri(mod(k + 1, 3) + 1, t)
            g = cross(x(:, j), x(:, l)) / 6.0_dp
            grad(:, i) = grad(:, i) + g
            moment_grad(:, i) = moment_grad(:, i) + zbar * g
            moment_grad(3, i) = moment_grad(3, i) + vol_t / 4.0_dp
         end do
      end do
   end subroutine volume_gradients

   !> The P1 single layer carries a spurious net flux through the membrane at O(h**2)
   !> (capsule_dynamics measured 12 % volume loss over 25 time units without a correction):
   !> remove the velocity's component along the volume gradient (the least-squares
   !> correction with sum_i u_i . dV/dx_i = 0).
   pure subroutine remove_volume_flux(u, grad)
      real(dp), intent(inout) :: u(:, :)
      real(dp), intent(in) :: grad(:, :)
      u = u - (sum(u * grad) / sum(grad * grad)) * grad
   end subroutine remove_volume_flux

   !> Checkpoint state: the positions and, at lambda /= 1, the last interface solution (the
   !> next GMRES solve starts from it, so that its result depends on it to the tolerance).
   subroutine exchange_state(self, state, cursor)
      class(tube_capsule_t), intent(inout) :: self
      real(dp), intent(inout) :: state(:)
      type(state_cursor_t), intent(inout) :: cursor
      call cursor%reals(state, self%positions, size(self%positions))
      if (self%lambda == 1.0_dp) return
      call cursor%flag(state, self%have_guess)
      call cursor%reals(state, self%u_guess, size(self%u_guess))
   end subroutine exchange_state

   !> Heun's RK2 in the frame of the centroid, then the centroid put back at the origin.
   subroutine rk2_step(self)
      class(tube_capsule_t), intent(inout) :: self
      call self%velocity(self%positions, self%u0)
      self%x_pred = self%positions + self%dt * self%u0
      call self%velocity(self%x_pred, self%u1)
      self%positions = self%positions + 0.5_dp * self%dt * (self%u0 + self%u1)
      if (self%hold_offset) then
         call recentre(self%mesh, self%positions, axial_only=.false., target=[self%offset, 0.0_dp, 0.0_dp])
      else
         call recentre(self%mesh, self%positions, axial_only=self%offset /= 0.0_dp)
      end if
      self%t = self%t + self%dt
      self%step = self%step + 1
   end subroutine rk2_step

   !> Translate x so that its volume centroid is at the origin (on the axis, mid-tube), or
   !> only to mid-tube (z = 0) when `axial_only`, or to `target` when given.
   pure subroutine recentre(mesh, x, axial_only, target)
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(inout) :: x(:, :)
      logical, intent(in) :: axial_only
      real(dp), intent(in), optional :: target(3)
      real(dp) :: c(3)
      integer :: k
      c = volume_centroid(mesh, x)
      if (axial_only) c(1:2) = 0.0_dp
      if (present(target)) c = c - target
      do k = 1, size(x, 2)
         x(:, k) = x(:, k) - c
      end do
   end subroutine recentre

   !> Volume centroid of the closed triangulated surface x (tetrahedra from the origin).
   pure function volume_centroid(mesh, x) result(c)
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      real(dp) :: c(3), vol_t, volume
      integer :: t
      c = 0.0_dp
      volume = 0.0_dp
      do t = 1, mesh%n_tri
         vol_t = dot_product(x(:, mesh%tri(1, t)), cross(x(:, mesh%tri(2, t)), x(:, mesh%tri(3, t)))) / 6.0_dp
         volume = volume + vol_t
         c = c + vol_t * sum(x(:, mesh%tri(:, t)), dim=2) / 4.0_dp
      end do
      c = c / volume
   end function volume_centroid

   !> z where the line parallel to the tube axis through (axis(1), axis(2), .) crosses the
   !> membrane: the lowest crossing (rear) when `rear`, the highest (front) otherwise.
   pure real(dp) function axis_crossing(mesh, x, rear, axis) result(z_cross)
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      logical, intent(in) :: rear
      real(dp), intent(in) :: axis(2)
      integer :: t
      real(dp) :: p(3, 3), det, b1, b2, b3, z
      z_cross = merge(huge(1.0_dp), -huge(1.0_dp), rear)
      do t = 1, mesh%n_tri
         p = x(:, mesh%tri(:, t))
         p(1, :) = p(1, :) - axis(1)
         p(2, :) = p(2, :) - axis(2)
         ! Barycentric coordinates of (0, 0) in the triangle's projection on the xy plane.
         det = (p(1, 2) - p(1, 1)) * (p(2, 3) - p(2, 1)) - (p(1, 3) - p(1, 1)) * (p(2, 2) - p(2, 1))
         if (abs(det) < tiny(1.0_dp)) cycle
         b2 = ((0 - p(1, 1)) * (p(2, 3) - p(2, 1)) - (p(1, 3) - p(1, 1)) * (0 - p(2, 1))) / det
         b3 = ((p(1, 2) - p(1, 1)) * (0 - p(2, 1)) - (0 - p(1, 1)) * (p(2, 2) - p(2, 1))) / det
         b1 = 1.0_dp - b2 - b3
         if (min(b1, b2, b3) < -1.0e-12_dp) cycle
         z = b1 * p(3, 1) + b2 * p(3, 2) + b3 * p(3, 3)
         if (rear) then
            z_cross = min(z_cross, z)
         else
            z_cross = max(z_cross, z)
         end if
      end do
   end function axis_crossing

   !> Append diagnostics: L_z (front to rear), L_p (rear crossing of the axis to the rear-most
   !> point: the parachute depth, 0 for a convex rear), v_c/V, the largest radius r_max.
   subroutine record(self)
      class(tube_capsule_t), intent(inout) :: self
      real(dp) :: area, volume, l_z, l_p, stretch, l1, l2, centroid(3), axis(2)
      integer :: t
      call self%velocity(self%positions, self%u0)
      call area_and_volume(self%mesh, self%positions, area, volume)
      centroid = volume_centroid(self%mesh, self%positions)
      axis = 0.0_dp
      if (self%offset /= 0.0_dp) axis = centroid(1:2)
      l_z = maxval(self%positions(3, :)) - minval(self%positions(3, :))
      l_p = max(axis_crossing(self%mesh, self%positions, .true., axis) - minval(self%positions(3, :)), 0.0_dp)
      stretch = 1.0_dp
      do t = 1, self%mesh%n_tri
         call principal_stretches(self%ref, self%mesh, self%positions, t, l1, l2)
         stretch = max(stretch, l1, 1.0_dp / max(l2, 1.0e-12_dp))
      end do
      call self%next_record()
      self%history(:, self%n_rec) = [self%t, area, volume, l_z, l_p, self%v_c, &
                                     sqrt(maxval(self%positions(1, :)**2 + self%positions(2, :)**2)), self%energy, stretch, &
                                     norm2(centroid(1:2))]
   end subroutine record

   function progress_text(self) result(text)
      class(tube_capsule_t), intent(in) :: self
      character(len=:), allocatable :: text
      text = tube_progress_text(self%history(:, self%n_rec))
   end function progress_text

   !> /mesh (reference and current nodes (3, n), triangles 0-based), /profile (r, z: the
   !> section by the plane y = 0 on the x > 0 side, front first, as the axisymmetric
   !> meridian) and the wall's provenance.
   subroutine write_geometry(self, f, stat, errmsg)
      class(tube_capsule_t), intent(in) :: self
      type(h5_file_t), intent(inout) :: f
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      real(dp), allocatable :: r(:), z(:)
      real(dp) :: swapped(3, self%mesh%n_nodes), axis(2), centroid(3)
      logical, allocatable :: keep(:)
      axis = 0.0_dp
      if (self%offset /= 0.0_dp) then
         centroid = volume_centroid(self%mesh, self%positions)
         axis = centroid(1:2)
      end if
      ! shear_plane_contour cuts the plane x = x0 and orders the points by atan2(y, z): with
      ! x and y swapped that is the plane y = y_c, ordered from the front (+z) over x > x_c
      ! (the capsule's own axis; the tube's for a centred capsule).
      swapped = self%positions([2, 1, 3], :)
      call shear_plane_contour(self%mesh, swapped, [axis(2), axis(1), 0.0_dp], r, z)
      r = r - axis(1)
      keep = r >= 0.0_dp
      r = pack(r, keep)
      z = pack(z, keep)
      call f%write_attr('/', 'n_nodes', self%mesh%n_nodes, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'tube_length', self%wall%length, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'wall_h_far', self%wall%h_far, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'wall_h_centre', self%wall%h_centre, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'self_quadrature', trim(merge('full  ', 'vertex', self%self_full)), stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'n_wall_nodes', self%wall%mesh%n_nodes, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'wall_from_cache', merge(1, 0, self%wall_op%from_cache), stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'wall_setup_s', self%wall_seconds, stat, errmsg)
      if (stat == 0) call write_surface_mesh(f, self%x_ref, self%positions, self%mesh%tri, 'l', stat, errmsg)
      if (stat == 0) call f%make_group('/profile', stat, errmsg)
      if (stat == 0) call f%write_attr('/profile', 'plane', 'y = 0, x > 0, front first (flow along +z)', stat, errmsg)
      if (stat == 0) call f%write_dataset('/profile/r', r, 'l', stat, errmsg)
      if (stat == 0) call f%write_dataset('/profile/z', z, 'l', stat, errmsg)
   end subroutine write_geometry

end module tube_capsule
