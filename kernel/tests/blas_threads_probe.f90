!> Prints the BLAS library's thread count after capsim's rule (blas_threads) for each thread
!> count given, so that tests/kernel/test_blas_threads.py can check that --threads N gives the
!> BLAS N threads (and that OPENBLAS_NUM_THREADS, when set, is left as the user set it).
!>
!> Usage: blas_threads_probe N1 [N2 ...]; prints "before K" then "threads N K" per argument,
!> K = -1 where the BLAS library is not OpenBLAS.
program blas_threads_probe
   use, intrinsic :: iso_fortran_env, only: output_unit
   use blas_threads, only: match_blas_threads, blas_thread_count
   implicit none
   integer :: k, n
   character(len=32) :: arg
   write (output_unit, '(a,1x,i0)') 'before', blas_thread_count()
   do k = 1, command_argument_count()
      call get_command_argument(k, arg)
      read (arg, *) n
      call match_blas_threads(n)
      write (output_unit, '(a,1x,i0,1x,i0)') 'threads', n, blas_thread_count()
   end do
end program blas_threads_probe
