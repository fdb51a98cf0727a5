!> A centred capsule in Poiseuille flow in a circular tube, axisymmetric (the fast path for
!> tube databases): ring Stokeslets on the capsule meridian and on the tube boundary.
!>
!> Non-dimensional: lengths in l (tube radius), velocities in V (mean velocity), time in
!> l/V, forces in G_s; Ca_s = mu V / G_s. The undisturbed flow is v_inf = 2 (1 - r**2) e_z.
!> The disturbance is represented by single layers on the membrane (known force density f,
!> P1 on the meridian) and on the tube boundary B (unknown disturbance traction g, constant
!> per wall element, collocated at element mid-points): the disturbance velocity vanishes on
!> B (no-slip on the wall, undisturbed Poiseuille on the end sections), so
!>     W g = -(membrane single layer at the wall collocation points),
!> with W factorised once (LAPACK), and the membrane moves with
!>     v = v_inf + 1/(8 pi Ca) [ membrane single layer + wall single layer ].
!> The capsule's centroid is kept at z = 0 in the middle of the tube (frame moving with it);
!> its velocity v_c is recorded.
module axisymmetric_tube
   use capsim_kinds, only: dp, pi
   use hdf5_writer, only: h5_file_t
   use membrane_law, only: make_membrane_law
   use axisymmetric_membrane, only: meridian_reference_t, meridian_forces, meridian_node_areas, &
                                    meridian_area_volume, meridian_volume_gradient
   use ring_stokeslet, only: segment_integral
   use run_options, only: run_options_t
   use capsule_model, only: capsule_model_t
   implicit none
   private
   public :: axisymmetric_tube_t, tube_wall_elements

   integer, parameter :: h_t = 1, h_area = 2, h_volume = 3, h_lz = 4, h_lp = 5, h_vc = 6, h_rmax = 7, &
                         h_energy = 8, h_stretch = 9
   character(len=*), parameter :: tube_history_names(9) = [character(len=16) :: &
                                  't', 'area', 'volume', 'L_z', 'L_p', 'v_c', 'r_max', 'energy', 'max_stretch']
   character(len=*), parameter :: tube_history_units(9) = [character(len=16) :: &
                                  'l/V', 'l^2', 'l^3', 'l', 'l', 'V', 'l', 'G_s l^2', '1']

   !> Tube length [l] and wall element sizes: fine over |z| < fine_half_length, growing
   !> geometrically (ratio wall_growth) to coarse_size towards the end sections.
   real(dp), parameter :: tube_half_length = 5.0_dp
   real(dp), parameter :: fine_size = 0.04_dp, coarse_size = 0.3_dp, wall_growth = 1.2_dp
   integer, parameter :: disk_elements = 10
   !> Capsules this large start as a spheroid of this equatorial radius (they do not fit as
   !> spheres); their stresses are still measured from the spherical reference.
   real(dp), parameter :: predeform_from = 0.9_dp, predeform_radius = 0.8_dp

   interface
      subroutine dgetrf(m, n, a, lda, ipiv, info)
         import :: dp
         integer, intent(in) :: m, n, lda
         real(dp), intent(inout) :: a(lda, *)
         integer, intent(out) :: ipiv(*), info
      end subroutine dgetrf
      subroutine dgesv(n, nrhs, a, lda, ipiv, b, ldb, info)
         import :: dp
         integer, intent(in) :: n, nrhs, lda, ldb
         real(dp), intent(inout) :: a(lda, *), b(ldb, *)
         integer, intent(out) :: ipiv(*), info
      end subroutine dgesv
      subroutine dgetrs(trans, n, nrhs, a, lda, ipiv, b, ldb, info)
         import :: dp
         character, intent(in) :: trans
         integer, intent(in) :: n, nrhs, lda, ldb, ipiv(*)
         real(dp), intent(in) :: a(lda, *)
         real(dp), intent(inout) :: b(ldb, *)
         integer, intent(out) :: info
      end subroutine dgetrs
   end interface

   type, extends(capsule_model_t) :: axisymmetric_tube_t
      type(meridian_reference_t) :: ref
      real(dp) :: ca = 0, a = 0, h_min = 0, energy = 0, v_c = 0, volume0 = 0
      logical :: volume_correction = .true.
      !> Linearly implicit Euler with a finite-difference Jacobian (pseudo-time: reaches the
      !> same steady states as RK2 in far fewer steps) or Heun's RK2 (time-accurate).
      logical :: implicit = .true.
      real(dp) :: dt_max = 1.0e4_dp
      integer :: steps_since_jacobian = huge(1)
      real(dp) :: last_residual = huge(1.0_dp)
      real(dp), allocatable :: jacobian(:, :), system(:, :), dofs(:), dofs_trial(:), res(:), res_trial(:)
      integer, allocatable :: pivot(:)
      !> Reference (sphere of radius a/l) and initial (sphere or spheroid) meridians, current one.
      real(dp), allocatable :: rz_ref(:, :), rz_start(:, :), rz(:, :)
      !> Wall elements: end points and mid-points (r, z); factorised wall matrix.
      integer :: n_wall = 0
      real(dp), allocatable :: wall_a(:, :), wall_b(:, :), wall_mid(:, :)
      real(dp), allocatable :: wall_lu(:, :), wall_traction(:)
      integer, allocatable :: wall_pivot(:)
      ! Work arrays (allocated once).
      real(dp), allocatable :: rz_pred(:, :), u0(:, :), u1(:, :), force(:, :), density(:, :), node_area(:), grad(:, :)
   contains
      procedure :: init
      procedure :: velocity
      procedure :: rk2_step
      procedure :: record
      procedure :: reset
      procedure :: state_size
      procedure :: get_state
      procedure :: set_state
      procedure :: progress_text
      procedure :: write_geometry
   end type axisymmetric_tube_t

contains

   subroutine init(self, opts, stat, errmsg)
      class(axisymmetric_tube_t), intent(inout) :: self
      type(run_options_t), intent(in) :: opts
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: n, k, m
      real(dp) :: theta, c_axis

      call make_membrane_law(trim(opts%law), opts%nu_s, opts%c, self%law, stat, errmsg)
      if (stat /= 0) return
      self%a = opts%a_over_l
      self%ca = opts%ca
      self%volume_correction = opts%volume_correction
      n = opts%n_meridian + 1
      allocate (self%rz_ref(2, n), self%rz_start(2, n))
      c_axis = self%a
      if (self%a >= predeform_from) c_axis = self%a**3 / predeform_radius**2
      do k = 1, n
         theta = pi * (k - 1) / (n - 1)
         self%rz_ref(:, k) = self%a * [sin(theta), cos(theta)]
         if (self%a >= predeform_from) then
            self%rz_start(:, k) = [predeform_radius * sin(theta), c_axis * cos(theta)]
         else
            self%rz_start(:, k) = self%rz_ref(:, k)
         end if
      end do
      self%rz_ref(1, [1, n]) = 0.0_dp
      self%rz_start(1, [1, n]) = 0.0_dp
      self%rz = self%rz_start
      call self%ref%init(self%rz_ref)
      self%h_min = minval(self%ref%length0)
      allocate (self%rz_pred(2, n), self%u0(2, n), self%u1(2, n), self%force(2, n), self%density(2, n))
      allocate (self%node_area(n), self%grad(2, n))

      call tube_wall_elements(self%wall_a, self%wall_b)
      self%n_wall = size(self%wall_a, 2)
      self%wall_mid = 0.5_dp * (self%wall_a + self%wall_b)
      allocate (self%wall_traction(2 * self%n_wall))
      call factorise_wall(self, stat, errmsg)
      if (stat /= 0) return

      self%implicit = trim(opts%integrator) /= 'rk2'
      self%dt_max = opts%dt_max
      if (opts%dt > 0) then
         self%dt = opts%dt
      else if (self%implicit) then
         ! The implicit step starts at the explicit limit and grows (see rk2_step).
         self%dt = min(opts%dt_factor * opts%ca * self%h_min, 0.01_dp)
      else
         self%dt = min(opts%dt_factor * opts%ca * self%h_min, 0.01_dp)
      end if
      self%pseudo_time = self%implicit
      if (self%implicit) then
         m = 2 * n - 2
         allocate (self%jacobian(m, m), self%system(m, m), self%dofs(m), self%dofs_trial(m), self%res(m))
         allocate (self%res_trial(m), self%pivot(m))
      end if
      block
         real(dp) :: area
         call meridian_area_volume(self%rz_start, area, self%volume0)
      end block
      call self%allocate_history(tube_history_names, tube_history_units, opts%t_max, opts%record_every)
      self%col_length = h_lz
      self%col_stretch = h_stretch
      self%col_shape = [h_lz, h_lp, h_vc]
      self%area_scale = 4 * pi * self%a**2
      self%length_limit = 2 * opts%max_length * self%a
   end subroutine init

   !> Wall elements of the tube boundary, inlet disk, cylinder, outlet disk (end points (r, z)).
   subroutine tube_wall_elements(wall_a, wall_b)
      real(dp), allocatable, intent(out) :: wall_a(:, :), wall_b(:, :)
      real(dp), allocatable :: z_half(:), z(:)
      real(dp) :: h, zc
      integer :: k, nz, nh, m
      ! Half-cylinder node positions from z = 0 outwards.
      allocate (z_half(1000))
      nh = 1
      z_half(1) = 0.0_dp
      h = fine_size
      do while (z_half(nh) < tube_half_length - 1.0e-12_dp)
         zc = z_half(nh)
         if (zc >= 2.0_dp) h = min(h * wall_growth, coarse_size)
         nh = nh + 1
         z_half(nh) = min(zc + h, tube_half_length)
         ! Avoid a sliver at the end.
         if (tube_half_length - z_half(nh) < 0.3_dp * h) z_half(nh) = tube_half_length
      end do
      nz = 2 * nh - 1
      allocate (z(nz))
      z(nh:nz) = z_half(1:nh)
      z(1:nh - 1) = -z_half(nh:2:-1)
      m = disk_elements + (nz - 1) + disk_elements
      allocate (wall_a(2, m), wall_b(2, m))
      do k = 1, disk_elements
         wall_a(:, k) = [real(k - 1, dp) / disk_elements, -tube_half_length]
         wall_b(:, k) = [real(k, dp) / disk_elements, -tube_half_length]
      end do
      do k = 1, nz - 1
         wall_a(:, disk_elements + k) = [1.0_dp, z(k)]
         wall_b(:, disk_elements + k) = [1.0_dp, z(k + 1)]
      end do
      do k = 1, disk_elements
         wall_a(:, disk_elements + nz - 1 + k) = [1.0_dp - real(k - 1, dp) / disk_elements, tube_half_length]
         wall_b(:, disk_elements + nz - 1 + k) = [1.0_dp - real(k, dp) / disk_elements, tube_half_length]
      end do
   end subroutine tube_wall_elements

   !> Single layer of a constant traction g on wall element j at point (r0, z0); an element
   !> that contains the point (its own mid-point) is split there so that the log singularity
   !> sits at a segment end.
   pure function wall_element_velocity(wa, wb, g, r0, z0, own) result(u)
      real(dp), intent(in) :: wa(2), wb(2), g(2), r0, z0
      logical, intent(in) :: own
      real(dp) :: u(2), mid(2)
      if (own) then
         mid = 0.5_dp * (wa + wb)
         u = segment_integral(r0, z0, wa(1), wa(2), mid(1), mid(2), g, g, 2) + &
             segment_integral(r0, z0, mid(1), mid(2), wb(1), wb(2), g, g, 1)
      else
         u = segment_integral(r0, z0, wa(1), wa(2), wb(1), wb(2), g, g, 0)
      end if
   end function wall_element_velocity

   subroutine factorise_wall(self, stat, errmsg)
      type(axisymmetric_tube_t), intent(inout) :: self
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: i, j, m, info
      m = 2 * self%n_wall
      allocate (self%wall_lu(m, m), self%wall_pivot(m))
      !$omp parallel do default(none) shared(self) private(i, j) schedule(dynamic)
      do j = 1, self%n_wall
         do i = 1, self%n_wall
            self%wall_lu(2 * i - 1:2 * i, 2 * j - 1) = wall_element_velocity(self%wall_a(:, j), self%wall_b(:, j), &
                                                                             [1.0_dp, 0.0_dp], self%wall_mid(1, i), &
                                                                             self%wall_mid(2, i), i == j)
            self%wall_lu(2 * i - 1:2 * i, 2 * j) = wall_element_velocity(self%wall_a(:, j), self%wall_b(:, j), &
                                                                         [0.0_dp, 1.0_dp], self%wall_mid(1, i), &
                                                                         self%wall_mid(2, i), i == j)
         end do
      end do
      !$omp end parallel do
      call dgetrf(m, m, self%wall_lu, m, self%wall_pivot, info)
      stat = info
      errmsg = ''
      if (info /= 0) errmsg = 'tube wall matrix is singular (LAPACK dgetrf info /= 0)'
   end subroutine factorise_wall

   !> Membrane velocity (r, z components) at meridian rz in the frame of the capsule; sets v_c.
   subroutine velocity(self, rz, u)
      class(axisymmetric_tube_t), intent(inout) :: self
      real(dp), intent(in) :: rz(:, :)
      real(dp), intent(out) :: u(:, :)
      integer :: n, i, k, e, info, end_flag
      real(dp) :: acc(2), flux, norm_sum, rhs(2 * self%n_wall, 1)

      n = size(rz, 2)
      call meridian_forces(self%ref, self%law, rz, self%force, self%energy)
      call meridian_node_areas(rz, self%node_area)
      do k = 1, n
         self%density(:, k) = self%force(:, k) / self%node_area(k)
      end do
      ! Membrane single layer at the wall collocation points, then the wall traction.
      !$omp parallel do default(none) shared(self, rz, rhs, n) private(i, e, acc) schedule(static)
      do i = 1, self%n_wall
         acc = 0.0_dp
         do e = 1, n - 1
            acc = acc + segment_integral(self%wall_mid(1, i), self%wall_mid(2, i), rz(1, e), rz(2, e), &
                                         rz(1, e + 1), rz(2, e + 1), self%density(:, e), self%density(:, e + 1), 0)
         end do
         rhs(2 * i - 1:2 * i, 1) = -acc
      end do
      !$omp end parallel do
      call dgetrs('N', 2 * self%n_wall, 1, self%wall_lu, 2 * self%n_wall, self%wall_pivot, rhs, 2 * self%n_wall, info)
      self%wall_traction = rhs(:, 1)
      ! Velocity of the membrane nodes.
      !$omp parallel do default(none) shared(self, rz, u, n) private(k, e, i, acc, end_flag) schedule(static)
      do k = 1, n
         acc = 0.0_dp
         do e = 1, n - 1
            end_flag = 0
            if (k == e) end_flag = 1
            if (k == e + 1) end_flag = 2
            acc = acc + segment_integral(rz(1, k), rz(2, k), rz(1, e), rz(2, e), rz(1, e + 1), rz(2, e + 1), &
                                         self%density(:, e), self%density(:, e + 1), end_flag)
         end do
         do i = 1, self%n_wall
            acc = acc + wall_element_velocity(self%wall_a(:, i), self%wall_b(:, i), self%wall_traction(2 * i - 1:2 * i), &
                                              rz(1, k), rz(2, k), .false.)
         end do
         u(:, k) = acc / (8.0_dp * pi * self%ca) + [0.0_dp, 2.0_dp * (1.0_dp - rz(1, k)**2)]
      end do
      !$omp end parallel do
      u(1, [1, n]) = 0.0_dp
      if (self%volume_correction) then
         ! As in 3D: remove the discretisation's net flux through the membrane.
         call meridian_volume_gradient(rz, self%grad)
         self%grad(1, [1, n]) = 0.0_dp
         flux = sum(u * self%grad)
         norm_sum = sum(norm2(self%grad, dim=1))
         do k = 1, n
            u(:, k) = u(:, k) - (flux / norm_sum) * self%grad(:, k) / norm2(self%grad(:, k))
         end do
      end if
      self%v_c = centroid_velocity(rz, u)
      u(2, :) = u(2, :) - self%v_c
   end subroutine velocity

   !> d/dt of the volume centroid's z for node velocities u: (1/V) [oint z (u.n) dS - z_c oint u.n dS],
   !> with P1 velocity on the straight elements (3-point Gauss per element).
   pure real(dp) function centroid_velocity(rz, u) result(v_c)
      real(dp), intent(in) :: rz(:, :), u(:, :)
      real(dp), parameter :: gx(3) = [0.5_dp - sqrt(0.15_dp), 0.5_dp, 0.5_dp + sqrt(0.15_dp)]
      real(dp), parameter :: gw(3) = [5.0_dp / 18, 8.0_dp / 18, 5.0_dp / 18]
      real(dp) :: area, volume, moment, flux, zc, d(2), normal(2), p(2), uq(2), s
      integer :: e, q
      call meridian_area_volume(rz, area, volume)
      zc = centroid_z(rz, volume)
      moment = 0.0_dp
      flux = 0.0_dp
      do e = 1, size(rz, 2) - 1
         d = rz(:, e + 1) - rz(:, e)
         s = norm2(d)
         normal = [-d(2), d(1)] / s
         do q = 1, 3
            p = rz(:, e) + gx(q) * d
            uq = u(:, e) + gx(q) * (u(:, e + 1) - u(:, e))
            moment = moment + gw(q) * 2 * pi * p(1) * s * p(2) * dot_product(uq, normal)
            flux = flux + gw(q) * 2 * pi * p(1) * s * dot_product(uq, normal)
         end do
      end do
      v_c = (moment - zc * flux) / volume
   end function centroid_velocity

   !> z of the volume centroid: integral z dV / V over the frusta.
   pure real(dp) function centroid_z(rz, volume)
      real(dp), intent(in) :: rz(:, :), volume
      real(dp) :: ra, rb, za, zb, dz, m
      integer :: e
      m = 0.0_dp
      do e = 1, size(rz, 2) - 1
         ra = rz(1, e)
         rb = rz(1, e + 1)
         za = rz(2, e)
         zb = rz(2, e + 1)
         dz = zb - za
         ! -pi integral_0^1 r(t)**2 z(t) dt dz, r and z linear in t (exact polynomial integral).
         m = m - pi * dz * (ra * ra * (za / 4 + zb / 12) + 2 * ra * rb * (za / 12 + zb / 12) &
                            + rb * rb * (za / 12 + zb / 4))
      end do
      centroid_z = m / volume
   end function centroid_z

   !> One step in the capsule frame, then the centroid put back at z = 0.
   !> Explicit: Heun's RK2 (time-accurate). Implicit: pseudo-transient continuation,
   !> (I - dt J) delta = dt u(x) with J = du/dx by forward differences, dt grown by the ratio
   !> of successive residuals (switched evolution relaxation) until the step is Newton's
   !> method for u(x) = 0. Why: at small Ca the rear of the capsule is under compression,
   !> and a membrane without bending stiffness then has mesh-scale modes growing at a rate
   !> ~10 V/l whatever Ca. Explicit steps (bound to dt ~ Ca h) let them grow into wrinkles;
   !> implicit steps with dt >> 1/rate damp them (|1/(1 - dt rate)| < 1) and converge to the
   !> steady shape the paper reports. Continuous elongation still shows: the residual then
   !> grows, dt shrinks back and the capsule keeps stretching.
   subroutine rk2_step(self)
      class(axisymmetric_tube_t), intent(inout) :: self
      real(dp) :: area, volume
      if (self%implicit) then
         call implicit_step(self)
      else
         call self%velocity(self%rz, self%u0)
         self%rz_pred = self%rz + self%dt * self%u0
         call self%velocity(self%rz_pred, self%u1)
         self%rz = self%rz + 0.5_dp * self%dt * (self%u0 + self%u1)
         self%t = self%t + self%dt
      end if
      call meridian_area_volume(self%rz, area, volume)
      self%rz(2, :) = self%rz(2, :) - centroid_z(self%rz, volume)
      self%step = self%step + 1
   end subroutine rk2_step

   subroutine implicit_step(self)
      type(axisymmetric_tube_t), intent(inout) :: self
      integer, parameter :: jacobian_every = 4
      real(dp), parameter :: fd_step = 1.0e-7_dp
      integer :: m, j, info, k
      real(dp) :: residual, area, volume, shift

      m = size(self%dofs)
      call pack_dofs(self%rz, self%dofs)
      call self%velocity(self%rz, self%u0)
      call pack_dofs(self%u0, self%res)
      residual = maxval(abs(self%res))
      self%residual = residual
      ! Switched evolution relaxation: the step follows the residual's decrease.
      if (self%step > 0) self%dt = min(self%dt * min(max(self%last_residual / residual, 0.5_dp), 4.0_dp), &
                                       self%dt_max)
      if (self%steps_since_jacobian >= jacobian_every .or. residual > 0.5_dp * self%last_residual) then
         do j = 1, m
            self%dofs_trial = self%dofs
            self%dofs_trial(j) = self%dofs(j) + fd_step
            call unpack_dofs(self%dofs_trial, self%rz_pred)
            call self%velocity(self%rz_pred, self%u1)
            call pack_dofs(self%u1, self%res_trial)
            self%jacobian(:, j) = (self%res_trial - self%res) / fd_step
         end do
         self%steps_since_jacobian = 0
      end if
      self%system = -self%dt * self%jacobian
      do k = 1, m
         self%system(k, k) = self%system(k, k) + 1.0_dp
      end do
      self%res_trial = self%dt * self%res
      call dgesv(m, 1, self%system, m, self%pivot, self%res_trial, m, info)
      if (info /= 0) self%res_trial = self%dt * self%res
      call unpack_dofs(self%dofs + self%res_trial, self%rz)
      ! Implicit Euler conserves the volume only to first order: restore it by a uniform
      ! displacement along the node normals (dV = sum grad_k . delta_k).
      call meridian_area_volume(self%rz, area, volume)
      call meridian_volume_gradient(self%rz, self%grad)
      self%grad(1, [1, size(self%rz, 2)]) = 0.0_dp
      shift = (self%volume0 - volume) / sum(self%grad**2)
      self%rz = self%rz + shift * self%grad
      self%t = self%t + self%dt
      self%steps_since_jacobian = self%steps_since_jacobian + 1
      self%last_residual = residual
   end subroutine implicit_step

   !> Degrees of freedom: (r, z) of every node but the poles' r (on the axis).
   pure subroutine pack_dofs(rz, q)
      real(dp), intent(in) :: rz(:, :)
      real(dp), intent(out) :: q(:)
      integer :: n
      n = size(rz, 2)
      q(1) = rz(2, 1)
      q(2:2 * n - 3) = reshape(rz(:, 2:n - 1), [2 * n - 4])
      q(2 * n - 2) = rz(2, n)
   end subroutine pack_dofs

   pure subroutine unpack_dofs(q, rz)
      real(dp), intent(in) :: q(:)
      real(dp), intent(out) :: rz(:, :)
      integer :: n
      n = size(rz, 2)
      rz(:, 1) = [0.0_dp, q(1)]
      rz(:, 2:n - 1) = reshape(q(2:2 * n - 3), [2, n - 2])
      rz(:, n) = [0.0_dp, q(2 * n - 2)]
   end subroutine unpack_dofs

   !> Append diagnostics: L_z (front to rear), L_p (rear pole to the rear-most point: the
   !> parachute depth, 0 for a convex rear), v_c/V, film-side radius r_max.
   subroutine record(self)
      class(axisymmetric_tube_t), intent(inout) :: self
      real(dp) :: area, volume, l_z, l_p, stretch, lam_s, lam_p
      integer :: n, e
      n = size(self%rz, 2)
      call self%velocity(self%rz, self%u0)
      call meridian_area_volume(self%rz, area, volume)
      l_z = maxval(self%rz(2, :)) - minval(self%rz(2, :))
      l_p = self%rz(2, n) - minval(self%rz(2, :))
      stretch = 1.0_dp
      do e = 1, n - 1
         lam_s = norm2(self%rz(:, e + 1) - self%rz(:, e)) / self%ref%length0(e)
         lam_p = 0.5_dp * (self%rz(1, e) + self%rz(1, e + 1)) / self%ref%radius0(e)
         stretch = max(stretch, lam_s, lam_p, 1.0_dp / lam_s, 1.0_dp / lam_p)
      end do
      self%n_rec = min(self%n_rec + 1, size(self%history, 2))
      self%history(:, self%n_rec) = [self%t, area, volume, l_z, l_p, self%v_c, maxval(self%rz(1, :)), &
                                     self%energy, stretch]
   end subroutine record

   subroutine reset(self)
      class(axisymmetric_tube_t), intent(inout) :: self
      self%rz = self%rz_start
   end subroutine reset

   pure integer function state_size(self)
      class(axisymmetric_tube_t), intent(in) :: self
      state_size = size(self%rz)
   end function state_size

   subroutine get_state(self, state)
      class(axisymmetric_tube_t), intent(in) :: self
      real(dp), intent(out) :: state(:)
      integer :: k
      do k = 1, size(self%rz, 2)
         state(2 * k - 1:2 * k) = self%rz(:, k)
      end do
   end subroutine get_state

   subroutine set_state(self, state)
      class(axisymmetric_tube_t), intent(inout) :: self
      real(dp), intent(in) :: state(:)
      integer :: k
      do k = 1, size(self%rz, 2)
         self%rz(:, k) = state(2 * k - 1:2 * k)
      end do
   end subroutine set_state

   function progress_text(self) result(text)
      class(axisymmetric_tube_t), intent(in) :: self
      character(len=:), allocatable :: text
      character(len=80) :: buf
      write (buf, '(a,f7.4,a,f7.4,a,f7.4)') 'L_z/l = ', self%history(h_lz, self%n_rec), '  L_p/l = ', &
         self%history(h_lp, self%n_rec), '  v_c/V = ', self%history(h_vc, self%n_rec)
      text = trim(buf)
   end function progress_text

   !> /mesh (reference and current meridian as (n, 2) arrays of (r, z)) and /profile (r, z).
   subroutine write_geometry(self, f, stat, errmsg)
      class(axisymmetric_tube_t), intent(in) :: self
      type(h5_file_t), intent(inout) :: f
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      call f%write_attr('/', 'n_nodes', size(self%rz, 2), stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'n_wall_elements', self%n_wall, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'tube_length', 2 * tube_half_length, stat, errmsg)
      if (stat == 0) call f%make_group('/mesh', stat, errmsg)
      if (stat == 0) call f%write_dataset('/mesh/reference_meridian', self%rz_ref, 'l', stat, errmsg)
      if (stat == 0) call f%write_dataset('/mesh/meridian', self%rz, 'l', stat, errmsg)
      if (stat == 0) call f%make_group('/profile', stat, errmsg)
      if (stat == 0) call f%write_attr('/profile', 'plane', 'meridian, front pole first (flow along +z)', stat, errmsg)
      if (stat == 0) call f%write_dataset('/profile/r', self%rz(1, :), 'l', stat, errmsg)
      if (stat == 0) call f%write_dataset('/profile/z', self%rz(2, :), 'l', stat, errmsg)
   end subroutine write_geometry

end module axisymmetric_tube
