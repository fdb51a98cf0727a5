!> Triangulated closed surfaces: the icosahedral subdivision of the unit sphere and the
!> node-to-triangle adjacency that the quadrature and force assembly need.
!>
!> Level L has 10*4**L + 2 nodes and 20*4**L triangles (level 4: 2562 / 5120, the paper's
!> capsule mesh). Triangles are oriented counter-clockwise seen from outside, so that
!> (x2 - x1) x (x3 - x1) is the outward normal.
module sphere_mesh
   use capsim_kinds, only: dp
   use vector_algebra, only: cross
   implicit none
   private
   public :: surface_mesh_t, icosphere, mesh_nodes_at_level

   type :: surface_mesh_t
      integer :: n_nodes = 0
      integer :: n_tri = 0
      !> Vertex indices of each triangle (1-based).
      integer, allocatable :: tri(:, :)
      !> Triangles around each node (CSR): node_tri(node_tri_start(i) : node_tri_start(i+1)-1).
      integer, allocatable :: node_tri_start(:), node_tri(:)
      !> Position of the node inside each of those triangles (1, 2 or 3).
      integer, allocatable :: node_tri_vertex(:)
   contains
      procedure :: build_adjacency
   end type surface_mesh_t

contains

   pure integer function mesh_nodes_at_level(level)
      integer, intent(in) :: level
      mesh_nodes_at_level = 10 * 4**level + 2
   end function mesh_nodes_at_level

   !> Unit sphere by recursive 4-to-1 subdivision of the icosahedron, new nodes projected
   !> onto the sphere. Subdivision (rather than a geodesic parametrisation) keeps triangle
   !> sizes within a factor of about 1.3 of each other, which the explicit time step needs.
   subroutine icosphere(level, mesh, x, stat, errmsg)
      integer, intent(in) :: level
      type(surface_mesh_t), intent(out) :: mesh
      real(dp), allocatable, intent(out) :: x(:, :)
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg

      real(dp), parameter :: phi = (1.0_dp + sqrt(5.0_dp)) / 2.0_dp
      integer, allocatable :: tri_old(:, :), edge_mid(:, :), edge_nbr(:, :)
      integer :: l, n, nt, t, k, a, b, m, n_new, max_nodes
      integer :: mids(3)

      stat = 0
      if (level < 0 .or. level > 6) then
         stat = 1
         errmsg = 'mesh level must be between 0 and 6'
         return
      end if
      max_nodes = mesh_nodes_at_level(level)
      allocate (x(3, max_nodes))
      x(:, 1:12) = reshape([ &
                           -1.0_dp, phi, 0.0_dp, 1.0_dp, phi, 0.0_dp, -1.0_dp, -phi, 0.0_dp, 1.0_dp, -phi, 0.0_dp, &
                           0.0_dp, -1.0_dp, phi, 0.0_dp, 1.0_dp, phi, 0.0_dp, -1.0_dp, -phi, 0.0_dp, 1.0_dp, -phi, &
                           phi, 0.0_dp, -1.0_dp, phi, 0.0_dp, 1.0_dp, -phi, 0.0_dp, -1.0_dp, -phi, 0.0_dp, 1.0_dp], [3, 12])
      do k = 1, 12
         x(:, k) = x(:, k) / norm2(x(:, k))
      end do
      allocate (mesh%tri(3, 20))
      mesh%tri = reshape([1, 12, 6, 1, 6, 2, 1, 2, 8, 1, 8, 11, 1, 11, 12, &
                          2, 6, 10, 6, 12, 5, 12, 11, 3, 11, 8, 7, 8, 2, 9, &
                          4, 10, 5, 4, 5, 3, 4, 3, 7, 4, 7, 9, 4, 9, 10, &
                          5, 10, 6, 3, 5, 12, 7, 3, 11, 9, 7, 8, 10, 9, 2], [3, 20])
      n = 12
      nt = 20
      ! Orientation of the table above is fixed here rather than trusted.
      do t = 1, nt
         if (dot_product(cross(x(:, mesh%tri(2, t)) - x(:, mesh%tri(1, t)), &
                               x(:, mesh%tri(3, t)) - x(:, mesh%tri(1, t))), x(:, mesh%tri(1, t))) < 0) then
            mesh%tri(2:3, t) = mesh%tri([3, 2], t)
         end if
      end do

      do l = 1, level
         call move_alloc(mesh%tri, tri_old)
         allocate (mesh%tri(3, 4 * nt))
         ! Midpoint of edge (a, b) is remembered at the smaller index: at most 6 edges per node
         ! on an icosphere, so a fixed-width table replaces a hash map.
         allocate (edge_nbr(8, n), edge_mid(8, n))
         edge_nbr = 0
         edge_mid = 0
         n_new = n
         do t = 1, nt
            do k = 1, 3
               a = tri_old(k, t)
               b = tri_old(mod(k, 3) + 1, t)
               call midpoint_index(min(a, b), max(a, b), m)
               mids(k) = m
            end do
            mesh%tri(:, 4 * t - 3) = [tri_old(1, t), mids(1), mids(3)]
            mesh%tri(:, 4 * t - 2) = [mids(1), tri_old(2, t), mids(2)]
            mesh%tri(:, 4 * t - 1) = [mids(3), mids(2), tri_old(3, t)]
            mesh%tri(:, 4 * t) = [mids(1), mids(2), mids(3)]
         end do
         n = n_new
         nt = 4 * nt
         deallocate (tri_old, edge_nbr, edge_mid)
      end do
      mesh%n_nodes = n
      mesh%n_tri = nt
      call mesh%build_adjacency()

   contains

      subroutine midpoint_index(lo, hi, mid)
         integer, intent(in) :: lo, hi
         integer, intent(out) :: mid
         integer :: s
         do s = 1, size(edge_nbr, 1)
            if (edge_nbr(s, lo) == hi) then
               mid = edge_mid(s, lo)
               return
            else if (edge_nbr(s, lo) == 0) then
               n_new = n_new + 1
               x(:, n_new) = 0.5_dp * (x(:, lo) + x(:, hi))
               x(:, n_new) = x(:, n_new) / norm2(x(:, n_new))
               edge_nbr(s, lo) = hi
               edge_mid(s, lo) = n_new
               mid = n_new
               return
            end if
         end do
         error stop 'sphere_mesh: node valence above 8 (corrupt subdivision)'
      end subroutine midpoint_index

   end subroutine icosphere

   !> Node-to-triangle lists (CSR), rebuilt whenever the connectivity changes.
   subroutine build_adjacency(self)
      class(surface_mesh_t), intent(inout) :: self
      integer :: t, k, i, pos
      integer, allocatable :: fill(:)

      if (allocated(self%node_tri_start)) deallocate (self%node_tri_start, self%node_tri, self%node_tri_vertex)
      allocate (self%node_tri_start(self%n_nodes + 1), fill(self%n_nodes))
      fill = 0
      do t = 1, self%n_tri
         do k = 1, 3
            fill(self%tri(k, t)) = fill(self%tri(k, t)) + 1
         end do
      end do
      self%node_tri_start(1) = 1
      do i = 1, self%n_nodes
         self%node_tri_start(i + 1) = self%node_tri_start(i) + fill(i)
      end do
      allocate (self%node_tri(self%node_tri_start(self%n_nodes + 1) - 1))
      allocate (self%node_tri_vertex(size(self%node_tri)))
      fill = 0
      do t = 1, self%n_tri
         do k = 1, 3
            i = self%tri(k, t)
            pos = self%node_tri_start(i) + fill(i)
            self%node_tri(pos) = t
            self%node_tri_vertex(pos) = k
            fill(i) = fill(i) + 1
         end do
      end do
   end subroutine build_adjacency

end module sphere_mesh
