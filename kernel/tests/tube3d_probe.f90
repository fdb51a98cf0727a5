!> tube3d_probe: measures the 3D tube model (tube_capsule) and prints "key value" lines;
!> tests/kernel/test_tube_3d.py and bench/bench_tube_3d.py run it, so tolerances live there.
!>
!>   tube3d_probe timing LEVEL A_OVER_L CA TUBE_LENGTH H_FAR H_CENTRE CACHE_DIR STEPS
!>     wall setup (assembly + LU, or the cache load), then STEPS RK2 steps from the start shape
!>     and one velocity evaluation after them, each part timed.
program tube3d_probe
   use omp_lib, only: omp_get_wtime, omp_get_max_threads
   use capsim_kinds, only: dp
   use command_args, only: int_arg, real_arg, string_arg, put, put_int
   use run_options, only: run_options_t
   use tube_capsule, only: tube_capsule_t
   implicit none

   character(len=64) :: command
   call get_command_argument(1, command)
   select case (command)
   case ('timing')
      call probe_timing()
   case default
      write (*, '(a)') 'usage: tube3d_probe timing LEVEL A_OVER_L CA TUBE_LENGTH H_FAR H_CENTRE CACHE_DIR STEPS'
      error stop 2
   end select

contains

   subroutine probe_timing()
      type(run_options_t) :: opts
      type(tube_capsule_t) :: model
      integer :: stat, steps, k
      character(len=:), allocatable :: errmsg
      real(dp) :: t0, t_step, t_velocity

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
      steps = int_arg(9)
      call model%init(opts, stat, errmsg)
      if (stat /= 0) error stop errmsg
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
      t0 = omp_get_wtime()
      call model%velocity(model%positions, model%u0)
      t_velocity = omp_get_wtime() - t0
      call put('dt', model%dt)
      call put('rk2_step_s', t_step)
      call put('velocity_s', t_velocity)
      call put('capsule_at_wall_s', model%seconds_capsule_at_wall)
      call put('wall_solve_s', model%seconds_wall_solve)
      call put('wall_at_capsule_s', model%seconds_wall_at_capsule)
      call put('v_c', model%v_c)
      call put('max_speed', maxval(norm2(model%u0, dim=1)))
   end subroutine probe_timing


end program tube3d_probe
