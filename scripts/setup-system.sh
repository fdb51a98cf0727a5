#!/usr/bin/env bash
# The system packages the kernel and the Python environment need.
#
# Debian or Ubuntu (dpkg-query and apt-get here): installs the missing ones with apt-get.
# Anywhere else (RHEL, Rocky, Fedora, openSUSE, a cluster's login node with environment
# modules): installs nothing. It checks, by compiling and linking small programs as the Makefile
# does, that the Fortran compiler (with OpenMP), HDF5's Fortran interface, LAPACK and BLAS, and
# Python 3.10+ with venv are there; prints each missing one with how to get it, and exits 1 only
# when something is missing (so `make build` / `make database` go on when all is there).
#
# FC, HDF5_INC and HDF5_LIB are read from the environment: make passes them when they are given
# on its command line (`make HDF5_INC=... HDF5_LIB=...`); the defaults below are the Makefile's.
set -euo pipefail

if command -v dpkg-query >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1; then
    packages=(gfortran libhdf5-dev liblapack-dev libopenblas-dev python3-venv)
    missing=()
    for p in "${packages[@]}"; do
        dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
    done
    [ ${#missing[@]} -eq 0 ] && exit 0
    echo "capsmech setup: installing Debian packages: ${missing[*]}"
    SUDO=""
    [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
    exit 0
fi

FC=${FC:-gfortran}
HDF5_INC=${HDF5_INC:-/usr/include/hdf5/serial}
HDF5_LIB=${HDF5_LIB:-/usr/lib/x86_64-linux-gnu/hdf5/serial}
HDF5_LIBS=(-lhdf5hl_fortran -lhdf5_hl -lhdf5_fortran -lhdf5)

problems=()
found=()
missing() { problems+=("$1"$'\n'"      fix: $2"); }

first_error() {  # the first line of a compiler's complaint, for the message
    grep -m 1 -iE "error|cannot find|not found" "$1" 2>/dev/null | cut -c 1-160 || true
}

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# Where a distribution or a module may have put HDF5's Fortran module (hdf5.mod) and its
# libraries, for the hint when the Makefile's paths do not hold them.
find_hdf5() {
    local dirs=() dir mod_dir="" lib_dir=""
    if command -v h5fc >/dev/null 2>&1; then
        for word in $(h5fc -show 2>/dev/null); do
            case $word in -I*) dirs+=("${word#-I}") ;; -L*) dirs+=("${word#-L}") ;; esac
        done
    fi
    dirs+=(/usr/include/hdf5/serial /usr/lib64/gfortran/modules /usr/lib/gfortran/modules /usr/include
           /usr/lib/x86_64-linux-gnu/hdf5/serial /usr/lib64 /usr/lib /usr/local/include /usr/local/lib)
    for dir in ${HDF5_DIR:+"$HDF5_DIR/include" "$HDF5_DIR/lib"} ${HDF5_ROOT:+"$HDF5_ROOT/include" "$HDF5_ROOT/lib"} "${dirs[@]}"; do
        [ -z "$mod_dir" ] && [ -f "$dir/hdf5.mod" ] && mod_dir=$dir
        [ -z "$lib_dir" ] && compgen -G "$dir/libhdf5_fortran.*" >/dev/null && lib_dir=$dir
    done
    echo "$mod_dir|$lib_dir"
}

if ! command -v "$FC" >/dev/null 2>&1; then
    missing "Fortran compiler '$FC' (gfortran with OpenMP)" \
        "dnf install gcc-gfortran (RHEL/Rocky/Fedora), zypper install gcc-fortran (openSUSE), or module load gcc; another compiler: make FC=... (HDF5 and LAPACK are checked once a compiler is found)"
else
    printf 'program p\nuse omp_lib\nprint *, omp_get_max_threads()\nend program p\n' > "$work/omp.f90"
    if "$FC" -fopenmp -std=f2018 "$work/omp.f90" -o "$work/omp" >"$work/omp.log" 2>&1; then
        found+=("$FC")
    else
        missing "a Fortran compiler with OpenMP ($FC -fopenmp: $(first_error "$work/omp.log"))" \
            "dnf install gcc-gfortran libgomp, or module load gcc"
    fi

    printf 'program p\nuse hdf5\nuse h5lt\ninteger :: e\ncall h5open_f(e)\nend program p\n' > "$work/h5.f90"
    if "$FC" -I"$HDF5_INC" "$work/h5.f90" -o "$work/h5" -L"$HDF5_LIB" "${HDF5_LIBS[@]}" >"$work/h5.log" 2>&1; then
        found+=("HDF5 Fortran")
    else
        IFS='|' read -r mod_dir lib_dir < <(find_hdf5)
        if [ -n "$mod_dir" ] && [ -n "$lib_dir" ] && { [ "$mod_dir" != "$HDF5_INC" ] || [ "$lib_dir" != "$HDF5_LIB" ]; }; then
            missing "HDF5's Fortran interface is not at HDF5_INC=$HDF5_INC HDF5_LIB=$HDF5_LIB, but hdf5.mod is in $mod_dir and libhdf5_fortran in $lib_dir" \
                "build with make HDF5_INC=$mod_dir HDF5_LIB=$lib_dir ... (the same two on every make command)"
        else
            missing "HDF5 with its Fortran interface (hdf5.mod in HDF5_INC=$HDF5_INC, libhdf5_fortran in HDF5_LIB=$HDF5_LIB: $(first_error "$work/h5.log"))" \
                "dnf install hdf5-devel (RHEL/Rocky: from EPEL), zypper install hdf5-devel, or module load hdf5; then make HDF5_INC=<folder of hdf5.mod> HDF5_LIB=<folder of libhdf5_fortran.so>"
        fi
    fi

    printf 'program p\nexternal dgesv, dgemm\nend program p\n' > "$work/la.f90"
    if "$FC" "$work/la.f90" -o "$work/la" -llapack -lblas >"$work/la.log" 2>&1; then
        found+=("LAPACK/BLAS")
    else
        missing "LAPACK and BLAS (liblapack.so and libblas.so for -llapack -lblas: $(first_error "$work/la.log"))" \
            "dnf install lapack-devel blas-devel (RHEL/Rocky/Fedora), zypper install lapack-devel blas-devel, or module load of a LAPACK that provides both names"
    fi
fi

if command -v python3 >/dev/null 2>&1 && python3 -c 'import sys, venv, ensurepip; sys.exit(sys.version_info < (3, 10))' 2>/dev/null; then
    found+=("python3 venv")
else
    missing "Python 3.10 or newer with venv and ensurepip (python3: $(python3 --version 2>&1 || echo not found))" \
        "dnf install python3.11 (RHEL/Rocky 8/9), zypper install python311, or module load python; it must be the python3 on PATH"
fi

if [ ${#problems[@]} -gt 0 ]; then
    echo "capsmech setup: no dpkg-query/apt-get here, so nothing is installed; missing:" >&2
    for p in "${problems[@]}"; do echo "  - $p" >&2; done
    exit 1
fi
echo "capsmech setup: no apt here; found ${found[*]}"
