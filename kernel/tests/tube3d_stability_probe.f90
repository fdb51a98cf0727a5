!> tube3d_stability_probe: checks the 3D steady solver's growth-rate estimate against time
!> stepping, and prints "key value" lines; tests/kernel/test_tube_3d_stability.py runs it, so
!> tolerances live there.
!>
!>   tube3d_stability_probe LEVEL A_OVER_L CA TUBE_LENGTH H_FAR H_CENTRE CACHE_DIR AMPLITUDE T_END
!>     the NH tube case solved by Newton-Krylov (tube_steady_capsule_t%run, as capsim
!>     --integrator newton), its growth-rate estimate (growth_rate, growth_frequency,
!>     growth_residual, growth_evaluations, stable) and solver figures; then the model's own
!>     RK2 steps for T_END l/V from the steady shape and from the steady shape plus AMPLITUDE
!>     (l, the largest node displacement) times the estimate's eigenvector. The difference of
!>     the two runs is the perturbation (the steady shape's own drift, at the Newton tolerance,
!>     cancels); its norm is sampled every twentieth of T_END, and measured_rate is the
!>     least-squares slope of its logarithm over the samples after the first fifth of T_END
!>     (the stiff remainder of the eigenvector's residual has decayed by then), with
!>     norm_ratio = |perturbation(T_END)| / |perturbation(0)|.
program tube3d_stability_probe
   use capsim_kinds, only: dp
   use command_args, only: int_arg, real_arg, string_arg, put, put_int
   use run_options, only: run_options_t
   use case_output, only: case_summary_t
   use tube_history, only: h_lz, h_lp, h_vc
   use tube_steady_3d, only: tube_steady_capsule_t, stability
   implicit none

   integer, parameter :: n_samples = 20
   type(run_options_t) :: opts
   type(tube_steady_capsule_t) :: model
   type(case_summary_t) :: summary
   character(len=:), allocatable :: errmsg, cache
   real(dp), allocatable :: steady(:, :), base(:, :, :)
   real(dp) :: amplitude, t_end, norms(0:n_samples), times(0:n_samples), t_skip
   integer :: stat, steady_index, steps_per_sample, k, s

   opts%flow = 'tube'
   opts%model = '3d'
   opts%integrator = 'newton'
   opts%law = 'NH'
   opts%level = int_arg(1)
   opts%a_over_l = real_arg(2)
   opts%ca = real_arg(3)
   opts%tube_length = real_arg(4)
   opts%wall_h_far = real_arg(5)
   opts%wall_h_centre = real_arg(6)
   cache = string_arg(7)
   opts%wall_cache = cache
   amplitude = real_arg(8)
   t_end = real_arg(9)
   opts%quiet = .true.

   call model%init(opts, stat, errmsg)
   if (stat /= 0) error stop errmsg
   call model%run(opts, cache//'/stability_probe.ckpt', summary, steady_index)
   call put_int('steady', merge(1, 0, steady_index > 0))
   if (steady_index == 0) stop
   call put_int('stable', stability(model))
   call put('growth_rate', model%growth_rate)
   call put('growth_frequency', model%growth_frequency)
   call put('growth_residual', model%growth_residual)
   call put_int('growth_evaluations', model%growth_evaluations)
   call put_int('velocity_evaluations', model%velocity_evaluations)
   call put_int('newton_iterations', model%newton_iterations)
   call put('newton_residual', model%residual)
   call put('L_z', model%history(h_lz, 1))
   call put('L_p', model%history(h_lp, 1))
   call put('v_c', model%history(h_vc, 1))
   if (.not. allocated(model%growth_mode)) stop

   steady = model%positions
   steps_per_sample = max(1, nint(t_end / (n_samples * model%dt)))
   call put('dt', model%dt)
   allocate (base(3, size(steady, 2), 0:n_samples))
   ! The steady shape's own trajectory, then the perturbed one against it.
   model%positions = steady
   base(:, :, 0) = steady
   do s = 1, n_samples
      do k = 1, steps_per_sample
         call model%advance()
      end do
      base(:, :, s) = model%positions
   end do
   model%positions = steady + (amplitude / maxval(abs(model%growth_mode))) * model%growth_mode
   norms(0) = norm2(model%positions - base(:, :, 0))
   times(0) = 0
   do s = 1, n_samples
      do k = 1, steps_per_sample
         call model%advance()
      end do
      norms(s) = norm2(model%positions - base(:, :, s))
      times(s) = s * steps_per_sample * model%dt
   end do
   t_skip = 0.2_dp * times(n_samples)
   call put('t_end', times(n_samples))
   call put('measured_rate', log_slope(pack(times, times >= t_skip), pack(log(norms), times >= t_skip)))
   call put('norm_ratio', norms(n_samples) / norms(0))

contains

   !> Least-squares slope of y against t.
   pure real(dp) function log_slope(t, y)
      real(dp), intent(in) :: t(:), y(:)
      real(dp) :: t_mean
      t_mean = sum(t) / size(t)
      log_slope = sum((t - t_mean) * (y - sum(y) / size(y))) / sum((t - t_mean)**2)
   end function log_slope

end program tube3d_stability_probe
