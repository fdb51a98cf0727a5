!> Files of one run: the HDF5 case file (written whole to a temporary name, then renamed)
!> and the binary checkpoint from which a killed run resumes.
module case_output
   use, intrinsic :: iso_fortran_env, only: int8, int64
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
   use capsim_kinds, only: dp, code_version, schema_version
   use file_ops, only: replace_file, path_kind, path_absent, path_regular, delete_file
   use checksum, only: crc32_t
   use text_format, only: real_text
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
      !> Estimated remaining change of the settled shape measure (shear: D12) between the
      !> steady row and its long-time limit, relative to the row's value; negative where the
      !> model does not estimate it (tube) or the run is not steady. Written as the root
      !> attribute time_error_rel, with time_error_measure naming the measure.
      real(dp) :: time_error = -1
      character(len=:), allocatable :: time_error_measure
      !> Set when the run cannot go on for a reason outside the model (a checkpoint that cannot
      !> be written): the program then exits 1 with this line and writes no case file.
      character(len=:), allocatable :: fatal
   end type case_summary_t

   !> First bytes of a checkpoint of this layout (write_checkpoint).
   character(len=*), parameter :: checkpoint_magic = 'CAPSCKP3'
   integer, parameter :: int_bytes = 4, real_bytes = 8, header_bytes = len(checkpoint_magic) + int_bytes
   !> Largest checkpoint file read [bytes].
   integer(int64), parameter :: max_checkpoint_bytes = 256_int64 * 2_int64**20


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
      if (summary%time_error >= 0.0_dp .and. allocated(summary%time_error_measure)) then
         if (stat == 0) call f%write_attr('/', 'time_error_rel', summary%time_error, stat, errmsg)
         if (stat == 0) call f%write_attr('/', 'time_error_measure', summary%time_error_measure, stat, errmsg)
      end if
      if (tube) then
         if (stat == 0) call f%write_attr('/', 'a_over_l', opts%a_over_l, stat, errmsg)
         if (stat == 0) call f%write_attr('/', 'model', trim(opts%model), stat, errmsg)
         if (stat == 0) call f%write_attr('/', 'channel', trim(opts%channel), stat, errmsg)
         if (stat == 0) call f%write_attr('/', 'aspect', opts%aspect, stat, errmsg)
         if (trim(opts%channel) == 'tube') then
            if (stat == 0) call f%write_attr('/', 'length_scale', 'l (tube radius)', stat, errmsg)
            if (stat == 0) call f%write_attr('/', 'time_scale', 'l/V (V mean velocity)', stat, errmsg)
         else
            ! The duct's half-width w plays the tube radius's part (a_over_l is a/w).
            if (stat == 0) call f%write_attr('/', 'length_scale', 'w (duct half-width)', stat, errmsg)
            if (stat == 0) call f%write_attr('/', 'time_scale', 'w/V (V mean velocity)', stat, errmsg)
         end if
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

   !> Binary checkpoint (stream, native byte order), written whole to PATH.tmp and renamed:
   !>   'CAPSCKP3' (8 bytes), CRC-32 (int32) of every byte after it, len(signature) (int32),
   !>   signature, step (int32), t, size(x) (int32), x, rows of history (int32), n_rec (int32),
   !>   history(:, 1:n_rec), wall_time_s (reals in 8 bytes; the wall time last).
   !> x is the model's state (capsule_model_t%get_state): the positions, then whatever else the
   !> next step depends on (step size, Jacobian age and where it was made, error history,
   !> counters, initial guesses of iterative solves), so that a resumed run continues bit for
   !> bit as the uninterrupted one. Format 3 (this): that state; format 2 held positions and,
   !> for implicit shear steps, dt only, and resumed those runs on another path.
   !> The signature (option_signature) holds every option that changes the result, t_max and
   !> the code version. Every write and the close are checked: on failure PATH.tmp is removed,
   !> PATH (the previous checkpoint) is left as it was, and stat /= 0.
   subroutine write_checkpoint(path, signature, step, t, x, history, n_rec, wall_time_s, stat, errmsg)
      character(len=*), intent(in) :: path, signature
      integer, intent(in) :: step, n_rec
      real(dp), intent(in) :: t, x(:), history(:, :), wall_time_s
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      type(crc32_t) :: crc
      integer :: unit, k, ios
      character(len=256) :: iomsg
      errmsg = ''
      iomsg = ''
      open (newunit=unit, file=path//'.tmp', access='stream', form='unformatted', status='replace', &
            action='write', iostat=stat, iomsg=iomsg)
      if (stat /= 0) then
         errmsg = 'cannot write checkpoint "'//path//'.tmp": '//trim(iomsg)
         return
      end if
      call crc%add_int(len(signature))
      call crc%add_text(signature)
      call crc%add_int(step)
      call crc%add_real(t)
      call crc%add_int(size(x))
      call crc%add_reals(x)
      call crc%add_int(size(history, 1))
      call crc%add_int(n_rec)
      do k = 1, n_rec
         call crc%add_reals(history(:, k))
      end do
      call crc%add_real(wall_time_s)
      write (unit, iostat=stat, iomsg=iomsg) checkpoint_magic, crc%value(), len(signature), signature, step, t, &
         size(x), x, size(history, 1), n_rec, history(:, 1:n_rec), wall_time_s
      if (stat == 0) flush (unit, iostat=stat, iomsg=iomsg)
      if (stat /= 0) then
         close (unit, status='delete', iostat=ios)
         errmsg = 'cannot write checkpoint "'//path//'.tmp": '//trim(iomsg)
         return
      end if
      close (unit, iostat=stat, iomsg=iomsg)
      if (stat /= 0) then
         call delete_file(path//'.tmp')
         errmsg = 'cannot close checkpoint "'//path//'.tmp": '//trim(iomsg)
         return
      end if
      ! A full disk does not always reach iostat (gfortran reported success for a stream
      ! write cut short by ENOSPC): the file is read back and must be whole before it
      ! replaces the previous checkpoint.
      if (.not. checkpoint_is_whole(path//'.tmp', checkpoint_size(len(signature), size(x), size(history, 1), n_rec))) then
         call delete_file(path//'.tmp')
         stat = 1
         errmsg = 'cannot write checkpoint "'//path//'.tmp": the file read back is not whole (disk full?)'
         return
      end if
      call replace_file(path//'.tmp', path, stat, errmsg)
      if (stat /= 0) call delete_file(path//'.tmp')
   end subroutine write_checkpoint

   !> Reads the checkpoint at `path` if it is whole (its CRC-32 matches), written for the same
   !> `signature` and shaped like this run's state; `found` is false otherwise, and `note` says
   !> why ('' when there is no checkpoint at all). `history` grows to hold the records read.
   subroutine read_checkpoint(path, signature, step, t, x, history, n_rec, wall_time_s, found, note)
      character(len=*), intent(in) :: path, signature
      integer, intent(inout) :: step, n_rec
      real(dp), intent(inout) :: t, x(:)
      real(dp), allocatable, intent(inout) :: history(:, :)
      real(dp), intent(out) :: wall_time_s
      logical, intent(out) :: found
      character(len=:), allocatable, intent(out) :: note
      integer :: unit, ios, sig_len, n_state, n_rows, n_rec_file, step_file
      integer(int64) :: file_size
      character(len=:), allocatable :: sig_file
      real(dp) :: t_file, wall_file
      real(dp), allocatable :: x_file(:), history_file(:, :)

      found = .false.
      note = ''
      wall_time_s = 0
      if (path_kind(path) == path_absent) return
      if (path_kind(path) /= path_regular) then
         note = 'not a regular file'
         return
      end if
      open (newunit=unit, file=path, access='stream', form='unformatted', status='old', action='read', &
            iostat=ios)
      if (ios /= 0) then
         note = 'cannot be opened'
         return
      end if
      check: block
         inquire (unit=unit, size=file_size)
         call check_crc(unit, file_size, note)
         if (len(note) > 0) exit check
         ! Whole as written: what follows guards against a checkpoint of another shape.
         note = 'written for other options or another kernel version (signature differs)'
         read (unit, iostat=ios, pos=header_bytes + 1) sig_len
         if (ios /= 0 .or. sig_len /= len(signature)) exit check
         allocate (character(len=sig_len) :: sig_file)
         read (unit, iostat=ios) sig_file
         if (ios /= 0 .or. sig_file /= signature) exit check
         note = 'of another model size'
         read (unit, iostat=ios) step_file, t_file, n_state
         if (ios /= 0 .or. n_state /= size(x)) exit check
         allocate (x_file(n_state))
         read (unit, iostat=ios) x_file, n_rows, n_rec_file
         if (ios /= 0 .or. n_rows /= size(history, 1) .or. n_rec_file < 1) exit check
         note = 'damaged (its size does not match its record count)'
         if (checkpoint_size(sig_len, n_state, n_rows, n_rec_file) /= file_size) exit check
         allocate (history_file(n_rows, n_rec_file))
         read (unit, iostat=ios) history_file, wall_file
         note = 'damaged (cannot be read whole)'
         if (ios /= 0) exit check
         note = 'damaged (non-finite or negative values)'
         if (step_file < 0 .or. .not. (ieee_is_finite(t_file) .and. all(ieee_is_finite(x_file)) .and. &
                                      all(ieee_is_finite(history_file)) .and. wall_file >= 0)) exit check
         if (size(history, 2) < n_rec_file) then
            deallocate (history)
            allocate (history(n_rows, n_rec_file))
         end if
         history(:, 1:n_rec_file) = history_file
         n_rec = n_rec_file
         step = step_file
         t = t_file
         x = x_file
         wall_time_s = wall_file
         found = .true.
         note = ''
      end block check
      close (unit, iostat=ios)
   end subroutine read_checkpoint

   !> Bytes of a checkpoint (write_checkpoint's layout).
   pure integer(int64) function checkpoint_size(sig_len, n_state, n_rows, n_rec)
      integer, intent(in) :: sig_len, n_state, n_rows, n_rec
      checkpoint_size = header_bytes + 5_int64 * int_bytes + sig_len + &
                        real_bytes * (2_int64 + n_state + int(n_rows, int64) * n_rec)
   end function checkpoint_size

   !> From the start of the open checkpoint of `file_size` bytes: its magic and CRC-32 against
   !> the bytes that follow. `note` is '' if they match, otherwise what is wrong; the file is
   !> then positioned anywhere.
   subroutine check_crc(unit, file_size, note)
      integer, intent(in) :: unit
      integer(int64), intent(in) :: file_size
      character(len=:), allocatable, intent(out) :: note
      character(len=len(checkpoint_magic)) :: magic
      integer(int8), allocatable :: bytes(:)
      integer :: ios, crc_file
      type(crc32_t) :: crc
      note = 'damaged (shorter than its header)'
      if (file_size < header_bytes) return
      ! Checked before the bytes are read into memory: a file this large is no checkpoint (the
      ! largest, a level-5 capsule's state and a full history, is a few MiB).
      note = 'larger than any checkpoint ('//real_text(real(file_size, dp))//' bytes, '// &
             real_text(real(max_checkpoint_bytes, dp))//' at most)'
      if (file_size > max_checkpoint_bytes) return
      read (unit, iostat=ios, pos=1) magic, crc_file
      note = 'not a checkpoint of this kernel (an older format or another file)'
      if (ios /= 0 .or. magic /= checkpoint_magic) return
      allocate (bytes(file_size - header_bytes))
      read (unit, iostat=ios) bytes
      note = 'damaged (cannot be read whole)'
      if (ios /= 0) return
      call crc%add_bytes(bytes)
      note = 'damaged (checksum mismatch: truncated or altered)'
      if (crc%value() /= crc_file) return
      note = ''
   end subroutine check_crc

   !> True if the checkpoint file at `path` has `expected_size` bytes and its CRC-32 matches.
   logical function checkpoint_is_whole(path, expected_size) result(whole)
      character(len=*), intent(in) :: path
      integer(int64), intent(in) :: expected_size
      integer :: unit, ios
      integer(int64) :: file_size
      character(len=:), allocatable :: note
      whole = .false.
      open (newunit=unit, file=path, access='stream', form='unformatted', status='old', action='read', iostat=ios)
      if (ios /= 0) return
      inquire (unit=unit, size=file_size)
      if (file_size == expected_size) then
         call check_crc(unit, file_size, note)
         whole = len(note) == 0
      end if
      close (unit, iostat=ios)
   end function checkpoint_is_whole

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
