!> Continuation of the steady tube shapes in Ca_s: from one steady shape, the next requested
!> Ca_s by a tangent predictor and chord-Newton corrector, and the fold where the steady branch
!> ends (the onset of continuous elongation) by pseudo-arclength steps. The unknowns are the
!> packed meridian x (axisymmetric_operator's dofs) and p = ln Ca_s: the paper's Ca_s grid is
!> nearly geometric, and in p the branch's slope stays O(1) over three decades.
!>
!> Every Newton system is the bordered one of axisymmetric_steady (u(x, p) = 0 with the volume
!> and axial-shift directions g, t as multipliers), extended by the p column u_p and one
!> constraint row c:
!>     [ J    u_p  g  t ] [dx]   [ -u ]
!>     [ g^T  0    0  0 ] [dp] = [  0 ]
!>     [ t^T  0    0  0 ] [lV]   [  0 ]
!>     [ c_x  c_p  0  0 ] [lz]   [ -N ]
!> with c = (0, 1), N = 0 to land on a requested Ca_s (p fixed), or c = the unit tangent and
!> N = tangent . (y - y_predicted) for a pseudo-arclength step (Keller), which passes the fold
!> where the p-fixed system turns singular.
!>
!> Cost: the finite-difference Jacobian is ~2 n / 15 velocity evaluations (velocity_jacobian);
!> it is made once per branch point (where it also gives the linear stability, the tangent
!> and the corrector's LU) and the corrector reuses that LU (chord iterations), making a new
!> one only when the residual falls by less than chord_rate per iteration.
!>
!> Determinism (a killed branch resumes bit for bit, tube_branch): a step from a requested
!> Ca_s depends only on the shape and Ca_s there: its tangent uses the p row, not the
!> previous tangent.
module axisymmetric_continuation
   use capsim_kinds, only: dp
   use lapack_interfaces, only: dgetrf, dgetrs
   use run_options, only: run_options_t
   use tube_history, only: h_stretch
   use axisymmetric_operator, only: axisymmetric_operator_t, velocity_jacobian, largest_growth_rate, pack_dofs, &
                                    unpack_dofs, restore_volume_and_centre, jacobian_fd_step
   use axisymmetric_steady, only: newton_state_t, newton_tolerance, constraint_directions, projected_residual
   implicit none
   private
   public :: branch_point_t, fold_search_t, start_branch_point, continue_to_ca, search_fold
   public :: end_none, end_fold, end_mesh_limit, end_unstable, end_no_convergence

   !> How a fold search ends (search_fold): the branch passed the target Ca_s (end_none), turned
   !> back in Ca_s (a fold), reached the mesh's stretch limit, lost stability without a fold,
   !> or the corrector failed at the smallest arclength step.
   integer, parameter :: end_none = 0, end_fold = 1, end_mesh_limit = 2, end_unstable = 3, end_no_convergence = 4

   !> Corrector tolerance (largest node velocity, V), at least newton_tolerance: at 64 elements
   !> the corrector stalled near 1e-8 V (the velocity's noise, ~1e-9 / Ca_s) and then failed
   !> steps of 1 % in Ca_s at NH a/l 0.9, Ca_s 0.1; a residual of 1e-7 V moves L_z, L_p, v_c
   !> by less than 1e-6 relative there.
   real(dp), parameter :: corrector_tol = 1.0e-7_dp
   !> Corrector: most iterations, and the residual ratio below which the chord (old LU) goes on.
   !> A corrector that needs more than max_fresh_jacobians new Jacobians is given up: a case the
   !> branch cannot reach is time-stepped (tube_branch), which costs 2-5 CPU s at 64 elements
   !> (kernel 0.3.3), and near a fold the attempts with 4 cost more than that (NH a/l 0.8, from
   !> Ca_s 0.01: 430 velocities and 64 Jacobians, 7.7 CPU s, for a step the branch never made).
   integer, parameter :: max_corrector_iterations = 25, max_fresh_jacobians = 3
   real(dp), parameter :: chord_rate = 0.5_dp
   !> A predicted shape whose residual (largest node velocity, V) exceeds this is not corrected:
   !> the step is shortened at once. Measured along NH a/l 0.75 (Ca_s 0.02-0.18, 64 elements),
   !> the corrector converged from predictors up to 0.1-0.2 V and failed from nearly all above,
   !> each failure after its 4 fresh Jacobians (~90 velocity evaluations); the test costs one.
   real(dp), parameter :: max_predictor_residual = 0.15_dp
   !> Relative step in Ca_s of the difference u_p = du/dp (u is affine in 1/Ca_s: the step
   !> only sets the rounding, 1e-6 relative).
   real(dp), parameter :: p_step = 1.0e-6_dp
   !> Smallest p-fixed step (continue_to_ca) before the case is left to time stepping and,
   !> where that elongates, to the fold search (tube_branch). 5 % in Ca_s: the halvings below
   !> it cost more than the time-stepped case. NH branches of the paper grid (64 elements,
   !> kernel 0.3.3), a/l 0.7, 0.75, 0.8, 1: 32, 31, 26, 21 CPU s with 5 %, 38, 35, 25, 22 with
   !> 2 %; with 1 % and 4 fresh Jacobians (and dt 0.1) 0.75, 0.8, 1 took 41, 41, 40. The cases
   !> and folds are the same to 1e-4 relative.
   real(dp), parameter :: min_p_step = 0.05_dp
   !> Fold search: first, smallest and largest arclength step (in (x [l], ln Ca_s)), and how many.
   real(dp), parameter :: first_arclength_step = 0.02_dp, min_arclength_step = 1.0e-4_dp, max_arclength_step = 0.2_dp
   integer, parameter :: max_arclength_steps = 60

   !> A converged point of the branch: its shape, p = ln Ca_s, the Jacobian there, u_p, the
   !> unit tangent (dx, dp), the largest growth rate (V/l) and the largest element stretch,
   !> with the work of the bordered system and counts of what the corrector spent.
   type :: branch_point_t
      real(dp), allocatable :: rz(:, :), jacobian(:, :), border(:, :), velocity_p(:), tangent(:)
      !> The corrector's work: the bordered LU, its right-hand side, the shapes (packed) at the
      !> point, now and on trial, the velocity, and a Jacobian made on the way (the point's own
      !> Jacobian and border stay those of the point: a failed step starts again from them).
      real(dp), allocatable :: system(:, :), rhs(:), dofs0(:), x(:), x_trial(:), u_packed(:), work_jacobian(:, :)
      integer, allocatable :: pivot(:)
      real(dp) :: log_ca = 0, growth_rate = 0, stretch = 1
      integer :: n_velocities = 0, n_jacobians = 0
      type(newton_state_t) :: newton
   end type branch_point_t

   !> What search_fold found: how the search ended (end_*), the critical ln Ca_s (the fold,
   !> or where the limit was crossed), and the number of arclength points.
   type :: fold_search_t
      integer :: outcome = end_none
      real(dp) :: critical_log_ca = 0
      integer :: n_points = 0
   end type fold_search_t

contains

   !> The branch point at the model's shape and Ca_s, which must be a converged steady shape
   !> (a polished time-stepped one, or the corrector's): Jacobian, growth rate, stretch and the
   !> tangent along increasing Ca_s.
   subroutine start_branch_point(self, point)
      class(axisymmetric_operator_t), intent(inout) :: self
      type(branch_point_t), intent(inout) :: point
      integer :: m
      m = size(self%dofs)
      if (.not. allocated(point%rz)) then
         allocate (point%jacobian(m, m), point%work_jacobian(m, m), point%border(m, 2), point%velocity_p(m))
         allocate (point%tangent(m + 1), point%system(m + 3, m + 3))
         allocate (point%rhs(m + 3), point%dofs0(m), point%x(m), point%x_trial(m), point%u_packed(m), point%pivot(m + 3))
         allocate (point%rz, source=self%positions)
         point%tangent = 0
         call point%newton%init(size(self%positions, 2))
      end if
      call prepare_point(self, point, natural=.true.)
   end subroutine start_branch_point

   !> At the model's converged shape: stores it, makes the Jacobian (and from it the growth
   !> rate), u_p, the stretch, and the unit tangent: with the p row (natural) at requested
   !> Ca_s, with the previous tangent's row inside a fold search (it stays regular at the fold).
   subroutine prepare_point(self, point, natural)
      class(axisymmetric_operator_t), intent(inout) :: self
      type(branch_point_t), intent(inout) :: point
      logical, intent(in) :: natural
      real(dp) :: ca, previous(size(point%tangent))
      integer :: m
      m = size(self%dofs)
      point%rz = self%positions
      point%log_ca = log(self%ca)
      point%stretch = meridian_stretch(self)
      call velocity_jacobian(self, self%positions, jacobian_fd_step * self%a, point%jacobian)
      point%n_jacobians = point%n_jacobians + 1
      point%growth_rate = largest_growth_rate(self, point%jacobian)
      ca = self%ca
      call self%velocity(self%positions, self%u0)
      call pack_dofs(self%u0, point%u_packed)
      self%ca = ca * exp(p_step)
      call self%velocity(self%positions, self%u1)
      call pack_dofs(self%u1, point%velocity_p)
      point%velocity_p = (point%velocity_p - point%u_packed) / p_step
      self%ca = ca
      point%n_velocities = point%n_velocities + 2
      call constraint_directions(self, point%newton%border, self%positions)
      point%border = point%newton%border
      previous = point%tangent
      if (natural) then
         call factorise(point, m, point%jacobian, point%border, spread(0.0_dp, 1, m), 1.0_dp)
      else
         call factorise(point, m, point%jacobian, point%border, previous(1:m), previous(m + 1))
      end if
      point%rhs = 0
      point%rhs(m + 3) = 1
      call solve(point, m)
      point%tangent = point%rhs(1:m + 1) / norm2(point%rhs(1:m + 1))
      if (natural) then
         if (point%tangent(m + 1) < 0) point%tangent = -point%tangent
      else if (dot_product(point%tangent, previous) < 0) then
         point%tangent = -point%tangent
      end if
   end subroutine prepare_point

   !> From the branch point to Ca_s = ca_target by p-fixed steps: the whole way first, each
   !> failed step halved, each success followed by a step 1.5 times longer, down to min_p_step.
   !> The target lies above the point, or just below it where a fold search stepped past it.
   !> converged: the model and the point are at ca_target; otherwise at the last point
   !> reached, where search_fold can take over.
   subroutine continue_to_ca(self, point, opts, ca_target, converged)
      class(axisymmetric_operator_t), intent(inout) :: self
      type(branch_point_t), intent(inout) :: point
      type(run_options_t), intent(in) :: opts
      real(dp), intent(in) :: ca_target
      logical, intent(out) :: converged
      real(dp) :: p_target, p_step, p_next
      logical :: stepped
      p_target = log(ca_target)
      p_step = p_target - point%log_ca
      converged = .false.
      do
         if (abs(p_target - point%log_ca) <= abs(p_step)) then
            p_next = p_target
         else
            p_next = point%log_ca + p_step
         end if
         call step_to_ca(self, point, opts, exp(p_next), stepped)
         if (stepped) then
            if (p_next == p_target) exit
            p_step = 1.5_dp * p_step
         else
            p_step = 0.5_dp * p_step
            if (abs(p_step) < min_p_step) return
         end if
      end do
      converged = .true.
   end subroutine continue_to_ca

   !> One p-fixed step from the branch point to Ca_s = ca_to: x predicted along the tangent,
   !> then the corrector. stepped: the model holds the steady shape at ca_to and the point is
   !> prepared there; otherwise the model is back at the point's shape and Ca_s.
   subroutine step_to_ca(self, point, opts, ca_to, stepped)
      class(axisymmetric_operator_t), intent(inout) :: self
      type(branch_point_t), intent(inout) :: point
      type(run_options_t), intent(in) :: opts
      real(dp), intent(in) :: ca_to
      logical, intent(out) :: stepped
      integer :: m
      real(dp) :: dp_to
      m = size(self%dofs)
      dp_to = log(ca_to) - point%log_ca
      call pack_dofs(point%rz, point%dofs0)
      point%x = point%dofs0
      if (abs(point%tangent(m + 1)) > 1.0e-3_dp) &
         point%x = point%dofs0 + dp_to / point%tangent(m + 1) * point%tangent(1:m)
      call unpack_dofs(point%x, self%positions)
      call restore_volume_and_centre(self, self%positions)
      self%ca = ca_to
      call factorise(point, m, point%jacobian, point%border, spread(0.0_dp, 1, m), 1.0_dp)
      call correct(self, point, opts, arclength=.false., converged=stepped)
      if (stepped) then
         call prepare_point(self, point, natural=.true.)
      else
         self%positions = point%rz
         self%ca = exp(point%log_ca)
      end if
   end subroutine step_to_ca

   !> Pseudo-arclength steps from the branch point (where the p-fixed corrector could not reach
   !> ca_target) until the branch turns back in Ca_s (a fold: p has a maximum along it), leaves
   !> the mesh (element stretch above stretch_limit), loses stability, or passes ca_target (then
   !> outcome end_none and the model and point hold the last arclength point, below ca_target,
   !> from which continue_to_ca can go on). The fold's Ca_s is where dp/ds, linear between the
   !> two points that bracket it, vanishes: p_fold = p_0 + (dp/ds)_0 s*/2.
   subroutine search_fold(self, point, opts, ca_target, stretch_limit, stable_limit, found)
      class(axisymmetric_operator_t), intent(inout) :: self
      type(branch_point_t), intent(inout) :: point
      type(run_options_t), intent(in) :: opts
      real(dp), intent(in) :: ca_target, stretch_limit, stable_limit
      type(fold_search_t), intent(out) :: found
      real(dp) :: ds, slope0, slope1, log_ca0, stretch0, s_star
      integer :: m, step
      logical :: converged
      m = size(self%dofs)
      ds = first_arclength_step
      do step = 1, max_arclength_steps
         slope0 = point%tangent(m + 1)
         log_ca0 = point%log_ca
         stretch0 = point%stretch
         call pack_dofs(point%rz, point%dofs0)
         point%x = point%dofs0 + ds * point%tangent(1:m)
         call unpack_dofs(point%x, self%positions)
         call restore_volume_and_centre(self, self%positions)
         self%ca = exp(point%log_ca + ds * slope0)
         call factorise(point, m, point%jacobian, point%border, point%tangent(1:m), slope0)
         call correct(self, point, opts, arclength=.true., converged=converged, step_length=ds)
         if (.not. converged) then
            self%positions = point%rz
            self%ca = exp(point%log_ca)
            ds = 0.5_dp * ds
            if (ds < min_arclength_step) then
               found%outcome = end_no_convergence
               found%critical_log_ca = point%log_ca
               return
            end if
            cycle
         end if
         call prepare_point(self, point, natural=.false.)
         found%n_points = found%n_points + 1
         slope1 = point%tangent(m + 1)
         if (slope1 <= 0) then
            s_star = ds * slope0 / (slope0 - slope1)
            found%outcome = end_fold
            found%critical_log_ca = log_ca0 + 0.5_dp * slope0 * s_star
            return
         else if (point%stretch > stretch_limit) then
            found%outcome = end_mesh_limit
            found%critical_log_ca = log_ca0 + (point%log_ca - log_ca0) * (stretch_limit - stretch0) / &
                                    (point%stretch - stretch0)
            return
         else if (point%growth_rate > stable_limit) then
            found%outcome = end_unstable
            found%critical_log_ca = log_ca0
            return
         else if (point%log_ca >= log(ca_target)) then
            ! Passed the target without a fold: go back below it (the caller lands on it).
            found%outcome = end_none
            return
         end if
         ds = min(1.5_dp * ds, max_arclength_step)
      end do
      found%outcome = end_no_convergence
      found%critical_log_ca = point%log_ca
   end subroutine search_fold

   !> The bordered matrix of `jacobian`, the point's u_p and `border`, with constraint row
   !> (row_x, row_p), LU-factorised in point%system.
   subroutine factorise(point, m, jacobian, border, row_x, row_p)
      type(branch_point_t), intent(inout) :: point
      integer, intent(in) :: m
      real(dp), intent(in) :: jacobian(:, :), border(:, :), row_x(:), row_p
      integer :: info
      point%system = 0
      point%system(1:m, 1:m) = jacobian
      point%system(1:m, m + 1) = point%velocity_p
      point%system(1:m, m + 2:m + 3) = border
      point%system(m + 1:m + 2, 1:m) = transpose(border)
      point%system(m + 3, 1:m) = row_x
      point%system(m + 3, m + 1) = row_p
      call dgetrf(m + 3, m + 3, point%system, m + 3, point%pivot, info)
   end subroutine factorise

   subroutine solve(point, m)
      type(branch_point_t), intent(inout) :: point
      integer, intent(in) :: m
      integer :: info
      call dgetrs('N', m + 3, 1, point%system, m + 3, point%pivot, point%rhs, m + 3, info)
   end subroutine solve

   !> Chord-Newton iterations on the bordered system last factorised, from the model's shape
   !> and Ca_s (p fixed, or p free on the arclength hyperplane through the point's tangent at
   !> step_length), each step damped by backtracking until the residual falls (as in
   !> axisymmetric_steady's newton_solve: full steps from a predictor 5 % away in Ca_s grew the
   !> residual from 0.05 to 0.2 V, the stiff membrane modes overshooting). A new Jacobian (at the
   !> current shape and Ca_s) replaces the old LU when the residual falls by less than
   !> chord_rate in a step, or when backtracking finds no descent with the old one; the
   !> corrector fails when a new Jacobian's step finds none either, or the iterations run out.
   subroutine correct(self, point, opts, arclength, converged, step_length)
      class(axisymmetric_operator_t), intent(inout) :: self
      type(branch_point_t), intent(inout) :: point
      type(run_options_t), intent(in) :: opts
      logical, intent(in) :: arclength
      logical, intent(out) :: converged
      real(dp), intent(in), optional :: step_length
      real(dp), parameter :: min_damping = 1.0_dp / 16
      real(dp) :: residual, trial, alpha, log_ca
      integer :: m, it, fresh
      logical :: lu_is_fresh, descended
      m = size(self%dofs)
      converged = .false.
      fresh = 0
      lu_is_fresh = .false.
      call evaluate(self%positions, self%ca, residual)
      if (residual > max_predictor_residual) return
      do it = 1, max_corrector_iterations
         if (residual < max(newton_tolerance(self, opts), corrector_tol) .and. abs(hyperplane(self%ca)) < 1.0e-8_dp) then
            converged = .true.
            self%residual = residual
            return
         end if
         call pack_dofs(self%positions, point%x)
         log_ca = log(self%ca)
         do
            ! The step from here with the LU in hand, damped until the residual falls.
            point%rhs(1:m) = -point%u_packed
            point%rhs(m + 1:m + 2) = 0
            point%rhs(m + 3) = -hyperplane(self%ca)
            call solve(point, m)
            alpha = 1
            descended = .false.
            do while (alpha >= min_damping)
               call unpack_dofs(point%x + alpha * point%rhs(1:m), self%rz_pred)
               call restore_volume_and_centre(self, self%rz_pred)
               call evaluate(self%rz_pred, exp(log_ca + alpha * point%rhs(m + 1)), trial)
               if (trial < (1.0_dp - 0.1_dp * alpha) * residual) then
                  descended = .true.
                  exit
               end if
               alpha = 0.5_dp * alpha
            end do
            if (descended) exit
            if (lu_is_fresh .or. fresh >= max_fresh_jacobians) return
            call refresh_jacobian()
         end do
         self%positions = self%rz_pred
         self%ca = exp(log_ca + alpha * point%rhs(m + 1))
         lu_is_fresh = .false.
         if (.not. (trial < chord_rate * residual) .and. fresh < max_fresh_jacobians) call refresh_jacobian()
         residual = trial
         ! evaluate left u_packed and the border at the accepted trial.
      end do

   contains

      !> The packed velocity at (rz, ca) into point%u_packed, the border there, and its
      !> projected residual.
      subroutine evaluate(rz, ca, r)
         real(dp), intent(in) :: rz(:, :), ca
         real(dp), intent(out) :: r
         real(dp) :: ca_saved
         ca_saved = self%ca
         self%ca = ca
         call self%velocity(rz, self%u0)
         self%ca = ca_saved
         point%n_velocities = point%n_velocities + 1
         call pack_dofs(self%u0, point%u_packed)
         call constraint_directions(self, point%newton%border, rz)
         r = projected_residual(point%newton%border, point%u_packed)
         call pack_dofs(rz, point%x_trial)
      end subroutine evaluate

      !> Keller's arclength condition at the last evaluated shape (0 for p-fixed steps).
      real(dp) function hyperplane(ca)
         real(dp), intent(in) :: ca
         hyperplane = 0
         if (arclength) hyperplane = dot_product(point%tangent(1:m), point%x_trial - point%dofs0) + &
                                     point%tangent(m + 1) * (log(ca) - point%log_ca) - step_length
      end function hyperplane

      !> A Jacobian at the model's shape and Ca_s, factorised with the same constraint row.
      subroutine refresh_jacobian()
         call velocity_jacobian(self, self%positions, jacobian_fd_step * self%a, point%work_jacobian)
         point%n_jacobians = point%n_jacobians + 1
         fresh = fresh + 1
         lu_is_fresh = .true.
         call constraint_directions(self, point%newton%border, self%positions)
         if (arclength) then
            call factorise(point, m, point%work_jacobian, point%newton%border, point%tangent(1:m), point%tangent(m + 1))
         else
            call factorise(point, m, point%work_jacobian, point%newton%border, spread(0.0_dp, 1, m), 1.0_dp)
         end if
         ! The step is taken from the shape the Jacobian was made at: its velocity again.
         call evaluate(self%positions, self%ca, residual)
      end subroutine refresh_jacobian

   end subroutine correct


   !> Largest principal stretch (or its inverse) of the meridian's elements, as recorded in the
   !> history (axisymmetric_tube's record): taken from a record that is then dropped.
   real(dp) function meridian_stretch(self) result(stretch)
      class(axisymmetric_operator_t), intent(inout) :: self
      call self%record()
      stretch = self%history(h_stretch, self%n_rec)
      self%n_rec = self%n_rec - 1
   end function meridian_stretch

end module axisymmetric_continuation
