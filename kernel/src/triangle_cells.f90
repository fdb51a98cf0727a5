!> Spatial index of triangles for the near-field corrections of the off-surface single layers
!> (the wall's at the membrane nodes, the capsule's at the wall nodes): which triangles have
!> their centroid within max(near_radius, ratio x diameter) of a point p.
!>
!> A uniform grid of cubic cells over the centroids' bounding box, the triangles sorted by cell
!> (counting sort, CSR), and the centroids and reaches copied in that order (structure of
!> arrays): a point visits only the cells that some triangle's reach can span, skips a cell
!> whose box lies beyond the largest reach in it, and scans the rest contiguously. A linear
!> scan of the wall's axial slabs visited every triangle of a ring of the tube ~2500 per
!> membrane node at level 4 (most of velocity_at's time); the cells cut this to the few hundred
!> around the point. The test is exactly the scan's (norm2 of p - centroid against the
!> reach), so the same triangles are found, in another order.
module triangle_cells
   use capsim_kinds, only: dp
   implicit none
   private
   public :: triangle_cells_t

   type :: triangle_cells_t
      integer :: n_tri = 0
      integer :: dims(3) = 0
      real(dp) :: lo(3) = 0, width = 1, max_reach = 0
      !> Cell c holds sorted entries start(c) .. start(c+1)-1; tri(s) is the triangle of entry s.
      integer, allocatable :: start(:), tri(:)
      !> Per sorted entry: centroid coordinates and reach max(near_radius, ratio x diameter).
      real(dp), allocatable :: cx(:), cy(:), cz(:), reach(:)
      !> Largest reach of the triangles in each cell.
      real(dp), allocatable :: cell_reach(:)
      integer, allocatable :: cell_of(:)
   contains
      procedure :: build
      procedure :: near
   end type triangle_cells_t

contains

   !> Index the triangles with centroids c (3, nt) and diameters d (nt). `width` is the cell
   !> edge (of the order of near_radius). Arrays are reallocated only when nt or the grid
   !> grows, so that a per-step rebuild (a moving surface) allocates nothing in steady use.
   subroutine build(self, c, d, near_radius, ratio, width)
      class(triangle_cells_t), intent(inout) :: self
      real(dp), intent(in) :: c(:, :), d(:), near_radius, ratio, width
      integer :: nt, t, k, n_cells, s
      real(dp) :: hi(3)

      nt = size(d)
      self%n_tri = nt
      self%width = width
      self%lo = minval(c, dim=2)
      hi = maxval(c, dim=2)
      self%dims = max(1, ceiling((hi - self%lo) / width))
      n_cells = product(self%dims)
      if (allocated(self%tri)) then
         if (size(self%tri) /= nt) deallocate (self%tri, self%cx, self%cy, self%cz, self%reach, self%cell_of)
      end if
      if (.not. allocated(self%tri)) allocate (self%tri(nt), self%cx(nt), self%cy(nt), self%cz(nt), self%reach(nt), &
                                               self%cell_of(nt))
      if (allocated(self%start)) then
         if (size(self%start) < n_cells + 1) deallocate (self%start, self%cell_reach)
      end if
      if (.not. allocated(self%start)) allocate (self%start(n_cells + 1), self%cell_reach(n_cells))
      self%start(1:n_cells + 1) = 0
      self%cell_reach(1:n_cells) = 0.0_dp
      do t = 1, nt
         k = cell_index(self, c(:, t))
         self%cell_of(t) = k
         self%start(k + 1) = self%start(k + 1) + 1
      end do
      self%start(1) = 1
      do k = 1, n_cells
         self%start(k + 1) = self%start(k + 1) + self%start(k)
      end do
      ! Counting sort (stable: a cell keeps its triangles in increasing order); start(k) is
      ! advanced while cell k fills, then restored.
      do t = 1, nt
         k = self%cell_of(t)
         self%tri(self%start(k)) = t
         self%start(k) = self%start(k) + 1
      end do
      do k = n_cells, 1, -1
         self%start(k + 1) = self%start(k)
      end do
      self%start(1) = 1
      self%max_reach = 0.0_dp
      do s = 1, nt
         t = self%tri(s)
         self%cx(s) = c(1, t)
         self%cy(s) = c(2, t)
         self%cz(s) = c(3, t)
         self%reach(s) = max(near_radius, ratio * d(t))
         k = self%cell_of(t)
         self%cell_reach(k) = max(self%cell_reach(k), self%reach(s))
         self%max_reach = max(self%max_reach, self%reach(s))
      end do
   end subroutine build

   pure integer function cell_index(self, x) result(k)
      type(triangle_cells_t), intent(in) :: self
      real(dp), intent(in) :: x(3)
      integer :: i(3)
      i = min(max(floor((x - self%lo) / self%width), 0), self%dims - 1)
      k = 1 + i(1) + self%dims(1) * (i(2) + self%dims(2) * i(3))
   end function cell_index

   !> The triangles whose centroid lies nearer to p than their reach (norm2(p - centroid) <
   !> max(near_radius, ratio x diameter)): m of them, in list(1:m) with those distances in
   !> dist(1:m). list and dist must hold n_tri entries.
   pure subroutine near(self, p, list, dist, m)
      class(triangle_cells_t), intent(in) :: self
      real(dp), intent(in) :: p(3)
      integer, intent(out) :: list(:), m
      real(dp), intent(out) :: dist(:)
      integer :: lo_i(3), hi_i(3), i, j, l, k, s
      real(dp) :: box_lo(3), gap(3), dst
      m = 0
      lo_i = max(floor((p - self%max_reach - self%lo) / self%width), 0)
      hi_i = min(floor((p + self%max_reach - self%lo) / self%width), self%dims - 1)
      do l = lo_i(3), hi_i(3)
         do j = lo_i(2), hi_i(2)
            do i = lo_i(1), hi_i(1)
               k = 1 + i + self%dims(1) * (j + self%dims(2) * l)
               if (self%start(k + 1) == self%start(k)) cycle
               ! Lower bound of the distance from p to any centroid in the cell (every centroid
               ! lies in its cell's box: the bounding box is covered and only hi is clamped).
               box_lo = self%lo + self%width * real([i, j, l], dp)
               gap = max(0.0_dp, box_lo - p, p - (box_lo + self%width))
               if (norm2(gap) >= self%cell_reach(k)) cycle
               do s = self%start(k), self%start(k + 1) - 1
                  dst = norm2(p - [self%cx(s), self%cy(s), self%cz(s)])
                  if (dst >= self%reach(s)) cycle
                  m = m + 1
                  list(m) = self%tri(s)
                  dist(m) = dst
               end do
            end do
         end do
      end do
   end subroutine near

end module triangle_cells
