!> membrane_force_probe: the kernel's discrete membrane load (membrane_nodal_forces, the load
!> density force/node_area that the shear flow feeds to the single layer) for a prescribed
!> deformation of the icosphere, printed node by node; pytest
!> (tests/kernel/test_membrane_force_probe.py) computes the continuous load of the same
!> deformation independently and measures the error and its order.
!>
!>   membrane_force_probe affine LAW LEVEL A B C
!>       the unit sphere mapped by x -> diag(A, B, C) x (an ellipsoid): every flat element is
!>       deformed by exactly that linear map, so the only error is the discretisation's.
!> Output: "energy E" and "area A" (the discrete strain energy [G_s a^2] and current area),
!> then one line per node: "node X Y Z x y z fx fy fz area", X the reference (unit sphere)
!> position, x the current one, f the load density -dE/dx_i / area_i [G_s/a], area_i a third
!> of the current areas of the node's triangles (the kernel's node_areas).
program membrane_force_probe
   use capsim_kinds, only: dp
   use command_args, only: int_arg, real_arg, string_arg
   use sphere_mesh, only: surface_mesh_t, icosphere
   use membrane_law, only: membrane_law_t, make_membrane_law
   use membrane_forces, only: membrane_reference_t, membrane_nodal_forces
   use stokes_single_layer, only: triangle_areas, node_areas
   implicit none

   character(len=64) :: command
   call get_command_argument(1, command)
   select case (command)
   case ('affine')
      call probe_affine(string_arg(2), int_arg(3), [real_arg(4), real_arg(5), real_arg(6)])
   case default
      write (*, '(a)') 'usage: membrane_force_probe affine LAW LEVEL A B C'
      error stop 2
   end select

contains

   subroutine probe_affine(law_name, level, stretch)
      character(len=*), intent(in) :: law_name
      integer, intent(in) :: level
      real(dp), intent(in) :: stretch(3)
      type(surface_mesh_t) :: mesh
      type(membrane_law_t) :: law
      type(membrane_reference_t) :: ref
      real(dp), allocatable :: x_ref(:, :), x(:, :), force(:, :), tri_area(:), node_area(:)
      real(dp) :: energy
      integer :: stat, i
      character(len=:), allocatable :: errmsg

      call icosphere(level, mesh, x_ref, stat, errmsg)
      if (stat /= 0) then
         write (*, '(a)') 'error: '//errmsg
         error stop 1
      end if
      call make_membrane_law(law_name, 0.5_dp, 1.0_dp, law, stat, errmsg)
      if (stat /= 0) then
         write (*, '(a)') 'error: '//errmsg
         error stop 1
      end if
      call ref%init(mesh, x_ref)
      allocate (x(3, mesh%n_nodes), force(3, mesh%n_nodes), tri_area(mesh%n_tri), node_area(mesh%n_nodes))
      do i = 1, mesh%n_nodes
         x(:, i) = stretch * x_ref(:, i)
      end do
      call membrane_nodal_forces(ref, mesh, law, x, force, energy)
      call triangle_areas(mesh, x, tri_area)
      call node_areas(mesh, tri_area, node_area)
      write (*, '(a, es24.16)') 'energy ', energy
      write (*, '(a, es24.16)') 'area ', sum(tri_area)
      do i = 1, mesh%n_nodes
         write (*, '(a, 10es24.16)') 'node ', x_ref(:, i), x(:, i), force(:, i) / node_area(i), node_area(i)
      end do
   end subroutine probe_affine

end program membrane_force_probe
