!> The catalogue of capsim's command-line options: per option its name, argument, group, unit,
!> a note on its default and one line of help. It is the one list of options: the parser
!> (run_options) accepts exactly these names, the namelist reader the same names written as
!> variables (a_over_l for --a-over-l), and `capsim --help` prints this table, with each default
!> read from the default-initialised run_options_t (nothing here types a default value).
!>
!> Scales: lengths in a (capsule radius) in the shear flow and l (tube radius) in the tube;
!> time in 1/gamma_dot (shear) or l/V (tube, V the mean velocity); forces in G_s.
module option_table
   implicit none
   private
   public :: option_spec_t, option_specs, option_index, option_applies, option_context, n_options

   type :: option_spec_t
      !> '--name', and a short alias ('-h') or ''.
      character(len=20) :: name = ''
      character(len=4) :: short = ''
      !> What follows the option ('VALUE', 'shear|tube'); '' for a flag that takes no value.
      character(len=28) :: arg = ''
      character(len=32) :: group = ''
      !> Unit of a number ('dimensionless' where it has none); '' for words and flags.
      character(len=72) :: unit = ''
      !> The option must be given (the default column then says "required" and the note).
      logical :: required = .false.
      !> Printed after the default value, or alone where the default is empty ('' = nothing).
      character(len=56) :: default_note = ''
      character(len=120) :: help = ''
      !> Where the option applies: the flows and tube models ('shear', 'tube-axi', 'tube-3d',
      !> blank-separated) and membrane laws ('NH', 'SK', 'GH'); '' = everywhere. Given
      !> elsewhere, the option is refused (it would be ignored): see option_applies.
      character(len=24) :: contexts = ''
      character(len=8) :: laws = ''
   end type option_spec_t

   character(len=*), parameter :: time_unit = '1/gamma_dot (shear), l/V (tube)'

   !> In the order of `capsim --help`, group by group.
   type(option_spec_t), parameter :: option_specs(*) = [ &
      option_spec_t(name='--flow', arg='shear|tube', group='flow and law', required=.true., &
                    help='undisturbed flow: unbounded simple shear, or Poiseuille flow in a circular tube'), &
      option_spec_t(name='--law', arg='NH|SK|GH', group='flow and law', required=.true., &
                    help='membrane law: neo-Hookean, Skalak (--C) or generalised Hooke (--nu-s)'), &
      option_spec_t(name='--ca', arg='VALUE', group='flow and law', required=.true., &
                    unit='dimensionless: Ca_s = mu gamma_dot a / G_s (shear), mu V / G_s (tube)', &
                    help='capillary number of the membrane, in (0, 100]'), &
      option_spec_t(name='--nu-s', arg='VALUE', group='flow and law', unit='dimensionless', &
                    help='surface Poisson ratio nu_s of the GH law, in (-1, 1)', &
                    laws='GH'), &
      option_spec_t(name='--C', arg='VALUE', group='flow and law', unit='dimensionless: K_s = (1 + 2 C) G_s', &
                    help='area-dilation parameter C of the SK law, > -0.5', &
                    laws='SK'), &
      option_spec_t(name='--lambda', arg='VALUE', group='flow and law', unit='dimensionless', &
                    help='viscosity ratio lambda = inner / outer viscosity, in (0, 1e6]'), &
      option_spec_t(name='--prestress', arg='ALPHA', group='flow and law', unit='dimensionless', &
                    help='pre-inflation: the stress-free membrane is the sphere of radius a/(1 + alpha); in [0, 0.5]'), &
      option_spec_t(name='--kb', arg='VALUE', group='flow and law', unit='dimensionless: k_b = K_B / (G_s a^2)', &
                    help='bending stiffness (discrete Helfrich energy), in [0, 1]; shear: the default keeps small '// &
                         'Ca_s free of node-scale wrinkles'), &
      option_spec_t(name='--level', arg='N', group='mesh', unit='count (level 4 = 2562 nodes)', &
                    help='subdivision level of the icosphere mesh of the capsule (shear; tube --model 3d), 1 to 5', &
                    contexts='shear tube-3d'), &
      option_spec_t(name='--n-meridian', arg='N', group='mesh', unit='count (elements)', &
                    help='meridian elements from pole to pole (tube --model axi), 8 to 1024', &
                    contexts='tube-axi'), &
      option_spec_t(name='--a-over-l', arg='VALUE', group='tube', unit='dimensionless: a / l', required=.true., &
                    default_note='with --flow tube', &
                    help='size ratio of the capsule radius a to the tube radius l, in (0, 1.3]', &
                    contexts='tube-axi tube-3d'), &
      option_spec_t(name='--model', arg='axi|3d', group='tube', &
                    help='tube model: axisymmetric (fast path) or 3D boundary elements', &
                    contexts='tube-axi tube-3d'), &
      option_spec_t(name='--channel', arg='tube|square|rect', group='tube', &
                    help='cross-section: circular tube, square or rectangular duct (--model 3d; lengths in the '// &
                         'half-width)', &
                    contexts='tube-axi tube-3d'), &
      option_spec_t(name='--aspect', arg='H/W', group='tube', unit='dimensionless: height / width', &
                    help='aspect ratio of the rectangular duct (--channel rect), 0.1 to 10; the height along y', &
                    contexts='tube-3d'), &
      option_spec_t(name='--tube-length', arg='LENGTH', group='tube', unit='l (tube radius)', &
                    help='length of the modelled tube, 4 to 40', &
                    contexts='tube-axi tube-3d'), &
      option_spec_t(name='--wall-h-far', arg='LENGTH', group='tube', unit='l (tube radius)', &
                    help='wall element size away from the centre (--model 3d), 0.02 to 1', &
                    contexts='tube-3d'), &
      option_spec_t(name='--wall-h-centre', arg='LENGTH', group='tube', unit='l (tube radius)', &
                    help='wall element size over |z| < 1 (--model 3d), 0.02 to --wall-h-far', &
                    contexts='tube-3d'), &
      ! A machine setting (like --threads), accepted with every flow: only --model 3d caches a wall.
      option_spec_t(name='--wall-cache', arg='DIR|none', group='tube', &
                    default_note='$XDG_CACHE_HOME/capsmech or ~/.cache/capsmech', &
                    help='directory of the cached wall LU (--model 3d); none = no cache'), &
      option_spec_t(name='--self-quadrature', arg='vertex|full', group='tube', default_note='full', &
                    help='membrane self single layer (--model 3d): 7-point rule on every triangle (full) or '// &
                         'one Stokeslet per node (vertex)', &
                    contexts='tube-3d'), &
      option_spec_t(name='--offset', arg='LENGTH', group='tube', unit='l (tube radius)', &
                    help='initial radial position of the capsule centroid along x (--model 3d), offset + a/l <= 0.9', &
                    contexts='tube-3d'), &
      option_spec_t(name='--offset-mode', arg='drift|held', group='tube', &
                    help='drift: the capsule migrates from --offset; held: its centroid is put back to x = offset', &
                    contexts='tube-3d'), &
      option_spec_t(name='--integrator', arg='auto|newton|implicit|rk2', group='time stepping and solver', &
                    help='auto: shear implicit ROS2 for small Ca_s else RK2; tube axi Newton for small Ca_s else '// &
                         'ROS2; tube 3d RK2 (or newton)'), &
      option_spec_t(name='--dt', arg='TIME', group='time stepping and solver', unit=time_unit, &
                    default_note='= automatic: dt_factor Ca_s h_min', &
                    help='time step; 0 = automatic'), &
      option_spec_t(name='--dt-factor', arg='VALUE', group='time stepping and solver', unit='dimensionless', &
                    help='automatic time step dt = dt_factor Ca_s h_min (h_min the smallest mesh edge), capped'), &
      option_spec_t(name='--t-max', arg='TIME', group='time stepping and solver', unit=time_unit, &
                    help='simulated time at which the run stops if it has not ended before'), &
      option_spec_t(name='--newton-tol', arg='VELOCITY', group='time stepping and solver', unit='V (mean velocity)', &
                    help='Newton (tube axi) converges when the largest membrane velocity in the capsule frame is below this', &
                    contexts='tube-axi'), &
      option_spec_t(name='--volume-correction', arg='on|off', group='time stepping and solver', &
                    help='remove the spurious net flux of the discretisation through the membrane'), &
      option_spec_t(name='--steady-tol', arg='VALUE', group='end of run', &
                    unit='dimensionless (a fraction of 4 pi a^2)', &
                    help='steady state when the area varies by less than steady_tol 4 pi a^2 over one time unit'), &
      option_spec_t(name='--max-length', arg='LENGTH', group='end of run', unit='a (capsule radius)', &
                    help='continuous elongation is declared when the half-length L1 exceeds this, > 1'), &
      option_spec_t(name='--branch-ca', arg='CA1,CA2,...', group='steady branch (axi, 3d newton)', &
                    unit='dimensionless', default_note='none: one case at --ca', &
                    help='follow the steady branch over these ascending Ca_s (a case file each, --out with {ca}); '// &
                         '3d: --integrator newton', &
                    contexts='tube-axi tube-3d'), &
      option_spec_t(name='--branch-summary', arg='FILE.h5', group='steady branch (axi, 3d newton)', &
                    default_note='none', &
                    help='with --branch-ca: the branch file (its points, the critical Ca_s where it ends)', &
                    contexts='tube-axi tube-3d'), &
      option_spec_t(name='--out', arg='FILE.h5', group='output and checkpoint', required=.true., &
                    help='path of the HDF5 case file to write (checkpoints go to FILE.h5.ckpt)'), &
      option_spec_t(name='--record-every', arg='TIME', group='output and checkpoint', unit=time_unit, &
                    help='interval between the rows of /history'), &
      option_spec_t(name='--checkpoint-every', arg='SECONDS', group='output and checkpoint', unit='s (wall clock)', &
                    help='wall-clock time between checkpoints'), &
      option_spec_t(name='--quiet', group='output and checkpoint', &
                    help='print nothing on stdout (no progress lines)'), &
      option_spec_t(name='--threads', arg='N', group='run', unit='count', &
                    default_note='= the OpenMP default (OMP_NUM_THREADS)', &
                    help='OpenMP threads; 0 = the OpenMP default'), &
      option_spec_t(name='--namelist', arg='FILE', group='run', default_note='none', &
                    help='read group &capsim of FILE first: every option with a value, named without -- and with _ '// &
                         'for - (a_over_l = 0.8)'), &
      option_spec_t(name='--help', short='-h', group='run', &
                    help='print this help and exit'), &
      option_spec_t(name='--version', group='run', &
                    help='print the kernel version (the code_version case files record) and exit') &
      ]

   integer, parameter :: n_options = size(option_specs)

contains

   !> Index in option_specs of the option called `name` (its long or short name); 0 if none.
   pure integer function option_index(name)
      character(len=*), intent(in) :: name
      integer :: i
      option_index = 0
      if (len_trim(name) == 0) return
      do i = 1, size(option_specs)
         if (trim(name) == trim(option_specs(i)%name) .or. trim(name) == trim(option_specs(i)%short)) then
            option_index = i
            return
         end if
      end do
   end function option_index

   !> The context of a run for option_applies: 'shear', 'tube-axi' or 'tube-3d'.
   pure function option_context(flow, model) result(context)
      character(len=*), intent(in) :: flow, model
      character(len=:), allocatable :: context
      if (trim(flow) == 'tube') then
         context = 'tube-'//trim(model)
      else
         context = trim(flow)
      end if
   end function option_context

   !> True if `spec` applies in `context` (option_context) with membrane law `law`.
   pure logical function option_applies(spec, context, law)
      type(option_spec_t), intent(in) :: spec
      character(len=*), intent(in) :: context, law
      option_applies = (len_trim(spec%contexts) == 0 .or. has_word(spec%contexts, context)) .and. &
                       (len_trim(spec%laws) == 0 .or. has_word(spec%laws, law))
   end function option_applies

   pure logical function has_word(list, word)
      character(len=*), intent(in) :: list, word
      has_word = index(' '//trim(list)//' ', ' '//trim(word)//' ') > 0
   end function has_word

end module option_table
