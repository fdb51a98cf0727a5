!> Single layer of the tube wall B (tube_wall_mesh): the dense collocation matrix that maps
!> the P1 wall traction to the velocity at the wall nodes, factorised once (LAPACK dgetrf),
!> cached on disk, and solved per time step (dgetrs); the velocity that a wall traction
!> induces at arbitrary points; and the Poiseuille data of the total-flow check.
!>
!> Normalisation (as stokes_single_layer): u(x) = 1/(8 pi mu) integral_B J(x - y) . f(y) dS(y),
!> J(r) = I/|r| + r r^T/|r|**3, mu = 1, r = x - y (target minus source).
!>
!> Sign convention. n is the mesh normal of tube_wall_mesh, pointing OUT OF THE FLUID, and the
!> wall traction is f = sigma . n: the force per unit area that the WALL exerts on the fluid.
!> Every single layer of the kernel then enters with the same sign, u = + 1/(8 pi) int J . f
!> (f = force density on the fluid, as the capsule's membrane load). By the reciprocal
!> theorem, for x inside the fluid domain D bounded by B,
!>
!>    u_j(x) = 1/(8 pi) int_B J_ji f_i dS + 1/(8 pi) int_B u_i T_ijk(x - y) n_k dS,
!>    T_ijk(r) = -6 r_i r_j r_k / |r|**5,
!>
!> (with constant u and f = 0 the double layer returns u: int_B T_ijk(x - y) n_k dS = 8 pi
!> delta_ij inside). At a smooth point of B the double layer jumps by half, so the
!> collocation equation at wall node x_i is
!>
!>    1/(8 pi) int_B J . f dS = (1/2) u(x_i) - 1/(8 pi) PV int_B u . T . n dS.
!>
!> Capsule problems (the paper's formulation) use it with the disturbance data
!> u = -(capsule single layer) on all of B, where no double layer appears.
!>
!> Traction at the rims. The traction jumps across the rim (the normal turns by 90 degrees),
!> which a continuous P1 field cannot follow: with shared rim values the error is O(h p_rim)
!> in a strip of width h, and it shifts the flow rate by O(h) (measured, L = 4: Poiseuille
!> wall shear off by 6 %, 2.8 %, 1.5 % at h = 0.28, 0.2, 0.14; the point force's pressure
!> rise by 4.5 % and 1 % at h = 0.28, 0.14). At the rim, however, the velocity
!> gradient is known from the data (tangential derivatives along both faces), so the stress
!> there is -p I + 2 e with e known and only p unknown. The nodal unknown f_k of a rim node is
!> its CYLINDER-side traction; the disk-side value that the disk triangles use is
!>
!>    f_k^disk = M_k f_k + c_k,   M_k = I + (n_d - e_r) e_r^T,   c_k = 2 (e - e_rr I) . (n_d - e_r),
!>
!> (e_r the radial unit vector at the node, n_d = -+e_z the disk normal). For the disturbance
!> flow of a capsule, u' = 0 on both faces, so e = 0 and c = 0: f^disk = -p' n_d when
!> f^cyl = -p' e_r. For Poiseuille, c = (+-4 e_r + 4 e_z) (poiseuille_rim_jump). The
!> corner map keeps the system square (3 unknowns and 3 equations per node); with it the
!> same errors are 0.8 %, 0.28 %, 0.09 % and 0.27 %, 0.03 % (order 3).
!> The same holds wherever the wall's normal turns: in the rectangular duct (duct_wall_mesh)
!> also along the four long edges and at the eight box corners. In general a node keeps the
!> traction of its own face (wall%side_normal; the section's inside a section) as unknown, and
!> each other face it touches has a slot with M = I + (n_face - n_own) n_own^T (the tube: one
!> slot per rim node, its corner map). The shape of the channel comes from the wall's
!> type-bound procedures (side normal, face of a side triangle, clearance, undisturbed flow).
!>
!> Poiseuille check (total flow, no capsule): u = 0 on the cylinder and u = v_inf =
!> 2 (1 - x^2 - y^2) e_z on both disks, so the double layer is known data over the disks
!> only; it is exactly zero for a target in the plane of a disk (r . n = 0), and the free
!> term (1/2) u lives only on disk-interior nodes (u = 0 on the cylinder and the rims). The
!> exact traction: cylinder f = -p e_r - 4 e_z (wall shear 4 mu V / l opposing the flow),
!> entry disk f = 4 r e_r + p e_z, exit disk f = -4 r e_r - p e_z, p = p0 - 8 z
!> (dp/dz = -8 mu V / l^2).
!>
!> Pressure gauge. On a closed surface the single layer annihilates the normal field
!> (int_B J . n dS = 0: a uniform pressure moves nothing), so the first-kind equation fixes the
!> traction only up to a constant pressure, and its discrete matrix A is nearly singular.
!> The factorised matrix is A + (1/|B|) nhat a^T, with a^T f = int_B n . f dS (a: the
!> flux weights, vector areas mapped through M_k^T at the rims) and nhat the unit node normal
!> (the cylinder's at the rims, which the corner map turns into n_d on the disks): for data
!> with zero net flux (any incompressible flow) the solution is the traction with
!> int_B n . f dS = 0 (zero mean wall pressure) and A f = data. a is (approximately) a left
!> null vector of A, so the added term does not disturb the solution.
!>
!> Quadrature of the matrix, for each (target node, triangle): the Duffy rule (4 x 4) when the
!> node is a vertex of the triangle, otherwise the 7-point rule, recursively subdivided while
!> the piece is within leaf_ratio (3) of its diameters from the node. The vertex rule of
!> stokes_single_layer is not used here: its mid-field error is O(h |f|), and the wall
!> tractions include the large end pressures (~4 L mu V / l); the Poiseuille check went from
!> 11 % to 0.8 % error at h = 0.28, L = 4 when it was replaced. Assembly runs over target nodes
!> with OpenMP and fills the TRANSPOSE of A (column i = row i of A, contiguous writes); dgetrs
!> with trans = 'T' then solves A f = u.
!>
!> Off-wall points (velocity_at, per step): vertex rule (one Stokeslet per node, vectorised)
!> beyond mid_radius (default 0.5 tube radii) from the triangle's centroid, the 7-point rule
!> within it, subdivided as above near the point. Against a brute-force rule (wall_probe
!> quadrature, smooth traction, points 1 to 0.05 h inside the wall, h = 0.28): 5e-9 relative
!> with mid_radius = 100 (7-point rule everywhere), 1.2e-3 with 0.5; in the Poiseuille check
!> (h = 0.14) the interior velocity error is 1.5e-3 and 3.3e-3. The far-field vertex rule
!> error is O(h^2 |f| / mid_radius): raise mid_radius (cost ~ triangles within it) when the
!> far wall carries large tractions.
module wall_single_layer
   use, intrinsic :: iso_c_binding, only: c_int
   use, intrinsic :: iso_fortran_env, only: int64
   use omp_lib, only: omp_get_wtime
   use capsim_kinds, only: dp, pi, code_version
   use lapack_interfaces, only: dgecon, dgetrf, dgetrs
   use vector_algebra, only: cross
   use triangle_quadrature, only: quadrature_rule_t, dunavant7_rule, duffy_rule
   use stokes_single_layer, only: triangle_areas, add_stokeslets, stokeslet_block
   use file_ops, only: replace_file
   use triangle_cells, only: triangle_cells_t
   use tube_wall_mesh, only: tube_wall_t, wall_tag_inlet, wall_tag_outlet, wall_tag_rim, centre_half_length, &
                             grading_length, poiseuille_velocity
   implicit none
   private
   public :: wall_operator_t, poiseuille_velocity, poiseuille_rim_jump, corner_map
   public :: default_duffy_order, default_mid_radius, leaf_ratio, leaf_strengths, triangle_correction, subdivided_single_layer, &
             point_sum

   integer, parameter :: default_duffy_order = 4
   real(dp), parameter :: default_mid_radius = 0.5_dp
   !> Adaptive 7-point quadrature: a (sub-)triangle is a leaf beyond leaf_ratio of its
   !> diameters from the target, or at max_depth subdivisions.
   real(dp), parameter :: leaf_ratio = 3.0_dp
   integer, parameter :: max_depth = 10
   !> Layout version of the cache file (bump when the file or the matrix changes).
   integer, parameter :: cache_format = 2
   character(len=16), parameter :: cache_magic = 'CAPSMECH-WALL-LU'
   !> Largest matrix order accepted (3 n_wall): 40000 is a 12.8 GB matrix.
   integer, parameter :: max_order = 40000
   integer, parameter :: kernel_single_layer = 1, kernel_double_layer = 2
   !> Most mapped slots of one node (a box corner of the duct has two).
   integer, parameter :: max_slots = 4

   type :: wall_operator_t
      integer :: n_nodes = 0, n_rim = 0
      integer :: duffy_order = default_duffy_order
      logical :: pressure_gauge = .true.
      !> LU factors (dgetrf) of (A + gauge)^T, order 3 n_nodes, and the pivots.
      real(dp), allocatable :: lu(:, :)
      integer, allocatable :: ipiv(:)
      !> Single layer at every node of a unit disk-side traction at each rim node, before
      !> the corner map (transposed, (3 n_rim, 3 n_nodes)): applies the rim jumps c_k.
      real(dp), allocatable :: rim_disk(:, :)
      !> Reciprocal condition number (1-norm of A) of the factorised matrix (dgecon).
      real(dp) :: rcond = 0
      !> Mapped slots: a node where the wall's normal turns (a rim of the tube; in the duct
      !> also a long edge, and a box corner twice) has one slot per face other than its own,
      !> r = 1 .. n_rim in node order: rim_node(r) its node, slot_face(:, r) that face's normal
      !> (its corner map, slot_corner_map: M = I + (n_face - n_own) n_own^T), slot_area(r) the
      !> node area on that face, which carries M f_k + c_k. tri_slot(m, t): the slot that vertex m of triangle t uses, or 0
      !> (the node's own value f_k); node_slots(:, k): the slots of node k (0-padded).
      integer, allocatable :: rim_node(:), tri_slot(:, :), node_slots(:, :)
      real(dp), allocatable :: slot_face(:, :), slot_area(:)
      !> Node areas that carry the nodal value f_k (the node's own face).
      real(dp), allocatable :: area_main(:)
      !> Flux weights a (a^T f = int_B n . f dS) and unit node normals (the gauge).
      real(dp), allocatable :: flux_weight(:, :), node_normal(:, :)
      !> Fixed wall geometry per triangle.
      real(dp), allocatable :: tri_area(:), tri_normal(:, :), tri_centroid(:, :), tri_diameter(:)
      !> Corner positions per triangle (3, 3, n_tri): contiguous, so that the per-point loop of
      !> velocity_at passes them without gathering.
      real(dp), allocatable :: tri_corner(:, :, :)
      logical, allocatable :: disk_tri(:)
      real(dp) :: total_area = 0
      !> 7-point rule: reference rule, and its points and weights (area included) per triangle;
      !> Duffy rules with the singular vertex at corner 1, 2, 3.
      type(quadrature_rule_t) :: leaf_rule, duffy(3)
      real(dp), allocatable :: quad_point(:, :, :), quad_weight(:, :)
      !> velocity_at: the 7-point rule replaces the vertex rule on triangles whose centroid is
      !> nearer than mid_radius (tube radii) to the point.
      real(dp) :: mid_radius = default_mid_radius
      !> Triangles by cell of their centroid (triangle_cells), so that velocity_at visits only
      !> the triangles around a point; indexed for cells_radius (rebuilt when mid_radius changes).
      real(dp) :: max_diameter = 0, cells_radius = -1
      type(triangle_cells_t) :: cells
      !> Work arrays of the velocity evaluation (pair sums, disk-side rim values), allocated once.
      real(dp), allocatable :: xs(:), ys(:), zs(:), qx(:), qy(:), qz(:), f_disk(:, :)
      !> Per-step quadrature data of velocity_at, per triangle: corner tractions (disk side at
      !> the rims), 7-point strengths (weight x area x traction) and vertex-rule strengths.
      real(dp), allocatable :: tri_traction(:, :, :), quad_strength(:, :, :), vertex_strength(:, :, :)
      !> Provenance of the factorisation: loaded from the cache or computed, and timings.
      logical :: from_cache = .false.
      character(len=:), allocatable :: cache_file, cache_message
      real(dp) :: assembly_seconds = 0, factor_seconds = 0, cache_seconds = 0
   contains
      procedure :: prepare
      procedure :: init
      procedure :: assemble
      procedure :: solve
      procedure :: velocity_at
      procedure :: section_double_layer
      procedure :: poiseuille_rhs
   end type wall_operator_t

   interface
      integer(c_int) function c_getpid() bind(c, name='getpid')
         import :: c_int
      end function c_getpid
   end interface

contains

   !> Corner map of a tube rim node at x: disk-side traction = M cylinder-side traction (+ c).
   pure function corner_map(x) result(m)
      real(dp), intent(in) :: x(3)
      real(dp) :: m(3, 3)
      m = face_map([x(1), x(2), 0.0_dp] / norm2(x(1:2)), [0.0_dp, 0.0_dp, sign(1.0_dp, x(3))])
   end function corner_map

   !> Corner map of slot r: from the node's own face (its side wall's: only side-wall and rim
   !> nodes have slots) to the slot's face.
   pure function slot_corner_map(self, wall, r) result(m)
      class(wall_operator_t), intent(in) :: self
      class(tube_wall_t), intent(in) :: wall
      integer, intent(in) :: r
      real(dp) :: m(3, 3)
      m = face_map(wall%side_normal(wall%x(:, self%rim_node(r))), self%slot_face(:, r))
   end function slot_corner_map

   !> Map of the traction across a turn of the wall's normal from n_own to n_face:
   !> M = I + (n_face - n_own) n_own^T (so -p n_own goes to -p n_face).
   pure function face_map(n_own, n_face) result(m)
      real(dp), intent(in) :: n_own(3), n_face(3)
      real(dp) :: m(3, 3)
      integer :: a
      do a = 1, 3
         m(:, a) = (n_face - n_own) * n_own(a)
         m(a, a) = m(a, a) + 1.0_dp
      end do
   end function face_map

   !> Rim jumps c_k of the Poiseuille data (zero off the rims). In the tube the strain at the
   !> rim is e_rz = e_zr = -2, so c = 2 e . (n_d - e_r) = +4 e_r + 4 e_z (entry), -4 e_r + 4 e_z
   !> (exit). In general, with v = u e_z and g = grad u: e = (g e_z^T + e_z g^T) / 2 and
   !> c = 2 (e - e_ss I) . (n_d - n_s), e_ss = n_s . e . n_s (zero: g . e_z = 0 = n_s . e_z).
   pure subroutine poiseuille_rim_jump(wall, c)
      class(tube_wall_t), intent(in) :: wall
      real(dp), intent(out) :: c(:, :)
      integer :: k
      real(dp) :: er(3), g(3), jump(3)
      c = 0.0_dp
      do k = 1, wall%mesh%n_nodes
         if (wall%tag(k) /= wall_tag_rim) cycle
         select type (wall)
         type is (tube_wall_t)
            er = [wall%x(1, k), wall%x(2, k), 0.0_dp] / norm2(wall%x(1:2, k))
            c(:, k) = -sign(4.0_dp, wall%x(3, k)) * er + [0.0_dp, 0.0_dp, 4.0_dp]
         class default
            g = wall%undisturbed_gradient(wall%x(:, k))
            jump = [0.0_dp, 0.0_dp, sign(1.0_dp, wall%x(3, k))] - wall%side_normal(wall%x(:, k))
            ! e . d = (g (e_z . d) + e_z (g . d)) / 2.
            c(:, k) = g * jump(3) + [0.0_dp, 0.0_dp, dot_product(g, jump)]
         end select
      end do
   end subroutine poiseuille_rim_jump

   !> Options and the fixed geometry of the wall (no matrix): enough for assemble,
   !> velocity_at and section_double_layer.
   subroutine prepare(self, wall, stat, errmsg, duffy_order, pressure_gauge)
      class(wall_operator_t), intent(inout) :: self
      class(tube_wall_t), intent(in) :: wall
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer, intent(in), optional :: duffy_order
      logical, intent(in), optional :: pressure_gauge
      integer :: n, t, m, k, r, j
      real(dp) :: e(3), v3(3, 3), side(3), half_z, n_own(3), n_face(3)
      integer, allocatable :: slot_of(:, :), renumber(:)
      real(dp), allocatable :: slot_normal(:, :)

      stat = 0
      errmsg = ''
      self%duffy_order = default_duffy_order
      self%pressure_gauge = .true.
      if (present(duffy_order)) self%duffy_order = duffy_order
      if (present(pressure_gauge)) self%pressure_gauge = pressure_gauge
      if (self%duffy_order < 1 .or. self%duffy_order > 16) then
         stat = 1
         errmsg = 'wall single layer: duffy_order must be in 1..16'
         return
      end if
      n = wall%mesh%n_nodes
      if (n < 4 .or. 3 * n > max_order) then
         stat = 1
         errmsg = 'wall single layer: the wall mesh must have between 4 and 13333 nodes'
         return
      end if
      self%n_nodes = n
      if (allocated(self%rim_node)) then
         deallocate (self%rim_node, self%tri_slot, self%node_slots, self%slot_face, self%slot_area)
         deallocate (self%area_main, self%flux_weight, self%node_normal)
         deallocate (self%tri_area, self%tri_normal, self%tri_centroid, self%tri_diameter, self%disk_tri)
         deallocate (self%xs, self%ys, self%zs, self%qx, self%qy, self%qz, self%f_disk, self%quad_point, self%quad_weight)
         deallocate (self%tri_traction, self%quad_strength, self%vertex_strength)
         deallocate (self%tri_corner)
      end if
      if (allocated(self%lu)) deallocate (self%lu, self%ipiv, self%rim_disk)
      allocate (self%area_main(n))
      allocate (self%flux_weight(3, n), self%node_normal(3, n))
      allocate (self%tri_area(wall%mesh%n_tri), self%tri_normal(3, wall%mesh%n_tri), self%tri_centroid(3, wall%mesh%n_tri))
      allocate (self%tri_diameter(wall%mesh%n_tri), self%disk_tri(wall%mesh%n_tri))
      allocate (self%xs(n), self%ys(n), self%zs(n), self%qx(n), self%qy(n), self%qz(n))
      self%leaf_rule = dunavant7_rule(0)
      do m = 1, 3
         self%duffy(m) = duffy_rule(self%duffy_order, m)
      end do
      allocate (self%quad_point(3, size(self%leaf_rule%weight), wall%mesh%n_tri))
      allocate (self%quad_weight(size(self%leaf_rule%weight), wall%mesh%n_tri))
      allocate (self%tri_traction(3, 3, wall%mesh%n_tri), self%vertex_strength(3, 3, wall%mesh%n_tri))
      allocate (self%tri_corner(3, 3, wall%mesh%n_tri))
      allocate (self%quad_strength(3, size(self%leaf_rule%weight), wall%mesh%n_tri))
      call triangle_areas(wall%mesh, wall%x, self%tri_area)
      self%total_area = sum(self%tri_area)
      half_z = 0.5_dp * wall%length
      ! Slots: a triangle vertex whose face normal differs from the node's own (its side
      ! wall's; the section's inside a section) gets the slot of that face.
      allocate (self%tri_slot(3, wall%mesh%n_tri), slot_of(max_slots, n), slot_normal(3, max_slots * n))
      slot_of = 0
      r = 0
      do t = 1, wall%mesh%n_tri
         v3 = wall%x(:, wall%mesh%tri(:, t))
         self%disk_tri(t) = all(abs(abs(v3(3, :)) - half_z) <= 1.0e-12_dp)
         do m = 1, 3
            k = wall%mesh%tri(m, t)
            n_own = own_normal(k)
            if (self%disk_tri(t)) then
               n_face = [0.0_dp, 0.0_dp, sign(1.0_dp, wall%x(3, k))]
            else
               n_face = wall%side_face_normal(wall%x(:, k), sum(v3, dim=2) / 3.0_dp)
            end if
            self%tri_slot(m, t) = 0
            if (all(n_face == n_own)) cycle
            do j = 1, max_slots
               if (slot_of(j, k) == 0) then
                  r = r + 1
                  slot_of(j, k) = r
                  slot_normal(:, r) = n_face
               end if
               if (all(slot_normal(:, slot_of(j, k)) == n_face)) exit
            end do
            if (j > max_slots) then
               stat = 1
               errmsg = 'wall single layer: a wall node lies on more than 5 faces'
               return
            end if
            self%tri_slot(m, t) = slot_of(j, k)
         end do
      end do
      ! Slots in node order.
      self%n_rim = r
      allocate (self%rim_node(r), self%slot_face(3, r), self%slot_area(r), self%node_slots(max_slots, n))
      allocate (self%f_disk(3, r), renumber(r))
      r = 0
      self%node_slots = 0
      do k = 1, n
         do j = 1, max_slots
            if (slot_of(j, k) == 0) exit
            r = r + 1
            renumber(slot_of(j, k)) = r
            self%rim_node(r) = k
            self%node_slots(j, k) = r
            self%slot_face(:, r) = slot_normal(:, slot_of(j, k))
         end do
      end do
      do t = 1, wall%mesh%n_tri
         do m = 1, 3
            if (self%tri_slot(m, t) > 0) self%tri_slot(m, t) = renumber(self%tri_slot(m, t))
         end do
      end do
      self%area_main = 0.0_dp
      self%slot_area = 0.0_dp
      self%flux_weight = 0.0_dp
      self%node_normal = 0.0_dp
      do t = 1, wall%mesh%n_tri
         v3 = wall%x(:, wall%mesh%tri(:, t))
         e = cross(v3(:, 2) - v3(:, 1), v3(:, 3) - v3(:, 1))
         self%tri_normal(:, t) = e / norm2(e)
         self%tri_centroid(:, t) = sum(v3, dim=2) / 3.0_dp
         self%tri_corner(:, :, t) = v3
         self%tri_diameter(t) = max(norm2(v3(:, 2) - v3(:, 1)), norm2(v3(:, 3) - v3(:, 2)), norm2(v3(:, 1) - v3(:, 3)))
         self%quad_point(:, :, t) = matmul(v3, self%leaf_rule%bary)
         self%quad_weight(:, t) = self%tri_area(t) * self%leaf_rule%weight
         do m = 1, 3
            k = wall%mesh%tri(m, t)
            side = e / 6.0_dp
            r = self%tri_slot(m, t)
            if (r > 0) then
               self%slot_area(r) = self%slot_area(r) + self%tri_area(t) / 3.0_dp
               self%flux_weight(:, k) = self%flux_weight(:, k) + matmul(side, slot_corner_map(self, wall, r))
            else
               self%area_main(k) = self%area_main(k) + self%tri_area(t) / 3.0_dp
               self%flux_weight(:, k) = self%flux_weight(:, k) + side
               self%node_normal(:, k) = self%node_normal(:, k) + side
            end if
         end do
      end do
      do k = 1, n
         self%node_normal(:, k) = self%node_normal(:, k) / norm2(self%node_normal(:, k))
      end do
      self%xs = wall%x(1, 1:n)
      self%ys = wall%x(2, 1:n)
      self%zs = wall%x(3, 1:n)
      self%max_diameter = maxval(self%tri_diameter)
      self%cells_radius = -1
   contains
      !> The node's own normal: its section's inside a section, its side wall's otherwise.
      pure function own_normal(node) result(nrm)
         integer, intent(in) :: node
         real(dp) :: nrm(3)
         if (wall%tag(node) == wall_tag_inlet .or. wall%tag(node) == wall_tag_outlet) then
            nrm = [0.0_dp, 0.0_dp, sign(1.0_dp, wall%x(3, node))]
         else
            nrm = wall%side_normal(wall%x(:, node))
         end if
      end function own_normal
   end subroutine prepare

   !> Index the triangles for the near-field search of velocity_at at the current mid_radius:
   !> cells of half the reach (a point then visits a few cells per direction).
   subroutine index_triangles(self)
      class(wall_operator_t), intent(inout) :: self
      self%cells_radius = self%mid_radius
      call self%cells%build(self%tri_centroid, self%tri_diameter, self%mid_radius, leaf_ratio, &
                            max(0.5_dp * min(self%mid_radius, 10.0_dp), self%max_diameter))
   end subroutine index_triangles

   !> prepare, then the factorised wall matrix: read from `cache_dir` when a file with the
   !> same signature is there, otherwise assembled, factorised and written there (to a
   !> temporary name, then renamed). cache_dir = '' disables the cache. A cache that cannot
   !> be written is not an error (the operator is complete); cache_message says why.
   subroutine init(self, wall, cache_dir, stat, errmsg, duffy_order, pressure_gauge)
      class(wall_operator_t), intent(inout) :: self
      class(tube_wall_t), intent(in) :: wall
      character(len=*), intent(in) :: cache_dir
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer, intent(in), optional :: duffy_order
      logical, intent(in), optional :: pressure_gauge

      integer :: n3, info
      real(dp) :: anorm, t0
      real(dp), allocatable :: work(:)
      integer, allocatable :: iwork(:)
      character(len=:), allocatable :: signature
      logical :: loaded

      call self%prepare(wall, stat, errmsg, duffy_order, pressure_gauge)
      if (stat /= 0) return
      n3 = 3 * self%n_nodes
      allocate (self%lu(n3, n3), self%ipiv(n3), self%rim_disk(3 * self%n_rim, n3))
      signature = cache_signature(self, wall)
      self%from_cache = .false.
      self%cache_message = 'cache disabled'
      self%cache_file = ''
      self%assembly_seconds = 0
      self%factor_seconds = 0
      self%cache_seconds = 0
      if (len_trim(cache_dir) > 0) then
         self%cache_file = trim(cache_dir)//'/tube_wall_'//hex32(fnv1a32(signature))//'.lu'
         t0 = omp_get_wtime()
         call read_cache(self, signature, loaded)
         if (loaded) then
            self%from_cache = .true.
            self%cache_seconds = omp_get_wtime() - t0
            self%cache_message = 'loaded '//self%cache_file
            return
         end if
      end if

      t0 = omp_get_wtime()
      call self%assemble(wall, self%lu, self%rim_disk)
      if (self%pressure_gauge) call add_pressure_gauge(self)
      self%assembly_seconds = omp_get_wtime() - t0
      t0 = omp_get_wtime()
      anorm = infinity_norm(self%lu)
      call dgetrf(n3, n3, self%lu, n3, self%ipiv, info)
      if (info /= 0) then
         stat = 2
         errmsg = 'wall single layer: the wall matrix is singular (dgetrf)'
         return
      end if
      allocate (work(4 * n3), iwork(n3))
      call dgecon('I', n3, self%lu, n3, anorm, self%rcond, work, iwork, info)
      self%factor_seconds = omp_get_wtime() - t0
      if (len_trim(cache_dir) > 0) then
         t0 = omp_get_wtime()
         call write_cache(self, signature)
         self%cache_seconds = omp_get_wtime() - t0
      end if
   end subroutine init

   !> Largest absolute row sum (the infinity norm of the stored A^T, i.e. the 1-norm of A).
   pure real(dp) function infinity_norm(a)
      real(dp), intent(in) :: a(:, :)
      real(dp) :: row_sum(size(a, 1))
      integer :: j
      row_sum = 0.0_dp
      do j = 1, size(a, 2)
         row_sum = row_sum + abs(a(:, j))
      end do
      infinity_norm = maxval(row_sum)
   end function infinity_norm

   !> Wall traction f_wall (3, n) (cylinder-side values at the rims) whose single layer is
   !> u_wall (3, n) at the wall nodes. Per-step routine: no allocation.
   subroutine solve(self, u_wall, f_wall, stat, errmsg)
      class(wall_operator_t), intent(in) :: self
      real(dp), intent(in) :: u_wall(3, self%n_nodes)
      real(dp), intent(out) :: f_wall(3, self%n_nodes)
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: info
      stat = 0
      if (.not. allocated(self%lu)) then
         stat = 1
         errmsg = 'wall single layer: solve called before init'
         return
      end if
      f_wall = u_wall
      call dgetrs('T', 3 * self%n_nodes, 1, self%lu, 3 * self%n_nodes, self%ipiv, f_wall, 3 * self%n_nodes, info)
      if (info /= 0) then
         stat = 2
         errmsg = 'wall single layer: dgetrs failed'
      end if
   end subroutine solve

   !> Transpose of the wall single-layer matrix (1/(8 pi) included, corner map included, no
   !> gauge): at(3(j-1)+b, 3(i-1)+a) = d u_a(x_i) / d f_b(x_j); and rim_disk (3 n_rim, 3 n),
   !> the disk-side blocks of the rim nodes before the corner map.
   !> Quadrature for each (target node, triangle): the Duffy rule when the node is a vertex of
   !> the triangle, otherwise the 7-point rule, on recursive subdivisions while the triangle is
   !> within leaf_ratio diameters. Not the vertex rule of stokes_single_layer: summed over the
   !> mid-field its error is O(h |f|), amplified here by the large end pressures (Poiseuille
   !> check at h = 0.28, L = 4: 11 % error with it, 0.8 % without).
   subroutine assemble(self, wall, at, rim_disk)
      class(wall_operator_t), intent(in) :: self
      class(tube_wall_t), intent(in) :: wall
      real(dp), intent(out) :: at(:, :), rim_disk(:, :)
      real(dp), allocatable :: dbuf(:, :)
      integer :: n, i, t, m, corner, v(3), r, k
      real(dp) :: xi(3), scale

      n = self%n_nodes
      scale = 1.0_dp / (8.0_dp * pi)
      !$omp parallel default(none) shared(self, wall, at, rim_disk, n, scale) private(i, t, m, corner, v, xi, r, k, dbuf)
      allocate (dbuf(3 * self%n_rim, 3))
      !$omp do schedule(dynamic, 8)
      do i = 1, n
         xi = wall%x(:, i)
         at(:, 3 * i - 2:3 * i) = 0.0_dp
         dbuf = 0.0_dp
         do t = 1, wall%mesh%n_tri
            v = wall%mesh%tri(:, t)
            corner = 0
            do m = 1, 3
               if (v(m) == i) corner = m
            end do
            if (corner > 0) then
               call add_rule(self%duffy(corner), xi, wall%x(:, v), self%tri_area(t), v, .true., &
                             self%tri_slot(:, t), at(:, 3 * i - 2:3 * i), dbuf)
            else if (norm2(xi - self%tri_centroid(:, t)) > leaf_ratio * self%tri_diameter(t)) then
               call add_far_triangle(self%quad_point(:, :, t), self%quad_weight(:, t), self%leaf_rule%bary, xi, v, &
                                     .true., self%tri_slot(:, t), at(:, 3 * i - 2:3 * i), dbuf)
            else
               call add_adaptive_blocks(self%leaf_rule, xi, wall%x(:, v), self%tri_area(t), v, .true., &
                                        self%tri_slot(:, t), at(:, 3 * i - 2:3 * i), dbuf, identity_corners(), 0)
            end if
         end do
         ! The mapped faces' side of the slots through their maps: A_ik += D_ik M_k.
         do r = 1, self%n_rim
            k = self%rim_node(r)
            at(3 * k - 2:3 * k, 3 * i - 2:3 * i) = at(3 * k - 2:3 * k, 3 * i - 2:3 * i) &
                                                   + matmul(transpose(slot_corner_map(self, wall, r)), dbuf(3 * r - 2:3 * r, :))
         end do
         at(:, 3 * i - 2:3 * i) = scale * at(:, 3 * i - 2:3 * i)
         rim_disk(:, 3 * i - 2:3 * i) = scale * dbuf
      end do
      !$omp end do
      deallocate (dbuf)
      !$omp end parallel
   end subroutine assemble

   !> Add a (transposed) 3x3 block of source node k: to the disk-side buffer when it comes from
   !> a disk triangle at a rim node (rim slot r > 0), to the matrix column otherwise.
   pure subroutine add_block(disk, r, k, blk, col, dbuf)
      logical, intent(in) :: disk
      integer, intent(in) :: r, k
      real(dp), intent(in) :: blk(3, 3)
      real(dp), intent(inout) :: col(:, :), dbuf(:, :)
      if (disk .and. r > 0) then
         dbuf(3 * r - 2:3 * r, :) = dbuf(3 * r - 2:3 * r, :) + blk
      else
         col(3 * k - 2:3 * k, :) = col(3 * k - 2:3 * k, :) + blk
      end if
   end subroutine add_block

   !> The rule's integral of J(xt - y) times the hat function of each vertex, area included.
   pure subroutine add_rule(rule, xt, xv, area, v, disk, rim_slot, col, dbuf)
      type(quadrature_rule_t), intent(in) :: rule
      real(dp), intent(in) :: xt(3), xv(3, 3), area
      integer, intent(in) :: v(3), rim_slot(3)
      logical, intent(in) :: disk
      real(dp), intent(inout) :: col(:, :), dbuf(:, :)
      integer :: q, m
      real(dp) :: blk(3, 3)
      do q = 1, size(rule%weight)
         blk = (area * rule%weight(q)) * stokeslet_block(xt - matmul(xv, rule%bary(:, q)))
         do m = 1, 3
            call add_block(disk, rim_slot(m), v(m), rule%bary(m, q) * blk, col, dbuf)
         end do
      end do
   end subroutine add_rule

   !> add_rule for a far triangle, with its quadrature points and weights (area included)
   !> computed once in prepare; the hot loop of the assembly, written on the 6 distinct
   !> entries of the symmetric J.
   pure subroutine add_far_triangle(points, weights, bary, xt, v, disk, rim_slot, col, dbuf)
      real(dp), intent(in) :: points(:, :), weights(:), bary(:, :), xt(3)
      integer, intent(in) :: v(3), rim_slot(3)
      logical, intent(in) :: disk
      real(dp), intent(inout) :: col(:, :), dbuf(:, :)
      real(dp) :: acc(6, 3), j6(6), dx, dy, dz, rinv, rinv3
      integer :: q, m
      acc = 0.0_dp
      do q = 1, size(weights)
         dx = xt(1) - points(1, q)
         dy = xt(2) - points(2, q)
         dz = xt(3) - points(3, q)
         rinv = 1.0_dp / sqrt(dx * dx + dy * dy + dz * dz)
         rinv3 = weights(q) * rinv**3
         rinv = weights(q) * rinv
         j6 = [rinv + dx * dx * rinv3, rinv + dy * dy * rinv3, rinv + dz * dz * rinv3, &
               dx * dy * rinv3, dx * dz * rinv3, dy * dz * rinv3]
         do m = 1, 3
            acc(:, m) = acc(:, m) + bary(m, q) * j6
         end do
      end do
      do m = 1, 3
         call add_block(disk, rim_slot(m), v(m), reshape([acc(1, m), acc(4, m), acc(5, m), acc(4, m), acc(2, m), &
                                                          acc(6, m), acc(5, m), acc(6, m), acc(3, m)], [3, 3]), col, dbuf)
      end do
   end subroutine add_far_triangle

   !> add_rule with the 7-point rule on recursive subdivisions (barycentric corners b) until
   !> each piece is more than leaf_ratio of its diameters from xt.
   pure recursive subroutine add_adaptive_blocks(rule, xt, xv, area, v, disk, rim_slot, col, dbuf, b, depth)
      type(quadrature_rule_t), intent(in) :: rule
      real(dp), intent(in) :: xt(3), xv(3, 3), area, b(3, 3)
      integer, intent(in) :: v(3), rim_slot(3), depth
      logical, intent(in) :: disk
      real(dp), intent(inout) :: col(:, :), dbuf(:, :)
      real(dp) :: c(3, 3), bm(3, 3), bb(3), diam, blk(3, 3)
      integer :: q, m
      c = matmul(xv, b)
      diam = max(norm2(c(:, 2) - c(:, 1)), norm2(c(:, 3) - c(:, 2)), norm2(c(:, 1) - c(:, 3)))
      if (depth >= max_depth .or. norm2(xt - sum(c, dim=2) / 3.0_dp) > leaf_ratio * diam) then
         do q = 1, size(rule%weight)
            bb = matmul(b, rule%bary(:, q))
            blk = (area * rule%weight(q) / 4.0_dp**depth) * stokeslet_block(xt - matmul(xv, bb))
            do m = 1, 3
               call add_block(disk, rim_slot(m), v(m), bb(m) * blk, col, dbuf)
            end do
         end do
      else
         bm(:, 1) = 0.5_dp * (b(:, 1) + b(:, 2))
         bm(:, 2) = 0.5_dp * (b(:, 2) + b(:, 3))
         bm(:, 3) = 0.5_dp * (b(:, 3) + b(:, 1))
         call add_adaptive_blocks(rule, xt, xv, area, v, disk, rim_slot, col, dbuf, &
                                  reshape([b(:, 1), bm(:, 1), bm(:, 3)], [3, 3]), depth + 1)
         call add_adaptive_blocks(rule, xt, xv, area, v, disk, rim_slot, col, dbuf, &
                                  reshape([bm(:, 1), b(:, 2), bm(:, 2)], [3, 3]), depth + 1)
         call add_adaptive_blocks(rule, xt, xv, area, v, disk, rim_slot, col, dbuf, &
                                  reshape([bm(:, 3), bm(:, 2), b(:, 3)], [3, 3]), depth + 1)
         call add_adaptive_blocks(rule, xt, xv, area, v, disk, rim_slot, col, dbuf, bm, depth + 1)
      end if
   end subroutine add_adaptive_blocks

   !> J(r) . g
   pure function stokeslet(r, g) result(w)
      real(dp), intent(in) :: r(3), g(3)
      real(dp) :: w(3), rinv
      rinv = 1.0_dp / sqrt(r(1)**2 + r(2)**2 + r(3)**2)
      w = rinv * g + r * ((r(1) * g(1) + r(2) * g(2) + r(3) * g(3)) * rinv**3)
   end function stokeslet

   !> The rank-one pressure gauge (1/|B|) nhat a^T, added to the transposed matrix.
   subroutine add_pressure_gauge(self)
      class(wall_operator_t), intent(inout) :: self
      integer :: i, j, a
      !$omp parallel do default(none) shared(self) private(i, j, a) schedule(static)
      do i = 1, self%n_nodes
         do a = 1, 3
            do j = 1, self%n_nodes
               self%lu(3 * j - 2:3 * j, 3 * i - 3 + a) = self%lu(3 * j - 2:3 * j, 3 * i - 3 + a) &
                                                         + self%flux_weight(:, j) * (self%node_normal(a, i) / self%total_area)
            end do
         end do
      end do
      !$omp end parallel do
   end subroutine add_pressure_gauge

   !> u(:, k) = 1/(8 pi) int_B J(p_k - y) . f(y) dS for points p_k off the wall, for the P1
   !> traction f_wall (cylinder-side values at the rims; disk side M_k f_k + rim_jump_k, the
   !> jump being zero when absent). Vertex rule (one Stokeslet per node) beyond mid_radius,
   !> the 7-point rule within it, subdivided within leaf_ratio diameters.
   !> Per-step routine: no allocation (work arrays of self). The traction-dependent
   !> quadrature data (7-point and vertex strengths per triangle) are computed once per call,
   !> not once per point; points farther than the reach of any correction from the cylinder
   !> and the disks skip the triangle search, the others find their near triangles through
   !> the cell index (triangle_cells; the first call, or a changed mid_radius, builds it).
   subroutine velocity_at(self, wall, f_wall, points, u, rim_jump)
      class(wall_operator_t), intent(inout) :: self
      class(tube_wall_t), intent(in) :: wall
      real(dp), intent(in) :: f_wall(:, :), points(:, :)
      real(dp), intent(out) :: u(:, :)
      real(dp), intent(in), optional :: rim_jump(:, :)
      integer :: k, n, t, m, r
      real(dp) :: acc(3), p(3), g(3), reach, clearance

      n = self%n_nodes
      do r = 1, self%n_rim
         k = self%rim_node(r)
         self%f_disk(:, r) = matmul(slot_corner_map(self, wall, r), f_wall(:, k))
         if (present(rim_jump)) self%f_disk(:, r) = self%f_disk(:, r) + rim_jump(:, k)
      end do
      do k = 1, n
         g = self%area_main(k) * f_wall(:, k)
         do r = 1, max_slots
            if (self%node_slots(r, k) == 0) exit
            g = g + self%slot_area(self%node_slots(r, k)) * self%f_disk(:, self%node_slots(r, k))
         end do
         self%qx(k) = g(1)
         self%qy(k) = g(2)
         self%qz(k) = g(3)
      end do
      !$omp parallel do default(none) shared(self, wall, f_wall) private(t, m, r) schedule(static)
      do t = 1, size(self%tri_area)
         do m = 1, 3
            self%tri_traction(:, m, t) = f_wall(:, wall%mesh%tri(m, t))
            r = self%tri_slot(m, t)
            if (r > 0) self%tri_traction(:, m, t) = self%f_disk(:, r)
         end do
         call leaf_strengths(self%leaf_rule, self%tri_area(t), self%tri_traction(:, :, t), self%quad_strength(:, :, t), &
                             self%vertex_strength(:, :, t))
      end do
      !$omp end parallel do
      if (self%cells_radius /= self%mid_radius) call index_triangles(self)
      ! No triangle farther than `reach` needs more than the vertex rule.
      reach = self%cells%max_reach
      !$omp parallel do default(none) shared(self, points, u, n, reach, wall) &
      !$omp private(k, p, acc, clearance) schedule(dynamic, 4)
      do k = 1, size(points, 2)
         p = points(:, k)
         acc = 0.0_dp
         call add_stokeslets(n, self%xs, self%ys, self%zs, self%qx, self%qy, self%qz, p, 1, n, acc)
         ! Distance to the nearest triangle centroid is at least this (centroids lie within a
         ! diameter of the surface).
         clearance = min(wall%side_clearance(p), 0.5_dp * wall%length - abs(p(3))) - self%max_diameter
         if (clearance < reach) acc = acc + near_corrections(self, p)
         u(:, k) = acc / (8.0_dp * pi)
      end do
      !$omp end parallel do
   end subroutine velocity_at

   !> Sum of triangle_correction over the wall triangles that need more than the vertex rule
   !> at p (found by the cell index).
   function near_corrections(self, p) result(corr)
      class(wall_operator_t), intent(in) :: self
      real(dp), intent(in) :: p(3)
      real(dp) :: corr(3)
      integer :: list(self%cells%n_tri), m, j, t
      real(dp) :: dist(self%cells%n_tri)
      call self%cells%near(p, list, dist, m)
      corr = 0.0_dp
      do j = 1, m
         t = list(j)
         corr = corr + triangle_correction(self%leaf_rule, p, dist(j), self%tri_diameter(t), self%tri_area(t), &
                                           self%tri_corner(:, :, t), self%tri_traction(:, :, t), self%quad_point(:, :, t), &
                                           self%quad_strength(:, :, t), self%vertex_strength(:, :, t))
      end do
   end function near_corrections

   !> What replaces the vertex rule of one P1 triangle (corners xv, densities fv) at an
   !> off-surface point p at distance `dist` from its centroid, where the vertex rule is not
   !> good enough (nearer than mid_radius or leaf_ratio diameters: the caller's test), without
   !> 1/(8 pi): beyond leaf_ratio diameters its 7-point rule (points qp, strengths qs, from
   !> leaf_strengths) minus its vertex rule (strengths vs); nearer, the subdivided 7-point
   !> rule minus the vertex rule (near_triangle_correction).
   pure function triangle_correction(rule, p, dist, diameter, area, xv, fv, qp, qs, vs) result(corr)
      type(quadrature_rule_t), intent(in) :: rule
      real(dp), intent(in) :: p(3), dist, diameter, area, xv(3, 3), fv(3, 3), qp(:, :), qs(:, :), vs(3, 3)
      real(dp) :: corr(3)
      if (dist > leaf_ratio * diameter) then
         corr = leaf_correction(p, qp, qs, xv, vs)
      else
         corr = near_triangle_correction(rule, p, xv, fv, area)
      end if
   end function triangle_correction

   !> Strengths of one P1 triangle's rules (density fv at the corners): qs(:, q) = weight_q x
   !> area x density at point q of the rule, vs(:, m) = area/3 x density at corner m (vertex rule).
   pure subroutine leaf_strengths(rule, area, fv, qs, vs)
      type(quadrature_rule_t), intent(in) :: rule
      real(dp), intent(in) :: area, fv(3, 3)
      real(dp), intent(out) :: qs(:, :), vs(3, 3)
      integer :: q
      do q = 1, size(rule%weight)
         qs(:, q) = (area * rule%weight(q)) * (rule%bary(1, q) * fv(:, 1) + rule%bary(2, q) * fv(:, 2) &
                                               + rule%bary(3, q) * fv(:, 3))
      end do
      vs = (area / 3.0_dp) * fv
   end subroutine leaf_strengths

   !> Stokeslets of strengths qs at points qp, summed at p, without 1/(8 pi). Inline (no call
   !> per point, no norm2 scaling): the hot loop of the off-surface single layers and of the
   !> membrane's near self term once the near triangles are found by cells.
   pure function point_sum(p, qp, qs) result(acc)
      real(dp), intent(in) :: p(3), qp(:, :), qs(:, :)
      real(dp) :: acc(3), r(3), rinv, proj
      integer :: q
      acc = 0.0_dp
      do q = 1, size(qp, 2)
         r = p - qp(:, q)
         rinv = 1.0_dp / sqrt(r(1) * r(1) + r(2) * r(2) + r(3) * r(3))
         proj = (r(1) * qs(1, q) + r(2) * qs(2, q) + r(3) * qs(3, q)) * rinv**3
         acc = acc + rinv * qs(:, q) + proj * r
      end do
   end function point_sum

   !> One triangle's 7-point rule (points qp, strengths qs) minus its vertex rule (corners xv,
   !> strengths vs) at p, without 1/(8 pi): added to the one-Stokeslet-per-node sum, it
   !> replaces the vertex rule by the 7-point rule on a triangle beyond leaf_ratio diameters.
   pure function leaf_correction(p, qp, qs, xv, vs) result(corr)
      real(dp), intent(in) :: p(3), qp(:, :), qs(:, :), xv(3, 3), vs(3, 3)
      real(dp) :: corr(3)
      integer :: q
      real(dp) :: r(3), rinv, proj
      corr = point_sum(p, qp, qs)
      do q = 1, 3
         r = p - xv(:, q)
         rinv = 1.0_dp / sqrt(r(1) * r(1) + r(2) * r(2) + r(3) * r(3))
         proj = (r(1) * vs(1, q) + r(2) * vs(2, q) + r(3) * vs(3, q)) * rinv**3
         corr = corr - (rinv * vs(:, q) + proj * r)
      end do
   end function leaf_correction

   !> Off-surface single layer of one P1 triangle (vertices xv, nodal densities fv, area)
   !> at p, accurate minus vertex rule: the 7-point rule, subdivided within leaf_ratio
   !> diameters of p (adaptive_integral), minus the triangle's share of the one-Stokeslet-per-
   !> node sum. Added to that sum, it replaces the vertex rule on the triangle; without
   !> 1/(8 pi). For other surfaces near the wall (the capsule's single layer at wall nodes).
   pure function near_triangle_correction(rule, p, xv, fv, area) result(corr)
      type(quadrature_rule_t), intent(in) :: rule
      real(dp), intent(in) :: p(3), xv(3, 3), fv(3, 3), area
      real(dp) :: corr(3)
      integer :: m
      corr = subdivided_single_layer(rule, p, xv, fv, area, leaf_ratio)
      do m = 1, 3
         corr = corr - (area / 3.0_dp) * stokeslet(p - xv(:, m), fv(:, m))
      end do
   end function near_triangle_correction

   !> int over the triangle (corners xv, P1 densities fv, area) of J(p - y) . f(y) dS by
   !> `rule` on subdivisions into 4 until each piece's centroid lies `ratio` of its diameters
   !> from p (or max_depth is reached); without 1/(8 pi).
   pure function subdivided_single_layer(rule, p, xv, fv, area, ratio) result(corr)
      type(quadrature_rule_t), intent(in) :: rule
      real(dp), intent(in) :: p(3), xv(3, 3), fv(3, 3), area, ratio
      real(dp) :: corr(3)
      ! adaptive_integral's subdivision for the single layer, iterative on an explicit stack of
      ! sub-triangles held by their corners and corner densities (depth first: at most 3
      ! siblings wait per level): the recursive version, with its barycentric matrix
      ! products, took 2/3 of the per-step time of the 3D tube model.
      integer, parameter :: stack_size = 3 * max_depth + 1
      real(dp) :: sx(3, 3, stack_size), sf(3, 3, stack_size), c(3, 3), g(3, 3), mx(3, 3), mf(3, 3)
      real(dp) :: diam, w, r(3), fq(3), rinv
      integer :: depth(stack_size), top, d, q, m
      corr = 0.0_dp
      top = 1
      sx(:, :, 1) = xv
      sf(:, :, 1) = fv
      depth(1) = 0
      do while (top > 0)
         c = sx(:, :, top)
         g = sf(:, :, top)
         d = depth(top)
         top = top - 1
         diam = max(norm2(c(:, 2) - c(:, 1)), norm2(c(:, 3) - c(:, 2)), norm2(c(:, 1) - c(:, 3)))
         if (d >= max_depth .or. norm2(p - (c(:, 1) + c(:, 2) + c(:, 3)) / 3.0_dp) > ratio * diam) then
            w = area / 4.0_dp**d
            do q = 1, size(rule%weight)
               r = p - (rule%bary(1, q) * c(:, 1) + rule%bary(2, q) * c(:, 2) + rule%bary(3, q) * c(:, 3))
               fq = rule%bary(1, q) * g(:, 1) + rule%bary(2, q) * g(:, 2) + rule%bary(3, q) * g(:, 3)
               rinv = 1.0_dp / sqrt(r(1)**2 + r(2)**2 + r(3)**2)
               corr = corr + (w * rule%weight(q) * rinv) * (fq + r * ((r(1) * fq(1) + r(2) * fq(2) + r(3) * fq(3)) * rinv**2))
            end do
         else
            ! Midpoints of edges 12, 23, 31, then the four children as in adaptive_integral.
            do m = 1, 3
               mx(:, m) = 0.5_dp * (c(:, m) + c(:, mod(m, 3) + 1))
               mf(:, m) = 0.5_dp * (g(:, m) + g(:, mod(m, 3) + 1))
            end do
            sx(:, :, top + 1) = reshape([c(:, 1), mx(:, 1), mx(:, 3)], [3, 3])
            sf(:, :, top + 1) = reshape([g(:, 1), mf(:, 1), mf(:, 3)], [3, 3])
            sx(:, :, top + 2) = reshape([mx(:, 1), c(:, 2), mx(:, 2)], [3, 3])
            sf(:, :, top + 2) = reshape([mf(:, 1), g(:, 2), mf(:, 2)], [3, 3])
            sx(:, :, top + 3) = reshape([mx(:, 3), mx(:, 2), c(:, 3)], [3, 3])
            sf(:, :, top + 3) = reshape([mf(:, 3), mf(:, 2), g(:, 3)], [3, 3])
            sx(:, :, top + 4) = mx
            sf(:, :, top + 4) = mf
            depth(top + 1:top + 4) = d + 1
            top = top + 4
         end if
      end do
   end function subdivided_single_layer

   pure function identity_corners() result(b)
      real(dp) :: b(3, 3)
      b = reshape([1.0_dp, 0.0_dp, 0.0_dp, 0.0_dp, 1.0_dp, 0.0_dp, 0.0_dp, 0.0_dp, 1.0_dp], [3, 3])
   end function identity_corners

   !> (1/area) int over the sub-triangle with barycentric corners b (columns) of the triangle
   !> xv, by recursive subdivision into 4 near the target p. Kernels: the single layer
   !> J(p - y) . f(y) with P1 f from the vertex values fv; the Poiseuille double layer
   !> -6 (r . v) (r . n) r / |r|**5 with v = the wall's undisturbed velocity at y and n = fv(:, 1).
   pure recursive function adaptive_integral(wall, rule, kernel, p, xv, fv, b, depth) result(acc)
      class(tube_wall_t), intent(in) :: wall
      type(quadrature_rule_t), intent(in) :: rule
      integer, intent(in) :: kernel, depth
      real(dp), intent(in) :: p(3), xv(3, 3), fv(3, 3), b(3, 3)
      real(dp) :: acc(3)
      real(dp) :: c(3, 3), bm(3, 3), bb(3), r(3), g(3), rinv, diam
      integer :: q
      c = matmul(xv, b)
      diam = max(norm2(c(:, 2) - c(:, 1)), norm2(c(:, 3) - c(:, 2)), norm2(c(:, 1) - c(:, 3)))
      acc = 0.0_dp
      if (depth >= max_depth .or. norm2(p - sum(c, dim=2) / 3.0_dp) > leaf_ratio * diam) then
         do q = 1, size(rule%weight)
            bb = matmul(b, rule%bary(:, q))
            r = p - matmul(xv, bb)
            rinv = 1.0_dp / norm2(r)
            if (kernel == kernel_single_layer) then
               g = matmul(fv, bb)
               acc = acc + (rule%weight(q) * rinv) * (g + r * (dot_product(r, g) * rinv**2))
            else
               g = wall%undisturbed_velocity(matmul(xv, bb))
               acc = acc - (6.0_dp * rule%weight(q) * dot_product(r, g) * dot_product(r, fv(:, 1)) * rinv**5) * r
            end if
         end do
         acc = acc / 4.0_dp**depth
      else
         ! Midpoints of edges 12, 23, 31 (barycentric), then the four children.
         bm(:, 1) = 0.5_dp * (b(:, 1) + b(:, 2))
         bm(:, 2) = 0.5_dp * (b(:, 2) + b(:, 3))
         bm(:, 3) = 0.5_dp * (b(:, 3) + b(:, 1))
         acc = adaptive_integral(wall, rule, kernel, p, xv, fv, reshape([b(:, 1), bm(:, 1), bm(:, 3)], [3, 3]), depth + 1) &
               + adaptive_integral(wall, rule, kernel, p, xv, fv, reshape([bm(:, 1), b(:, 2), bm(:, 2)], [3, 3]), depth + 1) &
               + adaptive_integral(wall, rule, kernel, p, xv, fv, reshape([bm(:, 3), bm(:, 2), b(:, 3)], [3, 3]), depth + 1) &
               + adaptive_integral(wall, rule, kernel, p, xv, fv, bm, depth + 1)
      end if
   end function adaptive_integral

   !> Double layer of the Poiseuille data over the two disks,
   !> u_dl(:, k) = 1/(8 pi) int_{S_in + S_out} v_inf . T(p_k - y) . n dS, at points p_k inside
   !> the tube or on its wall. A disk whose plane contains p_k contributes exactly zero
   !> (r . n = 0) and is skipped; everything else is integrated adaptively (targets on the
   !> cylinder next to a rim are nearly singular).
   subroutine section_double_layer(self, wall, points, u_dl)
      class(wall_operator_t), intent(in) :: self
      class(tube_wall_t), intent(in) :: wall
      real(dp), intent(in) :: points(:, :)
      real(dp), intent(out) :: u_dl(:, :)
      integer :: k, t
      real(dp) :: acc(3), p(3), nv(3, 3), xv(3, 3)
      !$omp parallel do default(none) shared(self, wall, points, u_dl) private(k, t, acc, p, nv, xv) schedule(dynamic, 4)
      do k = 1, size(points, 2)
         p = points(:, k)
         acc = 0.0_dp
         do t = 1, wall%mesh%n_tri
            if (.not. self%disk_tri(t)) cycle
            xv = wall%x(:, wall%mesh%tri(:, t))
            if (abs(p(3) - xv(3, 1)) <= 1.0e-12_dp) cycle
            nv = 0.0_dp
            nv(:, 1) = self%tri_normal(:, t)
            acc = acc + self%tri_area(t) * adaptive_integral(wall, self%leaf_rule, kernel_double_layer, p, xv, nv, &
                                                             identity_corners(), 0)
         end do
         u_dl(:, k) = acc / (8.0_dp * pi)
      end do
      !$omp end parallel do
   end subroutine section_double_layer

   !> Right-hand side of the total-flow Poiseuille check at the wall nodes: (1/2) v_inf on
   !> disk-interior nodes (0 on the cylinder and the rims), minus the disks' double layer,
   !> minus the single layer of the rim jumps (poiseuille_rim_jump); solve() then returns the
   !> Poiseuille wall traction. Needs init (rim_disk).
   subroutine poiseuille_rhs(self, wall, rhs)
      class(wall_operator_t), intent(in) :: self
      class(tube_wall_t), intent(in) :: wall
      real(dp), intent(out) :: rhs(:, :)
      real(dp) :: jump(3, wall%mesh%n_nodes)
      integer :: i, r
      call self%section_double_layer(wall, wall%x, rhs)
      call poiseuille_rim_jump(wall, jump)
      do i = 1, wall%mesh%n_nodes
         rhs(:, i) = -rhs(:, i)
         if (wall%tag(i) == wall_tag_inlet .or. wall%tag(i) == wall_tag_outlet) &
            rhs(:, i) = rhs(:, i) + 0.5_dp * wall%undisturbed_velocity(wall%x(:, i))
         do r = 1, self%n_rim
            rhs(:, i) = rhs(:, i) - matmul(jump(:, self%rim_node(r)), self%rim_disk(3 * r - 2:3 * r, 3 * i - 2:3 * i))
         end do
      end do
   end subroutine poiseuille_rhs

   !> Everything the factorised matrix depends on; the cache file carries it and is used only
   !> when it matches exactly.
   function cache_signature(self, wall) result(signature)
      class(wall_operator_t), intent(in) :: self
      class(tube_wall_t), intent(in) :: wall
      character(len=:), allocatable :: signature
      character(len=400) :: buffer
      write (buffer, '(a,i0,4a,es24.16,a,es24.16,a,es24.16,a,es24.16,a,es24.16,a,i0,a,es24.16,a,l1,a,i0,a,i0)') &
         'capsmech tube wall LU format=', cache_format, ' code=', code_version, wall%geometry_signature(), &
         ' L=', wall%length, ' h_far=', wall%h_far, ' h_centre=', wall%h_centre, &
         ' centre_half_length=', centre_half_length, ' grading_length=', grading_length, &
         ' duffy=', self%duffy_order, ' leaf_ratio=', leaf_ratio, ' gauge=', self%pressure_gauge, &
         ' n_nodes=', wall%mesh%n_nodes, ' n_tri=', wall%mesh%n_tri
      signature = trim(buffer)
   end function cache_signature

   !> 32-bit FNV-1a hash of a string (in 64-bit arithmetic: no overflow).
   pure integer(int64) function fnv1a32(s) result(h)
      character(len=*), intent(in) :: s
      integer :: k
      h = 2166136261_int64
      do k = 1, len(s)
         h = ieor(h, int(ichar(s(k:k)), int64))
         h = modulo(h * 16777619_int64, 4294967296_int64)
      end do
   end function fnv1a32

   pure function hex32(h) result(s)
      integer(int64), intent(in) :: h
      character(len=8) :: s
      character(len=16), parameter :: digits = '0123456789abcdef'
      integer :: k
      integer(int64) :: rest
      rest = h
      do k = 8, 1, -1
         s(k:k) = digits(int(modulo(rest, 16_int64)) + 1:int(modulo(rest, 16_int64)) + 1)
         rest = rest / 16
      end do
   end function hex32

   !> Load the factorisation if the file exists, is complete, and has exactly our signature.
   subroutine read_cache(self, signature, loaded)
      class(wall_operator_t), intent(inout) :: self
      character(len=*), intent(in) :: signature
      logical, intent(out) :: loaded
      integer :: unit, ios, sig_len, n3
      character(len=16) :: magic, tail
      character(len=:), allocatable :: stored

      loaded = .false.
      open (newunit=unit, file=self%cache_file, access='stream', form='unformatted', status='old', &
            action='read', iostat=ios)
      if (ios /= 0) return
      read (unit, iostat=ios) magic, sig_len
      if (ios /= 0 .or. magic /= cache_magic .or. sig_len /= len(signature)) then
         close (unit)
         return
      end if
      allocate (character(len=sig_len) :: stored)
      read (unit, iostat=ios) stored, n3
      if (ios /= 0 .or. stored /= signature .or. n3 /= size(self%lu, 1)) then
         close (unit)
         return
      end if
      read (unit, iostat=ios) self%ipiv, self%lu, self%rim_disk, self%rcond, tail
      close (unit)
      loaded = ios == 0 .and. tail == cache_magic
   end subroutine read_cache

   !> Write the factorisation to a temporary name (unique per process), then rename it over
   !> the cache file: readers never see a partial file.
   subroutine write_cache(self, signature)
      class(wall_operator_t), intent(inout) :: self
      character(len=*), intent(in) :: signature
      integer :: unit, ios
      character(len=24) :: pid
      character(len=:), allocatable :: tmp, rename_msg
      write (pid, '(i0)') c_getpid()
      tmp = self%cache_file//'.tmp'//trim(pid)
      open (newunit=unit, file=tmp, access='stream', form='unformatted', status='replace', action='write', iostat=ios)
      if (ios /= 0) then
         self%cache_message = 'not written: cannot create '//tmp
         return
      end if
      write (unit, iostat=ios) cache_magic, len(signature), signature, size(self%lu, 1), self%ipiv, self%lu, &
         self%rim_disk, self%rcond, cache_magic
      if (ios /= 0) then
         close (unit, status='delete')
         self%cache_message = 'not written: write error on '//tmp
         return
      end if
      close (unit)
      call replace_file(tmp, self%cache_file, ios, rename_msg)
      if (ios /= 0) then
         self%cache_message = 'not written: '//rename_msg
         return
      end if
      self%cache_message = 'written '//self%cache_file
   end subroutine write_cache

end module wall_single_layer
