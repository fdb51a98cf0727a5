!> Real kind and the few constants that every module of the kernel shares.
module capsim_kinds
   implicit none
   private
   public :: dp, pi, code_version, schema_version

   integer, parameter :: dp = selected_real_kind(15, 307)
   real(dp), parameter :: pi = 3.14159265358979323846264338327950288_dp
   !> Version of the kernel written into every case file (provenance of databases).
   character(len=*), parameter :: code_version = '0.3.6'
   !> Layout version of the HDF5 case file.
   integer, parameter :: schema_version = 1
end module capsim_kinds
