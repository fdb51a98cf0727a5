!> Files of one run: the HDF5 case file (written whole to a temporary name, then renamed)
!> and the binary checkpoint from which a killed run resumes.
module case_output
   use capsim_kinds, only: dp, code_version, schema_version
   use file_ops, only: replace_file
   use hdf5_writer, only: h5_file_t
   use run_options, only: run_options_t
   use membrane_law, only: membrane_law_t
   implicit none
   private
   public :: case_summary_t, open_case_file, close_case_file, write_checkpoint, read_checkpoint, write_surface_mesh

   !> What the run ends with: status, its reason, and timing.
   type :: case_summary_t
      character(len=32) :: status = 'failed'
      character(len=:), allocatable :: message
      real(dp) :: wall_time_s = 0
      !> Wall seconds the earlier, interrupted runs of this case spent in their time loops up to
      !> their last checkpoint (0 for a run that did not resume), so that wall_time_s is the
      !> case's cost, not only its last segment's.
      real(dp) :: wall_time_before_s = 0
      integer :: threads = 1
      real(dp) :: dt = 0
      real(dp) :: volume_change = 0
   end type case_summary_t


contains

   !> Creates OUT.tmp and writes the root attributes, /history and, for a steady run only
   !> (`steady_row` present), /steady. The caller adds its geometry (/mesh, /profile) to the
   !> open file and calls close_case_file, which renames OUT.tmp to OUT.
   subroutine open_case_file(opts, law, summary, names, units, history, f, stat, errmsg, steady_row)
      type(run_options_t), intent(in) :: opts
      type(membrane_law_t), intent(in) :: law
      type(case_summary_t), intent(in) :: summary
      character(len=*), intent(in) :: names(:), units(:)
      real(dp), intent(in) :: history(:, :)
      type(h5_file_t), intent(inout) :: f
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      real(dp), intent(in), optional :: steady_row(:)
      integer :: k
      logical :: tube

      tube = trim(opts%flow) == 'tube'
      call f%create(trim(opts%out)//'.tmp', stat, errmsg)
      if (stat /= 0) return
      call f%write_attr('/', 'schema_version', schema_version, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'code_version', code_version, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'flow', trim(opts%flow), stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'law', law%name(), stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'nu_s', law%nu_s, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'C', law%c, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'K_s_over_G_s', law%dilation_modulus(), stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'Ca_s', opts%ca, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'prestress', opts%prestress, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'lambda', opts%lambda, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'k_b', opts%kb, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'offset', opts%offset, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'offset_mode', trim(opts%offset_mode), stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'mesh_level', opts%level, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'dt', summary%dt, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'status', trim(summary%status), stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'message', summary%message, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'wall_time_s', summary%wall_time_s, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'threads', summary%threads, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'volume_change_rel', summary%volume_change, stat, errmsg)
      if (stat == 0) call f%write_attr('/', 'volume_correction', merge(1, 0, opts%volume_correction), stat, errmsg)
      if (tube) then
         if (stat == 0) call f%write_attr('/', 'a_over_l', opts%a_over_l, stat, errmsg)
         if (stat == 0) call f%write_attr('/', 'model', trim(opts%model), stat, errmsg)
         if (stat == 0) call f%write_attr('/', 'length_scale', 'l (tube radius)', stat, errmsg)
         if (stat == 0) call f%write_attr('/', 'time_scale', 'l/V (V mean velocity)', stat, errmsg)
      else
         if (stat == 0) call f%write_attr('/', 'length_scale', 'a (capsule radius)', stat, errmsg)
         if (stat == 0) call f%write_attr('/', 'time_scale', '1/gamma_dot', stat, errmsg)
      end if
      if (stat == 0) call f%write_attr('/', 'force_scale', 'G_s (surface shear modulus)', stat, errmsg)
      if (stat == 0) call f%make_group('/history', stat, errmsg)
      do k = 1, size(names)
         if (stat == 0) call f%write_dataset('/history/'//trim(names(k)), history(k, :), trim(units(k)), stat, errmsg)
      end do
      if (present(steady_row)) then
         if (stat == 0) call f%make_group('/steady', stat, errmsg)
         do k = 1, size(names)
            if (stat == 0) call f%write_dataset('/steady/'//trim(names(k)), steady_row(k), trim(units(k)), stat, errmsg)
         end do
      end if
   end subroutine open_case_file

   !> Closes the case file and moves it to its final name: the file is whole or absent.
   subroutine close_case_file(f, opts, stat, errmsg)
      type(h5_file_t), intent(inout) :: f
      type(run_options_t), intent(in) :: opts
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      call f%close(stat, errmsg)
      if (stat /= 0) return
      call replace_file(trim(opts%out)//'.tmp', trim(opts%out), stat, errmsg)
   end subroutine close_case_file

   !> Binary checkpoint: signature, step, time, model state, the history so far and the wall
   !> seconds spent on the case up to now.
   subroutine write_checkpoint(path, signature, step, t, x, history, n_rec, wall_time_s, stat, errmsg)
      character(len=*), intent(in) :: path, signature
      integer, intent(in) :: step, n_rec
      real(dp), intent(in) :: t, x(:), history(:, :), wall_time_s
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: unit
      character(len=256) :: iomsg
      open (newunit=unit, file=path//'.tmp', access='stream', form='unformatted', status='replace', &
            action='write', iostat=stat, iomsg=iomsg)
      if (stat /= 0) then
         errmsg = 'cannot write checkpoint "'//path//'.tmp": '//trim(iomsg)
         return
      end if
      write (unit) len(signature), signature, step, t, size(x), x, n_rec, history(:, 1:n_rec), wall_time_s
      close (unit)
      call replace_file(path//'.tmp', path, stat, errmsg)
   end subroutine write_checkpoint

   !> Reads a checkpoint if one exists for the same options; `found` is false otherwise.
   !> `wall_time_s` is 0 for a checkpoint written before it recorded the wall time.
   subroutine read_checkpoint(path, signature, step, t, x, history, n_rec, wall_time_s, found)
      character(len=*), intent(in) :: path, signature
      integer, intent(inout) :: step, n_rec
      real(dp), intent(inout) :: t, x(:), history(:, :)
      real(dp), intent(out) :: wall_time_s
      logical, intent(out) :: found
      integer :: unit, ios, sig_len, n_nodes, n_rec_file
      character(len=:), allocatable :: sig_file
      found = .false.
      wall_time_s = 0
      open (newunit=unit, file=path, access='stream', form='unformatted', status='old', action='read', &
            iostat=ios)
      if (ios /= 0) return
      read (unit, iostat=ios) sig_len
      if (ios == 0 .and. sig_len == len(signature)) then
         allocate (character(len=sig_len) :: sig_file)
         read (unit, iostat=ios) sig_file
         if (ios == 0 .and. sig_file == signature) then
            read (unit, iostat=ios) step, t, n_nodes
            if (ios == 0 .and. n_nodes == size(x)) then
               read (unit, iostat=ios) x, n_rec_file
               if (ios == 0 .and. n_rec_file <= size(history, 2)) then
                  read (unit, iostat=ios) history(:, 1:n_rec_file)
                  if (ios == 0) then
                     n_rec = n_rec_file
                     found = .true.
                     read (unit, iostat=ios) wall_time_s
                     if (ios /= 0) wall_time_s = 0
                  end if
               end if
            end if
         end if
      end if
      close (unit)
   end subroutine read_checkpoint

   !> /mesh of a 3D capsule: reference and current nodes (3, n) in `length_unit`, triangles
   !> 0-based (read as (n, 3) and (m, 3) in h5py). Does nothing if stat /= 0 on entry.
   subroutine write_surface_mesh(f, reference_nodes, nodes, triangles, length_unit, stat, errmsg)
      type(h5_file_t), intent(inout) :: f
      real(dp), intent(in) :: reference_nodes(:, :), nodes(:, :)
      integer, intent(in) :: triangles(:, :)
      character(len=*), intent(in) :: length_unit
      integer, intent(inout) :: stat
      character(len=:), allocatable, intent(inout) :: errmsg
      if (stat == 0) call f%make_group('/mesh', stat, errmsg)
      if (stat == 0) call f%write_dataset('/mesh/reference_nodes', reference_nodes, length_unit, stat, errmsg)
      if (stat == 0) call f%write_dataset('/mesh/nodes', nodes, length_unit, stat, errmsg)
      if (stat == 0) call f%write_dataset('/mesh/triangles', triangles - 1, '1', stat, errmsg)
      if (stat == 0) call f%write_attr('/mesh/triangles', 'index_base', 0, stat, errmsg)
   end subroutine write_surface_mesh

end module case_output
