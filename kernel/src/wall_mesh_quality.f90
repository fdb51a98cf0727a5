!> Quality measures of a closed wall mesh (the tube's, the duct's): whether it is closed and
!> consistently oriented, the angles and aspect ratio of a triangle, the size ratio of
!> neighbouring triangles, and the lengths of the side-wall edges in a band of z. The probes
!> that check the wall meshes (wall_probe, duct_probe) print them (put_wall_topology writes the
!> topology and tag counts as their "key value" lines); the tests hold the bounds.
module wall_mesh_quality
   use capsim_kinds, only: dp, pi
   use vector_algebra, only: cross
   use command_args, only: put_int
   use sphere_mesh, only: surface_mesh_t
   use tube_wall_mesh, only: tube_wall_t, wall_tag_cylinder, wall_tag_inlet, wall_tag_outlet, wall_tag_rim
   implicit none
   private
   public :: count_edge_defects, min_angle_deg, aspect_ratio, max_neighbour_size_ratio, side_edge_lengths, &
             put_wall_topology

contains

   !> The wall's topology as "key value" lines: sizes, the Euler characteristic (2 for a closed
   !> surface of genus 0), the edge defects (count_edge_defects), the adjacency's size, and how
   !> many nodes carry each tag (`side_key` names the side-wall count: the tube's cylinder, the
   !> duct's side walls), the entry rim's among the rims.
   subroutine put_wall_topology(wall, side_key)
      type(tube_wall_t), intent(in) :: wall
      character(len=*), intent(in) :: side_key
      integer :: unmatched, duplicated
      associate (mesh => wall%mesh)
         call count_edge_defects(mesh, unmatched, duplicated)
         call put_int('n_nodes', mesh%n_nodes)
         call put_int('n_tri', mesh%n_tri)
         call put_int('n_rings', wall%n_rings)
         call put_int('euler_characteristic', mesh%n_nodes - 3 * mesh%n_tri / 2 + mesh%n_tri)
         call put_int('unmatched_edges', unmatched)
         call put_int('duplicated_edges', duplicated)
         call put_int('adjacency_entries', mesh%node_tri_start(mesh%n_nodes + 1) - 1)
         call put_int(side_key, count(wall%tag == wall_tag_cylinder))
         call put_int('n_inlet', count(wall%tag == wall_tag_inlet))
         call put_int('n_outlet', count(wall%tag == wall_tag_outlet))
         call put_int('n_rim', count(wall%tag == wall_tag_rim))
         call put_int('n_rim_inlet', count(wall%tag == wall_tag_rim .and. wall%x(3, :) < 0))
      end associate
   end subroutine put_wall_topology

   !> Directed edges (a, b) of the triangles whose reverse (b, a) is not held by exactly one
   !> triangle (`unmatched`: a hole, or a neighbour oriented the other way), and those held by
   !> more than one triangle (`duplicated`: not a 2-manifold). Both are 0 for a closed,
   !> consistently oriented mesh. Needs the mesh's adjacency.
   subroutine count_edge_defects(mesh, unmatched, duplicated)
      type(surface_mesh_t), intent(in) :: mesh
      integer, intent(out) :: unmatched, duplicated
      integer :: t, k, a, b
      unmatched = 0
      duplicated = 0
      do t = 1, mesh%n_tri
         do k = 1, 3
            a = mesh%tri(k, t)
            b = mesh%tri(mod(k, 3) + 1, t)
            if (triangles_with_edge(mesh, b, a) /= 1) unmatched = unmatched + 1
            if (triangles_with_edge(mesh, a, b) /= 1) duplicated = duplicated + 1
         end do
      end do
   end subroutine count_edge_defects

   !> Smallest of the three corner angles of the triangle with corners xv(:, 1:3), in degrees.
   pure real(dp) function min_angle_deg(xv)
      real(dp), intent(in) :: xv(3, 3)
      integer :: k
      min_angle_deg = 180
      do k = 1, 3
         min_angle_deg = min(min_angle_deg, angle_at(xv(:, k), xv(:, mod(k, 3) + 1), xv(:, mod(k + 1, 3) + 1)))
      end do
   end function min_angle_deg

   !> Longest edge over the equilateral triangle's for the same inradius: 1 for an equilateral
   !> triangle, large for a sliver.
   pure real(dp) function aspect_ratio(xv)
      real(dp), intent(in) :: xv(3, 3)
      real(dp) :: edges(3), area
      integer :: k
      do k = 1, 3
         edges(k) = norm2(xv(:, mod(k, 3) + 1) - xv(:, k))
      end do
      area = 0.5_dp * norm2(cross(xv(:, 2) - xv(:, 1), xv(:, 3) - xv(:, 1)))
      aspect_ratio = maxval(edges) * sum(edges) / (4 * sqrt(3.0_dp) * area)
   end function aspect_ratio

   !> Largest size ratio of two triangles that share an edge (size: the square root of twice
   !> the area), the smoothness of the grading. Needs the mesh's adjacency.
   real(dp) function max_neighbour_size_ratio(mesh, x) result(worst)
      type(surface_mesh_t), intent(in) :: mesh
      real(dp), intent(in) :: x(:, :)
      real(dp) :: tri_size(mesh%n_tri)
      integer :: t, k, a, b, p, s
      do t = 1, mesh%n_tri
         tri_size(t) = sqrt(2.0_dp * norm2(cross(x(:, mesh%tri(2, t)) - x(:, mesh%tri(1, t)), &
                                                 x(:, mesh%tri(3, t)) - x(:, mesh%tri(1, t)))))
      end do
      worst = 1
      do t = 1, mesh%n_tri
         do k = 1, 3
            a = mesh%tri(k, t)
            b = mesh%tri(mod(k, 3) + 1, t)
            do p = mesh%node_tri_start(b), mesh%node_tri_start(b + 1) - 1
               s = mesh%node_tri(p)
               if (has_directed_edge(mesh%tri(:, s), b, a)) worst = max(worst, tri_size(t) / tri_size(s))
            end do
         end do
      end do
   end function max_neighbour_size_ratio

   !> Lengths of the side-wall edges (no end point in an end section) whose midpoint has
   !> z_from <= |z| < z_to, each edge once per triangle that holds it.
   subroutine side_edge_lengths(wall, z_from, z_to, lengths)
      type(tube_wall_t), intent(in) :: wall
      real(dp), intent(in) :: z_from, z_to
      real(dp), allocatable, intent(out) :: lengths(:)
      real(dp) :: found(3 * wall%mesh%n_tri), z_mid
      integer :: t, k, a, b, n
      n = 0
      do t = 1, wall%mesh%n_tri
         do k = 1, 3
            a = wall%mesh%tri(k, t)
            b = wall%mesh%tri(mod(k, 3) + 1, t)
            if (any(wall%tag([a, b]) == wall_tag_inlet .or. wall%tag([a, b]) == wall_tag_outlet)) cycle
            z_mid = 0.5_dp * abs(wall%x(3, a) + wall%x(3, b))
            if (z_mid < z_from .or. z_mid >= z_to) cycle
            n = n + 1
            found(n) = norm2(wall%x(:, a) - wall%x(:, b))
         end do
      end do
      lengths = found(1:n)
   end subroutine side_edge_lengths

   !> How many triangles around node a hold the directed edge (a, b).
   integer function triangles_with_edge(mesh, a, b) result(matches)
      type(surface_mesh_t), intent(in) :: mesh
      integer, intent(in) :: a, b
      integer :: p
      matches = 0
      do p = mesh%node_tri_start(a), mesh%node_tri_start(a + 1) - 1
         if (has_directed_edge(mesh%tri(:, mesh%node_tri(p)), a, b)) matches = matches + 1
      end do
   end function triangles_with_edge

   pure logical function has_directed_edge(v, a, b)
      integer, intent(in) :: v(3), a, b
      integer :: k
      has_directed_edge = .false.
      do k = 1, 3
         if (v(k) == a .and. v(mod(k, 3) + 1) == b) has_directed_edge = .true.
      end do
   end function has_directed_edge

   !> Angle at p of the triangle (p, q, r), in degrees.
   pure real(dp) function angle_at(p, q, r)
      real(dp), intent(in) :: p(3), q(3), r(3)
      angle_at = acos(max(-1.0_dp, min(1.0_dp, dot_product(q - p, r - p) / (norm2(q - p) * norm2(r - p))))) * 180 / pi
   end function angle_at

end module wall_mesh_quality
