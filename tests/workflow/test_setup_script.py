"""scripts/setup-system.sh on a machine without dpkg-query and apt-get (a RHEL-like login node).

There it installs nothing: it checks the compiler, HDF5's Fortran interface, LAPACK/BLAS and
Python's venv, exits 0 when all are there (``make build`` / ``make database`` go on) and 1 with
each missing piece and how to get it otherwise. The machine is simulated by a PATH of links to
every command of this one except dpkg, dpkg-query, apt and apt-get; the libraries themselves
are this machine's, so the tests are skipped where the kernel could not be built anyway.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from conftest import REPO

SCRIPT = REPO / "scripts" / "setup-system.sh"
PACKAGE_MANAGER = {"dpkg", "dpkg-query", "apt", "apt-get"}


@pytest.fixture(scope="module")
def path_without_apt(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A PATH with every command of this machine's PATH but dpkg and apt."""
    if shutil.which("gfortran") is None:
        pytest.skip("gfortran is not installed: the kernel cannot be built here either")
    farm = tmp_path_factory.mktemp("bin")
    for folder in os.environ["PATH"].split(os.pathsep):
        if not Path(folder).is_dir():
            continue
        for command in Path(folder).iterdir():
            link = farm / command.name
            if command.name not in PACKAGE_MANAGER and not link.exists() and os.access(command, os.X_OK):
                link.symlink_to(command)
    assert not any(shutil.which(name, path=str(farm)) for name in PACKAGE_MANAGER)
    return str(farm)


def setup(path: str, **env: str) -> subprocess.CompletedProcess:
    clean = {k: v for k, v in os.environ.items() if k not in ("FC", "HDF5_INC", "HDF5_LIB")}
    return subprocess.run(["bash", str(SCRIPT)], text=True, capture_output=True, timeout=120,
                          env={**clean, "PATH": path, **env})


def test_everything_present_goes_on_without_installing(path_without_apt: str) -> None:
    result = setup(path_without_apt)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "capsmech setup: no apt here; found gfortran HDF5 Fortran LAPACK/BLAS python3 venv"
    assert "install" not in result.stdout + result.stderr


def test_a_missing_compiler_is_named_with_how_to_get_it(path_without_apt: str) -> None:
    result = setup(path_without_apt, FC="gfortran-absent")
    assert result.returncode == 1
    assert "nothing is installed; missing:" in result.stderr
    assert "Fortran compiler 'gfortran-absent'" in result.stderr and "dnf install gcc-gfortran" in result.stderr


def test_hdf5_elsewhere_gives_the_make_variables_to_pass(path_without_apt: str, tmp_path: Path) -> None:
    """HDF5_INC naming an empty folder: the build would fail; the message says where hdf5.mod
    really is (found on this machine) and the make command that uses it."""
    real_mod = next((d for d in ("/usr/include/hdf5/serial", "/usr/lib64/gfortran/modules", "/usr/include")
                     if Path(d, "hdf5.mod").is_file()), None)
    if real_mod is None:
        pytest.skip("no hdf5.mod in the usual folders here")
    result = setup(path_without_apt, HDF5_INC=str(tmp_path))
    assert result.returncode == 1
    assert f"HDF5's Fortran interface is not at HDF5_INC={tmp_path}" in result.stderr
    assert f"hdf5.mod is in {real_mod}" in result.stderr and f"make HDF5_INC={real_mod} HDF5_LIB=" in result.stderr


def test_missing_lapack_and_python_venv_are_listed_together(path_without_apt: str, tmp_path: Path) -> None:
    """A linker that finds no LAPACK (LIBRARY_PATH cannot remove one, so -llapack is made to
    fail through a compiler wrapper) and a python3 without venv: both listed, exit 1."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    real_fc = shutil.which("gfortran")
    wrapper = bin_dir / "fc-without-lapack"
    wrapper.write_text(f'#!/bin/bash\nfor a in "$@"; do [ "$a" = -llapack ] && {{ echo "ld: cannot find -llapack" >&2; '
                       f'exit 1; }}; done\nexec {real_fc} "$@"\n')
    wrapper.chmod(0o755)
    python = bin_dir / "python3"
    python.write_text("#!/bin/bash\n[ \"$1\" = --version ] && { echo 'Python 3.6.8'; exit 0; }\nexit 1\n")
    python.chmod(0o755)
    result = setup(f"{bin_dir}{os.pathsep}{path_without_apt}", FC=str(wrapper))
    assert result.returncode == 1
    assert "LAPACK and BLAS" in result.stderr and "cannot find -llapack" in result.stderr
    assert "dnf install lapack-devel blas-devel" in result.stderr
    assert "Python 3.10 or newer with venv" in result.stderr and "Python 3.6.8" in result.stderr
    assert "HDF5" not in result.stderr  # found through the wrapper
