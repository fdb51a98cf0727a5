!> The history table of a capsule in the tube, shared by the axisymmetric and the 3D model so
!> that the two compare column by column: column indices, names, units, and the progress line.
module tube_history
   use capsim_kinds, only: dp
   implicit none
   private
   public :: h_t, h_area, h_volume, h_lz, h_lp, h_vc, h_rmax, h_energy, h_stretch
   public :: tube_history_names, tube_history_units, tube_progress_text
   public :: h_rc, tube3d_history_names, tube3d_history_units

   integer, parameter :: h_t = 1, h_area = 2, h_volume = 3, h_lz = 4, h_lp = 5, h_vc = 6, h_rmax = 7, &
                         h_energy = 8, h_stretch = 9
   character(len=*), parameter :: tube_history_names(9) = [character(len=16) :: &
                                  't', 'area', 'volume', 'L_z', 'L_p', 'v_c', 'r_max', 'energy', 'max_stretch']
   character(len=*), parameter :: tube_history_units(9) = [character(len=16) :: &
                                  'l/V', 'l^2', 'l^3', 'l', 'l', 'V', 'l', 'G_s l^2', '1']
   !> The 3D model adds the radial position of the capsule's volume centroid (an off-centre
   !> capsule drifts; a centred one stays at 0 to round-off).
   integer, parameter :: h_rc = 10
   character(len=*), parameter :: tube3d_history_names(10) = [character(len=16) :: tube_history_names, 'r_c']
   character(len=*), parameter :: tube3d_history_units(10) = [character(len=16) :: tube_history_units, 'l']

contains

   !> "L_z/l = ...  L_p/l = ...  v_c/V = ..." from one history row.
   pure function tube_progress_text(row) result(text)
      real(dp), intent(in) :: row(:)
      character(len=:), allocatable :: text
      character(len=80) :: buf
      write (buf, '(a,f7.4,a,f7.4,a,f7.4)') 'L_z/l = ', row(h_lz), '  L_p/l = ', row(h_lp), '  v_c/V = ', row(h_vc)
      text = trim(buf)
   end function tube_progress_text

end module tube_history
