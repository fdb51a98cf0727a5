!> double_layer_probe: measures the double layer (stokes_double_layer) and the viscosity-ratio
!> interface equation (interface_equation) on icosphere meshes, one property per call, as
!> "key value" lines; tests/kernel/test_viscosity_ratio.py asserts them.
!>
!>   double_layer_probe identity LEVEL        raw quadrature of 1/(8 pi) PV int T . n dS against -I/2
!>   double_layer_probe identity-off LEVEL   the same off the surface: -I at 0 and 0.5 e_z, 0 at 1.5 e_z
!>   double_layer_probe normal LEVEL          D[n] against +n/2 on the unit sphere (subtracted form)
!>   double_layer_probe rigid LEVEL           D[U + Omega x y] against -(U + Omega x x)/2, sphere and ellipsoid
!>   double_layer_probe translate LEVEL LAMBDA [DEFLATE]  uniform load on a sphere: U = 2/3 whatever
!>                                               lambda (DEFLATE 0 switches the deflation off)
!>   double_layer_probe lambda-one LEVEL DLAMBDA  capsule velocity at lambda = 1 + DLAMBDA (GMRES path)
!>                                               against lambda = 1 (explicit path)
!>   double_layer_probe capsule LEVEL LAMBDA DEFLATE  one capsule velocity (NH, Ca 0.2, ellipsoid, no
!>                                               volume correction) from the right-hand side: GMRES
!>                                               applications and the net flux, with or without deflation
!>   double_layer_probe bench LEVEL REPEATS  seconds per single-layer velocity and per double-layer application
program double_layer_probe
   use capsim_kinds, only: dp
   use command_args, only: int_arg, real_arg, string_arg
   use sphere_mesh, only: surface_mesh_t, icosphere
   use stokes_single_layer, only: single_layer_t
   use stokes_double_layer, only: double_layer_t
   use interface_equation, only: interface_equation_t
   use run_options, only: run_options_t
   use capsule_dynamics, only: capsule_t
   implicit none

   character(len=:), allocatable :: command
   command = string_arg(1)
   select case (command)
   case ('identity')
      call probe_identity(int_arg(2))
   case ('identity-off')
      call probe_identity_off(int_arg(2))
   case ('normal')
      call probe_normal(int_arg(2))
   case ('rigid')
      call probe_rigid(int_arg(2))
   case ('translate')
      if (command_argument_count() >= 4) then
         call probe_translate(int_arg(2), real_arg(3), int_arg(4) /= 0)
      else
         call probe_translate(int_arg(2), real_arg(3), .true.)
      end if
   case ('lambda-one')
      call probe_lambda_one(int_arg(2), real_arg(3))
   case ('capsule')
      call probe_capsule(int_arg(2), real_arg(3), int_arg(4) /= 0)
   case ('bench')
      call probe_bench(int_arg(2), int_arg(3))
   case default
      write (*, '(a)') 'usage: double_layer_probe identity|normal|rigid|translate|lambda-one|bench ...'
      error stop 2
   end select

contains

   subroutine sphere(level, mesh, x, sl, dl)
      integer, intent(in) :: level
      type(surface_mesh_t), intent(out) :: mesh
      real(dp), allocatable, intent(out) :: x(:, :)
      type(single_layer_t), intent(out) :: sl
      type(double_layer_t), intent(out) :: dl
      integer :: stat, t, k
      character(len=:), allocatable :: errmsg
      real(dp) :: h
      call icosphere(level, mesh, x, stat, errmsg)
      if (stat /= 0) error stop errmsg
      call sl%init(mesh, 4, 0)
      call dl%init(mesh, sl)
      call dl%set_geometry(mesh, x)
      h = 0
      do t = 1, mesh%n_tri
         do k = 1, 3
            h = max(h, norm2(x(:, mesh%tri(k, t)) - x(:, mesh%tri(mod(k, 3) + 1, t))))
         end do
      end do
      call put('n_nodes', real(mesh%n_nodes, dp))
      call put('h_max', h)
   end subroutine sphere

   subroutine put(key, value)
      character(len=*), intent(in) :: key
      real(dp), intent(in) :: value
      write (*, '(a,1x,es24.16)') key, value
   end subroutine put

   !> max_i max_kl |M_i,kl + delta_kl / 2| and its rms over the nodes.
   subroutine probe_identity(level)
      integer, intent(in) :: level
      type(surface_mesh_t) :: mesh
      real(dp), allocatable :: x(:, :), m(:, :, :)
      type(single_layer_t) :: sl
      type(double_layer_t) :: dl
      real(dp) :: e, emax, esum
      integer :: i, k
      call sphere(level, mesh, x, sl, dl)
      allocate (m(3, 3, mesh%n_nodes))
      call dl%principal_value_tensor(mesh, m)
      emax = 0
      esum = 0
      do i = 1, mesh%n_nodes
         do k = 1, 3
            m(k, k, i) = m(k, k, i) + 0.5_dp
         end do
         e = maxval(abs(m(:, :, i)))
         emax = max(emax, e)
         esum = esum + e**2
      end do
      call put('identity_max_error', emax)
      call put('identity_rms_error', sqrt(esum / mesh%n_nodes))
      ! Mean over the nodes of trace(M_i) + 3/2 (m now holds M + I/2): the scalar part of the error.
      call put('trace_mean_error', sum([(m(1, 1, i) + m(2, 2, i) + m(3, 3, i), i=1, mesh%n_nodes)]) / mesh%n_nodes)
   end subroutine probe_identity

   subroutine probe_identity_off(level)
      integer, intent(in) :: level
      type(surface_mesh_t) :: mesh
      real(dp), allocatable :: x(:, :)
      type(single_layer_t) :: sl
      type(double_layer_t) :: dl
      real(dp) :: m(3, 3), eye(3, 3)
      integer :: k
      call sphere(level, mesh, x, sl, dl)
      eye = 0
      do k = 1, 3
         eye(k, k) = 1
      end do
      m = dl%tensor_off_surface([0.0_dp, 0.0_dp, 0.0_dp])
      call put('centre_max_error', maxval(abs(m + eye)))
      m = dl%tensor_off_surface([0.1_dp, 0.2_dp, 0.5_dp])
      call put('inside_max_error', maxval(abs(m + eye)))
      m = dl%tensor_off_surface([0.2_dp, 0.1_dp, 1.5_dp])
      call put('outside_max_error', maxval(abs(m)))
   end subroutine probe_identity_off

   !> On the unit sphere n(y) = y and D[n] = n/2 exactly (the eigenvalue +1 of 2D).
   subroutine probe_normal(level)
      integer, intent(in) :: level
      type(surface_mesh_t) :: mesh
      real(dp), allocatable :: x(:, :), w(:, :)
      type(single_layer_t) :: sl
      type(double_layer_t) :: dl
      call sphere(level, mesh, x, sl, dl)
      allocate (w(3, mesh%n_nodes))
      call dl%apply(mesh, x, w)
      call put('normal_max_error', maxval(norm2(w - 0.5_dp * x, dim=1)))
      call put('normal_rms_error', sqrt(sum((w - 0.5_dp * x)**2) / mesh%n_nodes))
   end subroutine probe_normal

   !> Rigid-body motions are eigenfunctions with eigenvalue -1/2, on the sphere and on an ellipsoid.
   subroutine probe_rigid(level)
      integer, intent(in) :: level
      type(surface_mesh_t) :: mesh
      real(dp), allocatable :: x(:, :), u(:, :), w(:, :)
      type(single_layer_t) :: sl
      type(double_layer_t) :: dl
      real(dp), parameter :: big_u(3) = [0.3_dp, -1.0_dp, 0.7_dp], omega(3) = [0.5_dp, 0.2_dp, -0.9_dp]
      integer :: i, shape
      call sphere(level, mesh, x, sl, dl)
      allocate (u(3, mesh%n_nodes), w(3, mesh%n_nodes))
      do shape = 1, 2
         if (shape == 2) then
            x(1, :) = 1.3_dp * x(1, :)
            x(2, :) = 0.8_dp * x(2, :)
            call dl%set_geometry(mesh, x)
         end if
         do i = 1, mesh%n_nodes
            u(:, i) = big_u + [omega(2) * x(3, i) - omega(3) * x(2, i), omega(3) * x(1, i) - omega(1) * x(3, i), &
                               omega(1) * x(2, i) - omega(2) * x(1, i)]
         end do
         call dl%apply(mesh, u, w)
         if (shape == 1) then
            call put('rigid_sphere_max_error', maxval(norm2(w + 0.5_dp * u, dim=1)) / maxval(norm2(u, dim=1)))
         else
            call put('rigid_ellipsoid_max_error', maxval(norm2(w + 0.5_dp * u, dim=1)) / maxval(norm2(u, dim=1)))
         end if
      end do
   end subroutine probe_rigid

   !> A uniform load f = e_z on a sphere: the rigid sphere's Stokes traction, so the interface
   !> translates at U = 2/3 (2 a f / (3 mu)) whatever lambda (the interior moves rigidly).
   subroutine probe_translate(level, lambda, deflate)
      integer, intent(in) :: level
      real(dp), intent(in) :: lambda
      logical, intent(in) :: deflate
      type(surface_mesh_t) :: mesh
      real(dp), allocatable :: x(:, :), f(:, :), s(:, :), b(:, :), u(:, :)
      type(single_layer_t) :: sl
      type(double_layer_t) :: dl
      type(interface_equation_t) :: eq
      integer :: stat
      character(len=:), allocatable :: errmsg
      call sphere(level, mesh, x, sl, dl)
      allocate (f(3, mesh%n_nodes), s(3, mesh%n_nodes), b(3, mesh%n_nodes), u(3, mesh%n_nodes))
      f = 0
      f(3, :) = 1
      call sl%velocity(mesh, x, f, s)
      call eq%init(mesh%n_nodes, lambda)
      eq%deflate = deflate
      b = (2.0_dp / (1.0_dp + lambda)) * s
      u = b
      call eq%solve(dl, mesh, b, u, stat, errmsg)
      if (stat /= 0) error stop errmsg
      ! Net flux through the surface over (area x U): zero for the exact solution.
      call put('relative_flux', dl%normal_flux(u) / (dl%area_sum * 2.0_dp / 3.0_dp))
      call put('rhs_relative_flux', dl%normal_flux(b) / (dl%area_sum * 2.0_dp / 3.0_dp))
      u(3, :) = u(3, :) - 2.0_dp / 3.0_dp
      call put('translate_max_rel_error', maxval(norm2(u, dim=1)) / (2.0_dp / 3.0_dp))
      s(3, :) = s(3, :) - 2.0_dp / 3.0_dp
      call put('single_layer_max_rel_error', maxval(norm2(s, dim=1)) / (2.0_dp / 3.0_dp))
      call put('applications', real(eq%last_applications, dp))
      call put('residual', eq%last_residual)
   end subroutine probe_translate

   !> Capsule velocity (NH, Ca = 0.2) at an ellipsoidal shape: lambda = 1 + dlambda through the
   !> interface equation against lambda = 1 through the explicit formula.
   subroutine probe_lambda_one(level, dlambda)
      integer, intent(in) :: level
      real(dp), intent(in) :: dlambda
      type(run_options_t) :: opts
      type(capsule_t) :: base, ratio
      real(dp), allocatable :: x(:, :), u_base(:, :), u_ratio(:, :)
      integer :: stat
      character(len=:), allocatable :: errmsg
      opts%flow = 'shear'
      opts%law = 'NH'
      opts%ca = 0.2_dp
      opts%level = level
      call base%init(opts, stat, errmsg)
      if (stat /= 0) error stop errmsg
      opts%lambda = 1.0_dp + dlambda
      call ratio%init(opts, stat, errmsg)
      if (stat /= 0) error stop errmsg
      x = base%x_ref
      x(3, :) = 1.2_dp * x(3, :) + 0.1_dp * x(2, :)
      x(2, :) = x(2, :) / 1.1_dp
      allocate (u_base(3, size(x, 2)), u_ratio(3, size(x, 2)))
      call base%velocity(x, u_base)
      call ratio%velocity(x, u_ratio)
      call put('lambda_minus_one', ratio%lambda - 1.0_dp)
      call put('max_rel_difference', maxval(abs(u_ratio - u_base)) / maxval(abs(u_base)))
      call put('applications', real(ratio%interface%last_applications, dp))
   end subroutine probe_lambda_one

   subroutine probe_capsule(level, lambda, deflate)
      integer, intent(in) :: level
      real(dp), intent(in) :: lambda
      logical, intent(in) :: deflate
      type(run_options_t) :: opts
      type(capsule_t) :: capsule
      real(dp), allocatable :: x(:, :), u(:, :)
      integer :: stat
      character(len=:), allocatable :: errmsg
      opts%flow = 'shear'
      opts%law = 'NH'
      opts%ca = 0.2_dp
      opts%level = level
      opts%lambda = lambda
      opts%volume_correction = .false.
      call capsule%init(opts, stat, errmsg)
      if (stat /= 0) error stop errmsg
      capsule%interface%deflate = deflate
      x = capsule%x_ref
      x(3, :) = 1.2_dp * x(3, :) + 0.1_dp * x(2, :)
      x(2, :) = x(2, :) / 1.1_dp
      allocate (u(3, size(x, 2)))
      call capsule%velocity(x, u)
      if (allocated(capsule%fault)) error stop capsule%fault
      call put('applications', real(capsule%interface%last_applications, dp))
      call put('relative_flux', capsule%double_layer%normal_flux(u) / (capsule%double_layer%area_sum * maxval(norm2(u, dim=1))))
      call put('rhs_relative_flux', capsule%double_layer%normal_flux(capsule%rhs) / &
               (capsule%double_layer%area_sum * maxval(norm2(capsule%rhs, dim=1))))
   end subroutine probe_capsule

   subroutine probe_bench(level, repeats)
      integer, intent(in) :: level, repeats
      type(surface_mesh_t) :: mesh
      real(dp), allocatable :: x(:, :), f(:, :), w(:, :)
      type(single_layer_t) :: sl
      type(double_layer_t) :: dl
      integer :: k
      integer(8) :: c0, c1, rate
      call sphere(level, mesh, x, sl, dl)
      allocate (f(3, mesh%n_nodes), w(3, mesh%n_nodes))
      f = x
      call system_clock(c0, rate)
      do k = 1, repeats
         call sl%velocity(mesh, x, f, w)
         f(1, 1) = f(1, 1) + 1.0e-3_dp * w(1, 1)
      end do
      call system_clock(c1)
      call put('single_layer_s', real(c1 - c0, dp) / rate / repeats)
      call system_clock(c0, rate)
      do k = 1, repeats
         call dl%apply(mesh, f, w)
         f(1, 1) = f(1, 1) + 1.0e-3_dp * w(1, 1)
      end do
      call system_clock(c1)
      call put('double_layer_s', real(c1 - c0, dp) / rate / repeats)
   end subroutine probe_bench

end program double_layer_probe
