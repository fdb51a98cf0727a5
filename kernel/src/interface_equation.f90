!> Interface velocity of a capsule whose inner viscosity is lambda times the outer one: the
!> second-kind boundary integral equation (Pozrikidis 1992, eq. 5.3.8), written in the
!> normalisation of stokes_single_layer and stokes_double_layer (mu = 1, n outward, f the force
!> density that the membrane exerts on the fluid, as in the base model):
!>
!>   u = b + kappa L[u],   b = 2/(1+lambda) (u_inf + S[f]/Ca),   kappa = (1-lambda)/(1+lambda),
!>   L = 2 D  (eigenvalues in [-1, 1]: -1 for rigid-body motions, +1 with left eigenfunction n).
!>
!> At lambda = 1, kappa = 0 and u = u_inf + S[f]/Ca, the base model's explicit formula (the
!> capsule model does not even call this module then). Pozrikidis writes
!> -1/(4 pi mu (1+lambda)) int G . Df dS with Df the traction jump, which is minus our f.
!>
!> Wielandt deflation: as lambda -> 0 (kappa -> 1) the +1 eigenvalue makes I - kappa L nearly
!> singular. Because int n . L[u] dS = int n . u dS, the operator
!>   L'[u] = L[u] - n(x) (1/S) int u . n dS
!> has the same spectrum with that eigenvalue moved to 0, and the solution is unchanged since
!> int u . n dS = 0 for an incompressible inner fluid (the discrete b carries an O(h^2) flux;
!> the undeflated equation would amplify it by (1+lambda)/(2 lambda), the deflated one does not).
!> The rigid-body eigenvalue -1 (lambda -> infinity) is left to GMRES, which resolves six
!> isolated eigenvalues in a few extra iterations.
!>
!> Solver: restarted GMRES(m), matrix-free, from the caller's initial guess (the previous
!> solution in the time loop). Converged when GMRES's residual estimate falls below tol |b|/2
!> (in exact arithmetic it is the true residual; the margin covers the drift of modified
!> Gram-Schmidt over at most `restart` vectors), or when the true residual |b - A u|, computed
!> at the start and after a restart, falls below tol |b|.
!> Work arrays are allocated by init: a solve allocates nothing.
!>
!> Bounded flows (the 3D tube): the double layer's reflection by the walls enters as an
!> operator_term_t that the caller passes to solve, added to D[u] before the rest of the
!> operator (L = 2 (D + term)); without it (shear) the operations are those of before.
module interface_equation
   use capsim_kinds, only: dp
   use text_format, only: real_text, int_text
   use sphere_mesh, only: surface_mesh_t
   use stokes_double_layer, only: double_layer_t
   implicit none
   private
   public :: interface_equation_t, operator_term_t

   !> A linear addition to the double layer at the nodes, w <- w + T[u] (the walls' response
   !> to the capsule's double layer in the 3D tube).
   type, abstract :: operator_term_t
   contains
      procedure(term_add_iface), deferred :: add
   end type operator_term_t

   abstract interface
      subroutine term_add_iface(self, u, w)
         import :: operator_term_t, dp
         class(operator_term_t), intent(inout) :: self
         real(dp), intent(in) :: u(:, :)
         real(dp), intent(inout) :: w(:, :)
      end subroutine term_add_iface
   end interface

   type :: interface_equation_t
      real(dp) :: lambda = 1, kappa = 0
      !> Relative residual at which a solve stops. |b| is of the order of the shear velocity, so
      !> the velocities are exact to ~1e-8 against a discretisation error of ~1e-3 and a steady
      !> criterion of 1e-4 on D12 per time unit: the iteration error never shows.
      real(dp) :: tol = 1.0e-8_dp
      integer :: restart = 30, max_iter = 400
      !> The Wielandt deflation of the normal mode (off only to measure what it does).
      logical :: deflate = .true.
      real(dp), allocatable :: basis(:, :, :), hess(:, :), cs(:), sn(:), g(:), y(:), r(:, :), w(:, :)
      !> Statistics: operator applications of the last solve and of all solves, number of solves.
      integer :: last_applications = 0
      integer(8) :: total_applications = 0, n_solves = 0
      real(dp) :: last_residual = 0
   contains
      procedure :: init
      procedure :: solve
      procedure :: apply_operator
   end type interface_equation_t

contains

   subroutine init(self, n_nodes, lambda)
      class(interface_equation_t), intent(inout) :: self
      integer, intent(in) :: n_nodes
      real(dp), intent(in) :: lambda
      integer :: m
      self%lambda = lambda
      self%kappa = (1.0_dp - lambda) / (1.0_dp + lambda)
      m = self%restart
      allocate (self%basis(3, n_nodes, m + 1), self%hess(m + 1, m), self%cs(m), self%sn(m), self%g(m + 1), self%y(m))
      allocate (self%r(3, n_nodes), self%w(3, n_nodes))
   end subroutine init

   !> A[u] = u - kappa L'[u] for the geometry last given to dl%set_geometry (L = 2 (D + term)
   !> with a term).
   subroutine apply_operator(self, dl, mesh, u, au, term)
      class(interface_equation_t), intent(in) :: self
      type(double_layer_t), intent(inout) :: dl
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: u(:, :)
      real(dp), intent(out) :: au(:, :)
      class(operator_term_t), intent(inout), optional :: term
      real(dp) :: mean_flux
      call dl%apply(mesh, u, au)
      if (present(term)) call term%add(u, au)
      mean_flux = 0
      if (self%deflate) mean_flux = dl%normal_flux(u) / dl%area_sum
      au = u - self%kappa * (2.0_dp * au - mean_flux * dl%node_normal)
   end subroutine apply_operator

   !> Solve A[u] = b; u holds the initial guess on entry. stat /= 0 if the residual did not
   !> fall below tol |b| within max_iter applications (u is then the last iterate).
   subroutine solve(self, dl, mesh, b, u, stat, errmsg, term)
      class(interface_equation_t), intent(inout) :: self
      type(double_layer_t), intent(inout) :: dl
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: b(:, :)
      real(dp), intent(inout) :: u(:, :)
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      class(operator_term_t), intent(inout), optional :: term
      integer :: k, kk, j, applications
      real(dp) :: bnorm, beta, temp, denom

      stat = 0
      errmsg = ''
      applications = 0
      bnorm = norm2(b)
      self%n_solves = self%n_solves + 1
      if (bnorm == 0.0_dp) then
         u = 0
         self%last_applications = 0
         self%last_residual = 0
         return
      end if
      do
         ! The true residual, at the start and after a cycle that did not converge.
         call self%apply_operator(dl, mesh, u, self%w, term)
         applications = applications + 1
         self%r = b - self%w
         beta = norm2(self%r)
         self%last_residual = beta / bnorm
         if (beta <= self%tol * bnorm) exit
         if (applications >= self%max_iter) then
            stat = 1
            errmsg = 'the viscosity-ratio interface equation did not converge (GMRES, relative residual '// &
                     real_text(self%last_residual)//' after '//int_text(applications)//' operator applications)'
            exit
         end if
         self%basis(:, :, 1) = self%r / beta
         self%g = 0
         self%g(1) = beta
         kk = 0
         do k = 1, self%restart
            call self%apply_operator(dl, mesh, self%basis(:, :, k), self%w, term)
            applications = applications + 1
            ! Modified Gram-Schmidt.
            do j = 1, k
               self%hess(j, k) = sum(self%w * self%basis(:, :, j))
               self%w = self%w - self%hess(j, k) * self%basis(:, :, j)
            end do
            self%hess(k + 1, k) = norm2(self%w)
            if (self%hess(k + 1, k) > 0.0_dp) self%basis(:, :, k + 1) = self%w / self%hess(k + 1, k)
            ! Givens rotations keep the Hessenberg matrix triangular and give the residual norm.
            do j = 1, k - 1
               temp = self%cs(j) * self%hess(j, k) + self%sn(j) * self%hess(j + 1, k)
               self%hess(j + 1, k) = -self%sn(j) * self%hess(j, k) + self%cs(j) * self%hess(j + 1, k)
               self%hess(j, k) = temp
            end do
            denom = hypot(self%hess(k, k), self%hess(k + 1, k))
            self%cs(k) = self%hess(k, k) / denom
            self%sn(k) = self%hess(k + 1, k) / denom
            self%hess(k, k) = denom
            self%hess(k + 1, k) = 0.0_dp
            self%g(k + 1) = -self%sn(k) * self%g(k)
            self%g(k) = self%cs(k) * self%g(k)
            kk = k
            if (abs(self%g(k + 1)) <= 0.5_dp * self%tol * bnorm .or. applications >= self%max_iter) exit
         end do
         do j = kk, 1, -1
            self%y(j) = (self%g(j) - sum(self%hess(j, j + 1:kk) * self%y(j + 1:kk))) / self%hess(j, j)
         end do
         do j = 1, kk
            u = u + self%y(j) * self%basis(:, :, j)
         end do
         if (abs(self%g(kk + 1)) <= 0.5_dp * self%tol * bnorm) then
            self%last_residual = abs(self%g(kk + 1)) / bnorm
            exit
         end if
      end do
      self%last_applications = applications
      self%total_applications = self%total_applications + applications
   end subroutine solve

end module interface_equation
