!> Time integrators of the axisymmetric tube model (axisymmetric_operator's velocity): Heun's
!> RK2, explicit and time-accurate, and linearly implicit Euler steps with a reused velocity
!> Jacobian (implicit_step), whose state lives in implicit_state_t.
module axisymmetric_integrators
   use capsim_kinds, only: dp
   use lapack_interfaces, only: dgetrf, dgetrs
   use axisymmetric_operator, only: axisymmetric_operator_t, velocity_jacobian, largest_growth_rate, pack_dofs, &
                                    unpack_dofs, restore_volume_and_centre, jacobian_fd_step
   use state_vector, only: state_cursor_t
   implicit none
   private
   public :: implicit_state_t, rk2_step, implicit_step, exchange_implicit_state, implicit_dt

   !> Linearly implicit steps: largest step (l/V) and largest age of a Jacobian (steps).
   !> 0.2 l/V: the steady shapes (polished) equal those of 0.1 to 1e-7 (NH, a/l 0.3-1.1, Ca_s
   !> 0.02-0.2, 64 elements) in 10-40 % less time; with 0.4 the polish at a/l 0.3, Ca_s 0.2
   !> failed and the unpolished L_p was 13 % off. The buckling modes are not affected: their
   !> growth still limits dt (growth_step_limit).
   real(dp), parameter :: implicit_dt = 0.2_dp
   integer, parameter :: jacobian_max_age = 20
   !> Largest correction of an implicit step, relative to its size (see implicit_step).
   real(dp), parameter :: defect_tol = 0.5_dp
   !> Largest lambda dt for the growing modes (Re lambda > 0) of an implicit step.
   real(dp), parameter :: growth_step_limit = 0.5_dp
   !> Largest relative change of an element's stretch (meridional or azimuthal) in one step.
   !> The chord check judges the implicit equation, not how far the shape moved: at large
   !> Ca_s, where the rear rim is a corner that jumps from node to node, a step of 0.2 l/V took
   !> an element from stretch 2.85 to 4.43 (GH nu_s 0.5, a/l 0.8, Ca_s 1.5, t = 1.4) or 2.46 to
   !> 5.92 (a/l 0.85, Ca_s 2, t = 4.3): the run ended as continuous elongation or mesh
   !> breakdown where steps of 0.1 reach a steady shape (stretch at most 2.66 on the way). The start from a
   !> sphere at dt 0.2 changes stretches by at most 23 % a step at Ca_s 1.5.
   real(dp), parameter :: step_stretch_limit = 0.3_dp

   !> What a linearly implicit step carries to the next: the velocity Jacobian J and the LU of
   !> I - dt J (see implicit_step), the velocity u_here at positions rz_here (the next step's
   !> u(x)), the Jacobian's age in steps, the step cap after halvings, and the solver's counts.
   type :: implicit_state_t
      real(dp), allocatable :: jacobian(:, :), step_matrix(:, :), step_rhs(:), correction(:)
      real(dp), allocatable :: rz_here(:, :), u_here(:, :)
      !> Positions at which the Jacobian in use was made: a resumed run makes it again there.
      real(dp), allocatable :: rz_jacobian(:, :)
      integer, allocatable :: step_pivot(:)
      integer :: jacobian_age = huge(1)
      !> Step cap after halvings (see implicit_step), dt_max when none.
      real(dp) :: dt_limit = huge(1.0_dp)
      !> Counts of the implicit solver: Jacobians computed, steps redone.
      integer :: n_jacobians = 0, n_rejected = 0
   contains
      procedure :: init => implicit_state_init
   end type implicit_state_t

contains

   !> Work arrays for a meridian of n_nodes nodes; no Jacobian yet; the step cap dt.
   subroutine implicit_state_init(self, n_nodes, dt)
      class(implicit_state_t), intent(inout) :: self
      integer, intent(in) :: n_nodes
      real(dp), intent(in) :: dt
      integer :: m
      m = 2 * n_nodes - 2
      allocate (self%jacobian(m, m), self%step_matrix(m, m), self%step_rhs(m), self%step_pivot(m), self%correction(m))
      allocate (self%rz_here(2, n_nodes), self%u_here(2, n_nodes), self%rz_jacobian(2, n_nodes))
      self%rz_here = huge(1.0_dp)
      self%rz_jacobian = 0
      self%dt_limit = dt
   end subroutine implicit_state_init

   !> One step of Heun's RK2 in the capsule frame (time-accurate), with the centroid put back
   !> at z = 0.
   subroutine rk2_step(self)
      class(axisymmetric_operator_t), intent(inout) :: self
      call self%velocity(self%positions, self%u0)
      self%rz_pred = self%positions + self%dt * self%u0
      call self%velocity(self%rz_pred, self%u1)
      self%positions = self%positions + 0.5_dp * self%dt * (self%u0 + self%u1)
      call restore_volume_and_centre(self, self%positions)
      self%t = self%t + self%dt
      self%step = self%step + 1
   end subroutine rk2_step

   !> One linearly implicit (Rosenbrock-Euler) step, (I - dt J) delta = dt u(x), x <- x + delta,
   !> with J the velocity Jacobian (velocity_jacobian), reused over steps while it serves.
   !> Why: the explicit step is bound to dt ~ Ca h by the membrane's stiffness (dt = 3e-3
   !> at a/l = 0.9, Ca_s = 0.1, 48 elements: 4400 RK2 steps to steady state); the implicit
   !> step damps the stiff elastic modes whatever dt. The rear-buckling modes (Jacobian
   !> eigenvalues up to ~ +50 V/l just after the start, ~ +9 V/l at the rear later) must
   !> still grow, by 1/(1 - lambda dt) per step, which needs lambda dt < 1: dt is set to
   !> growth_step_limit / (largest growth rate) at each new Jacobian, at most dt_max.
   !> A fixed point of the step is a zero of u, whatever J: a stale Jacobian changes the
   !> path, never the steady shape; but a stale J let a buckling rear (a/l = 0.3, Ca_s =
   !> 0.05) blow up. So each step checks itself: delta should equal dt u(x + delta) (the
   !> implicit Euler equation), and the step is redone with a new Jacobian, or with half the
   !> step if the Jacobian is new, when the correction that one more chord iteration would
   !> make, c = (I - dt J)**-1 (dt u(x + delta) - delta), exceeds defect_tol |delta|. The
   !> correction, not the defect itself: a stiff membrane mode (eigenvalue ~ -1/Ca_s) carries
   !> a defect dt dJ delta that is large against delta when J is a little stale, yet its
   !> correction is damped by 1/(1 - dt lambda); judged by the raw defect, NH a/l 0.75 at
   !> Ca_s = 0.01 redid 110 of its 91 steps with 77 Jacobians (12 CPU s), against 17 steps and
   !> 17 Jacobians (3.8 CPU s), to the same polished shape, judged by the correction. The
   !> velocity at the new position is the next step's u(x): the check costs one solve with the
   !> LU in hand and no extra evaluation.
   subroutine implicit_step(self, st)
      class(axisymmetric_operator_t), intent(inout) :: self
      type(implicit_state_t), intent(inout) :: st
      integer, parameter :: max_attempts = 12
      integer :: m, info, attempt
      real(dp) :: change
      m = size(self%dofs)
      if (any(self%positions /= st%rz_here)) then
         call self%velocity(self%positions, st%u_here)
         st%rz_here = self%positions
      end if
      if (st%jacobian_age >= jacobian_max_age) call refresh_jacobian(self, st)
      call pack_dofs(self%positions, self%dofs)
      do attempt = 1, max_attempts
         call pack_dofs(st%u_here, st%step_rhs)
         st%step_rhs = self%dt * st%step_rhs
         call dgetrs('N', m, 1, st%step_matrix, m, st%step_pivot, st%step_rhs, m, info)
         call unpack_dofs(self%dofs + st%step_rhs, self%rz_pred)
         call restore_volume_and_centre(self, self%rz_pred)
         call self%velocity(self%rz_pred, self%u1)
         call pack_dofs(self%rz_pred, self%dofs_trial)
         call pack_dofs(self%u1, self%res_trial)
         change = maxval(abs(self%dofs_trial - self%dofs))
         st%correction = self%dt * self%res_trial - (self%dofs_trial - self%dofs)
         call dgetrs('N', m, 1, st%step_matrix, m, st%step_pivot, st%correction, m, info)
         if (maxval(abs(st%correction)) <= defect_tol * change .and. &
             largest_stretch_change(self%positions, self%rz_pred) <= step_stretch_limit) exit
         st%n_rejected = st%n_rejected + 1
         if (st%jacobian_age == 0) then
            self%dt = 0.5_dp * self%dt
            st%dt_limit = self%dt
            call factorise_step_matrix(self, st)
         else
            call refresh_jacobian(self, st)
         end if
      end do
      self%positions = self%rz_pred
      st%rz_here = self%rz_pred
      st%u_here = self%u1
      st%jacobian_age = st%jacobian_age + 1
      ! A step that had to be halved caps the next ones; the cap relaxes by half per accepted step.
      st%dt_limit = min(self%dt_max, 1.5_dp * st%dt_limit)
      self%t = self%t + self%dt
      self%step = self%step + 1
   end subroutine implicit_step

   !> Largest relative change of an element's meridional or azimuthal stretch from rz0 to rz1:
   !> the reference cancels in both ratios (lengths, and mean radii, which only the poles'
   !> nodes lack: every element has a node off the axis).
   pure real(dp) function largest_stretch_change(rz0, rz1) result(change)
      real(dp), intent(in) :: rz0(:, :), rz1(:, :)
      integer :: e
      real(dp) :: length0, length1, radius0, radius1
      change = 0
      do e = 1, size(rz0, 2) - 1
         length0 = norm2(rz0(:, e + 1) - rz0(:, e))
         length1 = norm2(rz1(:, e + 1) - rz1(:, e))
         if (length0 > 0.0_dp) change = max(change, abs(length1 / length0 - 1.0_dp))
         radius0 = rz0(1, e) + rz0(1, e + 1)
         radius1 = rz1(1, e) + rz1(1, e + 1)
         if (radius0 > 0.0_dp) change = max(change, abs(radius1 / radius0 - 1.0_dp))
      end do
   end function largest_stretch_change

   !> New Jacobian at the current positions, the step it allows, and the LU of I - dt J.
   subroutine refresh_jacobian(self, st)
      class(axisymmetric_operator_t), intent(inout) :: self
      type(implicit_state_t), intent(inout) :: st
      st%rz_jacobian = self%positions
      call velocity_jacobian(self, st%rz_jacobian, jacobian_fd_step * self%a, st%jacobian)
      st%n_jacobians = st%n_jacobians + 1
      self%dt = min(st%dt_limit, growth_step_limit / max(largest_growth_rate(self, st%jacobian), tiny(1.0_dp)))
      call factorise_step_matrix(self, st)
      st%jacobian_age = 0
   end subroutine refresh_jacobian

   subroutine factorise_step_matrix(self, st)
      class(axisymmetric_operator_t), intent(inout) :: self
      type(implicit_state_t), intent(inout) :: st
      integer :: j, m, info
      m = size(st%jacobian, 1)
      st%step_matrix = -self%dt * st%jacobian
      do j = 1, m
         st%step_matrix(j, j) = st%step_matrix(j, j) + 1.0_dp
      end do
      call dgetrf(m, m, st%step_matrix, m, st%step_pivot, info)
   end subroutine factorise_step_matrix

   !> The implicit steps' part of the checkpoint state (see capsule_model's exchange_state):
   !> the step and its cap, the Jacobian's age and where it was made, the counts. The Jacobian
   !> (a function of its positions alone) and the LU of I - dt J, which always belongs to the
   !> current dt after a step, are made again when restoring; the velocity at the positions
   !> (u_here) is recomputed by the next step, as rz_here no longer matches.
   subroutine exchange_implicit_state(self, st, state, cursor)
      class(axisymmetric_operator_t), intent(inout) :: self
      type(implicit_state_t), intent(inout) :: st
      real(dp), intent(inout) :: state(:)
      type(state_cursor_t), intent(inout) :: cursor
      call cursor%real_value(state, self%dt)
      call cursor%real_value(state, st%dt_limit)
      call cursor%int_value(state, st%jacobian_age)
      call cursor%int_value(state, st%n_jacobians)
      call cursor%int_value(state, st%n_rejected)
      call cursor%reals(state, st%rz_jacobian, size(st%rz_jacobian))
      if (.not. cursor%restoring()) return
      st%rz_here = huge(1.0_dp)
      ! No Jacobian before the first step (its age is then huge); an expired one is renewed
      ! by the next step before any use.
      if (st%jacobian_age < jacobian_max_age) then
         call velocity_jacobian(self, st%rz_jacobian, jacobian_fd_step * self%a, st%jacobian)
         call factorise_step_matrix(self, st)
      end if
   end subroutine exchange_implicit_state

end module axisymmetric_integrators
