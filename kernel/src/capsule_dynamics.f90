!> One capsule in unbounded simple shear flow, 3D: the membrane (P1 forces) coupled to the
!> fluid (boundary integrals), advanced by RK2 (Heun). The time loop and the classification
!> of the run are capsule_model's.
!>
!> Non-dimensional velocity of the membrane nodes (lengths in a, time in 1/gamma_dot,
!> forces in G_s), viscosity ratio 1:  v = v_inf + 1/(8 pi Ca) integral J . f dS,
!> f = F/A_node, F = -dE/dx. With an inner viscosity lambda /= 1 the velocity solves the
!> second-kind equation of interface_equation, v = 2/(1+lambda) (v_inf + S[f]/Ca) + kappa 2D[v],
!> by GMRES from the previous solutions; at lambda = 1 the explicit formula is taken unchanged
!> (the same operations, bit for bit, as before the option existed).
module capsule_dynamics
   use capsim_kinds, only: dp, pi
   use vector_algebra, only: cross
   use hdf5_writer, only: h5_file_t
   use sphere_mesh, only: surface_mesh_t, icosphere
   use membrane_law, only: make_membrane_law
   use membrane_forces, only: membrane_reference_t, membrane_nodal_forces, principal_stretches
   use membrane_bending, only: bending_t
   use stokes_single_layer, only: single_layer_t, triangle_areas, node_areas
   use stokes_double_layer, only: double_layer_t
   use interface_equation, only: interface_equation_t
   use surface_diagnostics, only: shape_measures_t, shape_measures, shear_plane_contour
   use background_flow, only: flow_shear, undisturbed_velocity
   use run_options, only: run_options_t
   use case_output, only: write_surface_mesh
   use capsule_model, only: capsule_model_t
   implicit none
   private
   public :: capsule_t

   !> Columns of the history table.
   integer, parameter :: h_t = 1, h_area = 2, h_volume = 3, h_d12 = 4, h_l1 = 5, h_l2 = 6, h_l3 = 7, &
                         h_theta = 8, h_energy = 9, h_stretch = 10
   character(len=*), parameter :: shear_history_names(10) = [character(len=16) :: &
                                  't', 'area', 'volume', 'D12', 'L1', 'L2', 'L3', 'theta', 'energy', 'max_stretch']
   character(len=*), parameter :: shear_history_units(10) = [character(len=16) :: &
                                  '1/gamma_dot', 'a^2', 'a^3', '1', 'a', 'a', 'a', 'rad', 'G_s a^2', '1']

   type, extends(capsule_model_t) :: capsule_t
      type(surface_mesh_t) :: mesh
      type(membrane_reference_t) :: ref
      !> Bending stiffness (--kb); set up only when k_b > 0.
      type(bending_t) :: bending
      type(single_layer_t) :: single_layer
      !> Viscosity ratio; the double layer and its equation are set up only when lambda /= 1.
      real(dp) :: lambda = 1
      type(double_layer_t) :: double_layer
      type(interface_equation_t) :: interface
      !> Solutions of the interface equation at the last two RK2 steps, per stage (1: at x_n,
      !> 2: at the predictor), from which the next solve's initial guess is extrapolated.
      real(dp), allocatable :: v_stage(:, :, :, :), rhs(:, :)
      integer :: n_stage(2) = 0, stage = 1
      integer :: flow = flow_shear
      real(dp) :: ca = 0, h_min = 0, energy = 0
      !> Reference (stress-free) positions; the run starts from them.
      real(dp), allocatable :: x_ref(:, :)
      logical :: volume_correction = .true.
      ! Work arrays allocated once by init: the time loop allocates nothing.
      real(dp), allocatable :: x_pred(:, :), u0(:, :), u1(:, :), force(:, :), density(:, :), v_inf(:, :)
      real(dp), allocatable :: tri_area(:), node_area(:)
   contains
      procedure :: init
      procedure :: velocity
      procedure :: advance => rk2_step
      procedure :: record
      procedure :: progress_text
      procedure :: write_geometry
   end type capsule_t

contains

   subroutine init(self, opts, stat, errmsg)
      class(capsule_t), intent(inout) :: self
      type(run_options_t), intent(in) :: opts
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: n, t, k
      real(dp) :: h

      call icosphere(opts%level, self%mesh, self%x_ref, stat, errmsg)
      if (stat /= 0) return
      call make_membrane_law(trim(opts%law), opts%nu_s, opts%c, self%law, stat, errmsg)
      if (stat /= 0) return
      n = self%mesh%n_nodes
      self%positions = self%x_ref
      self%start_positions = self%x_ref
      ! Strains are measured from the stress-free sphere of radius 1/(1 + alpha).
      call self%ref%init(self%mesh, self%x_ref / (1.0_dp + opts%prestress))
      ! Bending is measured from the sphere at rest (radius a), pre-stressed or not.
      if (opts%kb > 0.0_dp) call self%bending%init(self%mesh, self%x_ref, opts%kb)
      ! Duffy 4x4 on touching triangles, 7-point rule on the next ring: the quadrature error is
      ! then far below the flat-triangle geometry error (translating-sphere test, orders 3-6).
      call self%single_layer%init(self%mesh, 4, 0)
      allocate (self%x_pred(3, n), self%u0(3, n), self%u1(3, n), self%force(3, n), self%density(3, n))
      allocate (self%v_inf(3, n), self%tri_area(self%mesh%n_tri), self%node_area(n))
      self%h_min = huge(1.0_dp)
      do t = 1, self%mesh%n_tri
         do k = 1, 3
            h = norm2(self%x_ref(:, self%mesh%tri(k, t)) - self%x_ref(:, self%mesh%tri(mod(k, 3) + 1, t)))
            self%h_min = min(self%h_min, h)
         end do
      end do
      self%ca = opts%ca
      self%flow = flow_shear
      self%volume_correction = opts%volume_correction
      self%lambda = opts%lambda
      if (self%lambda /= 1.0_dp) then
         call self%double_layer%init(self%mesh, self%single_layer)
         call self%interface%init(n, self%lambda)
         allocate (self%v_stage(3, n, 2, 2), self%rhs(3, n))
      end if
      ! Explicit membrane stiffness: stable for dt < O(Ca h); 0.02 bounds the advection error.
      if (opts%dt > 0) then
         self%dt = opts%dt
      else if (self%lambda < 1.0_dp) then
         ! A less viscous interior lets the short membrane waves relax up to 2/(1+lambda)
         ! times faster (the single layer's factor; the double layer vanishes on them).
         ! Measured at level 2, Ca 0.1: lambda = 0.001 breaks down at twice the lambda = 1
         ! step, where lambda = 1 still runs; this factor keeps the lambda = 1 margin.
         self%dt = min(opts%dt_factor * opts%ca * self%h_min * (0.5_dp * (1.0_dp + self%lambda)), 0.02_dp)
      else
         self%dt = min(opts%dt_factor * opts%ca * self%h_min, 0.02_dp)
      end if
      ! Bending waves of length h relax at ~ K_B / (mu h**3): stable for dt < O(Ca h**3 / k_b).
      ! Measured at Ca 0.1 (NH): the limit is 1.0 - 1.9 Ca h_min**3 / k_b (level 2 k_b 1,
      ! level 3 k_b 0.1 and 1), so dt_factor keeps the elastic step's margin of about 2.
      if (opts%dt <= 0 .and. opts%kb > 0.0_dp) &
         self%dt = min(self%dt, opts%dt_factor * opts%ca * self%h_min**3 / opts%kb)
      call self%allocate_history(shear_history_names, shear_history_units, opts%t_max, opts%record_every)
      self%col_length = h_l1
      self%col_stretch = h_stretch
      self%col_shape = [h_d12]
      self%area_scale = 4 * pi
      self%length_limit = opts%max_length
      self%shape_rel_tol = opts%shape_tol
   end subroutine init

   !> Membrane velocity at positions x.
   subroutine velocity(self, x, u)
      class(capsule_t), intent(inout) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: u(:, :)
      integer :: i
      call membrane_nodal_forces(self%ref, self%mesh, self%law, x, self%force, self%energy)
      if (self%bending%kb > 0.0_dp) call self%bending%add_forces(self%mesh, x, self%force, self%energy)
      call triangle_areas(self%mesh, x, self%tri_area)
      call node_areas(self%mesh, self%tri_area, self%node_area)
      do i = 1, self%mesh%n_nodes
         self%density(:, i) = self%force(:, i) / self%node_area(i)
      end do
      call self%single_layer%velocity(self%mesh, x, self%density, u)
      call undisturbed_velocity(self%flow, x, self%v_inf)
      if (self%lambda /= 1.0_dp) then
         call interface_velocity(self, x, u)
         if (allocated(self%fault)) return
      else
         u = self%v_inf + u / self%ca
      end if
      if (self%volume_correction) call remove_volume_flux(self%mesh, x, u, self%force)
   end subroutine velocity

   !> lambda /= 1: on entry u = S[f] (the single layer of the membrane load), on exit the
   !> solution of u = 2/(1+lambda) (v_inf + S[f]/Ca) + kappa L'[u] (interface_equation).
   subroutine interface_velocity(self, x, u)
      class(capsule_t), intent(inout) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(inout) :: u(:, :)
      integer :: stat
      character(len=:), allocatable :: errmsg
      integer :: k
      k = self%stage
      self%rhs = (2.0_dp / (1.0_dp + self%lambda)) * (self%v_inf + u / self%ca)
      call self%double_layer%set_geometry(self%mesh, x)
      ! Initial guess: the same stage's solutions of the last two steps extrapolated linearly
      ! in time (v(t + dt) = 2 v(t) - v(t - dt) + O(dt**2): 6 operator applications per solve
      ! instead of 7 at level 2, lambda = 5); with one such solution, that solution; the very
      ! first predictor solve starts from the first stage's solution, and the very first
      ! solve from the right-hand side (the lambda = 1 velocity scaled by 2/(1+lambda)).
      if (self%n_stage(k) >= 2) then
         u = 2.0_dp * self%v_stage(:, :, 1, k) - self%v_stage(:, :, 2, k)
      else if (self%n_stage(k) == 1) then
         u = self%v_stage(:, :, 1, k)
      else if (k == 2 .and. self%n_stage(1) > 0) then
         u = self%v_stage(:, :, 1, 1)
      else
         u = self%rhs
      end if
      call self%interface%solve(self%double_layer, self%mesh, self%rhs, u, stat, errmsg)
      if (stat /= 0) then
         self%fault = errmsg
         return
      end if
      self%v_stage(:, :, 2, k) = self%v_stage(:, :, 1, k)
      self%v_stage(:, :, 1, k) = u
      self%n_stage(k) = min(self%n_stage(k) + 1, 2)
   end subroutine interface_velocity

   !> The exact single layer carries no net flux through the closed membrane, its P1
   !> discretisation does at O(h**2): at level 3, Ca_s = 0.3, the capsule lost 12 % of its
   !> volume over 25 time units, and the lost volume, not the membrane law, then set D12.
   !> Subtracting the spurious flux along the node normals, u_i -= c n_i with
   !> dV/dt = sum_i u_i . dV/dx_i = 0, removes a term of the discretisation error's order.
   !> `grad` is scratch for dV/dx_i = (1/3) sum of the area vectors of the node's triangles.
   subroutine remove_volume_flux(mesh, x, u, grad)
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(inout) :: u(:, :)
      real(dp), intent(out) :: grad(:, :)
      integer :: i, p, t
      real(dp) :: flux, norm_sum, g(3)
      flux = 0
      norm_sum = 0
      !$omp parallel do default(none) shared(mesh, x, u, grad) private(i, p, t, g) &
      !$omp reduction(+:flux, norm_sum) schedule(static)
      do i = 1, mesh%n_nodes
         g = 0
         do p = mesh%node_tri_start(i), mesh%node_tri_start(i + 1) - 1
            t = mesh%node_tri(p)
            g = g + cross(x(:, mesh%tri(2, t)) - x(:, mesh%tri(1, t)), x(:, mesh%tri(3, t)) - x(:, mesh%tri(1, t)))
         end do
         grad(:, i) = g / 6.0_dp
         flux = flux + dot_product(u(:, i), grad(:, i))
         norm_sum = norm_sum + norm2(grad(:, i))
      end do
      !$omp end parallel do
      do i = 1, mesh%n_nodes
         u(:, i) = u(:, i) - (flux / norm_sum) * grad(:, i) / norm2(grad(:, i))
      end do
   end subroutine remove_volume_flux

   !> Heun's RK2: predictor with v(x), corrector with the mean of v(x) and v(x_pred).
   subroutine rk2_step(self)
      class(capsule_t), intent(inout) :: self
      self%stage = 1
      call self%velocity(self%positions, self%u0)
      if (allocated(self%fault)) return
      self%x_pred = self%positions + self%dt * self%u0
      self%stage = 2
      call self%velocity(self%x_pred, self%u1)
      if (allocated(self%fault)) return
      self%positions = self%positions + 0.5_dp * self%dt * (self%u0 + self%u1)
      self%t = self%t + self%dt
      self%step = self%step + 1
   end subroutine rk2_step

   !> Append the current diagnostics to the history.
   subroutine record(self)
      class(capsule_t), intent(inout) :: self
      type(shape_measures_t) :: m
      real(dp) :: l1, l2, stretch, energy
      integer :: t
      call shape_measures(self%mesh, self%positions, m)
      stretch = 1.0_dp
      do t = 1, self%mesh%n_tri
         call principal_stretches(self%ref, self%mesh, self%positions, t, l1, l2)
         stretch = max(stretch, l1, 1.0_dp / max(l2, 1.0e-12_dp))
      end do
      ! The force array is scratch here: velocity() recomputes it before every use.
      call membrane_nodal_forces(self%ref, self%mesh, self%law, self%positions, self%force, energy)
      if (self%bending%kb > 0.0_dp) call self%bending%add_forces(self%mesh, self%positions, self%force, energy)
      self%n_rec = min(self%n_rec + 1, size(self%history, 2))
      self%history(:, self%n_rec) = [self%t, m%area, m%volume, m%d12, m%l1, m%l2, m%l3, m%theta, energy, stretch]
   end subroutine record

   function progress_text(self) result(text)
      class(capsule_t), intent(in) :: self
      character(len=:), allocatable :: text
      character(len=80) :: buf
      write (buf, '(a,f8.5,a,f8.4,a,f7.3)') 'D12 = ', self%history(h_d12, self%n_rec), '  L1/a = ', &
         self%history(h_l1, self%n_rec), '  area/4pi = ', self%history(h_area, self%n_rec) / (4 * pi)
      text = trim(buf)
      if (self%lambda /= 1.0_dp .and. self%interface%n_solves > 0) then
         write (buf, '(a,f6.2)') '  GMRES applications/solve = ', &
            real(self%interface%total_applications, dp) / real(self%interface%n_solves, dp)
         text = text//trim(buf)
      end if
   end function progress_text

   !> /mesh (reference and current nodes, triangles 0-based) and /profile (shear-plane contour).
   subroutine write_geometry(self, f, stat, errmsg)
      class(capsule_t), intent(in) :: self
      type(h5_file_t), intent(inout) :: f
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      type(shape_measures_t) :: m
      real(dp), allocatable :: y(:), z(:)
      call shape_measures(self%mesh, self%positions, m)
      call shear_plane_contour(self%mesh, self%positions, m%centroid, y, z)
      call f%write_attr('/', 'n_nodes', self%mesh%n_nodes, stat, errmsg)
      if (stat == 0) call write_surface_mesh(f, self%x_ref, self%positions, self%mesh%tri, 'a', stat, errmsg)
      if (stat == 0) call f%make_group('/profile', stat, errmsg)
      if (stat == 0) call f%write_attr('/profile', 'plane', 'x = x_centroid (shear plane yz)', stat, errmsg)
      if (stat == 0) call f%write_dataset('/profile/y', y, 'a', stat, errmsg)
      if (stat == 0) call f%write_dataset('/profile/z', z, 'a', stat, errmsg)
   end subroutine write_geometry

end module capsule_dynamics
