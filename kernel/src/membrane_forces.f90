!> P1 membrane finite elements: strain invariants per triangle and nodal forces as the exact
!> gradient of the discrete strain energy E = sum_T A0_T w_s(I1, I2).
!>
!> With reference edges E_a and current edges e_a (a = 1, 2), G_ab = E_a.E_b, g_ab = e_a.e_b:
!>   I1 = tr(G^-1 g) - 2,   I2 = det g / det G - 1,
!>   dI1/de_a = 2 sum_b (G^-1)_ab e_b,   dI2/de_a = 2 (det g / det G) sum_b (g^-1)_ab e_b.
!> Forces are assembled per triangle and then gathered per node through the node-to-triangle
!> lists, so both loops run in parallel without atomics and give the same bits on any
!> number of threads.
module membrane_forces
   use capsim_kinds, only: dp
   use sphere_mesh, only: surface_mesh_t
   use membrane_law, only: membrane_law_t
   implicit none
   private
   public :: membrane_reference_t, membrane_nodal_forces, triangle_invariants, principal_stretches

   type :: membrane_reference_t
      !> Inverse reference metric (G^-1)_11, (G^-1)_12, (G^-1)_22 and det G per triangle.
      real(dp), allocatable :: ginv(:, :)
      real(dp), allocatable :: det_g0(:)
      !> Reference (stress-free) area of each triangle.
      real(dp), allocatable :: area0(:)
      !> Work array: derivative of the triangle energy with respect to its 3 vertices.
      real(dp), allocatable :: tri_grad(:, :, :)
   contains
      procedure :: init => reference_init
   end type membrane_reference_t

contains

   subroutine reference_init(self, mesh, x_ref)
      class(membrane_reference_t), intent(inout) :: self
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x_ref(:, :)
      integer :: t
      real(dp) :: e1(3), e2(3), g11, g12, g22, det
      allocate (self%ginv(3, mesh%n_tri), self%det_g0(mesh%n_tri), self%area0(mesh%n_tri))
      allocate (self%tri_grad(3, 3, mesh%n_tri))
      do t = 1, mesh%n_tri
         e1 = x_ref(:, mesh%tri(2, t)) - x_ref(:, mesh%tri(1, t))
         e2 = x_ref(:, mesh%tri(3, t)) - x_ref(:, mesh%tri(1, t))
         g11 = dot_product(e1, e1)
         g12 = dot_product(e1, e2)
         g22 = dot_product(e2, e2)
         det = g11 * g22 - g12**2
         self%ginv(:, t) = [g22, -g12, g11] / det
         self%det_g0(t) = det
         self%area0(t) = 0.5_dp * sqrt(det)
      end do
   end subroutine reference_init

   !> I1 and I2 of triangle t at positions x.
   pure subroutine triangle_invariants(ref, mesh, x, t, i1, i2)
      type(membrane_reference_t), intent(in) :: ref
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      integer, intent(in) :: t
      real(dp), intent(out) :: i1, i2
      real(dp) :: e1(3), e2(3), g11, g12, g22
      e1 = x(:, mesh%tri(2, t)) - x(:, mesh%tri(1, t))
      e2 = x(:, mesh%tri(3, t)) - x(:, mesh%tri(1, t))
      g11 = dot_product(e1, e1)
      g12 = dot_product(e1, e2)
      g22 = dot_product(e2, e2)
      i1 = ref%ginv(1, t) * g11 + 2.0_dp * ref%ginv(2, t) * g12 + ref%ginv(3, t) * g22 - 2.0_dp
      i2 = (g11 * g22 - g12**2) / ref%det_g0(t) - 1.0_dp
   end subroutine triangle_invariants

   !> Principal stretches lambda1 >= lambda2 of triangle t (from I1 and I2).
   pure subroutine principal_stretches(ref, mesh, x, t, lambda1, lambda2)
      type(membrane_reference_t), intent(in) :: ref
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      integer, intent(in) :: t
      real(dp), intent(out) :: lambda1, lambda2
      real(dp) :: i1, i2, tr, det, disc
      call triangle_invariants(ref, mesh, x, t, i1, i2)
      tr = i1 + 2.0_dp
      det = i2 + 1.0_dp
      disc = sqrt(max(tr**2 - 4.0_dp * det, 0.0_dp))
      lambda1 = sqrt(0.5_dp * (tr + disc))
      lambda2 = sqrt(max(0.5_dp * (tr - disc), 0.0_dp))
   end subroutine principal_stretches

   !> Nodal elastic forces F = -dE/dx [G_s a] and the total strain energy E [G_s a**2].
   subroutine membrane_nodal_forces(ref, mesh, law, x, force, energy)
      type(membrane_reference_t), intent(inout) :: ref
      type(surface_mesh_t), intent(in) :: mesh
      type(membrane_law_t), intent(in) :: law
      real(dp), intent(in) :: x(:, :)
      real(dp), intent(out) :: force(:, :)
      real(dp), intent(out) :: energy
      integer :: t, i, p
      real(dp) :: e1(3), e2(3), g11, g12, g22, det_g, i1, i2, w1, w2, ratio
      real(dp) :: d1(3), d2(3), gi11, gi12, gi22

      energy = 0.0_dp
      !$omp parallel default(none) shared(ref, mesh, law, x, force) &
      !$omp private(t, i, p, e1, e2, g11, g12, g22, det_g, i1, i2, w1, w2, ratio, d1, d2, gi11, gi12, gi22) &
      !$omp reduction(+:energy)
      !$omp do schedule(static)
      do t = 1, mesh%n_tri
         e1 = x(:, mesh%tri(2, t)) - x(:, mesh%tri(1, t))
         e2 = x(:, mesh%tri(3, t)) - x(:, mesh%tri(1, t))
         g11 = dot_product(e1, e1)
         g12 = dot_product(e1, e2)
         g22 = dot_product(e2, e2)
         det_g = g11 * g22 - g12**2
         i1 = ref%ginv(1, t) * g11 + 2.0_dp * ref%ginv(2, t) * g12 + ref%ginv(3, t) * g22 - 2.0_dp
         ratio = det_g / ref%det_g0(t)
         i2 = ratio - 1.0_dp
         call law%derivatives(i1, i2, w1, w2)
         energy = energy + ref%area0(t) * law%energy(i1, i2)
         gi11 = g22 / det_g
         gi12 = -g12 / det_g
         gi22 = g11 / det_g
         ! dE/de_a = A0 [w1 * 2 (G^-1 e)_a + w2 * 2 ratio (g^-1 e)_a]
         d1 = 2.0_dp * ref%area0(t) * (w1 * (ref%ginv(1, t) * e1 + ref%ginv(2, t) * e2) &
                                       + w2 * ratio * (gi11 * e1 + gi12 * e2))
         d2 = 2.0_dp * ref%area0(t) * (w1 * (ref%ginv(2, t) * e1 + ref%ginv(3, t) * e2) &
                                       + w2 * ratio * (gi12 * e1 + gi22 * e2))
         ref%tri_grad(:, 1, t) = -(d1 + d2)
         ref%tri_grad(:, 2, t) = d1
         ref%tri_grad(:, 3, t) = d2
      end do
      !$omp end do
      !$omp do schedule(static)
      do i = 1, mesh%n_nodes
         force(:, i) = 0.0_dp
         do p = mesh%node_tri_start(i), mesh%node_tri_start(i + 1) - 1
            force(:, i) = force(:, i) - ref%tri_grad(:, mesh%node_tri_vertex(p), mesh%node_tri(p))
         end do
      end do
      !$omp end do
      !$omp end parallel
   end subroutine membrane_nodal_forces

end module membrane_forces
