!> One capsule in Stokes flow: the membrane (P1 forces) coupled to the fluid (single layer,
!> viscosity ratio 1), advanced by RK2 (Heun) until a steady state, a continuous elongation,
!> a mesh breakdown or the time limit.
!>
!> Non-dimensional velocity of the membrane nodes (lengths in a, time in 1/gamma_dot,
!> forces in G_s):  v = v_inf + 1/(8 pi Ca) integral J . f dS,  f = F/A_node, F = -dE/dx.
module capsule_dynamics
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
   use capsim_kinds, only: dp, pi
   use vector_algebra, only: cross
   use sphere_mesh, only: surface_mesh_t, icosphere
   use membrane_law, only: membrane_law_t, make_membrane_law
   use membrane_forces, only: membrane_reference_t, membrane_nodal_forces, principal_stretches
   use stokes_single_layer, only: single_layer_t, triangle_areas, node_areas
   use surface_diagnostics, only: shape_measures_t, shape_measures
   use background_flow, only: flow_shear, undisturbed_velocity
   use run_options, only: run_options_t, option_signature
   use case_output, only: n_history, case_summary_t, write_checkpoint, read_checkpoint
   implicit none
   private
   public :: capsule_t, t_min_steady

   !> Column indices of the history table (names in case_output).
   integer, parameter, public :: h_t = 1, h_area = 2, h_volume = 3, h_d12 = 4, h_l1 = 5, h_l2 = 6, h_l3 = 7, &
                                 h_theta = 8, h_energy = 9, h_stretch = 10
   !> A steady state is not declared before this time: the first unit holds the start-up.
   real(dp), parameter :: t_min_steady = 2.0_dp
   !> Largest principal stretch a P1 triangle may reach before the mesh is declared broken.
   real(dp), parameter :: max_element_stretch = 15.0_dp

   type :: capsule_t
      type(surface_mesh_t) :: mesh
      type(membrane_law_t) :: law
      type(membrane_reference_t) :: ref
      type(single_layer_t) :: single_layer
      integer :: flow = flow_shear
      real(dp) :: ca = 0, dt = 0, t = 0, h_min = 0, energy = 0
      integer :: step = 0
      real(dp), allocatable :: x_ref(:, :), x(:, :)
      logical :: volume_correction = .true.
      real(dp), allocatable :: history(:, :)
      integer :: n_rec = 0
      ! Work arrays allocated once by init: the time loop allocates nothing.
      real(dp), allocatable :: x_pred(:, :), u0(:, :), u1(:, :), force(:, :), density(:, :), v_inf(:, :)
      real(dp), allocatable :: tri_area(:), node_area(:)
   contains
      procedure :: init
      procedure :: velocity
      procedure :: rk2_step
      procedure :: record
      procedure :: run
   end type capsule_t

contains

   subroutine init(self, opts, stat, errmsg)
      class(capsule_t), intent(inout) :: self
      type(run_options_t), intent(in) :: opts
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: n, t, k, capacity
      real(dp) :: h

      call icosphere(opts%level, self%mesh, self%x_ref, stat, errmsg)
      if (stat /= 0) return
      call make_membrane_law(trim(opts%law), opts%nu_s, opts%c, self%law, stat, errmsg)
      if (stat /= 0) return
      n = self%mesh%n_nodes
      self%x = self%x_ref
      call self%ref%init(self%mesh, self%x_ref)
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
      ! Explicit membrane stiffness: stable for dt < O(Ca h); 0.02 bounds the advection error.
      if (opts%dt > 0) then
         self%dt = opts%dt
      else
         self%dt = min(opts%dt_factor * opts%ca * self%h_min, 0.02_dp)
      end if
      capacity = ceiling(opts%t_max / max(opts%record_every, self%dt)) + 16
      allocate (self%history(n_history, capacity))
      self%history = 0
   end subroutine init

   !> Membrane velocity at positions x.
   subroutine velocity(self, x, u)
      class(capsule_t), intent(inout) :: self
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: u(:, :)
      integer :: i
      call membrane_nodal_forces(self%ref, self%mesh, self%law, x, self%force, self%energy)
      call triangle_areas(self%mesh, x, self%tri_area)
      call node_areas(self%mesh, self%tri_area, self%node_area)
      do i = 1, self%mesh%n_nodes
         self%density(:, i) = self%force(:, i) / self%node_area(i)
      end do
      call self%single_layer%velocity(self%mesh, x, self%density, u)
      call undisturbed_velocity(self%flow, x, self%v_inf)
      u = self%v_inf + u / self%ca
      if (self%volume_correction) call remove_volume_flux(self%mesh, x, u, self%force)
   end subroutine velocity

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
      call self%velocity(self%x, self%u0)
      self%x_pred = self%x + self%dt * self%u0
      call self%velocity(self%x_pred, self%u1)
      self%x = self%x + 0.5_dp * self%dt * (self%u0 + self%u1)
      self%t = self%t + self%dt
      self%step = self%step + 1
   end subroutine rk2_step

   !> Append the current diagnostics to the history.
   subroutine record(self)
      class(capsule_t), intent(inout) :: self
      type(shape_measures_t) :: m
      real(dp) :: l1, l2, stretch, energy
      integer :: t
      call shape_measures(self%mesh, self%x, m)
      stretch = 1.0_dp
      do t = 1, self%mesh%n_tri
         call principal_stretches(self%ref, self%mesh, self%x, t, l1, l2)
         stretch = max(stretch, l1, 1.0_dp / max(l2, 1.0e-12_dp))
      end do
      ! The force array is scratch here: velocity() recomputes it before every use.
      call membrane_nodal_forces(self%ref, self%mesh, self%law, self%x, self%force, energy)
      self%n_rec = min(self%n_rec + 1, size(self%history, 2))
      self%history(:, self%n_rec) = [self%t, m%area, m%volume, m%d12, m%l1, m%l2, m%l3, m%theta, energy, stretch]
   end subroutine record

   !> Advance until a final status; checkpoints to `checkpoint_path` every
   !> opts%checkpoint_every wall seconds and resumes from it if it matches the options.
   subroutine run(self, opts, checkpoint_path, summary, steady_index)
      class(capsule_t), intent(inout) :: self
      type(run_options_t), intent(in) :: opts
      character(len=*), intent(in) :: checkpoint_path
      type(case_summary_t), intent(inout) :: summary
      integer, intent(out) :: steady_index
      integer(8) :: clock_start, clock_now, clock_rate, clock_ckpt, clock_print
      real(dp) :: t_next_record, v0
      character(len=:), allocatable :: signature, errmsg
      logical :: resumed, decided
      integer :: stat

      steady_index = 0
      summary%dt = self%dt
      signature = option_signature(opts)
      call read_checkpoint(checkpoint_path, signature, self%step, self%t, self%x, self%history, self%n_rec, resumed)
      if (resumed) then
         if (.not. opts%quiet) write (*, '(a,f0.3)') 'capsim: resumed from checkpoint at t = ', self%t
      else
         self%x = self%x_ref
         self%t = 0
         self%step = 0
         self%n_rec = 0
         call self%record()
      end if
      v0 = self%history(h_volume, 1)
      t_next_record = next_record_time(self%history(h_t, self%n_rec), opts%record_every)
      call system_clock(clock_start, clock_rate)
      clock_ckpt = clock_start
      clock_print = clock_start
      decided = .false.
      do while (self%t < opts%t_max - 0.5_dp * self%dt)
         call self%rk2_step()
         if (.not. all(ieee_is_finite(self%x))) then
            summary%status = 'failed'
            summary%message = 'non-finite node positions at t = '//num(self%t)//' (time step too large?)'
            decided = .true.
            exit
         end if
         if (self%t >= t_next_record - 1.0e-9_dp) then
            call self%record()
            t_next_record = next_record_time(self%t, opts%record_every)
            call classify(self, opts, summary, decided)
            if (decided) exit
         end if
         call system_clock(clock_now)
         if (real(clock_now - clock_ckpt, dp) / clock_rate >= opts%checkpoint_every) then
            call write_checkpoint(checkpoint_path, signature, self%step, self%t, self%x, self%history, &
                                  self%n_rec, stat, errmsg)
            if (stat /= 0 .and. .not. opts%quiet) write (*, '(a)') 'capsim: warning: '//errmsg
            clock_ckpt = clock_now
         end if
         if (.not. opts%quiet .and. real(clock_now - clock_print, dp) / clock_rate >= 2.0_dp) then
            write (*, '(a,f9.3,a,f0.1,a,f8.5,a,f8.4,a,f7.3)') 'capsim: t = ', self%t, ' / ', opts%t_max, &
               '  D12 = ', self%history(h_d12, self%n_rec), '  L1/a = ', self%history(h_l1, self%n_rec), &
               '  area/4pi = ', self%history(h_area, self%n_rec) / (4 * pi)
            flush (6)
            clock_print = clock_now
         end if
      end do
      if (.not. decided) call classify_at_time_limit(self, opts, summary)
      if (trim(summary%status) == 'steady') steady_index = self%n_rec
      summary%volume_change = self%history(h_volume, self%n_rec) / v0 - 1.0_dp
   end subroutine run

   !> Steady, continuous elongation or mesh breakdown, from the history so far.
   subroutine classify(self, opts, summary, decided)
      type(capsule_t), intent(in) :: self
      type(run_options_t), intent(in) :: opts
      type(case_summary_t), intent(inout) :: summary
      logical, intent(out) :: decided
      integer :: first, n
      real(dp) :: t_now, area_var, d12_var, d12_now, growth

      decided = .false.
      n = self%n_rec
      t_now = self%history(h_t, n)
      if (self%history(h_l1, n) > opts%max_length) then
         summary%status = 'continuous_elongation'
         summary%message = 'L1/a exceeded '//num(opts%max_length)//' at t = '//num(t_now)// &
                           ': the capsule elongates without reaching a steady shape'
         decided = .true.
         return
      end if
      first = window_start(self, t_now - 1.0_dp)
      if (self%history(h_stretch, n) > max_element_stretch) then
         growth = self%history(h_l1, n) - self%history(h_l1, first)
         if (growth > 0.01_dp) then
            summary%status = 'continuous_elongation'
            summary%message = 'mesh broke down at t = '//num(t_now)//' while L1/a grew by '//num(growth)// &
                              ' over the last time unit: no steady shape'
         else
            summary%status = 'failed'
            summary%message = 'mesh breakdown at t = '//num(t_now)//' (element stretch above '// &
                              num(max_element_stretch)//')'
         end if
         decided = .true.
         return
      end if
      if (t_now < t_min_steady .or. self%history(h_t, 1) > t_now - 1.0_dp) return
      area_var = maxval(self%history(h_area, first:n)) - minval(self%history(h_area, first:n))
      d12_var = maxval(self%history(h_d12, first:n)) - minval(self%history(h_d12, first:n))
      d12_now = self%history(h_d12, n)
      if (area_var < opts%steady_tol * 4 * pi .and. d12_var < opts%shape_tol * d12_now + 1.0e-4_dp) then
         summary%status = 'steady'
         summary%message = 'over the last time unit area varied by '//num(area_var / (4 * pi))// &
                           ' x 4 pi a^2 and D12 by '//num(d12_var)
         decided = .true.
      end if
   end subroutine classify

   !> At t_max: continuous elongation if L1 still grows without slowing down (growth over the
   !> last time unit at least half that over the one before) after a run long enough to judge.
   subroutine classify_at_time_limit(self, opts, summary)
      type(capsule_t), intent(in) :: self
      type(run_options_t), intent(in) :: opts
      type(case_summary_t), intent(inout) :: summary
      real(dp), parameter :: min_time_to_judge = 5.0_dp
      integer :: last, mid, first
      real(dp) :: t_now, growth_last, growth_before
      last = self%n_rec
      t_now = self%history(h_t, last)
      mid = window_start(self, t_now - 1.0_dp)
      first = window_start(self, t_now - 2.0_dp)
      growth_last = self%history(h_l1, last) - self%history(h_l1, mid)
      growth_before = self%history(h_l1, mid) - self%history(h_l1, first)
      if (t_now >= min_time_to_judge .and. growth_last > opts%shape_tol * self%history(h_l1, last) .and. &
          growth_last >= 0.5_dp * growth_before) then
         summary%status = 'continuous_elongation'
         summary%message = 'L1/a still growing at t_max = '//num(opts%t_max)//' (by '//num(growth_last)// &
                           ' over the last time unit, not slowing down): no steady shape'
      else
         summary%status = 'max_time'
         summary%message = 'no steady state by t_max = '//num(opts%t_max)
      end if
   end subroutine classify_at_time_limit

   !> Records fall on the first step at or after each multiple of `every`; computed from the
   !> last record alone, so that a resumed run records at the same steps as an uninterrupted one.
   pure real(dp) function next_record_time(t_last, every)
      real(dp), intent(in) :: t_last, every
      next_record_time = (floor(t_last / every + 1.0e-6_dp) + 1) * every
   end function next_record_time

   pure integer function window_start(self, t_from)
      type(capsule_t), intent(in) :: self
      real(dp), intent(in) :: t_from
      integer :: k
      window_start = 1
      do k = self%n_rec, 1, -1
         if (self%history(h_t, k) < t_from - 1.0e-9_dp) then
            window_start = k + 1
            exit
         end if
      end do
      window_start = min(window_start, self%n_rec)
   end function window_start

   pure function num(x) result(s)
      real(dp), intent(in) :: x
      character(len=:), allocatable :: s
      character(len=32) :: buf
      write (buf, '(es10.3)') x
      s = trim(adjustl(buf))
   end function num

end module capsule_dynamics
