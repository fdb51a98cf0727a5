!> Explicit interfaces of the LAPACK routines the kernel calls, declared once so that every
!> call is checked against one signature (LAPACK itself ships no Fortran module).
module lapack_interfaces
   use capsim_kinds, only: dp
   implicit none
   private
   public :: dgetrf, dgetrs, dgesv, dgecon, dgeev

   interface
      !> LU factorisation with partial pivoting.
      subroutine dgetrf(m, n, a, lda, ipiv, info)
         import :: dp
         integer, intent(in) :: m, n, lda
         real(dp), intent(inout) :: a(lda, *)
         integer, intent(out) :: ipiv(*), info
      end subroutine dgetrf
      !> Solve with the factors of dgetrf.
      subroutine dgetrs(trans, n, nrhs, a, lda, ipiv, b, ldb, info)
         import :: dp
         character, intent(in) :: trans
         integer, intent(in) :: n, nrhs, lda, ldb
         real(dp), intent(in) :: a(lda, *)
         integer, intent(in) :: ipiv(*)
         real(dp), intent(inout) :: b(ldb, *)
         integer, intent(out) :: info
      end subroutine dgetrs
      !> Factorise and solve in one call.
      subroutine dgesv(n, nrhs, a, lda, ipiv, b, ldb, info)
         import :: dp
         integer, intent(in) :: n, nrhs, lda, ldb
         real(dp), intent(inout) :: a(lda, *), b(ldb, *)
         integer, intent(out) :: ipiv(*), info
      end subroutine dgesv
      !> Reciprocal condition number from the factors of dgetrf.
      subroutine dgecon(norm, n, a, lda, anorm, rcond, work, iwork, info)
         import :: dp
         character, intent(in) :: norm
         integer, intent(in) :: n, lda
         real(dp), intent(in) :: a(lda, *), anorm
         real(dp), intent(out) :: rcond
         real(dp), intent(out) :: work(*)
         integer, intent(out) :: iwork(*)
         integer, intent(out) :: info
      end subroutine dgecon
      !> Eigenvalues (and vectors) of a general matrix.
      subroutine dgeev(jobvl, jobvr, n, a, lda, wr, wi, vl, ldvl, vr, ldvr, work, lwork, info)
         import :: dp
         character, intent(in) :: jobvl, jobvr
         integer, intent(in) :: n, lda, ldvl, ldvr, lwork
         real(dp), intent(inout) :: a(lda, *)
         real(dp), intent(out) :: wr(*), wi(*), vl(ldvl, *), vr(ldvr, *), work(*)
         integer, intent(out) :: info
      end subroutine dgeev
   end interface
end module lapack_interfaces
