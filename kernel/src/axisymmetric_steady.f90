!> Steady shapes of the axisymmetric tube model as roots of the capsule-frame velocity
!> (axisymmetric_operator): Newton's method on a bordered system, with continuation in Ca from
!> a nearly rigid capsule (newton_run), and the polish of a shape that time stepping declared
!> steady (polish_steady_shape). Newton's work arrays and the LU it reuses are newton_state_t.
module axisymmetric_steady
   use capsim_kinds, only: dp
   use lapack_interfaces, only: dgesv, dgetrs
   use axisymmetric_membrane, only: meridian_volume_gradient
   use run_options, only: run_options_t
   use capsule_model, only: num
   use case_output, only: case_summary_t
   use tube_history, only: h_t, h_lz
   use axisymmetric_operator, only: axisymmetric_operator_t, velocity_jacobian, largest_growth_rate, pack_dofs, &
                                    unpack_dofs, restore_volume_and_centre, jacobian_fd_step, rigid_fd_step
   implicit none
   private
   public :: newton_state_t, newton_run, polish_steady_shape, newton_tolerance, stable_rate_limit, &
             constraint_directions, projected_residual

   !> Newton tolerance of the polish after time stepping (largest node velocity, V).
   real(dp), parameter :: polish_tol = 1.0e-6_dp
   !> A steady shape is linearly stable when no Jacobian eigenvalue has a real part above this
   !> (V/l): the inflation and axial-shift directions have eigenvalues ~0 (to the noise).
   real(dp), parameter :: stable_rate_limit = 1.0e-2_dp

   !> Newton's bordered system and its LU (kept for the continuation's predictor), its right-hand
   !> side and border, the residual, the last converged shape, and the Jacobian of the polish.
   type :: newton_state_t
      real(dp), allocatable :: system(:, :), step_vector(:), border(:, :), res(:), rz_good(:, :), jacobian(:, :)
      integer, allocatable :: pivot(:)
      !> The bordered system's LU from the last Newton step, reused for the Ca predictor.
      logical :: have_lu = .false.
   contains
      procedure :: init => newton_state_init
   end type newton_state_t

contains

   !> Work arrays for a meridian of n_nodes nodes.
   subroutine newton_state_init(self, n_nodes)
      class(newton_state_t), intent(inout) :: self
      integer, intent(in) :: n_nodes
      integer :: m
      m = 2 * n_nodes - 2
      allocate (self%system(m + 2, m + 2), self%step_vector(m + 2), self%border(m, 2), self%pivot(m + 2))
      allocate (self%res(m), self%rz_good(2, n_nodes), self%jacobian(m, m))
   end subroutine newton_state_init

   !> Newton tolerance on the largest node velocity (V): the requested one, but not below the
   !> noise of the velocity, ~1e-9 / Ca_s (quadrature noise of the membrane single layer,
   !> scaled by 1/Ca: at a/l = 0.4, Ca_s = 1e-3, 64 elements, Newton stalled at 5e-7 V).
   pure real(dp) function newton_tolerance(self, opts) result(tol)
      class(axisymmetric_operator_t), intent(in) :: self
      type(run_options_t), intent(in) :: opts
      real(dp), parameter :: velocity_noise = 1.0e-9_dp
      tol = max(opts%newton_tol, velocity_noise / self%ca)
   end function newton_tolerance

   !> The steady shape as the root of u(x) = 0 (membrane at rest in the capsule frame), by
   !> Newton's method with a finite-difference Jacobian and continuation in Ca from a nearly
   !> rigid capsule. Why not time stepping: at small Ca the rear of the membrane is under
   !> compression, and a membrane without bending stiffness then has mesh-scale modes that
   !> grow at ~10 V/l whatever Ca (measured from the Jacobian's eigenvalues); explicit steps,
   !> bound to dt ~ Ca h, let them wrinkle the rear long before the shape is steady.
   !> Newton-type iterations (newton_solve) converge to the steady shape the paper reports.
   !> When continuation cannot pass some Ca (the steady branch ends), the run is reported
   !> as continuous elongation at that Ca.
   subroutine newton_run(self, newton, opts, summary, steady_index)
      class(axisymmetric_operator_t), intent(inout) :: self
      type(newton_state_t), intent(inout) :: newton
      type(run_options_t), intent(in) :: opts
      type(case_summary_t), intent(inout) :: summary
      integer, intent(out) :: steady_index
      real(dp), parameter :: ca_start = 1.0e-3_dp, min_factor = 1.02_dp
      real(dp) :: ca_target, ca_good, factor, ca_try
      logical :: converged

      steady_index = 0
      ca_target = opts%ca
      call self%reset()
      self%t = 0
      self%step = 0
      self%n_rec = 0
      self%ca = min(ca_target, ca_start)
      call self%record()
      call newton_solve(self, newton, newton_tolerance(self, opts), rigid_fd_step, converged)
      if (.not. converged) then
         summary%status = 'failed'
         summary%message = 'Newton did not converge for the nearly rigid capsule at Ca = '//num(self%ca)
         return
      end if
      ca_good = self%ca
      newton%rz_good = self%positions
      factor = 2.0_dp
      do while (ca_good < ca_target)
         ca_try = min(ca_good * factor, ca_target)
         call predict_shape(self, newton, ca_good, ca_try)
         self%ca = ca_try
         call newton_solve(self, newton, newton_tolerance(self, opts), rigid_fd_step, converged)
         if (converged) then
            ca_good = ca_try
            newton%rz_good = self%positions
            if (.not. opts%quiet) write (*, '(a,es10.3,a)') 'capsim: steady shape at Ca = ', ca_good, &
               '  '//self%progress_text()
            factor = min(factor**1.5_dp, 2.0_dp)
         else
            self%positions = newton%rz_good
            newton%have_lu = .false.
            factor = sqrt(factor)
            if (factor < min_factor) exit
         end if
         if (self%n_rec >= self%record_limit - 1) exit
      end do
      self%ca = ca_target
      if (ca_good >= ca_target) then
         summary%status = 'steady'
         summary%message = 'steady: Newton residual (largest membrane velocity in the capsule frame) '// &
                           num(self%residual)//' after continuation in Ca'
         steady_index = self%n_rec
      else
         self%positions = newton%rz_good
         self%ca = ca_good
         call self%record()
         summary%status = 'continuous_elongation'
         summary%message = 'no steady shape beyond Ca = '//num(ca_good)//' (L_z/l = '// &
                           num(self%history(h_lz, self%n_rec))//'): the steady branch ends before Ca = '// &
                           num(ca_target)
      end if
   end subroutine newton_run

   !> Newton iterations on u(x) = 0 with a finite-difference Jacobian J. J is singular along
   !> the inflation of the capsule (a uniform pressure moves no fluid) and nearly so along
   !> its axial translation (only the tube's ends feel it): plain Newton followed those
   !> directions into steps of the order of the capsule size. The step is therefore the
   !> bordered system
   !>     J delta + lambda_V g + lambda_z t = -u,   g . delta = 0,   t . delta = 0,
   !> with g = dV/dx and t the uniform axial shift: delta keeps the volume and position, and
   !> the multipliers absorb what no shape change can cancel. The residual is u with its
   !> g and t components removed; a backtracking line search keeps every step downhill.
   !> Tangent predictor for the continuation: from the steady shape at ca_from,
   !> x(ca_to) ~ x + (ca_to - ca_from) dx/dCa with J dx/dCa = -du/dCa (bordered as in
   !> newton_solve, with the LU of its last step); du/dCa by a difference in Ca at fixed shape.
   !> Without it each doubling of Ca starts Newton half an elastic velocity away from the
   !> root, which near the wall film takes ten or more damped steps.
   subroutine predict_shape(self, newton, ca_from, ca_to)
      class(axisymmetric_operator_t), intent(inout) :: self
      type(newton_state_t), intent(inout) :: newton
      real(dp), intent(in) :: ca_from, ca_to
      real(dp), parameter :: rel_step = 1.0e-4_dp
      integer :: m, info
      if (.not. newton%have_lu) return
      m = size(self%dofs)
      self%ca = ca_from
      call self%velocity(self%positions, self%u0)
      call pack_dofs(self%u0, newton%res)
      self%ca = ca_from * (1.0_dp + rel_step)
      call self%velocity(self%positions, self%u1)
      call pack_dofs(self%u1, self%res_trial)
      newton%step_vector(1:m) = -(self%res_trial - newton%res) / (ca_from * rel_step) * (ca_to - ca_from)
      newton%step_vector(m + 1:m + 2) = 0.0_dp
      call dgetrs('N', m + 2, 1, newton%system, m + 2, newton%pivot, newton%step_vector, m + 2, info)
      if (info /= 0) return
      call pack_dofs(self%positions, self%dofs)
      call unpack_dofs(self%dofs + newton%step_vector(1:m), self%positions)
      call restore_volume_and_centre(self, self%positions)
   end subroutine predict_shape

   subroutine newton_solve(self, newton, tol, fd_step, converged)
      class(axisymmetric_operator_t), intent(inout) :: self
      type(newton_state_t), intent(inout) :: newton
      real(dp), intent(in) :: tol, fd_step
      logical, intent(out) :: converged
      integer, parameter :: max_iterations = 40
      integer :: m, it, info
      real(dp) :: residual, trial, alpha

      converged = .false.
      m = size(self%dofs)
      call self%velocity(self%positions, self%u0)
      call pack_dofs(self%u0, newton%res)
      call constraint_directions(self, newton%border, self%positions)
      residual = projected_residual(newton%border, newton%res)
      do it = 1, max_iterations
         self%residual = residual
         if (residual < tol) then
            converged = .true.
            call self%record()
            return
         end if
         call pack_dofs(self%positions, self%dofs)
         call velocity_jacobian(self, self%positions, fd_step, newton%system(1:m, 1:m))
         newton%system(1:m, m + 1:m + 2) = newton%border
         newton%system(m + 1:m + 2, 1:m) = transpose(newton%border)
         newton%system(m + 1:m + 2, m + 1:m + 2) = 0.0_dp
         newton%step_vector(1:m) = -newton%res
         newton%step_vector(m + 1:m + 2) = 0.0_dp
         call dgesv(m + 2, 1, newton%system, m + 2, newton%pivot, newton%step_vector, m + 2, info)
         if (info /= 0) return
         newton%have_lu = .true.
         alpha = 1.0_dp
         do
            call unpack_dofs(self%dofs + alpha * newton%step_vector(1:m), self%rz_pred)
            call restore_volume_and_centre(self, self%rz_pred)
            call self%velocity(self%rz_pred, self%u1)
            call pack_dofs(self%u1, self%dofs_trial)
            call constraint_directions(self, newton%border, self%rz_pred)
            trial = projected_residual(newton%border, self%dofs_trial)
            if (trial < (1.0_dp - 0.1_dp * alpha) * residual) exit
            alpha = 0.5_dp * alpha
            if (alpha < 1.0_dp / 64) return
         end do
         self%positions = self%rz_pred
         newton%res = self%dofs_trial
         residual = trial
         self%t = self%t + 1
         self%step = self%step + 1
      end do
      self%residual = residual
   end subroutine newton_solve

   !> The two border columns at rz, orthonormalised: the volume gradient and the uniform axial
   !> shift (also the continuation's border, axisymmetric_continuation).
   subroutine constraint_directions(self, border, rz)
      class(axisymmetric_operator_t), intent(inout) :: self
      real(dp), intent(out) :: border(:, :)
      real(dp), intent(in) :: rz(:, :)
      integer :: m
      m = size(border, 1)
      call meridian_volume_gradient(rz, self%grad)
      call pack_dofs(self%grad, border(:, 1))
      ! The z entries of the packed dofs: the poles' (1 and m) and every interior node's (odd
      ! entries 3 .. m-1; the even ones are radii). Up to kernel 0.3.1 this took the radii: the
      ! "translation" border was a radial swelling, translation was left free, and the polish
      ! after time stepping stalled at ~1e-3 V (NH a/l 0.9, Ca_s 0.07, 64 elements) and was discarded.
      border(:, 2) = 0.0_dp
      border(1, 2) = 1.0_dp
      border(3:m - 1:2, 2) = 1.0_dp
      border(m, 2) = 1.0_dp
      border(:, 2) = border(:, 2) / norm2(border(:, 2))
      border(:, 1) = border(:, 1) - dot_product(border(:, 1), border(:, 2)) * border(:, 2)
      border(:, 1) = border(:, 1) / norm2(border(:, 1))
   end subroutine constraint_directions

   !> Time stepping declares a steady state when the lengths drift by less than 1e-3 per
   !> time unit; the shape is then within ~1e-3 l of the steady one, and how far depends on
   !> the path (a/l = 0.9, Ca_s = 0.1: L_z 2.2193 after RK2, 2.2153 after implicit steps).
   !> Newton's method from there converges to the steady shape itself, in whose basin the
   !> time stepping ended; the polished shape is kept only if it is linearly stable (no
   !> Jacobian eigenvalue with a real part above stable_rate_limit), so that Newton cannot
   !> swap the physical shape for an unstable neighbour.
   subroutine polish_steady_shape(self, newton, opts, summary, steady_index)
      class(axisymmetric_operator_t), intent(inout) :: self
      type(newton_state_t), intent(inout) :: newton
      type(run_options_t), intent(in) :: opts
      type(case_summary_t), intent(inout) :: summary
      integer, intent(inout) :: steady_index
      real(dp) :: t_settled, rate
      real(dp), allocatable :: settled(:, :)
      integer :: n_settled
      logical :: converged
      t_settled = self%t
      allocate (settled, source=self%positions)
      n_settled = self%n_rec
      call newton_solve(self, newton, max(newton_tolerance(self, opts), polish_tol), jacobian_fd_step * self%a, converged)
      self%t = t_settled
      rate = huge(1.0_dp)
      if (converged) then
         call velocity_jacobian(self, self%positions, jacobian_fd_step * self%a, newton%jacobian)
         rate = largest_growth_rate(self, newton%jacobian)
      end if
      if (converged .and. rate < stable_rate_limit) then
         self%history(h_t, self%n_rec) = t_settled
         steady_index = self%n_rec
         summary%message = summary%message//'; Newton polish: residual '//num(self%residual)// &
                           ', largest growth rate '//num(rate)//' V/l'
      else
         self%positions = settled
         self%n_rec = n_settled
         if (converged) then
            summary%message = summary%message//'; the Newton polish found an unstable shape (growth rate '// &
                              num(rate)//' V/l) and was discarded'
         else
            summary%message = summary%message//'; the Newton polish stopped at residual '//num(self%residual)// &
                              ' V and was discarded'
         end if
      end if
   end subroutine polish_steady_shape

   !> Largest component of u once its parts along the border (inflation, translation) are removed.
   pure real(dp) function projected_residual(border, u) result(r)
      real(dp), intent(in) :: border(:, :), u(:)
      r = maxval(abs(u - matmul(border, matmul(transpose(border), u))))
   end function projected_residual

end module axisymmetric_steady
