!> The closed boundary B of the rectangular duct flow domain: the four side walls |x| = w and
!> |y| = h for z in [-L/2, L/2] (lengths in duct half-widths: w = 1, h = aspect = H/W), closed
!> by the entry section at z = -L/2 and the exit section at z = +L/2, as one watertight P1
!> triangle mesh with the layout of the tube wall (tube_wall_mesh): duct_wall_t extends
!> tube_wall_t, so its parent component is a tube_wall_t that wall_single_layer can take.
!> Tags as for the tube: wall_tag_cylinder on the side walls (not on a rim), wall_tag_inlet /
!> wall_tag_outlet inside the end sections, wall_tag_rim on the two end rings.
!>
!> Orientation as for the tube: (x2 - x1) x (x3 - x1) points out of the fluid (the face normal
!> +-e_x, +-e_y on the side walls, -e_z / +e_z on the entry / exit section), fixed geometrically
!> after the construction. Every triangle lies in one face, so the mesh is the duct exactly
!> (area and volume to rounding).
!>
!> Structure: rings of nodes around the cross-section at z_k, placed as the tube's rings (the
!> same graded element size tube_element_size and the same ring placement, so that the two
!> walls are graded alike: h_centre over |z| <= 1, h_far beyond 1 + grading_length, a C1
!> smoothstep between). A ring walks the perimeter counter-clockwise from the corner (-w, -h);
!> an entry on it has the parameter s in [0, 4) (side index + fraction along the side), and
!> the four corners are nodes of every ring, so no triangle folds over an edge of the duct.
!> Side j of ring k has n = max(2, nint(side length / h(z_k))) segments; odd rings are
!> staggered by half a segment (the corner, then the midpoints), so that triangles are nearly
!> equilateral. Consecutive rings are joined by a zipper that walks both rings and adds a
!> triangle on one ring's next edge at a time; a triangle must lie on one side (its three
!> entries share a side), and where both choices may, the shorter new edge wins (which also
!> keeps the triangles at the duct's edges from turning into slivers).
!> Each end section is concentric (unstaggered) rectangles inset by steps of about
!> (sqrt(3)/2) h_end from the rim down to the inset min(w, h), where the rectangle closes to
!> a point (square) or to a segment along the longer side; a ring's side of zero length keeps
!> only its start corner (that node then lies on the collapsed side and both neighbours), so
!> the same zipper joins the rings. h_end is the element size at the ends, h(L/2).
!>
!> Edge grading (optional, build_duct_wall's grade_edges): the wall shear of the duct's flow
!> grows like d log d with the distance d from a long edge, which a uniform P1 traction follows
!> to order 1 only (docs/theory/duct.md). A graded lateral ring places a side's nodes at
!> x = side * edge_graded_fraction(t), t = j / n: the segment sizes grow linearly from
!> edge_min_size times the uniform size at the corner to the uniform size over the first
!> edge_zone of t, then stay uniform, and n is raised so that the uniform part keeps the size
!> h(z). Staggered rings take the midpoints of the graded segments. The end sections are
!> unchanged (their rectangles zip to the graded rims as to any ring).
!>
!> Measured (duct_probe mesh, tests/kernel/test_duct.py): side-wall triangles have angles
!> >= 26 degrees and aspect ratios <= 1.7, section triangles >= 18 degrees and <= 2.5; with
!> the edge grading, side-wall angles >= 8 degrees and aspect ratios <= 4.5 (long in z).
module duct_wall_mesh
   use capsim_kinds, only: dp
   use vector_algebra, only: cross
   use duct_poiseuille, only: duct_flow_t, build_duct_flow
   use tube_wall_mesh, only: tube_wall_t, tube_element_size, graded_ring_positions, wall_tag_cylinder, &
                             wall_tag_inlet, wall_tag_outlet, wall_tag_rim
   implicit none
   private
   public :: duct_wall_t, build_duct_wall

   !> Ring spacing over edge length for equilateral triangles (as the tube's).
   real(dp), parameter :: ring_step = 0.8660254037844386_dp
   !> Positions closer than this (in half-widths) are the same node.
   real(dp), parameter :: same_point = 1.0e-12_dp
   !> A point this close to a face's plane (in half-widths) lies on it.
   real(dp), parameter :: on_face = 1.0e-9_dp
   !> Edge grading: the segment size at a corner relative to the uniform part's, and the
   !> fraction of a side's segment parameter t (from each end) over which it grows linearly.
   !> Chosen on the Poiseuille wall shear (duct_probe poiseuille): smaller corner segments
   !> make slivers (angles below 4 degrees) for little gain, a wider zone costs more nodes.
   real(dp), parameter :: edge_min_size = 0.15_dp, edge_zone = 0.3_dp
   !> A graded side has this many times the segments of a uniform one (the uniform part keeps
   !> the element size): 1 / (1 - edge_zone (1 - edge_min_size)).
   real(dp), parameter :: edge_segment_factor = 1.0_dp / (1.0_dp - edge_zone * (1.0_dp - edge_min_size))

   type, extends(tube_wall_t) :: duct_wall_t
      !> Half-width w (along x, the unit of length) and half-height h (along y).
      real(dp) :: half_width = 0, half_height = 0
      !> The duct's Poiseuille flow (mean velocity 1): the undisturbed flow.
      type(duct_flow_t) :: flow
      !> Lateral rings graded towards the long edges (edge_graded_fraction).
      logical :: edges_graded = .false.
   contains
      procedure :: side_normal => duct_side_normal
      procedure :: side_face_normal => duct_side_face_normal
      procedure :: side_clearance => duct_side_clearance
      procedure :: undisturbed_velocity => duct_undisturbed_velocity
      procedure :: undisturbed_gradient => duct_undisturbed_gradient
      procedure :: channel_name => duct_channel_name
      procedure :: geometry_signature => duct_geometry_signature
   end type duct_wall_t

   !> A ring of nodes: node numbers, their perimeter parameters s (increasing in [0, 4)), and
   !> the sides each entry lies on (bit j: side j; a corner lies on two sides, the node of a
   !> side of zero length on it and on both neighbours, the single node of a point on all).
   type :: ring_t
      integer :: n = 0
      integer, allocatable :: node(:), sides(:)
      real(dp), allocatable :: s(:)
   end type ring_t

   !> Nodes, tags and triangles while the mesh is built (grown by doubling).
   type :: mesh_builder_t
      integer :: n_nodes = 0, n_tri = 0
      real(dp), allocatable :: x(:, :)
      integer, allocatable :: tag(:), tri(:, :)
   end type mesh_builder_t

contains

   !> Outward unit normal of the side wall at x: the face's (+-e_x, +-e_y); on a long edge of
   !> the duct (on two faces) the x face's, the node's own face (the y face's triangles there
   !> take the traction through the wall operator's edge map).
   pure function duct_side_normal(self, x) result(n)
      class(duct_wall_t), intent(in) :: self
      real(dp), intent(in) :: x(3)
      real(dp) :: n(3)
      n = 0.0_dp
      if (self%half_width - abs(x(1)) <= on_face) then
         n(1) = sign(1.0_dp, x(1))
      else
         n(2) = sign(1.0_dp, x(2))
      end if
   end function duct_side_normal

   !> The face of a side triangle is the one its centroid lies on (the nearer plane).
   pure function duct_side_face_normal(self, x, centroid) result(n)
      class(duct_wall_t), intent(in) :: self
      real(dp), intent(in) :: x(3), centroid(3)
      real(dp) :: n(3)
      n = 0.0_dp
      ! The face by the centroid (inside one face); its side by the node (on that face).
      if (self%half_width - abs(centroid(1)) <= self%half_height - abs(centroid(2))) then
         n(1) = sign(1.0_dp, x(1))
      else
         n(2) = sign(1.0_dp, x(2))
      end if
   end function duct_side_face_normal

   pure real(dp) function duct_side_clearance(self, p)
      class(duct_wall_t), intent(in) :: self
      real(dp), intent(in) :: p(3)
      duct_side_clearance = min(self%half_width - abs(p(1)), self%half_height - abs(p(2)))
   end function duct_side_clearance

   pure function duct_undisturbed_velocity(self, x) result(v)
      class(duct_wall_t), intent(in) :: self
      real(dp), intent(in) :: x(3)
      real(dp) :: v(3)
      v = [0.0_dp, 0.0_dp, self%flow%velocity(x(1), x(2))]
   end function duct_undisturbed_velocity

   pure function duct_undisturbed_gradient(self, x) result(g)
      class(duct_wall_t), intent(in) :: self
      real(dp), intent(in) :: x(3)
      real(dp) :: g(3)
      g(1:2) = self%flow%velocity_gradient(x(1), x(2))
      g(3) = 0.0_dp
   end function duct_undisturbed_gradient

   pure function duct_channel_name(self) result(name)
      class(duct_wall_t), intent(in) :: self
      character(len=:), allocatable :: name
      if (self%half_height == self%half_width) then
         name = 'square'
      else
         name = 'rect'
      end if
   end function duct_channel_name

   function duct_geometry_signature(self) result(text)
      class(duct_wall_t), intent(in) :: self
      character(len=:), allocatable :: text
      character(len=80) :: buffer
      write (buffer, '(a,es24.16)') ' mesh=duct_wall_mesh aspect=', self%half_height / self%half_width
      text = trim(buffer)
      if (self%edges_graded) text = text // ' edges=graded'
   end function duct_geometry_signature

   !> Mesh of the duct boundary of length `length` (in half-widths), aspect H/W (default 1,
   !> the square duct), with edge lengths h_far away from the centre and h_centre over |z| < 1;
   !> grade_edges (default no) grades the lateral rings towards the long edges.
   subroutine build_duct_wall(length, h_far, h_centre, wall, stat, errmsg, aspect, grade_edges)
      real(dp), intent(in) :: length, h_far, h_centre
      type(duct_wall_t), intent(out) :: wall
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      real(dp), intent(in), optional :: aspect
      logical, intent(in), optional :: grade_edges

      real(dp), allocatable :: z_ring(:)
      type(ring_t), allocatable :: lateral(:)
      type(mesh_builder_t) :: builder
      integer :: k, n_rings
      real(dp) :: w, h, h_end

      stat = 0
      errmsg = ''
      w = 1.0_dp
      h = 1.0_dp
      if (present(aspect)) h = aspect
      if (.not. (h >= 0.1_dp .and. h <= 10.0_dp)) then
         stat = 1
         errmsg = 'duct aspect H/W must be in [0.1, 10]'
         return
      end if
      if (.not. (length > 0.0_dp .and. length <= 1.0e3_dp)) then
         stat = 1
         errmsg = 'duct length must be in (0, 1000] half-widths'
         return
      end if
      if (.not. (h_centre >= 5.0e-3_dp .and. h_centre <= h_far .and. h_far <= 0.75_dp * min(w, h))) then
         stat = 1
         errmsg = 'element sizes must satisfy 0.005 <= h_centre <= h_far <= 0.75 min(1, aspect) (half-widths)'
         return
      end if
      wall%length = length
      wall%h_far = h_far
      wall%h_centre = h_centre
      wall%half_width = w
      wall%half_height = h
      if (present(grade_edges)) wall%edges_graded = grade_edges
      call build_duct_flow(w, h, wall%flow, stat, errmsg)
      if (stat /= 0) return

      call graded_ring_positions(length, h_far, h_centre, z_ring)
      n_rings = size(z_ring)
      wall%n_rings = n_rings
      allocate (builder%x(3, 1024), builder%tag(1024), builder%tri(3, 2048))
      allocate (lateral(0:n_rings - 1))
      do k = 0, n_rings - 1
         call add_ring(builder, w, h, tube_element_size(z_ring(k), h_far, h_centre), 2, mod(k, 2) == 1, z_ring(k), &
                       merge(wall_tag_rim, wall_tag_cylinder, k == 0 .or. k == n_rings - 1), lateral(k), &
                       wall%edges_graded)
      end do
      do k = 0, n_rings - 2
         if (stat == 0) call zipper(builder, lateral(k), lateral(k + 1), stat)
      end do
      h_end = tube_element_size(0.5_dp * length, h_far, h_centre)
      if (stat == 0) call add_section(builder, w, h, h_end, lateral(0), wall_tag_inlet, stat)
      if (stat == 0) call add_section(builder, w, h, h_end, lateral(n_rings - 1), wall_tag_outlet, stat)
      if (stat /= 0) then
         errmsg = 'duct wall mesh: two rings could not be joined'
         return
      end if

      associate (n_nodes => builder%n_nodes, n_tri => builder%n_tri)
         allocate (wall%x(3, n_nodes), wall%tag(n_nodes), wall%mesh%tri(3, n_tri))
         wall%x = builder%x(:, 1:n_nodes)
         wall%tag = builder%tag(1:n_nodes)
         wall%mesh%n_nodes = n_nodes
         wall%mesh%n_tri = n_tri
         wall%mesh%tri = builder%tri(:, 1:n_tri)
      end associate
      call orient_outward(wall, stat, errmsg)
      if (stat /= 0) return
      call wall%mesh%build_adjacency()
   end subroutine build_duct_wall

   !> A new node at p with tag t (arrays grown by doubling).
   subroutine new_node(builder, p, t, id)
      type(mesh_builder_t), intent(inout) :: builder
      real(dp), intent(in) :: p(3)
      integer, intent(in) :: t
      integer, intent(out) :: id
      real(dp), allocatable :: x_new(:, :)
      integer, allocatable :: tag_new(:)
      associate (n => builder%n_nodes)
         if (n == size(builder%tag)) then
            allocate (x_new(3, 2 * n), tag_new(2 * n))
            x_new(:, 1:n) = builder%x(:, 1:n)
            tag_new(1:n) = builder%tag(1:n)
            call move_alloc(x_new, builder%x)
            call move_alloc(tag_new, builder%tag)
         end if
         n = n + 1
         id = n
      end associate
      builder%x(:, id) = p
      builder%tag(id) = t
   end subroutine new_node

   subroutine add_triangle(builder, a, b, c)
      type(mesh_builder_t), intent(inout) :: builder
      integer, intent(in) :: a, b, c
      integer, allocatable :: tri_new(:, :)
      associate (n => builder%n_tri)
         if (n == size(builder%tri, 2)) then
            allocate (tri_new(3, 2 * n))
            tri_new(:, 1:n) = builder%tri(:, 1:n)
            call move_alloc(tri_new, builder%tri)
         end if
         n = n + 1
         builder%tri(:, n) = [a, b, c]
      end associate
   end subroutine add_triangle

   !> A ring around the rectangle |x| <= ax, |y| <= ay in the plane z (ax, ay >= 0, not both
   !> 0): side j from corner j to corner j+1 in max(min_segments, nint(length / edge))
   !> segments, staggered by half a segment when asked. A side of zero length keeps its start
   !> corner only (the next side then starts without it), so that the collapsed side's nodes
   !> sit at its start parameter; a position met twice (the two faces of a segment) is one node.
   !> Graded (optional, default no): edge_segment_factor times the segments, placed by
   !> edge_graded_fraction, the staggered nodes at the graded segments' midpoints.
   subroutine add_ring(builder, ax, ay, edge, min_segments, staggered, z, node_tag, ring, graded)
      type(mesh_builder_t), intent(inout) :: builder
      real(dp), intent(in) :: ax, ay, edge, z
      integer, intent(in) :: min_segments, node_tag
      logical, intent(in) :: staggered
      type(ring_t), intent(out) :: ring
      logical, intent(in), optional :: graded
      real(dp) :: corner(2, 0:4), side_length(0:3), frac
      logical :: grade
      integer :: side, n_seg, j, first_new
      corner(:, 0) = [-ax, -ay]
      corner(:, 1) = [ax, -ay]
      corner(:, 2) = [ax, ay]
      corner(:, 3) = [-ax, ay]
      corner(:, 4) = corner(:, 0)
      do side = 0, 3
         side_length(side) = norm2(corner(:, side + 1) - corner(:, side))
      end do
      grade = .false.
      if (present(graded)) grade = graded
      allocate (ring%s(0), ring%node(0), ring%sides(0))
      first_new = builder%n_nodes + 1
      do side = 0, 3
         if (side_length(side) <= same_point) then
            call put_node(real(side, dp), corner(:, side), &
                          ibset(ibset(ibset(0, modulo(side - 1, 4)), side), modulo(side + 1, 4)))
            cycle
         end if
         if (side_length(modulo(side - 1, 4)) > same_point) &
            call put_node(real(side, dp), corner(:, side), ibset(ibset(0, modulo(side - 1, 4)), side))
         if (grade) then
            n_seg = max(min_segments, nint(edge_segment_factor * side_length(side) / edge))
         else
            n_seg = max(min_segments, nint(side_length(side) / edge))
         end if
         do j = 0, n_seg - 1
            if (grade .and. staggered) then
               frac = 0.5_dp * (edge_graded_fraction(real(j, dp) / n_seg) + edge_graded_fraction(real(j + 1, dp) / n_seg))
            else if (staggered) then
               frac = (j + 0.5_dp) / n_seg
            else
               if (j == 0) cycle
               frac = real(j, dp) / n_seg
               if (grade) frac = edge_graded_fraction(frac)
            end if
            call put_node(side + frac, corner(:, side) + frac * (corner(:, side + 1) - corner(:, side)), ibset(0, side))
         end do
      end do
      ring%n = size(ring%node)
   contains
      subroutine put_node(s, q, on_sides)
         real(dp), intent(in) :: s, q(2)
         integer, intent(in) :: on_sides
         integer :: m, id
         id = 0
         do m = first_new, builder%n_nodes
            if (norm2(builder%x(1:2, m) - q) <= same_point) id = m
         end do
         if (id == 0) call new_node(builder, [q(1), q(2), z], node_tag, id)
         ring%s = [ring%s, s]
         ring%node = [ring%node, id]
         ring%sides = [ring%sides, on_sides]
      end subroutine put_node
   end subroutine add_ring

   !> Position along a graded side (fraction of its length) of the segment parameter t in
   !> [0, 1], symmetric about t = 1/2: with u = min(t, 1 - t) the size dx/dt grows linearly
   !> from edge_min_size c to c over u < edge_zone and is c beyond (c = edge_segment_factor,
   !> so that x(1/2) = 1/2).
   pure real(dp) function edge_graded_fraction(t) result(x)
      real(dp), intent(in) :: t
      real(dp) :: u
      u = min(t, 1.0_dp - t)
      if (u < edge_zone) then
         x = edge_segment_factor * (edge_min_size * u + (1.0_dp - edge_min_size) * u**2 / (2 * edge_zone))
      else
         x = edge_segment_factor * (0.5_dp * edge_zone * (1.0_dp + edge_min_size) + u - edge_zone)
      end if
      if (t > 0.5_dp) x = 1.0_dp - x
   end function edge_graded_fraction

   !> Triangles between ring a (outer or earlier) and ring b, walking both from a's first node
   !> (b from its last node at or before it in s). Each step adds (a_i, a_i+1, b_j) or
   !> (a_i, b_j+1, b_j); a triangle must lie on one side (all three entries share a side bit), so
   !> no triangle folds over an edge of the duct or leaves its trapezoid of a section; when
   !> both may, the shorter new edge wins (a_i+1 - b_j against a_i - b_j+1). A ring of one
   !> node is a fan.
   subroutine zipper(builder, a, b, stat)
      type(mesh_builder_t), intent(inout) :: builder
      type(ring_t), intent(in) :: a, b
      integer, intent(out) :: stat
      integer :: ia, jb, j0
      logical :: can_a, can_b, take_a
      stat = 0
      if (b%n == 1) then
         do ia = 1, a%n
            call add_triangle(builder, a%node(ia), a%node(mod(ia, a%n) + 1), b%node(1))
         end do
         return
      end if
      j0 = b%n
      do jb = 1, b%n
         if (b%s(jb) <= a%s(1) + same_point) j0 = jb
      end do
      ia = 0
      jb = 0
      do while (ia < a%n .or. jb < b%n)
         can_a = ia < a%n .and. iand(iand(sides_a(ia), sides_a(ia + 1)), sides_b(jb)) /= 0
         can_b = jb < b%n .and. iand(iand(sides_a(ia), sides_b(jb + 1)), sides_b(jb)) /= 0
         if (can_a .and. can_b) then
            take_a = norm2(builder%x(:, node_a(ia + 1)) - builder%x(:, node_b(jb))) &
                     < norm2(builder%x(:, node_a(ia)) - builder%x(:, node_b(jb + 1)))
         else if (can_a .or. can_b) then
            take_a = can_a
         else
            stat = 1
            return
         end if
         if (take_a) then
            call add_triangle(builder, node_a(ia), node_a(ia + 1), node_b(jb))
            ia = ia + 1
         else
            call add_triangle(builder, node_a(ia), node_b(jb + 1), node_b(jb))
            jb = jb + 1
         end if
      end do
   contains
      !> Node and side bits of the q-th step along a (from its entry 1) and b (from entry j0).
      integer function node_a(q)
         integer, intent(in) :: q
         node_a = a%node(mod(q, a%n) + 1)
      end function node_a
      integer function sides_a(q)
         integer, intent(in) :: q
         sides_a = a%sides(mod(q, a%n) + 1)
      end function sides_a
      integer function node_b(q)
         integer, intent(in) :: q
         node_b = b%node(mod(j0 - 1 + q, b%n) + 1)
      end function node_b
      integer function sides_b(q)
         integer, intent(in) :: q
         sides_b = b%sides(mod(j0 - 1 + q, b%n) + 1)
      end function sides_b
   end subroutine zipper

   !> End section of the duct |x| <= w, |y| <= h inside the rim ring: rectangles inset by
   !> t_m = m t_end / M, M steps of about ring_step h_end, down to t_end = min(w, h): a point,
   !> or a segment along the longer side (a point too when that segment would be shorter than
   !> h_end / 2).
   subroutine add_section(builder, w, h, h_end, rim, section_tag, stat)
      type(mesh_builder_t), intent(inout) :: builder
      real(dp), intent(in) :: w, h, h_end
      type(ring_t), intent(in) :: rim
      integer, intent(in) :: section_tag
      integer, intent(out) :: stat
      type(ring_t) :: outer, inner
      real(dp) :: t_end, t, z_end, ax, ay
      integer :: m, n_steps, centre
      stat = 0
      z_end = builder%x(3, rim%node(1))
      t_end = min(w, h)
      n_steps = max(1, nint(t_end / (ring_step * h_end)))
      outer = rim
      do m = 1, n_steps
         t = t_end * m / n_steps
         ax = w - t
         ay = h - t
         if (m == n_steps) then
            ax = max(ax, 0.0_dp)
            ay = max(ay, 0.0_dp)
            if (2 * max(ax, ay) < 0.5_dp * h_end) then
               ax = 0
               ay = 0
            end if
         end if
         if (ax <= same_point .and. ay <= same_point) then
            call new_node(builder, [0.0_dp, 0.0_dp, z_end], section_tag, centre)
            inner%n = 1
            inner%node = [centre]
            inner%s = [0.0_dp]
            inner%sides = [15]
         else
            call add_ring(builder, ax, ay, h_end, 1, .false., z_end, section_tag, inner)
         end if
         call zipper(builder, outer, inner, stat)
         if (stat /= 0) return
         outer = inner
      end do
   end subroutine add_section

   !> Orientation fixed geometrically: the triangle normal must point along the outward normal
   !> of the one face that holds all three corners; a triangle in no face is an error.
   subroutine orient_outward(wall, stat, errmsg)
      type(duct_wall_t), intent(inout) :: wall
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: t, face
      real(dp) :: p(3, 3), nrm(3), out(3), plane(6), normals(3, 6)
      stat = 0
      errmsg = ''
      plane = [wall%half_width, wall%half_width, wall%half_height, wall%half_height, &
               0.5_dp * wall%length, 0.5_dp * wall%length]
      normals = reshape([1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1], [3, 6]) * 1.0_dp
      do t = 1, wall%mesh%n_tri
         p = wall%x(:, wall%mesh%tri(:, t))
         out = 0
         do face = 1, 6
            if (all(abs(matmul(normals(:, face), p) - plane(face)) <= same_point)) out = normals(:, face)
         end do
         nrm = cross(p(:, 2) - p(:, 1), p(:, 3) - p(:, 1))
         if (all(out == 0.0_dp) .or. norm2(nrm) <= same_point) then
            stat = 1
            errmsg = 'duct wall mesh: a triangle is degenerate or lies in no face of the duct'
            return
         end if
         if (dot_product(nrm, out) < 0.0_dp) wall%mesh%tri(2:3, t) = wall%mesh%tri([3, 2], t)
      end do
   end subroutine orient_outward

end module duct_wall_mesh
