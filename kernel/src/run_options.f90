!> Run parameters of capsim: read from the command line (and optionally a namelist file),
!> validated field by field. Errors come back as (stat, errmsg) naming the field; the program
!> turns them into one line on stderr and exit code 2. The options themselves (names, units,
!> help) are option_table's; bind_option ties each to its component here, for the parser and
!> for the defaults that write_help prints.
module run_options
   use capsim_kinds, only: dp, code_version
   use text_format, only: real_text, int_text
   use text_parse, only: parse_real, parse_int
   use file_ops, only: path_kind, path_absent, path_regular, path_directory, folder_of, folder_writable
   use option_table, only: option_spec_t, option_specs, option_index, option_applies, option_context, n_options
   use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
   use omp_lib, only: omp_get_num_procs
   implicit none
   private
   public :: run_options_t, parse_command_line, option_signature, write_help, path_len, branch_ca_values, branch_case_path, &
             step_count_problem, shear_kb_default, shear_implicit_below_ca

   !> Most time steps a run may take to reach t = 1 (one time unit, the shortest span over which
   !> a steady state is judged): the smallest automatic step (level 5, Ca_s 1e-3) takes 1e5, so
   !> more is a time step typed wrong, refused before any work. A long t_max is no fault: the
   !> run ends at its steady state.
   real(dp), parameter :: max_time_steps = 1.0e7_dp
   !> Largest namelist file read: a namelist of every option is under 2 kB.
   integer, parameter :: max_namelist_bytes = 65536

   !> Longest path (--out, --wall-cache, --namelist) the kernel holds; a longer one is refused.
   integer, parameter :: path_len = 1024
   !> Longest command-line argument read (an option with its "=value").
   integer, parameter :: arg_len = path_len + 64

   !> The shear flow's model choices where the options leave them open: those of the shipped
   !> shear database (config/paper.yaml, shear.settings), so that a plain run reaches the steady
   !> state the database holds. Without bending stiffness the membrane wrinkles at the node
   !> scale under the compressive tensions of Ca_s < 0.15 and has no steady shape; k_b = 3e-4 is
   !> the smallest that keeps levels 3 and 4 steady down to Ca_s 0.01, at a cost of -0.18 %
   !> (Ca_s 0.15) to -0.11 % (0.3) in D12. The tube's default k_b is 0.
   real(dp), parameter :: shear_kb_default = 3.0e-4_dp
   !> Below this Ca_s, --integrator auto takes implicit (ROS2) steps in shear: the explicit
   !> step is bound by the membrane's stiffness (dt ~ Ca_s h_min), the implicit one is not.
   real(dp), parameter :: shear_implicit_below_ca = 0.07_dp

   type :: run_options_t
      character(len=16) :: flow = ''
      character(len=16) :: law = ''
      !> Tube flow: size ratio a/l and the solver ('axi' fast path or '3d').
      real(dp) :: a_over_l = -huge(1.0_dp)
      character(len=16) :: model = 'axi'
      !> Cross-section of the channel: 'tube' (circular, radius l), 'square' or 'rect' (a duct
      !> of half-width w along x, the length scale then, and half-height aspect w along y).
      character(len=16) :: channel = 'tube'
      real(dp) :: aspect = 1.0_dp
      !> Axisymmetric model: number of meridian elements from pole to pole, and the solver
      !> ('newton': steady shape by Newton with continuation in Ca; 'rk2': time stepping;
      !> 'auto': Newton for nearly rigid capsules, Ca < 0.005, implicit steps otherwise and after
      !> a failed Newton; see axisymmetric_tube). 3D tube: 'auto' is 'rk2'. Shear: 'implicit'
      !> takes linearly implicit ROS2 steps (capsule_dynamics); 'auto' becomes 'implicit' below
      !> Ca_s shear_implicit_below_ca and 'rk2' above (apply_flow_defaults).
      integer :: n_meridian = 64
      !> Tube length [l] (the paper's 3D tube is 20 l; the disturbance decays within a few l).
      real(dp) :: tube_length = 10.0_dp
      character(len=16) :: integrator = 'auto'
      !> 3D tube model: wall element sizes [l] away from the centre and over |z| < 1 (the
      !> paper's 0.14 and 0.07), and the directory of the cached wall LU ('' = the user's
      !> cache, $XDG_CACHE_HOME/capsmech or ~/.cache/capsmech; 'none' = no cache).
      real(dp) :: wall_h_far = 0.14_dp
      real(dp) :: wall_h_centre = 0.07_dp
      character(len=path_len) :: wall_cache = ''
      !> 3D tube model: quadrature of the membrane's own single layer ('full': the 7-point rule
      !> on every triangle; 'vertex': one Stokeslet per node beyond the second ring, the model
      !> before it). '' = the model's default, full.
      character(len=16) :: self_quadrature = ''
      !> Newton converges when the largest membrane velocity in the capsule frame is below this [V].
      real(dp) :: newton_tol = 1.0e-8_dp
      real(dp) :: nu_s = 0.5_dp
      !> Pre-stress alpha: the stress-free membrane is the sphere of radius a/(1 + alpha),
      !> inflated to radius a at rest (an isotropic pre-tension).
      real(dp) :: prestress = 0.0_dp
      !> Bending stiffness k_b = K_B / (G_s a**2) (discrete Helfrich energy, membrane_bending);
      !> not given, shear_kb_default in shear (apply_flow_defaults).
      real(dp) :: kb = 0.0_dp
      !> 3D tube: initial radial position of the capsule's centroid over l (along x); the
      !> capsule is then re-centred axially only and drifts radially as the flow moves it.
      real(dp) :: offset = 0.0_dp
      !> 'drift' (the capsule migrates from --offset) or 'held' (its centroid is put back to
      !> x = offset after every step: the quasi-steady shape at a fixed radial position, for
      !> capsules whose migration is slow against their shape's relaxation).
      character(len=8) :: offset_mode = 'drift'
      real(dp) :: c = 1.0_dp
      !> Viscosity ratio lambda = inner / outer viscosity (shear and both tube models; 1 = the base model).
      real(dp) :: lambda = 1.0_dp
      real(dp) :: ca = -huge(1.0_dp)
      integer :: level = 3
      !> Time step; 0 selects dt_factor * Ca * h_min.
      real(dp) :: dt = 0.0_dp
      real(dp) :: dt_factor = 0.5_dp
      real(dp) :: t_max = 60.0_dp
      integer :: threads = 0
      character(len=path_len) :: out = ''
      !> Steady branch (tube axi, or 3d with --integrator newton): the requested Ca_s as given ('0.01,0.02,...', '' = one case at
      !> --ca), and the branch file. --out then holds '{ca}', replaced by each value's text.
      character(len=path_len) :: branch_ca = ''
      character(len=path_len) :: branch_summary = ''
      !> Steady: area varies by less than steady_tol * 4 pi a**2 over one time unit, and D12
      !> by less than shape_tol * D12 (+1e-4 absolute).
      real(dp) :: steady_tol = 1.0e-3_dp
      real(dp) :: shape_tol = 5.0e-3_dp
      !> Continuous elongation is declared when L1 exceeds this [a].
      real(dp) :: max_length = 3.0_dp
      real(dp) :: record_every = 0.05_dp
      !> Wall-clock seconds between checkpoints.
      real(dp) :: checkpoint_every = 10.0_dp
      !> Remove the discretisation's spurious net flux through the membrane (see capsule_dynamics).
      logical :: volume_correction = .true.
      logical :: quiet = .false.
      logical :: show_help = .false.
      logical :: show_version = .false.
      !> Which options of option_table (by index) were given, on the command line or in the
      !> namelist: an option given where it does not apply is refused (validate).
      logical :: given(n_options) = .false.
   end type run_options_t

contains

   !> Reads the options (a namelist file first, if --namelist is given, then the flags, which
   !> override it) and validates them. Names come from option_table; unknown ones are errors.
   subroutine parse_command_line(opts, stat, errmsg)
      type(run_options_t), intent(out) :: opts
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: k, n, eq, i, arg_status
      character(len=arg_len) :: arg, key, value
      character(len=:), allocatable :: shown
      logical :: has_value, on_command_line(n_options)

      stat = 0
      errmsg = ''
      n = command_argument_count()
      ! A namelist file is read first so that flags given beside it override it.
      k = 1
      do while (k <= n)
         call get_command_argument(k, arg)
         if (trim(arg) == '--namelist' .or. arg(1:11) == '--namelist=') then
            if (trim(arg) == '--namelist') then
               if (k == n) then
                  call fail('--namelist', 'needs a file name')
                  return
               end if
               call get_command_argument(k + 1, value, status=arg_status)
               if (arg_status /= 0) then
                  call fail('--namelist', 'file name longer than '//int_text(path_len)//' characters')
                  return
               end if
            else
               value = arg(12:)
            end if
            if (len_trim(value) > path_len) then
               call fail('--namelist', 'file name longer than '//int_text(path_len)//' characters')
               return
            end if
            call read_namelist(trim(value), opts, stat, errmsg)
            if (stat /= 0) return
         end if
         k = k + 1
      end do
      on_command_line = .false.
      k = 1
      do while (k <= n)
         call get_command_argument(k, arg, status=arg_status)
         k = k + 1
         eq = index(arg, '=')
         if (arg_status /= 0) then
            ! Cut to arg_len: refused, as a path that long would be written elsewhere.
            if (arg(1:2) == '--' .and. eq > 0) then
               call fail(arg(:eq - 1), 'value longer than '//int_text(path_len)//' characters')
            else
               call fail(arg(:40)//'...', 'argument longer than '//int_text(path_len)//' characters')
            end if
            return
         end if
         if (arg(1:2) == '--' .and. eq > 0) then
            key = arg(:eq - 1)
            value = arg(eq + 1:)
            has_value = .true.
         else
            key = arg
            value = ''
            has_value = .false.
         end if
         i = option_index(trim(key))
         if (i == 0) then
            if (key(1:1) /= '-') then
               call fail(trim(arg), 'unexpected argument (options start with --)')
            else
               call fail(trim(key), 'unknown option')
            end if
            return
         end if
         if (len_trim(option_specs(i)%arg) == 0) then
            if (has_value) then
               call fail(trim(key), 'takes no value')
               return
            end if
         else if (.not. has_value) then
            if (k > n) then
               call fail(trim(key), 'needs a value')
               return
            end if
            call get_command_argument(k, value, status=arg_status)
            if (arg_status /= 0) then
               call fail(trim(key), 'value longer than '//int_text(path_len)//' characters')
               return
            end if
            k = k + 1
         end if
         ! A flag given twice is a mistake in the calling script, not a preference for the last.
         if (on_command_line(i)) then
            call fail(trim(option_specs(i)%name), 'given more than once')
            return
         end if
         on_command_line(i) = .true.
         opts%given(i) = .true.
         call bind_option(opts, trim(option_specs(i)%name), .true., value, shown, stat, errmsg)
         if (stat /= 0) return
      end do
      if (opts%show_help .or. opts%show_version) return
      ! A branch runs its cases at the listed Ca_s; --ca, if not given, is the first of them
      ! (the case that time stepping starts from).
      if (len_trim(opts%branch_ca) > 0 .and. .not. opts%given(option_index('--ca'))) then
         block
            real(dp), allocatable :: values(:)
            logical :: ok
            call branch_ca_values(opts, values, ok)
            if (ok) opts%ca = values(1)
         end block
      end if
      call apply_flow_defaults(opts)
      call validate(opts, stat, errmsg)

   contains

      subroutine fail(field, reason)
         character(len=*), intent(in) :: field, reason
         stat = 2
         errmsg = field//': '//reason
      end subroutine fail

   end subroutine parse_command_line

   !> The defaults that depend on the flow, for the options not given (on the command line or
   !> in the namelist): in shear, the bending stiffness shear_kb_default and, for --integrator
   !> auto, implicit steps below Ca_s shear_implicit_below_ca and RK2 above. The resolved values
   !> are those the run uses, the case file records (k_b) and the checkpoint signature holds:
   !> a checkpoint written under other defaults is never resumed.
   subroutine apply_flow_defaults(opts)
      type(run_options_t), intent(inout) :: opts
      if (trim(opts%flow) /= 'shear') return
      if (.not. opts%given(option_index('--kb'))) opts%kb = shear_kb_default
      ! An unset --ca is refused by validate; nothing to choose from then.
      if (trim(opts%integrator) == 'auto' .and. opts%ca /= -huge(1.0_dp)) &
         opts%integrator = merge('implicit', 'rk2     ', opts%ca < shear_implicit_below_ca)
   end subroutine apply_flow_defaults

   !> What the help adds to an option's default where a rule, not a value, chooses it.
   function default_rule(name) result(rule)
      character(len=*), intent(in) :: name
      character(len=:), allocatable :: rule
      rule = ''
      if (name == '--integrator') rule = '(shear: implicit below Ca_s '//short_real_text(shear_implicit_below_ca)// &
                                         ', rk2 above)'
   end function default_rule

   !> The one binding of each option of option_table to its component of run_options_t, both
   !> ways: with `set`, reads `text` into the component (stat = 2 and errmsg naming the option
   !> for a bad value); without, writes the component's value into `shown` (the help prints the
   !> defaults so). An option of the table without a case here is a bug: stat = 3.
   subroutine bind_option(opts, name, set, text, shown, stat, errmsg)
      type(run_options_t), intent(inout) :: opts
      character(len=*), intent(in) :: name
      logical, intent(in) :: set
      character(len=*), intent(in) :: text
      character(len=:), allocatable, intent(out) :: shown
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg

      stat = 0
      errmsg = ''
      shown = ''
      select case (name)
      case ('--help')
         call flag_field(opts%show_help)
      case ('--version')
         call flag_field(opts%show_version)
      case ('--quiet')
         call flag_field(opts%quiet)
      case ('--namelist')
         ! Read before the flags (parse_command_line); nothing is left to set.
         continue
      case ('--flow')
         call word_field(opts%flow)
      case ('--law')
         call word_field(opts%law)
      case ('--model')
         call word_field(opts%model)
      case ('--a-over-l')
         call real_field(opts%a_over_l)
      case ('--integrator')
         call word_field(opts%integrator)
      case ('--channel')
         call word_field(opts%channel)
      case ('--aspect')
         call real_field(opts%aspect)
      case ('--tube-length')
         call real_field(opts%tube_length)
      case ('--wall-h-far')
         call real_field(opts%wall_h_far)
      case ('--wall-h-centre')
         call real_field(opts%wall_h_centre)
      case ('--wall-cache')
         if (set .and. len_trim(text) == 0) then
            call fail('empty directory name (use none to disable the cache)')
         else
            call word_field(opts%wall_cache)
         end if
      case ('--self-quadrature')
         call word_field(opts%self_quadrature)
      case ('--n-meridian')
         call int_field(opts%n_meridian)
      case ('--out')
         call word_field(opts%out)
      case ('--nu-s')
         call real_field(opts%nu_s)
      case ('--C')
         call real_field(opts%c)
      case ('--ca')
         call real_field(opts%ca)
      case ('--lambda')
         call real_field(opts%lambda)
      case ('--dt')
         call real_field(opts%dt)
      case ('--dt-factor')
         call real_field(opts%dt_factor)
      case ('--newton-tol')
         call real_field(opts%newton_tol)
      case ('--t-max')
         call real_field(opts%t_max)
      case ('--steady-tol')
         call real_field(opts%steady_tol)
      case ('--max-length')
         call real_field(opts%max_length)
      case ('--record-every')
         call real_field(opts%record_every)
      case ('--checkpoint-every')
         call real_field(opts%checkpoint_every)
      case ('--volume-correction')
         call switch_field(opts%volume_correction)
      case ('--level')
         call int_field(opts%level)
      case ('--prestress')
         call real_field(opts%prestress)
      case ('--kb')
         call real_field(opts%kb)
      case ('--offset')
         call real_field(opts%offset)
      case ('--offset-mode')
         call word_field(opts%offset_mode)
      case ('--threads')
         call int_field(opts%threads)
      case ('--branch-ca')
         call word_field(opts%branch_ca)
      case ('--branch-summary')
         call word_field(opts%branch_summary)
      case default
         stat = 3
         errmsg = name//': in option_table but not bound to a field of run_options_t'
      end select

   contains

      subroutine fail(reason)
         character(len=*), intent(in) :: reason
         stat = 2
         errmsg = name//': '//reason
      end subroutine fail

      !> A word or a path; a value longer than the component is refused, not cut.
      subroutine word_field(s)
         character(len=*), intent(inout) :: s
         if (set) then
            if (len_trim(text) > len(s)) then
               call fail('longer than '//int_text(len(s))//' characters')
               return
            end if
            s = text
         else
            shown = trim(s)
         end if
      end subroutine word_field

      !> The whole value must be one finite decimal number (text_parse).
      subroutine real_field(x)
         real(dp), intent(inout) :: x
         logical :: ok
         if (.not. set) then
            shown = short_real_text(x)
            return
         end if
         call parse_real(text, x, ok)
         if (.not. ok) call fail('not a finite number: "'//trim(text)//'"')
      end subroutine real_field

      subroutine int_field(i)
         integer, intent(inout) :: i
         logical :: ok
         if (.not. set) then
            shown = int_text(i)
            return
         end if
         call parse_int(text, i, ok)
         if (.not. ok) call fail('not an integer: "'//trim(text)//'"')
      end subroutine int_field

      !> on|off (also 1|0, yes|no, and a namelist's .true.|.false.).
      subroutine switch_field(on)
         logical, intent(inout) :: on
         if (.not. set) then
            shown = merge('on ', 'off', on)
            shown = trim(shown)
            return
         end if
         select case (trim(text))
         case ('on', '1', 'yes', '.true.')
            on = .true.
         case ('off', '0', 'no', '.false.')
            on = .false.
         case default
            call fail('expected on or off, got "'//trim(text)//'"')
         end select
      end subroutine switch_field

      !> A flag without a value: given, it is on.
      subroutine flag_field(on)
         logical, intent(inout) :: on
         if (set) then
            on = .true.
         else
            shown = trim(merge('on ', 'off', on))
         end if
      end subroutine flag_field

   end subroutine bind_option

   !> `capsim --help`: a usage line, the scales, then every option of option_table, group by
   !> group, one line each: name, argument, help, [unit], (default: ...). The defaults are the
   !> components of a default-initialised run_options_t, shown through bind_option, after
   !> apply_flow_defaults for each flow: where the flows differ, both are shown.
   subroutine write_help(unit)
      integer, intent(in) :: unit
      type(run_options_t) :: shear_defaults, tube_defaults
      type(option_spec_t) :: spec
      character(len=len(spec%group)) :: group
      character(len=:), allocatable :: shown, shown_tube, errmsg, head, default_text
      integer :: i, stat, width

      shear_defaults%flow = 'shear'
      tube_defaults%flow = 'tube'
      call apply_flow_defaults(shear_defaults)
      call apply_flow_defaults(tube_defaults)

      write (unit, '(a)') 'usage: capsim --flow shear|tube --law NH|SK|GH --ca VALUE [--a-over-l VALUE] --out FILE.h5 [options]'
      write (unit, '(a)') '       capsim --namelist FILE [options]      capsim --help'
      write (unit, '(a)') 'Scales: lengths in a (capsule radius, shear) or l (tube radius, tube); time in 1/gamma_dot'// &
         ' (shear) or l/V (tube, V mean velocity); forces in G_s (surface shear modulus).'
      write (unit, '(a)') 'Options take their value as the next argument or after "=" (--ca=0.1).'
      ! The help text starts one column after the longest "-h, --name ARG".
      width = 0
      do i = 1, size(option_specs)
         width = max(width, len(option_head(option_specs(i))))
      end do
      group = ''
      do i = 1, size(option_specs)
         spec = option_specs(i)
         if (spec%group /= group) then
            group = spec%group
            write (unit, '(/,a)') trim(group)//':'
         end if
         call bind_option(tube_defaults, trim(spec%name), .false., '', shown_tube, stat, errmsg)
         if (stat == 0) call bind_option(shear_defaults, trim(spec%name), .false., '', shown, stat, errmsg)
         if (stat /= 0) then
            shown = '? ('//errmsg//')'
         else if (shown /= shown_tube) then
            shown = shown//' in shear, '//shown_tube//' in the tube'
         end if
         shown = trim(shown//' '//default_rule(trim(spec%name)))
         if (spec%required) then
            default_text = trim('required '//spec%default_note)
         else if (len(shown) == 0) then
            default_text = trim(spec%default_note)
            if (len(default_text) == 0) default_text = 'none'
         else
            default_text = trim(shown//' '//spec%default_note)
         end if
         head = option_head(spec)
         head = head//repeat(' ', width - len(head))
         if (len_trim(spec%unit) > 0) then
            write (unit, '(a)') '  '//head//' '//trim(spec%help)//' ['//trim(spec%unit)//'] (default: '//default_text//')'
         else
            write (unit, '(a)') '  '//head//' '//trim(spec%help)//' (default: '//default_text//')'
         end if
      end do
   end subroutine write_help

   !> "-h, --name ARG" of the help.
   pure function option_head(spec) result(head)
      type(option_spec_t), intent(in) :: spec
      character(len=:), allocatable :: head
      head = trim(spec%name)
      if (len_trim(spec%short) > 0) head = trim(spec%short)//', '//head
      if (len_trim(spec%arg) > 0) head = head//' '//trim(spec%arg)
   end function option_head

   !> A default value for the help: up to 6 significant digits, trailing zeros dropped
   !> (10, 0.5, 0.14, 1e-08).
   function short_real_text(x) result(s)
      real(dp), intent(in) :: x
      character(len=:), allocatable :: s
      character(len=32) :: buf
      integer :: e
      if (x == 0.0_dp) then
         s = '0'
         return
      end if
      if (abs(x) >= 1.0e-3_dp .and. abs(x) < 1.0e6_dp) then
         write (buf, '(f0.6)') x
         s = trim(adjustl(buf))
         do while (s(len(s):len(s)) == '0')
            s = s(:len(s) - 1)
         end do
         if (s(len(s):len(s)) == '.') s = s(:len(s) - 1)
         if (s(1:1) == '.') s = '0'//s
         if (s(1:2) == '-.') s = '-0'//s(2:)
      else
         write (buf, '(es13.5e3)') x
         buf = adjustl(buf)
         e = index(buf, 'E')
         s = buf(:e - 1)
         do while (s(len(s):len(s)) == '0')
            s = s(:len(s) - 1)
         end do
         if (s(len(s):len(s)) == '.') s = s(:len(s) - 1)
         ! Exponent without its leading zeros and plus sign: E-008 -> e-8.
         s = s//'e'//trim(merge('-', ' ', buf(e + 1:e + 1) == '-'))//int_text(abs(exponent_of(buf(e + 1:))))
      end if

   contains

      integer function exponent_of(t)
         character(len=*), intent(in) :: t
         read (t, *) exponent_of
      end function exponent_of

   end function short_real_text

   !> Group &capsim of the file `path`, read as Fortran's namelist input writes it: items
   !> `name = value` separated by blanks, commas or line ends, values quoted ('...', "...") or
   !> bare, '!' to the end of a line a comment, the group ended by '/'. The names are derived
   !> from option_table: every option that takes a value, without '--' and with '_' for '-'
   !> (a_over_l for --a-over-l, c for --C; in any case), and each value is read by bind_option
   !> as its flag's is, so the file accepts what the command line accepts, as strictly: an
   !> unknown name, a name given twice and a second group are refused, naming their line. A
   !> variable the group sets counts as its option given (an inapplicable one is refused like
   !> its flag).
   subroutine read_namelist(path, opts, stat, errmsg)
      character(len=*), intent(in) :: path
      type(run_options_t), intent(inout) :: opts
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      character(len=:), allocatable :: text, name, value, shown, reason
      integer :: i, j, k, n, line, name_line, groups, unit, ios, bind_stat
      integer :: first_line(n_options)
      integer(8) :: bytes
      character :: quote
      logical :: in_group

      stat = 2
      errmsg = ''
      ! A device or FIFO (/dev/zero) would be read for ever; a folder cannot be read.
      if (path_kind(path) /= path_regular) then
         if (path_kind(path) == path_absent) then
            errmsg = '--namelist: no such file "'//path//'"'
         else
            errmsg = '--namelist: not a regular file "'//path//'"'
         end if
         return
      end if
      open (newunit=unit, file=path, access='stream', form='unformatted', status='old', action='read', iostat=ios)
      if (ios /= 0) then
         errmsg = '--namelist: cannot open "'//path//'"'
         return
      end if
      inquire (unit=unit, size=bytes)
      if (bytes > max_namelist_bytes) then
         close (unit)
         errmsg = '--namelist: "'//path//'" is '//int_text(int(bytes))//' bytes, larger than any namelist ('// &
                  int_text(max_namelist_bytes)//' at most)'
         return
      end if
      allocate (character(len=max(0, int(bytes))) :: text)
      ios = 0
      if (bytes > 0) read (unit, iostat=ios) text
      close (unit)
      if (ios /= 0) then
         errmsg = '--namelist: cannot read "'//path//'"'
         return
      end if

      first_line = 0
      groups = 0
      in_group = .false.
      line = 1
      n = len(text)
      i = 1
      do while (i <= n)
         select case (text(i:i))
         case (achar(10))
            line = line + 1
            i = i + 1
         case (' ', ',', achar(9), achar(13))
            i = i + 1
         case ('!')
            do while (i <= n)
               if (text(i:i) == achar(10)) exit
               i = i + 1
            end do
         case ('&', '$')
            j = name_end(i + 1)
            name = lower(text(i + 1:j))
            i = j + 1
            if (in_group .and. name == 'end') then
               in_group = .false.
               cycle
            end if
            groups = groups + 1
            if (groups > 1) then
               call fail(line, 'a second group; the file must hold one group &capsim')
               return
            else if (name /= 'capsim') then
               call fail(line, 'group &'//name//' (expected &capsim)')
               return
            end if
            in_group = .true.
         case ('/')
            in_group = .false.
            i = i + 1
         case default
            ! Outside the group Fortran's reader skips everything (a title, notes).
            if (.not. in_group) then
               i = i + 1
               cycle
            end if
            if (.not. is_name_start(text(i:i))) then
               call fail(line, 'unexpected "'//text(i:i)//'" (expected name = value)')
               return
            end if
            name_line = line
            j = name_end(i)
            name = lower(text(i:j))
            i = skip_blanks(j + 1, .false.)
            if (i > n) then
               call fail(name_line, name//' without "= value"')
               return
            else if (text(i:i) /= '=') then
               call fail(name_line, name//' without "= value"')
               return
            end if
            i = skip_blanks(i + 1, .true.)
            if (i > n) then
               call fail(name_line, name//' without a value')
               return
            end if
            if (text(i:i) == "'" .or. text(i:i) == '"') then
               ! A quoted value; a doubled quote inside stands for one.
               quote = text(i:i)
               value = ''
               i = i + 1
               do
                  if (i > n) then
                     call fail(name_line, name//': the quoted value is not closed')
                     return
                  end if
                  if (text(i:i) == quote) then
                     if (i < n) then
                        if (text(i + 1:i + 1) == quote) then
                           value = value//quote
                           i = i + 2
                           cycle
                        end if
                     end if
                     i = i + 1
                     exit
                  end if
                  if (text(i:i) == achar(10)) line = line + 1
                  value = value//text(i:i)
                  i = i + 1
               end do
            else
               j = i
               do while (j <= n)
                  if (index(' ,/!'//achar(9)//achar(10)//achar(13), text(j:j)) > 0) exit
                  j = j + 1
               end do
               value = text(i:j - 1)
               i = j
            end if
            k = namelist_option(name)
            if (k == 0) then
               call fail(name_line, 'unknown name '//name//' (the names are the options that take a value, '// &
                         'without -- and with _ for -: a_over_l = 0.8)')
               return
            else if (first_line(k) > 0) then
               call fail(name_line, name//' is given twice (first on line '//int_text(first_line(k))//')')
               return
            end if
            first_line(k) = name_line
            call bind_option(opts, trim(option_specs(k)%name), .true., value, shown, bind_stat, reason)
            if (bind_stat /= 0) then
               call fail(name_line, name//' ('//reason//')')
               return
            end if
            opts%given(k) = .true.
         end select
      end do
      if (groups == 0) then
         errmsg = '--namelist: "'//path//'" holds no group &capsim'
      else if (in_group) then
         call fail(line, 'group &capsim is not ended by /')
      else
         stat = 0
      end if

   contains

      subroutine fail(at, reason_text)
         integer, intent(in) :: at
         character(len=*), intent(in) :: reason_text
         errmsg = '--namelist: "'//path//'" line '//int_text(at)//': '//reason_text
      end subroutine fail

      !> Index of the last character of the name that starts at `from`.
      integer function name_end(from)
         integer, intent(in) :: from
         name_end = from - 1
         do while (name_end < n)
            if (.not. is_name_char(text(name_end + 1:name_end + 1))) exit
            name_end = name_end + 1
         end do
      end function name_end

      !> The first character at or after `from` that is not a blank (nor, with `lines`, a line end).
      integer function skip_blanks(from, lines)
         integer, intent(in) :: from
         logical, intent(in) :: lines
         skip_blanks = from
         do while (skip_blanks <= n)
            if (text(skip_blanks:skip_blanks) == achar(10) .and. lines) then
               line = line + 1
            else if (index(' '//achar(9)//achar(13), text(skip_blanks:skip_blanks)) == 0) then
               exit
            end if
            skip_blanks = skip_blanks + 1
         end do
      end function skip_blanks

   end subroutine read_namelist

   !> The option of the namelist name `name` (lower case): an option of option_table that takes
   !> a value, its name without '--' and with '_' for '-'; 0 if none.
   integer function namelist_option(name)
      character(len=*), intent(in) :: name
      integer :: i
      namelist_option = 0
      do i = 1, n_options
         if (len_trim(option_specs(i)%arg) == 0 .or. trim(option_specs(i)%name) == '--namelist') cycle
         if (namelist_name(option_specs(i)%name) == name) then
            namelist_option = i
            return
         end if
      end do
   end function namelist_option

   !> 'a_over_l' for '--a-over-l', 'c' for '--C'.
   pure function namelist_name(option) result(name)
      character(len=*), intent(in) :: option
      character(len=:), allocatable :: name
      integer :: m
      name = lower(trim(option(3:)))
      do m = 1, len(name)
         if (name(m:m) == '-') name(m:m) = '_'
      end do
   end function namelist_name

   pure logical function is_name_start(ch)
      character, intent(in) :: ch
      is_name_start = (ch >= 'a' .and. ch <= 'z') .or. (ch >= 'A' .and. ch <= 'Z')
   end function is_name_start

   pure logical function is_name_char(ch)
      character, intent(in) :: ch
      is_name_char = is_name_start(ch) .or. (ch >= '0' .and. ch <= '9') .or. ch == '_'
   end function is_name_char

   pure function lower(word) result(low)
      character(len=*), intent(in) :: word
      character(len=len(word)) :: low
      integer :: m
      low = word
      do m = 1, len(word)
         if (word(m:m) >= 'A' .and. word(m:m) <= 'Z') low(m:m) = achar(iachar(word(m:m)) + 32)
      end do
   end function lower

   !> The most --threads accepted here: 4 per processor the OpenMP runtime sees, at least 64.
   integer function max_threads()
      max_threads = max(64, 4 * omp_get_num_procs())
   end function max_threads

   !> Why steps of dt are too small to get anywhere ('' when they are not): more than
   !> max_time_steps to reach min(t_max, 1).
   function step_count_problem(t_max, dt) result(problem)
      real(dp), intent(in) :: t_max, dt
      character(len=:), allocatable :: problem
      real(dp) :: span
      problem = ''
      span = min(t_max, 1.0_dp)
      if (.not. (span / dt <= max_time_steps)) then
         problem = 'a time step of '//real_text(dt)//' takes '//real_text(span / dt)//' steps to reach t = '// &
                   real_text(span)//', more than the '//real_text(max_time_steps)//' a run may take for one time unit'
      end if
   end function step_count_problem


   subroutine validate(opts, stat, errmsg)
      type(run_options_t), intent(in) :: opts
      integer, intent(out) :: stat
      character(len=:), allocatable, intent(out) :: errmsg
      integer :: unit, ios
      character(len=256) :: iomsg

      stat = 2
      errmsg = ''
      ! The words that choose the model come first: which options apply depends on them.
      select case (trim(opts%flow))
      case ('shear', 'tube')
      case ('')
         errmsg = '--flow: missing (expected shear or tube)'
      case default
         errmsg = '--flow: unknown flow "'//trim(opts%flow)//'" (expected shear or tube)'
      end select
      if (len(errmsg) > 0) return
      select case (trim(opts%law))
      case ('NH', 'SK', 'GH')
      case ('')
         errmsg = '--law: missing (expected NH, SK or GH)'
      case default
         errmsg = '--law: unknown membrane law "'//trim(opts%law)//'" (expected NH, SK or GH)'
      end select
      if (len(errmsg) > 0) return
      if (trim(opts%flow) == 'tube' .and. all(trim(opts%model) /= [character(len=3) :: 'axi', '3d'])) then
         errmsg = '--model: unknown model "'//trim(opts%model)//'" (expected axi or 3d)'
         return
      end if
      call refuse_inapplicable(opts, errmsg)
      if (len(errmsg) > 0) return
      select case (trim(opts%flow))
      case ('shear')
         if (opts%offset /= 0.0_dp) then
            errmsg = '--offset: only for --flow tube --model 3d, got '//real_text(opts%offset)
            return
         else if (len_trim(opts%self_quadrature) > 0) then
            errmsg = '--self-quadrature: only for --flow tube --model 3d, got "'//trim(opts%self_quadrature)//'"'
            return
         else if (all(trim(opts%integrator) /= [character(len=8) :: 'auto', 'implicit', 'rk2'])) then
            errmsg = '--integrator: the shear flow steps with rk2 (auto) or implicit, got "'//trim(opts%integrator)//'"'
            return
         end if
      case ('tube')
         if (opts%a_over_l == -huge(1.0_dp)) then
            errmsg = '--a-over-l: missing (size ratio a/l of the capsule to the tube radius)'
         else if (.not. (opts%a_over_l > 0.0_dp)) then
            errmsg = '--a-over-l: must be > 0, got '//real_text(opts%a_over_l)
         else if (opts%a_over_l > 1.3_dp) then
            errmsg = '--a-over-l: must be <= 1.3 (larger capsules do not fit the model), got '// &
                     real_text(opts%a_over_l)
         else if (all(trim(opts%model) /= [character(len=3) :: 'axi', '3d'])) then
            errmsg = '--model: unknown model "'//trim(opts%model)//'" (expected axi or 3d)'
         else if (all(trim(opts%integrator) /= [character(len=8) :: 'auto', 'newton', 'implicit', 'rk2'])) then
            errmsg = '--integrator: unknown solver "'//trim(opts%integrator)//'" (expected auto, newton, implicit or rk2)'
         else if (trim(opts%model) == '3d' .and. all(trim(opts%integrator) /= [character(len=6) :: 'auto', 'rk2', 'newton'])) then
            errmsg = '--integrator: the 3d tube model steps with rk2 or solves for the steady shape (newton), got "'// &
                     trim(opts%integrator)//'"'
         else if (trim(opts%model) == '3d' .and. trim(opts%integrator) == 'newton' .and. &
                  (opts%offset /= 0.0_dp .or. opts%lambda /= 1.0_dp)) then
            ! An off-centre capsule migrates (no steady shape); lambda /= 1 makes each velocity an
            ! iterative solve, too noisy for the Jacobian's differences.
            errmsg = '--integrator: newton (3d) solves for the steady shape of a centred capsule at lambda = 1 '// &
                     '(no --offset, no --lambda)'
         else if (all(trim(opts%channel) /= [character(len=6) :: 'tube', 'square', 'rect'])) then
            errmsg = '--channel: unknown channel "'//trim(opts%channel)//'" (expected tube, square or rect)'
         else if (trim(opts%channel) /= 'tube' .and. trim(opts%model) /= '3d') then
            errmsg = '--channel: a '//trim(opts%channel)//' duct needs --model 3d (the axisymmetric model is the '// &
                     'circular tube)'
         else if (.not. (opts%aspect >= 0.1_dp .and. opts%aspect <= 10.0_dp)) then
            errmsg = '--aspect: must be between 0.1 and 10 (height over width), got '//real_text(opts%aspect)
         else if (trim(opts%channel) /= 'rect' .and. opts%aspect /= 1.0_dp) then
            errmsg = '--aspect: only for --channel rect (a '//trim(opts%channel)//' has aspect 1), got '// &
                     real_text(opts%aspect)
         else if (trim(opts%channel) == 'rect' .and. opts%a_over_l > 0.9_dp * min(1.0_dp, opts%aspect)) then
            errmsg = '--a-over-l: the capsule must fit the duct, a/w <= 0.9 min(1, aspect) = '// &
                     real_text(0.9_dp * min(1.0_dp, opts%aspect))//', got '//real_text(opts%a_over_l)
         else if (trim(opts%channel) /= 'tube' .and. opts%wall_h_far > 0.75_dp * min(1.0_dp, opts%aspect)) then
            errmsg = '--wall-h-far: must be at most 0.75 min(1, aspect) half-widths in a duct, got '// &
                     real_text(opts%wall_h_far)
         else if (opts%tube_length < 4.0_dp .or. opts%tube_length > 40.0_dp) then
            errmsg = '--tube-length: must be between 4 and 40 tube radii, got '//real_text(opts%tube_length)
         else if (opts%n_meridian < 8 .or. opts%n_meridian > 1024) then
            errmsg = '--n-meridian: must be between 8 and 1024, got '//int_text(opts%n_meridian)
         else if (.not. (opts%wall_h_far >= 0.02_dp .and. opts%wall_h_far <= 1.0_dp)) then
            errmsg = '--wall-h-far: must be between 0.02 and 1 tube radii, got '//real_text(opts%wall_h_far)
         else if (.not. (opts%wall_h_centre >= 0.02_dp .and. opts%wall_h_centre <= opts%wall_h_far)) then
            errmsg = '--wall-h-centre: must be between 0.02 and --wall-h-far ('//real_text(opts%wall_h_far)// &
                     ') tube radii, got '//real_text(opts%wall_h_centre)
         else if (trim(opts%model) == '3d' .and. len_trim(opts%wall_cache) > 0 .and. trim(opts%wall_cache) /= 'none') then
            ! A cache directory given explicitly must exist and be writable now.
            open (newunit=unit, file=trim(opts%wall_cache)//'/.capsim-write-test', status='replace', action='write', &
                  iostat=ios, iomsg=iomsg)
            if (ios /= 0) then
               errmsg = '--wall-cache: cannot write in "'//trim(opts%wall_cache)//'": '//trim(iomsg)
            else
               ! Runs started together share the probe's name: another may have deleted it first.
               close (unit, status='delete', iostat=ios)
            end if
         end if
         if (len(errmsg) == 0 .and. len_trim(opts%self_quadrature) > 0) then
            if (trim(opts%model) /= '3d') then
               errmsg = '--self-quadrature: only for --model 3d, got "'//trim(opts%self_quadrature)//'"'
            else if (all(trim(opts%self_quadrature) /= [character(len=6) :: 'vertex', 'full'])) then
               errmsg = '--self-quadrature: unknown rule "'//trim(opts%self_quadrature)//'" (expected vertex or full)'
            end if
         end if
         if (len(errmsg) == 0 .and. all(trim(opts%offset_mode) /= [character(len=5) :: 'drift', 'held'])) then
            errmsg = '--offset-mode: unknown mode "'//trim(opts%offset_mode)//'" (expected drift or held)'
         else if (len(errmsg) == 0 .and. trim(opts%offset_mode) == 'held' .and. opts%offset == 0.0_dp) then
            errmsg = '--offset-mode: held needs --offset > 0 (a centred capsule has nothing to hold)'
         end if
         if (len(errmsg) == 0 .and. opts%offset /= 0.0_dp) then
            if (trim(opts%model) /= '3d') then
               errmsg = '--offset: an off-centre capsule needs --model 3d (the axisymmetric model is centred), got '// &
                        real_text(opts%offset)
            else if (.not. (opts%offset > 0.0_dp .and. opts%offset + opts%a_over_l <= 0.9_dp)) then
               ! The undeformed capsule must clear the wall by 0.1 l: the wall quadrature is
               ! checked to films of 0.05 l, and the capsule moves towards the wall as it deforms.
               errmsg = '--offset: must be > 0 with offset + a/l <= 0.9 (the capsule clear of the wall), got '// &
                        real_text(opts%offset)
            end if
         end if
         if (len(errmsg) > 0) return
      end select
      if (.not. (opts%nu_s > -1.0_dp .and. opts%nu_s < 1.0_dp)) then
         errmsg = '--nu-s: must lie in (-1, 1), got '//real_text(opts%nu_s)
      else if (.not. (opts%prestress >= 0.0_dp .and. opts%prestress <= 0.5_dp)) then
         ! A compressed reference (alpha < 0) would buckle at rest: the model has no bending stiffness.
         errmsg = '--prestress: must lie in [0, 0.5] (inflation of the stress-free sphere), got '//real_text(opts%prestress)
      else if (.not. (opts%kb >= 0.0_dp .and. opts%kb <= 1.0_dp)) then
         ! Capsules have k_b ~ 1e-3 - 1e-1; beyond 1 the explicit steps would be bending-bound.
         errmsg = '--kb: must lie in [0, 1] (bending stiffness K_B / (G_s a^2)), got '//real_text(opts%kb)
      else if (.not. (opts%c > -0.5_dp)) then
         errmsg = '--C: must be > -0.5 so that K_s = (1 + 2C) G_s > 0, got '//real_text(opts%c)
      else if (opts%ca == -huge(1.0_dp)) then
         errmsg = '--ca: missing (capillary number Ca_s > 0)'
      else if (.not. (opts%ca > 0.0_dp)) then
         errmsg = '--ca: must be > 0, got '//real_text(opts%ca)
      else if (.not. (opts%lambda > 0.0_dp)) then
         errmsg = '--lambda: must be > 0 (viscosity ratio inner/outer), got '//real_text(opts%lambda)
      else if (opts%lambda > 1.0e6_dp) then
         errmsg = '--lambda: must be <= 1e6 (beyond, the capsule is rigid), got '//real_text(opts%lambda)
      else if (opts%ca > 100.0_dp) then
         errmsg = '--ca: must be <= 100 (no membrane law supports a larger value), got '//real_text(opts%ca)
      else if (opts%level < 1 .or. opts%level > 5) then
         errmsg = '--level: must be between 1 and 5 (level 4 = 2562 nodes), got '//int_text(opts%level)
      else if (opts%dt < 0.0_dp) then
         errmsg = '--dt: must be > 0 (or 0 for automatic), got '//real_text(opts%dt)
      else if (.not. (opts%dt_factor > 0.0_dp)) then
         errmsg = '--dt-factor: must be > 0, got '//real_text(opts%dt_factor)
      else if (.not. (opts%newton_tol > 0.0_dp)) then
         errmsg = '--newton-tol: must be > 0, got '//real_text(opts%newton_tol)
      else if (.not. (opts%t_max > 0.0_dp)) then
         errmsg = '--t-max: must be > 0, got '//real_text(opts%t_max)
      else if (opts%dt > 0.0_dp .and. opts%dt > opts%t_max) then
         errmsg = '--dt: must not exceed --t-max'
      else if (opts%threads < 0) then
         errmsg = '--threads: must be >= 0 (0 = OpenMP default), got '//int_text(opts%threads)
      else if (opts%threads > max_threads()) then
         ! Each thread takes a stack; a count far beyond the processors crashes the OpenMP
         ! runtime (a segfault, or its own "out of memory") and never runs faster.
         errmsg = '--threads: at most '//int_text(max_threads())//' (4 per processor of this machine, '// &
                  int_text(omp_get_num_procs())//' processors), got '//int_text(opts%threads)
      else if (opts%dt > 0.0_dp .and. len(step_count_problem(opts%t_max, opts%dt)) > 0) then
         errmsg = '--dt: '//step_count_problem(opts%t_max, opts%dt)
      else if (.not. (opts%steady_tol > 0.0_dp)) then
         errmsg = '--steady-tol: must be > 0, got '//real_text(opts%steady_tol)
      else if (.not. (opts%max_length > 1.0_dp)) then
         errmsg = '--max-length: must be > 1 (capsule radii), got '//real_text(opts%max_length)
      else if (.not. (opts%record_every > 0.0_dp)) then
         errmsg = '--record-every: must be > 0, got '//real_text(opts%record_every)
      else if (.not. (opts%checkpoint_every > 0.0_dp)) then
         errmsg = '--checkpoint-every: must be > 0 seconds, got '//real_text(opts%checkpoint_every)
      else if (len_trim(opts%out) == 0) then
         errmsg = '--out: missing (path of the HDF5 case file to write)'
      end if
      if (len(errmsg) > 0) return
      if (len_trim(opts%branch_ca) > 0 .or. len_trim(opts%branch_summary) > 0) then
         call validate_branch(opts, errmsg)
         if (len(errmsg) > 0) return
         call check_output_path(branch_case_path(opts, 1), errmsg)
         if (len(errmsg) == 0) call check_output_path(trim(opts%branch_summary), errmsg)
         if (len(errmsg) == 0) stat = 0
         return
      end if
      ! Fail now, not after hours of computing, if the output cannot be written.
      call check_output_path(trim(opts%out), errmsg)
      if (len(errmsg) > 0) return
      stat = 0
   end subroutine validate

   !> The case file OUT is written as OUT.tmp, then renamed; checkpoints go to OUT.ckpt (via
   !> OUT.ckpt.tmp). OUT must be a new or a regular file (a directory cannot be replaced, and a
   !> device or FIFO must not be) in a writable folder, and so must the files beside it. The
   !> last check creates OUT.tmp and deletes it: nothing is left.
   subroutine check_output_path(out, errmsg)
      character(len=*), intent(in) :: out
      character(len=:), allocatable, intent(inout) :: errmsg
      character(len=*), parameter :: beside(3) = [character(len=9) :: '.tmp', '.ckpt', '.ckpt.tmp']
      character(len=:), allocatable :: folder
      character(len=256) :: iomsg
      integer :: k, unit, ios

      select case (path_kind(out))
      case (path_directory)
         errmsg = '--out: "'//out//'" is a directory (expected the path of the case file)'
         return
      case (path_absent, path_regular)
      case default
         errmsg = '--out: "'//out//'" is not a regular file (a device, FIFO or socket): it would be replaced'
         return
      end select
      folder = folder_of(out)
      if (path_kind(folder) /= path_directory) then
         errmsg = '--out: folder "'//folder//'" of "'//out//'" does not exist'
         return
      else if (.not. folder_writable(folder)) then
         errmsg = '--out: folder "'//folder//'" of "'//out//'" is not writable'
         return
      end if
      do k = 1, size(beside)
         if (all(path_kind(out//trim(beside(k))) /= [path_absent, path_regular])) then
            errmsg = '--out: "'//out//trim(beside(k))//'" exists and is not a regular file'
            return
         end if
      end do
      open (newunit=unit, file=out//'.tmp', status='replace', action='write', iostat=ios, iomsg=iomsg)
      if (ios /= 0) then
         errmsg = '--out: cannot write "'//out//'": '//trim(iomsg)
         return
      end if
      close (unit, status='delete', iostat=ios)
   end subroutine check_output_path

   !> An option given (on the command line or in the namelist) where it does not apply
   !> (option_table: its contexts and laws) is refused: it would be silently ignored. The
   !> message names the most specific such option first (the fewest contexts), then the others.
   subroutine refuse_inapplicable(opts, errmsg)
      type(run_options_t), intent(in) :: opts
      character(len=:), allocatable, intent(inout) :: errmsg
      character(len=:), allocatable :: context, others
      integer :: i, first, width, best

      context = option_context(opts%flow, opts%model)
      first = 0
      best = huge(1)
      others = ''
      do i = 1, n_options
         if (.not. opts%given(i)) cycle
         if (option_applies(option_specs(i), context, opts%law)) cycle
         width = context_count(option_specs(i))
         if (width < best) then
            if (first > 0) others = others//', '//trim(option_specs(first)%name)
            first = i
            best = width
         else
            others = others//', '//trim(option_specs(i)%name)
         end if
      end do
      if (first == 0) return
      associate (spec => option_specs(first))
         if (len_trim(spec%contexts) > 0 .and. .not. option_applies(spec, context, spec%laws)) then
            errmsg = trim(spec%name)//': does not apply to '//context_text(context)//' (only to '// &
                     contexts_text(spec%contexts)//')'
         else
            errmsg = trim(spec%name)//': does not apply to --law '//trim(opts%law)//' (only to --law '// &
                     words_joined(spec%laws, ' or --law ')//')'
         end if
      end associate
      if (len(others) > 0) errmsg = errmsg//'; nor do '//others(3:)

   contains

      integer function context_count(spec)
         type(option_spec_t), intent(in) :: spec
         context_count = merge(3, count_words(spec%contexts), len_trim(spec%contexts) == 0)
      end function context_count

   end subroutine refuse_inapplicable

   !> '--flow shear', '--flow tube --model axi' for an option_context.
   function context_text(context) result(text)
      character(len=*), intent(in) :: context
      character(len=:), allocatable :: text
      if (context(1:min(5, len(context))) == 'tube-') then
         text = '--flow tube --model '//context(6:)
      else
         text = '--flow '//context
      end if
   end function context_text

   !> The contexts of an option as flags: '--flow shear or --flow tube --model 3d'.
   function contexts_text(list) result(text)
      character(len=*), intent(in) :: list
      character(len=:), allocatable :: text
      character(len=:), allocatable :: rest
      integer :: blank
      text = ''
      rest = trim(adjustl(list))
      do while (len(rest) > 0)
         blank = index(rest, ' ')
         if (blank == 0) blank = len(rest) + 1
         if (len(text) > 0) text = text//' or '
         text = text//context_text(rest(:blank - 1))
         rest = trim(adjustl(rest(min(blank, len(rest) + 1):)))
      end do
      if (text == '--flow tube --model axi or --flow tube --model 3d') text = '--flow tube'
   end function contexts_text

   pure integer function count_words(list)
      character(len=*), intent(in) :: list
      integer :: k
      count_words = 0
      do k = 1, len_trim(list)
         if (list(k:k) /= ' ' .and. (k == 1)) count_words = count_words + 1
         if (k > 1) then
            if (list(k:k) /= ' ' .and. list(k - 1:k - 1) == ' ') count_words = count_words + 1
         end if
      end do
   end function count_words

   !> The blank-separated words of `list` joined by `sep`.
   pure function words_joined(list, sep) result(text)
      character(len=*), intent(in) :: list, sep
      character(len=:), allocatable :: text
      integer :: k
      text = ''
      do k = 1, len_trim(list)
         if (list(k:k) == ' ') then
            if (k > 1) then
               if (list(k - 1:k - 1) /= ' ') text = text//sep
            end if
         else
            text = text//list(k:k)
         end if
      end do
   end function words_joined

   !> A steady branch needs its list (ascending, each value a valid --ca), its branch file,
   !> the steady solver for the 3d model, and '{ca}' in --out (each case has its own file,
   !> named by its value's text).
   subroutine validate_branch(opts, errmsg)
      type(run_options_t), intent(in) :: opts
      character(len=:), allocatable, intent(inout) :: errmsg
      real(dp), allocatable :: values(:)
      logical :: ok
      if (len_trim(opts%branch_ca) == 0) then
         errmsg = '--branch-summary: only with --branch-ca'
         return
      else if (len_trim(opts%branch_summary) == 0) then
         errmsg = '--branch-summary: missing (the branch file of --branch-ca)'
         return
      else if (index(opts%out, '{ca}') == 0) then
         errmsg = '--out: with --branch-ca it must hold {ca} (one case file per Ca_s), got "'//trim(opts%out)//'"'
         return
      else if (trim(opts%model) == '3d' .and. trim(opts%integrator) /= 'newton') then
         ! The 3D branch continues steady shapes: only the steady solver has them.
         errmsg = '--branch-ca: the 3d model follows a branch with --integrator newton, got "'// &
                  trim(opts%integrator)//'"'
         return
      end if
      call branch_ca_values(opts, values, ok)
      if (.not. ok) then
         errmsg = '--branch-ca: expected comma-separated numbers in (0, 100], got "'//trim(opts%branch_ca)//'"'
      else if (any(values(2:) <= values(:size(values) - 1))) then
         errmsg = '--branch-ca: the values must increase (the branch is followed upwards in Ca_s)'
      else if (values(1) /= opts%ca) then
         errmsg = '--ca: with --branch-ca it is the first value of the list, got '//real_text(opts%ca)
      end if
   end subroutine validate_branch

   !> The Ca_s of --branch-ca; ok is false unless every item is a number in (0, 100].
   subroutine branch_ca_values(opts, values, ok)
      type(run_options_t), intent(in) :: opts
      real(dp), allocatable, intent(out) :: values(:)
      logical, intent(out) :: ok
      integer :: k, n
      n = count_items(opts%branch_ca)
      allocate (values(n))
      ok = n > 0
      do k = 1, n
         if (.not. ok) exit
         call parse_real(branch_item(opts%branch_ca, k), values(k), ok)
         ok = ok .and. values(k) > 0.0_dp .and. values(k) <= 100.0_dp
      end do
   end subroutine branch_ca_values

   !> The case file of the k-th Ca_s of the branch: --out with '{ca}' replaced by the value
   !> as written in --branch-ca (so that the caller chooses the names).
   function branch_case_path(opts, k) result(path)
      type(run_options_t), intent(in) :: opts
      integer, intent(in) :: k
      character(len=:), allocatable :: path
      integer :: at
      at = index(opts%out, '{ca}')
      path = opts%out(:at - 1)//branch_item(opts%branch_ca, k)//trim(opts%out(at + 4:))
   end function branch_case_path

   pure integer function count_items(list) result(n)
      character(len=*), intent(in) :: list
      integer :: k
      n = 0
      if (len_trim(list) == 0) return
      n = 1
      do k = 1, len_trim(list)
         if (list(k:k) == ',') n = n + 1
      end do
   end function count_items

   !> The k-th comma-separated item of list, without blanks.
   pure function branch_item(list, k) result(item)
      character(len=*), intent(in) :: list
      integer, intent(in) :: k
      character(len=:), allocatable :: item
      integer :: first, last, j
      first = 1
      do j = 1, k - 1
         first = first + index(list(first:), ',')
      end do
      last = index(list(first:), ',')
      if (last == 0) then
         last = len_trim(list)
      else
         last = first + last - 2
      end if
      item = trim(adjustl(list(first:last)))
   end function branch_item

   !> Everything that determines the result: a checkpoint is resumed only if this matches. It
   !> holds the values the run uses (after apply_flow_defaults: shear's integrator and k_b as
   !> chosen), so that a checkpoint written under other defaults does not match.
   function option_signature(opts) result(sig)
      type(run_options_t), intent(in) :: opts
      character(len=:), allocatable :: sig
      character(len=1024) :: buf
      write (buf, '(4(a,1x),2(i0,1x),l1,14(1x,es23.16))') trim(opts%flow), trim(opts%law), trim(opts%model), &
         trim(opts%integrator), opts%level, opts%n_meridian, opts%volume_correction, opts%nu_s, opts%c, opts%ca, &
         opts%a_over_l, opts%dt, opts%dt_factor, opts%steady_tol, opts%shape_tol, opts%max_length, &
         opts%record_every, opts%newton_tol, opts%tube_length, opts%wall_h_far, opts%wall_h_centre
      sig = trim(buf)
      ! The time limit decides where the history ends, and another kernel version may step
      ! differently: a checkpoint of either is not resumed.
      write (buf, '(a,es23.16)') ' t_max ', opts%t_max
      sig = sig//trim(buf)//' code_version '//code_version
      ! Effects are appended only when present, so that the signatures (and checkpoints) of
      ! the base model are those of kernel versions without the options.
      call append_effect(sig, 'prestress', opts%prestress, 0.0_dp)
      call append_effect(sig, 'lambda', opts%lambda, 1.0_dp)
      call append_effect(sig, 'kb', opts%kb, 0.0_dp)
      call append_effect(sig, 'offset', opts%offset, 0.0_dp)
      if (trim(opts%offset_mode) == 'held') sig = sig//' offset_mode held'
      if (trim(opts%channel) /= 'tube') then
         write (buf, '(a,es23.16)') ' channel '//trim(opts%channel)//' aspect ', opts%aspect
         sig = sig//trim(buf)
      end if
      ! The 3D model's full self quadrature (its default) is a different model from the vertex
      ! rule: old 3D checkpoints (vertex) resume only with --self-quadrature vertex.
      if (trim(opts%flow) == 'tube' .and. trim(opts%model) == '3d' .and. trim(opts%self_quadrature) /= 'vertex') &
         sig = sig//' self_quadrature full'
   end function option_signature

   !> Append " name value" to a signature when the effect is away from its neutral value.
   pure subroutine append_effect(sig, name, value, neutral)
      character(len=:), allocatable, intent(inout) :: sig
      character(len=*), intent(in) :: name
      real(dp), intent(in) :: value, neutral
      character(len=64) :: buf
      if (value == neutral) return
      write (buf, '(a,es23.16)') ' '//name//' ', value
      sig = sig//trim(buf)
   end subroutine append_effect

end module run_options
