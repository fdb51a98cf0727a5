!> The thread count of the BLAS/LAPACK library, set to the kernel's own (--threads).
!>
!> Why: OpenBLAS (Debian's default libblas.so.3) starts one thread per core when it is loaded,
!> whatever --threads says, and its idle threads spin and yield between calls. A --threads 1
!> tube branch at 64 elements then used 87 CPU s for 46 s of work (35 s of it system time), and
!> a workflow running one single-threaded case per core ran twice as many busy threads as
!> cores. The LAPACK calls of the kernel are small (axisymmetric Jacobians of 130-260 unknowns)
!> or made outside OpenMP regions, so they need no more threads than the kernel has.
!>
!> The setter is looked up at run time (dlsym, glibc >= 2.34 has it in libc), so that the
!> kernel still links and runs against any BLAS: with reference BLAS or one without the
!> symbol nothing is done. OPENBLAS_NUM_THREADS set by the user is honoured (not overridden).
module blas_threads
   use, intrinsic :: iso_c_binding, only: c_ptr, c_funptr, c_char, c_int, c_null_char, c_null_ptr, &
                                          c_associated, c_f_procpointer
   implicit none
   private
   public :: match_blas_threads, blas_thread_count

   abstract interface
      subroutine set_threads_t(n) bind(c)
         import :: c_int
         integer(c_int), value :: n
      end subroutine set_threads_t
      function get_threads_t() bind(c) result(n)
         import :: c_int
         integer(c_int) :: n
      end function get_threads_t
   end interface

   interface
      !> dlsym(RTLD_DEFAULT, name): RTLD_DEFAULT is the null handle in glibc.
      function dlsym(handle, name) bind(c, name='dlsym') result(address)
         import :: c_ptr, c_funptr, c_char
         type(c_ptr), value :: handle
         character(kind=c_char), intent(in) :: name(*)
         type(c_funptr) :: address
      end function dlsym
   end interface

contains

   !> Gives OpenBLAS `threads` threads unless OPENBLAS_NUM_THREADS is set.
   subroutine match_blas_threads(threads)
      integer, intent(in) :: threads
      type(c_funptr) :: address
      procedure(set_threads_t), pointer :: set_threads
      integer :: length, status
      call get_environment_variable('OPENBLAS_NUM_THREADS', length=length, status=status)
      if (status == 0 .and. length > 0) return
      address = dlsym(c_null_ptr, 'openblas_set_num_threads'//c_null_char)
      if (.not. c_associated(address)) return
      call c_f_procpointer(address, set_threads)
      call set_threads(int(max(1, threads), c_int))
   end subroutine match_blas_threads

   !> The number of threads OpenBLAS uses; -1 where the BLAS library is not OpenBLAS.
   integer function blas_thread_count()
      type(c_funptr) :: address
      procedure(get_threads_t), pointer :: get_threads
      blas_thread_count = -1
      address = dlsym(c_null_ptr, 'openblas_get_num_threads'//c_null_char)
      if (.not. c_associated(address)) return
      call c_f_procpointer(address, get_threads)
      blas_thread_count = get_threads()
   end function blas_thread_count

end module blas_threads
