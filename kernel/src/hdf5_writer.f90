!> Thin writer over the HDF5 Fortran API, so that the kernel writes a case file in a few lines.
!>
!> Every failure is returned through `stat` (0 on success) and `errmsg` (always allocated,
!> empty on success, otherwise naming the file, the object path and the operation); nothing
!> here prints or stops, because the caller decides whether a failed write is fatal.
!>
!> Arrays are written in Fortran order without transposing: HDF5 reverses the dimensions,
!> so a Fortran x(3,n) is read by h5py/NumPy as shape (n,3) with x[j-1,i-1] == x(i,j).
!>
!> The module keeps one piece of global state (whether the HDF5 library is initialised), so
!> it must be called from serial code only, never from inside an OpenMP parallel region.
module hdf5_writer
   use capsim_kinds, only: dp
   use hdf5, only: hid_t, hsize_t, size_t, &
                   h5open_f, h5eset_auto_f, h5kind_to_type, h5_real_kind, h5_integer_kind, &
                   h5f_acc_trunc_f, h5fcreate_f, h5fclose_f, h5p_file_access_f, h5pset_libver_bounds_f, &
                   h5f_libver_v18_f, h5d_compact_f, h5pset_layout_f, &
                   h5gcreate_f, h5gclose_f, &
                   h5oopen_f, h5oclose_f, &
                   h5s_scalar_f, h5screate_f, h5screate_simple_f, h5sclose_f, &
                   h5t_fortran_s1, h5t_str_nullpad_f, h5tcopy_f, h5tset_size_f, h5tset_strpad_f, &
                   h5tclose_f, &
                   h5p_dataset_create_f, h5pcreate_f, h5pset_chunk_f, h5pset_deflate_f, h5pset_fletcher32_f, &
                   h5pclose_f, &
                   h5aexists_f, h5adelete_f, h5acreate_f, h5awrite_f, h5aclose_f, &
                   h5dcreate_f, h5dwrite_f, h5dclose_f
   implicit none
   private

   public :: h5_file_t

   !> Checksums, so that a flipped bit fails the read (h5py raises OSError) instead of changing
   !> a fitted quantity silently: every array dataset carries HDF5's Fletcher-32 checksum per
   !> chunk (it needs a chunked layout); a scalar dataset (rank 0: it cannot be chunked) is
   !> stored compact, inside its object header, and object headers (with the attributes) carry
   !> a checksum of their own in the file format of HDF5 1.8 on (create sets it as the oldest).
   !> Datasets with more elements than this are also gzip-compressed; below it the filter's
   !> overhead outweighs any saving.
   integer, parameter :: compress_min_elements = 64
   integer, parameter :: gzip_level = 4
   !> Target chunk size in elements (1 MiB of real(dp)): large enough for good compression
   !> ratios, small enough that reading one time step does not decompress the whole history.
   integer(hsize_t), parameter :: chunk_target_elements = 131072_hsize_t

   integer(hid_t), parameter :: no_id = -1_hid_t

   !> h5open_f must run before any predefined HDF5 type id is valid; once per process suffices.
   logical, save :: library_ready = .false.

   !> An HDF5 file open for writing.
   type :: h5_file_t
      private
      integer(hid_t) :: file_id = no_id
      character(len=:), allocatable :: path
   contains
      procedure, public :: create
      procedure, public :: close
      procedure, public :: make_group
      procedure, public :: is_open
      procedure, private :: attr_string
      procedure, private :: attr_real
      procedure, private :: attr_int
      procedure, private :: ds_real0
      procedure, private :: ds_real1
      procedure, private :: ds_real2
      procedure, private :: ds_int1
      procedure, private :: ds_int2
      generic, public :: write_attr => attr_string, attr_real, attr_int
      generic, public :: write_dataset => ds_real0, ds_real1, ds_real2, ds_int1, ds_int2
   end type h5_file_t

contains

   !> Create (or truncate) the file at `path` and keep it open for writing.
   subroutine create(self, path, stat, errmsg)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: path
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: hdferr, ignored
      integer(hid_t) :: fapl_id

      if (self%is_open()) then
         ! Silently closing would hide a caller bug that leaves a half-written file behind.
         call fail(stat, errmsg, "cannot create '" // path // "': this handle still has '" // &
                   self%path // "' open")
         return
      end if
      call ensure_library(stat, errmsg)
      if (stat /= 0) return
      ! The 1.8 format: object headers with checksums (see the module's checksums note).
      call h5pcreate_f(h5p_file_access_f, fapl_id, hdferr)
      if (hdferr < 0) then
         call fail(stat, errmsg, "cannot create file '" // path // "' (h5pcreate_f failed)")
         return
      end if
      call h5pset_libver_bounds_f(fapl_id, h5f_libver_v18_f, h5f_libver_v18_f, hdferr)
      if (hdferr >= 0) call h5fcreate_f(path, h5f_acc_trunc_f, self%file_id, hdferr, access_prp=fapl_id)
      call h5pclose_f(fapl_id, ignored)
      if (hdferr < 0) then
         self%file_id = no_id
         call fail(stat, errmsg, "cannot create file '" // path // "'")
         return
      end if
      self%path = path
      call succeed(stat, errmsg)
   end subroutine create

   !> Close the file; closing a handle that is not open is a no-op, so cleanup paths may
   !> call it unconditionally.
   subroutine close(self, stat, errmsg)
      class(h5_file_t), intent(inout) :: self
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: hdferr

      call succeed(stat, errmsg)
      if (.not. self%is_open()) return
      call h5fclose_f(self%file_id, hdferr)
      if (hdferr < 0) call fail(stat, errmsg, "cannot close file '" // self%path // "'")
      ! The id is dead either way; keeping it would make a retry close a recycled id.
      self%file_id = no_id
   end subroutine close

   logical function is_open(self)
      class(h5_file_t), intent(in) :: self
      is_open = self%file_id /= no_id
   end function is_open

   !> Create the group at absolute `path`; its parent must already exist.
   subroutine make_group(self, path, stat, errmsg)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: path
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer(hid_t) :: group_id
      integer :: hdferr, ignored

      if (.not. require_open(self, path, stat, errmsg)) return
      call h5gcreate_f(self%file_id, path, group_id, hdferr)
      if (hdferr < 0) then
         call fail(stat, errmsg, "cannot create group '" // path // "' in '" // self%path // &
                   "' (does the parent group exist, or does the group exist already?)")
         return
      end if
      call h5gclose_f(group_id, ignored)
      call succeed(stat, errmsg)
   end subroutine make_group

   ! ---------------------------------------------------------------- attributes

   !> String attribute `name` on the object at `object_path` ('/' for the root group).
   !> Trailing blanks are dropped so that fixed-length Fortran variables store just their text.
   subroutine attr_string(self, object_path, name, value, stat, errmsg)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: object_path, name, value
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer(hid_t) :: obj_id
      integer :: ignored

      call open_object(self, object_path, obj_id, stat, errmsg)
      if (stat /= 0) return
      call put_string_attr(obj_id, name, value, stat)
      call h5oclose_f(obj_id, ignored)
      if (stat /= 0) then
         call fail(stat, errmsg, attr_failure(self, object_path, name))
      else
         call succeed(stat, errmsg)
      end if
   end subroutine attr_string

   !> Scalar real(dp) attribute `name` on the object at `object_path`.
   subroutine attr_real(self, object_path, name, value, stat, errmsg)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: object_path, name
      real(dp), intent(in) :: value
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer(hid_t) :: obj_id, attr_id
      integer :: hdferr, ignored

      call open_object(self, object_path, obj_id, stat, errmsg)
      if (stat /= 0) return
      call new_scalar_attr(obj_id, name, real_type(), attr_id, hdferr)
      if (hdferr >= 0) then
         call h5awrite_f(attr_id, real_type(), value, [1_hsize_t], hdferr)
         call h5aclose_f(attr_id, ignored)
      end if
      call h5oclose_f(obj_id, ignored)
      if (hdferr < 0) then
         call fail(stat, errmsg, attr_failure(self, object_path, name))
      else
         call succeed(stat, errmsg)
      end if
   end subroutine attr_real

   !> Scalar default-integer attribute `name` on the object at `object_path`.
   subroutine attr_int(self, object_path, name, value, stat, errmsg)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: object_path, name
      integer, intent(in) :: value
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer(hid_t) :: obj_id, attr_id
      integer :: hdferr, ignored

      call open_object(self, object_path, obj_id, stat, errmsg)
      if (stat /= 0) return
      call new_scalar_attr(obj_id, name, int_type(), attr_id, hdferr)
      if (hdferr >= 0) then
         call h5awrite_f(attr_id, int_type(), value, [1_hsize_t], hdferr)
         call h5aclose_f(attr_id, ignored)
      end if
      call h5oclose_f(obj_id, ignored)
      if (hdferr < 0) then
         call fail(stat, errmsg, attr_failure(self, object_path, name))
      else
         call succeed(stat, errmsg)
      end if
   end subroutine attr_int

   ! ---------------------------------------------------------------- datasets

   !> Scalar real(dp) dataset (rank-0 dataspace, so h5py's `ds[()]` is a plain float).
   subroutine ds_real0(self, path, data, units, stat, errmsg)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: path
      real(dp), intent(in) :: data
      character(len=*), intent(in) :: units
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer(hid_t) :: dset_id
      integer(hsize_t) :: dims(0)
      integer :: hdferr

      call open_new_dataset(self, path, real_type(), dims, dset_id, stat, errmsg)
      if (stat /= 0) return
      call h5dwrite_f(dset_id, real_type(), data, [1_hsize_t], hdferr)
      call finish_dataset(self, path, dset_id, units, hdferr, stat, errmsg)
   end subroutine ds_real0

   subroutine ds_real1(self, path, data, units, stat, errmsg)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: path
      real(dp), intent(in) :: data(:)
      character(len=*), intent(in) :: units
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer(hid_t) :: dset_id
      integer(hsize_t) :: dims(1)
      integer :: hdferr

      dims = shape(data, kind=hsize_t)
      call open_new_dataset(self, path, real_type(), dims, dset_id, stat, errmsg)
      if (stat /= 0) return
      call h5dwrite_f(dset_id, real_type(), data, dims, hdferr)
      call finish_dataset(self, path, dset_id, units, hdferr, stat, errmsg)
   end subroutine ds_real1

   !> Fortran data(m,n) is stored with HDF5 dims (n,m): no transpose, see the module header.
   subroutine ds_real2(self, path, data, units, stat, errmsg)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: path
      real(dp), intent(in) :: data(:, :)
      character(len=*), intent(in) :: units
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer(hid_t) :: dset_id
      integer(hsize_t) :: dims(2)
      integer :: hdferr

      dims = shape(data, kind=hsize_t)
      call open_new_dataset(self, path, real_type(), dims, dset_id, stat, errmsg)
      if (stat /= 0) return
      call h5dwrite_f(dset_id, real_type(), data, dims, hdferr)
      call finish_dataset(self, path, dset_id, units, hdferr, stat, errmsg)
   end subroutine ds_real2

   subroutine ds_int1(self, path, data, units, stat, errmsg)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: path
      integer, intent(in) :: data(:)
      character(len=*), intent(in) :: units
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer(hid_t) :: dset_id
      integer(hsize_t) :: dims(1)
      integer :: hdferr

      dims = shape(data, kind=hsize_t)
      call open_new_dataset(self, path, int_type(), dims, dset_id, stat, errmsg)
      if (stat /= 0) return
      call h5dwrite_f(dset_id, int_type(), data, dims, hdferr)
      call finish_dataset(self, path, dset_id, units, hdferr, stat, errmsg)
   end subroutine ds_int1

   subroutine ds_int2(self, path, data, units, stat, errmsg)
      class(h5_file_t), intent(inout) :: self
      character(len=*), intent(in) :: path
      integer, intent(in) :: data(:, :)
      character(len=*), intent(in) :: units
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer(hid_t) :: dset_id
      integer(hsize_t) :: dims(2)
      integer :: hdferr

      dims = shape(data, kind=hsize_t)
      call open_new_dataset(self, path, int_type(), dims, dset_id, stat, errmsg)
      if (stat /= 0) return
      call h5dwrite_f(dset_id, int_type(), data, dims, hdferr)
      call finish_dataset(self, path, dset_id, units, hdferr, stat, errmsg)
   end subroutine ds_int2

   ! ---------------------------------------------------------------- internals

   subroutine ensure_library(stat, errmsg)
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: hdferr

      call succeed(stat, errmsg)
      if (library_ready) return
      call h5open_f(hdferr)
      if (hdferr < 0) then
         call fail(stat, errmsg, 'cannot initialise the HDF5 library (h5open_f)')
         return
      end if
      ! HDF5 otherwise prints its error stack to stderr on every failure; errors reach the
      ! caller through stat/errmsg instead, and an expected failure must not look like a crash.
      call h5eset_auto_f(0, hdferr)
      library_ready = .true.
   end subroutine ensure_library

   !> Memory and file type of real(dp); derived from the kind so a change of dp stays correct.
   integer(hid_t) function real_type()
      real_type = h5kind_to_type(dp, h5_real_kind)
   end function real_type

   integer(hid_t) function int_type()
      int_type = h5kind_to_type(kind(0), h5_integer_kind)
   end function int_type

   logical function require_open(self, path, stat, errmsg)
      class(h5_file_t), intent(in) :: self
      character(len=*), intent(in) :: path
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg

      require_open = self%is_open()
      if (require_open) then
         call succeed(stat, errmsg)
      else
         call fail(stat, errmsg, "cannot write '" // path // "': no file is open (call create first)")
      end if
   end function require_open

   subroutine open_object(self, object_path, obj_id, stat, errmsg)
      class(h5_file_t), intent(in) :: self
      character(len=*), intent(in) :: object_path
      integer(hid_t), intent(out) :: obj_id
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: hdferr

      obj_id = no_id
      if (.not. require_open(self, object_path, stat, errmsg)) return
      call h5oopen_f(self%file_id, object_path, obj_id, hdferr)
      if (hdferr < 0) then
         obj_id = no_id
         call fail(stat, errmsg, "cannot open object '" // object_path // "' in '" // self%path // &
                   "' to attach an attribute (does it exist?)")
      end if
   end subroutine open_object

   !> Create scalar attribute `name` of type `type_id` on `obj_id`, replacing an existing one so
   !> that metadata can be refined (e.g. a status updated at the end of a run).
   subroutine new_scalar_attr(obj_id, name, type_id, attr_id, hdferr)
      integer(hid_t), intent(in) :: obj_id, type_id
      character(len=*), intent(in) :: name
      integer(hid_t), intent(out) :: attr_id
      integer, intent(out) :: hdferr
      integer(hid_t) :: space_id
      logical :: exists
      integer :: ignored

      attr_id = no_id
      call h5aexists_f(obj_id, name, exists, hdferr)
      if (hdferr < 0) return
      if (exists) then
         call h5adelete_f(obj_id, name, hdferr)
         if (hdferr < 0) return
      end if
      call h5screate_f(h5s_scalar_f, space_id, hdferr)
      if (hdferr < 0) return
      call h5acreate_f(obj_id, name, type_id, space_id, attr_id, hdferr)
      call h5sclose_f(space_id, ignored)
   end subroutine new_scalar_attr

   !> Fixed-length string of exactly the trimmed length, NUL-padded as NumPy writes 'S' strings,
   !> so h5py decodes it to the bare text. An empty text is stored as one NUL because HDF5
   !> rejects zero-size string types.
   subroutine put_string_attr(obj_id, name, value, stat)
      integer(hid_t), intent(in) :: obj_id
      character(len=*), intent(in) :: name, value
      integer, intent(out) :: stat
      character(len=:), allocatable :: text
      integer(hid_t) :: type_id, attr_id
      integer :: hdferr, ignored

      text = trim(value)
      if (len(text) == 0) text = achar(0)
      stat = 1
      call h5tcopy_f(h5t_fortran_s1, type_id, hdferr)
      if (hdferr < 0) return
      steps: block
         call h5tset_size_f(type_id, int(len(text), size_t), hdferr)
         if (hdferr < 0) exit steps
         call h5tset_strpad_f(type_id, h5t_str_nullpad_f, hdferr)
         if (hdferr < 0) exit steps
         call new_scalar_attr(obj_id, name, type_id, attr_id, hdferr)
         if (hdferr < 0) exit steps
         call h5awrite_f(attr_id, type_id, text, [1_hsize_t], hdferr)
         call h5aclose_f(attr_id, ignored)
         if (hdferr >= 0) stat = 0
      end block steps
      call h5tclose_f(type_id, ignored)
   end subroutine put_string_attr

   function attr_failure(self, object_path, name) result(msg)
      class(h5_file_t), intent(in) :: self
      character(len=*), intent(in) :: object_path, name
      character(len=:), allocatable :: msg
      msg = "cannot write attribute '" // name // "' on '" // object_path // "' in '" // self%path // "'"
   end function attr_failure

   !> Create dataset `path` with dimensions `dims` (rank 0: scalar) and return it open.
   subroutine open_new_dataset(self, path, type_id, dims, dset_id, stat, errmsg)
      class(h5_file_t), intent(in) :: self
      character(len=*), intent(in) :: path
      integer(hid_t), intent(in) :: type_id
      integer(hsize_t), intent(in) :: dims(:)
      integer(hid_t), intent(out) :: dset_id
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer(hid_t) :: space_id, dcpl_id
      integer(hsize_t) :: chunk(size(dims))
      integer :: rank, hdferr, ignored
      character(len=:), allocatable :: step

      dset_id = no_id
      space_id = no_id
      dcpl_id = no_id
      if (.not. require_open(self, path, stat, errmsg)) return
      rank = size(dims)
      steps: block
         step = 'h5screate_f'
         if (rank == 0) then
            call h5screate_f(h5s_scalar_f, space_id, hdferr)
         else
            call h5screate_simple_f(rank, dims, space_id, hdferr)
         end if
         if (hdferr < 0) exit steps

         step = 'h5pcreate_f'
         call h5pcreate_f(h5p_dataset_create_f, dcpl_id, hdferr)
         if (hdferr < 0) exit steps
         if (rank == 0) then
            step = 'h5pset_layout_f'
            call h5pset_layout_f(dcpl_id, h5d_compact_f, hdferr)
            if (hdferr < 0) exit steps
         end if
         ! A chunk needs at least one element in each dimension: an empty dataset stays contiguous.
         if (rank > 0 .and. product(dims) > 0) then
            chunk = chunk_shape(dims)
            step = 'h5pset_chunk_f'
            call h5pset_chunk_f(dcpl_id, rank, chunk, hdferr)
            if (hdferr < 0) exit steps
            if (product(dims) > compress_min_elements) then
               step = 'h5pset_deflate_f'
               call h5pset_deflate_f(dcpl_id, gzip_level, hdferr)
               if (hdferr < 0) exit steps
            end if
            ! Last in the pipeline: the checksum covers the bytes as stored (compressed), so
            ! that a read checks them before anything else.
            step = 'h5pset_fletcher32_f'
            call h5pset_fletcher32_f(dcpl_id, hdferr)
            if (hdferr < 0) exit steps
         end if

         step = 'h5dcreate_f'
         call h5dcreate_f(self%file_id, path, type_id, space_id, dset_id, hdferr, dcpl_id=dcpl_id)
      end block steps

      if (dcpl_id /= no_id) call h5pclose_f(dcpl_id, ignored)
      if (space_id /= no_id) call h5sclose_f(space_id, ignored)
      if (hdferr < 0) then
         dset_id = no_id
         call fail(stat, errmsg, "cannot create dataset '" // path // "' in '" // self%path // &
                   "' (" // step // " failed; does the parent group exist, or does the dataset exist already?)")
      else
         call succeed(stat, errmsg)
      end if
   end subroutine open_new_dataset

   !> Keep whole leading (fastest-varying in Fortran) dimensions in each chunk and split only
   !> the last one, so a chunk holds complete records (e.g. all nodes of a time step).
   pure function chunk_shape(dims) result(chunk)
      integer(hsize_t), intent(in) :: dims(:)
      integer(hsize_t) :: chunk(size(dims))
      integer :: rank

      rank = size(dims)
      chunk = dims
      chunk(rank) = min(dims(rank), &
                        max(1_hsize_t, chunk_target_elements / max(1_hsize_t, product(dims(:rank - 1)))))
   end function chunk_shape

   !> Attach the `units` attribute and close the dataset, reporting the first failure;
   !> `write_err` is the status of the preceding h5dwrite_f.
   subroutine finish_dataset(self, path, dset_id, units, write_err, stat, errmsg)
      class(h5_file_t), intent(in) :: self
      character(len=*), intent(in) :: path, units
      integer(hid_t), intent(inout) :: dset_id
      integer, intent(in) :: write_err
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: hdferr

      if (write_err < 0) then
         call fail(stat, errmsg, "cannot write data of dataset '" // path // "' in '" // self%path // "'")
      else
         call put_string_attr(dset_id, 'units', units, stat)
         if (stat /= 0) then
            call fail(stat, errmsg, attr_failure(self, path, 'units'))
         else
            call succeed(stat, errmsg)
         end if
      end if
      call h5dclose_f(dset_id, hdferr)
      dset_id = no_id
      if (hdferr < 0 .and. stat == 0) then
         call fail(stat, errmsg, "cannot close dataset '" // path // "' in '" // self%path // "'")
      end if
   end subroutine finish_dataset

   subroutine succeed(stat, errmsg)
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      stat = 0
      errmsg = ''
   end subroutine succeed

   subroutine fail(stat, errmsg, msg)
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      character(len=*), intent(in) :: msg
      stat = 1
      errmsg = 'hdf5_writer: ' // msg
   end subroutine fail

end module hdf5_writer
