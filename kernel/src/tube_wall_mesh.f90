!> The closed boundary B of the tube flow domain: the cylinder r = 1 (tube radius l = 1,
!> axis z) for z in [-L/2, L/2], closed by the entry disk S_in at z = -L/2 and the exit disk
!> S_out at z = +L/2, as one watertight P1 triangle mesh (nodes shared along the two rims).
!>
!> Orientation: triangles are counter-clockwise seen from OUTSIDE the fluid, so that
!> (x2 - x1) x (x3 - x1) points OUT OF THE FLUID (radially outward on the cylinder, -e_z on
!> the entry disk, +e_z on the exit disk), as for the capsule meshes of sphere_mesh: the signed
!> volume of the mesh is the (positive) fluid volume. The wall traction of wall_single_layer,
!> f = sigma . n with this n, is then the force per unit area that the wall exerts on the fluid.
!>
!> Structure: rings of nodes around the cylinder at z_k (k = 0 .. K), with n_phi(k) =
!> max(8, nint(2 pi / h(z_k))) nodes, consecutive rings staggered by half a step and
!> spaced (sqrt(3)/2) h(z) apart, so that triangles are nearly equilateral with edge h(z).
!> Rings with different node counts are joined by a "zipper" (walk both rings in angle and
!> always advance the one whose next node comes first), which needs no special transition
!> elements. Each disk is concentric rings around a centre node, radial step (sqrt(3)/2) h,
!> the outermost ring being the cylinder's end ring (the rim).
!>
!> Element size (edge length) h(z): h_centre for |z| <= 1 (the paper's central part of
!> length 2l), h_far for |z| >= 1 + grading_length, and a C1 smoothstep in between
!> (grading_length = 1, so the element size changes by at most ~10 % from one ring to the
!> next for the paper's 0.14 / 0.07). The disks use the size of the end rings.
module tube_wall_mesh
   use capsim_kinds, only: dp, pi
   use vector_algebra, only: cross
   use sphere_mesh, only: surface_mesh_t
   implicit none
   private
   public :: tube_wall_t, build_tube_wall, tube_element_size, graded_ring_positions, poiseuille_velocity
   public :: wall_tag_cylinder, wall_tag_inlet, wall_tag_outlet, wall_tag_rim
   public :: centre_half_length, grading_length

   !> Node tags: cylinder (not on a rim), entry disk (z = -L/2, not on the rim), exit disk
   !> (z = +L/2, not on the rim), rim (shared by the cylinder and one disk; z tells which).
   integer, parameter :: wall_tag_cylinder = 1, wall_tag_inlet = 2, wall_tag_outlet = 3, wall_tag_rim = 4
   !> Half-length of the refined central part, and length of the smooth transition.
   real(dp), parameter :: centre_half_length = 1.0_dp, grading_length = 1.0_dp
   !> Ring spacing over edge length for equilateral triangles.
   real(dp), parameter :: ring_step = 0.8660254037844386_dp

   type :: tube_wall_t
      real(dp) :: length = 0, h_far = 0, h_centre = 0
      type(surface_mesh_t) :: mesh
      !> Node positions (3, n_nodes) and tags (wall_tag_*).
      real(dp), allocatable :: x(:, :)
      integer, allocatable :: tag(:)
      !> Number of rings on the cylinder (K + 1, both rims included).
      integer :: n_rings = 0
   contains
      !> What the wall operator and the capsule model need of the channel's shape, so that
      !> they serve every channel (duct_wall_t overrides these for the rectangular duct).
      procedure :: side_normal
      procedure :: side_face_normal
      procedure :: side_clearance
      procedure :: undisturbed_velocity
      procedure :: undisturbed_gradient
      procedure :: channel_name
      procedure :: geometry_signature
   end type tube_wall_t

contains

   !> Undisturbed Poiseuille flow in the tube, mean velocity 1: v = 2 (1 - x^2 - y^2) e_z.
   pure function poiseuille_velocity(x) result(v)
      real(dp), intent(in) :: x(3)
      real(dp) :: v(3)
      v = [0.0_dp, 0.0_dp, 2.0_dp * (1.0_dp - x(1)**2 - x(2)**2)]
   end function poiseuille_velocity

   !> Outward unit normal of the side wall at a point x on it (the cylinder's: radial).
   pure function side_normal(self, x) result(n)
      class(tube_wall_t), intent(in) :: self
      real(dp), intent(in) :: x(3)
      real(dp) :: n(3)
      associate (unused => self)  ! the circular tube of radius 1 needs nothing of the instance
      end associate
      n = [x(1), x(2), 0.0_dp] / norm2(x(1:2))
   end function side_normal

   !> Outward unit normal, at the node x, of the side face that holds a side-wall triangle
   !> with this centroid (the cylinder is one face: its normal at x).
   pure function side_face_normal(self, x, centroid) result(n)
      class(tube_wall_t), intent(in) :: self
      real(dp), intent(in) :: x(3), centroid(3)
      real(dp) :: n(3)
      associate (unused => centroid)  ! the cylinder is one face
      end associate
      n = self%side_normal(x)
   end function side_face_normal

   !> Distance of a point inside the channel to its side walls (negative outside).
   pure real(dp) function side_clearance(self, p)
      class(tube_wall_t), intent(in) :: self
      real(dp), intent(in) :: p(3)
      associate (unused => self)  ! the circular tube of radius 1 needs nothing of the instance
      end associate
      side_clearance = 1.0_dp - norm2(p(1:2))
   end function side_clearance

   !> The channel's undisturbed (Poiseuille) flow of mean velocity 1 at x.
   pure function undisturbed_velocity(self, x) result(v)
      class(tube_wall_t), intent(in) :: self
      real(dp), intent(in) :: x(3)
      real(dp) :: v(3)
      associate (unused => self)  ! the circular tube of radius 1 needs nothing of the instance
      end associate
      v = poiseuille_velocity(x)
   end function undisturbed_velocity

   !> Gradient (du/dx, du/dy, 0) of the undisturbed axial velocity u at x: v = u e_z.
   pure function undisturbed_gradient(self, x) result(g)
      class(tube_wall_t), intent(in) :: self
      real(dp), intent(in) :: x(3)
      real(dp) :: g(3)
      associate (unused => self)  ! the circular tube of radius 1 needs nothing of the instance
      end associate
      g = [-4.0_dp * x(1), -4.0_dp * x(2), 0.0_dp]
   end function undisturbed_gradient

   !> The channel as the case file names it: tube, square or rect.
   pure function channel_name(self) result(name)
      class(tube_wall_t), intent(in) :: self
      character(len=:), allocatable :: name
      associate (unused => self)  ! the circular tube of radius 1 needs nothing of the instance
      end associate
      name = 'tube'
   end function channel_name

   !> The mesh family and its shape parameters, for the wall cache's signature.
   function geometry_signature(self) result(text)
      class(tube_wall_t), intent(in) :: self
      character(len=:), allocatable :: text
      associate (unused => self)  ! the circular tube of radius 1 needs nothing of the instance
      end associate
      text = ' mesh=tube_wall_mesh'
   end function geometry_signature

   !> Target edge length at axial position z (even in z).
   pure real(dp) function tube_element_size(z, h_far, h_centre) result(h)
      real(dp), intent(in) :: z, h_far, h_centre
      real(dp) :: t
      t = min(max((abs(z) - centre_half_length) / grading_length, 0.0_dp), 1.0_dp)
      h = h_centre + (h_far - h_centre) * t * t * (3.0_dp - 2.0_dp * t)
   end function tube_element_size

   !> Ring positions z_0 = -L/2 < ... < z_K = L/2 at equal steps of
   !> s(z) = integral dz / (ring_step h(z)), h = tube_element_size, so that the ring spacing
   !> follows the graded element size; s is tabulated and inverted linearly. Exactly
   !> mirror-symmetric about z = 0 (the linear inversion is symmetric only to rounding). The
   !> tube and the duct share it, so that their walls are graded alike.
   pure subroutine graded_ring_positions(length, h_far, h_centre, z_ring)
      real(dp), intent(in) :: length, h_far, h_centre
      real(dp), allocatable, intent(out) :: z_ring(:)
      integer, parameter :: n_fine = 20000
      real(dp) :: s_fine(0:n_fine), dz, s_total, s_target, z
      integer :: j, k, n_rings
      dz = length / n_fine
      s_fine(0) = 0.0_dp
      do j = 1, n_fine
         s_fine(j) = s_fine(j - 1) + 0.5_dp * dz * (1.0_dp / step_at(-0.5_dp * length + (j - 1) * dz) &
                                                    + 1.0_dp / step_at(-0.5_dp * length + j * dz))
      end do
      s_total = s_fine(n_fine)
      n_rings = max(2, nint(s_total)) + 1
      allocate (z_ring(0:n_rings - 1))
      j = 1
      do k = 0, n_rings - 1
         s_target = s_total * k / (n_rings - 1)
         do while (j < n_fine .and. s_fine(j) < s_target)
            j = j + 1
         end do
         z_ring(k) = -0.5_dp * length + dz * ((j - 1) + (s_target - s_fine(j - 1)) / (s_fine(j) - s_fine(j - 1)))
      end do
      z_ring(0) = -0.5_dp * length
      z_ring(n_rings - 1) = 0.5_dp * length
      do k = 0, (n_rings - 1) / 2
         z = 0.5_dp * (z_ring(n_rings - 1 - k) - z_ring(k))
         z_ring(k) = -z
         z_ring(n_rings - 1 - k) = z
      end do
      if (mod(n_rings, 2) == 1) z_ring((n_rings - 1) / 2) = 0.0_dp
   contains
      pure real(dp) function step_at(zz)
         real(dp), intent(in) :: zz
         step_at = ring_step * tube_element_size(zz, h_far, h_centre)
      end function step_at
   end subroutine graded_ring_positions

   !> Mesh of the tube boundary of length `length` (in tube radii) with edge lengths h_far
   !> away from the centre and h_centre over |z| < 1.
   subroutine build_tube_wall(length, h_far, h_centre, wall, stat, errmsg)
      real(dp), intent(in) :: length, h_far, h_centre
      type(tube_wall_t), intent(out) :: wall
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg

      real(dp), allocatable :: z_ring(:), phase(:)
      integer, allocatable :: n_phi(:), first(:)
      real(dp) :: h_end
      integer :: k, j, n_rings, n_nodes, n_tri, max_tri, m, n_disk_rings, node
      integer, allocatable :: tri(:, :)
      integer :: disk

      stat = 0
      errmsg = ''
      if (.not. (length > 0.0_dp .and. length <= 1.0e3_dp)) then
         stat = 1
         errmsg = 'tube length must be in (0, 1000] tube radii'
         return
      end if
      if (.not. (h_centre >= 5.0e-3_dp .and. h_centre <= h_far .and. h_far <= 0.75_dp)) then
         stat = 1
         errmsg = 'element sizes must satisfy 0.005 <= h_centre <= h_far <= 0.75 (tube radii)'
         return
      end if
      wall%length = length
      wall%h_far = h_far
      wall%h_centre = h_centre

      call graded_ring_positions(length, h_far, h_centre, z_ring)
      n_rings = size(z_ring)
      allocate (n_phi(0:n_rings - 1), phase(0:n_rings - 1), first(0:n_rings - 1))
      n_nodes = 0
      do k = 0, n_rings - 1
         n_phi(k) = max(8, nint(2.0_dp * pi / tube_element_size(z_ring(k), h_far, h_centre)))
         phase(k) = pi * mod(k, 2) / n_phi(k)
         first(k) = n_nodes + 1
         n_nodes = n_nodes + n_phi(k)
      end do
      wall%n_rings = n_rings

      ! Disk rings: M radial steps, ring m (m = 1 .. M-1) at radius m/M; plus the centre.
      h_end = 2.0_dp * pi / n_phi(0)
      n_disk_rings = max(1, nint(1.0_dp / (ring_step * h_end)))
      do m = 1, n_disk_rings - 1
         n_nodes = n_nodes + 2 * disk_ring_nodes(m)
      end do
      n_nodes = n_nodes + 2
      allocate (wall%x(3, n_nodes), wall%tag(n_nodes))
      max_tri = 2 * n_nodes + 16
      allocate (tri(3, max_tri))
      n_tri = 0

      do k = 0, n_rings - 1
         do j = 0, n_phi(k) - 1
            node = first(k) + j
            wall%x(:, node) = [cos(phase(k) + 2 * pi * j / n_phi(k)), sin(phase(k) + 2 * pi * j / n_phi(k)), z_ring(k)]
            wall%tag(node) = wall_tag_cylinder
            if (k == 0 .or. k == n_rings - 1) wall%tag(node) = wall_tag_rim
         end do
      end do
      do k = 0, n_rings - 2
         call zipper(first(k), n_phi(k), phase(k), first(k + 1), n_phi(k + 1), phase(k + 1))
      end do

      node = first(n_rings - 1) + n_phi(n_rings - 1) - 1
      do disk = 1, 2
         call add_disk(disk)
      end do

      wall%mesh%n_nodes = node
      wall%mesh%n_tri = n_tri
      allocate (wall%mesh%tri(3, n_tri))
      wall%mesh%tri = tri(:, 1:n_tri)
      call orient_outward(wall)
      call wall%mesh%build_adjacency()

   contains

      pure integer function disk_ring_nodes(mm)
         integer, intent(in) :: mm
         disk_ring_nodes = max(6, nint(2.0_dp * pi * mm / (n_disk_rings * h_end)))
      end function disk_ring_nodes

      !> Triangles between two closed rings (first node, count, angular phase of node 0).
      subroutine zipper(fa, na, pa, fb, nb, pb)
         integer, intent(in) :: fa, na, fb, nb
         real(dp), intent(in) :: pa, pb
         integer :: ia, jb, j0
         real(dp) :: next_a, next_b, b0
         ! Ring B starts at its last node at or before ring A's node 0 in angle.
         j0 = floor((pa - pb) * nb / (2 * pi) + 1.0e-9_dp)
         b0 = pb + 2 * pi * j0 / nb
         ia = 0
         jb = 0
         do while (ia < na .or. jb < nb)
            next_a = pa + 2 * pi * (ia + 1) / na
            next_b = b0 + 2 * pi * (jb + 1) / nb
            n_tri = n_tri + 1
            if (jb == nb .or. (ia < na .and. next_a < next_b)) then
               tri(:, n_tri) = [fa + mod(ia, na), fa + mod(ia + 1, na), fb + modulo(j0 + jb, nb)]
               ia = ia + 1
            else
               tri(:, n_tri) = [fa + mod(ia, na), fb + modulo(j0 + jb + 1, nb), fb + modulo(j0 + jb, nb)]
               jb = jb + 1
            end if
         end do
      end subroutine zipper

      !> Disk 1 (entry, rim ring 0) or 2 (exit, rim ring K): rings from the rim inwards.
      subroutine add_disk(which)
         integer, intent(in) :: which
         integer :: rim, outer_first, outer_n, mm, nm, jj, centre, inner_first
         real(dp) :: outer_phase, pm, zd
         integer :: tag_disk
         if (which == 1) then
            rim = 0
            tag_disk = wall_tag_inlet
         else
            rim = n_rings - 1
            tag_disk = wall_tag_outlet
         end if
         zd = z_ring(rim)
         outer_first = first(rim)
         outer_n = n_phi(rim)
         outer_phase = phase(rim)
         do mm = n_disk_rings - 1, 1, -1
            nm = disk_ring_nodes(mm)
            pm = outer_phase + pi / nm
            inner_first = node + 1
            do jj = 0, nm - 1
               node = node + 1
               wall%x(:, node) = (real(mm, dp) / n_disk_rings) * [cos(pm + 2 * pi * jj / nm), sin(pm + 2 * pi * jj / nm), 0.0_dp]
               wall%x(3, node) = zd
               wall%tag(node) = tag_disk
            end do
            call zipper(outer_first, outer_n, outer_phase, inner_first, nm, pm)
            outer_first = inner_first
            outer_n = nm
            outer_phase = pm
         end do
         node = node + 1
         centre = node
         wall%x(:, centre) = [0.0_dp, 0.0_dp, zd]
         wall%tag(centre) = tag_disk
         do jj = 0, outer_n - 1
            n_tri = n_tri + 1
            tri(:, n_tri) = [centre, outer_first + jj, outer_first + mod(jj + 1, outer_n)]
         end do
      end subroutine add_disk

   end subroutine build_tube_wall

   !> Orientation is fixed geometrically rather than trusted from the construction: the
   !> triangle normal must point away from the axis on the cylinder and along -e_z / +e_z on
   !> the entry / exit disk.
   pure subroutine orient_outward(wall)
      type(tube_wall_t), intent(inout) :: wall
      integer :: t
      real(dp) :: p(3, 3), nrm(3), c(3), out(3)
      do t = 1, wall%mesh%n_tri
         p = wall%x(:, wall%mesh%tri(:, t))
         nrm = cross(p(:, 2) - p(:, 1), p(:, 3) - p(:, 1))
         c = sum(p, dim=2) / 3.0_dp
         if (all(abs(p(3, :) - p(3, 1)) < 1.0e-12_dp) .and. abs(abs(p(3, 1)) - 0.5_dp * wall%length) < 1.0e-12_dp) then
            out = [0.0_dp, 0.0_dp, sign(1.0_dp, c(3))]
         else
            out = [c(1), c(2), 0.0_dp]
         end if
         if (dot_product(nrm, out) < 0.0_dp) wall%mesh%tri(2:3, t) = wall%mesh%tri([3, 2], t)
      end do
   end subroutine orient_outward

end module tube_wall_mesh
