"""``--version`` names what a result depends on: the package, the kernel that would run, and the
kernel version that filled each shipped database (as the files record it)."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import h5py
import pytest

from capsmech.io.case import decode_str
from capsmech.io.catalog import CATALOG, database_path
from capsmech.version import __version__
from capsmech.workflow.paths import capsim_executable

ROOT = Path(__file__).resolve().parents[2]


def _capsmech_version(env: dict[str, str] | None = None) -> list[str]:
    done = subprocess.run([sys.executable, "-m", "capsmech.cli", "--version"], capture_output=True, text=True,
                          timeout=60, env=env)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    return done.stdout.splitlines()


def test_the_kernel_prints_the_code_version_its_case_files_record() -> None:
    try:
        exe = capsim_executable()
    except FileNotFoundError as err:
        pytest.skip(f"no kernel: {err}")
    done = subprocess.run([str(exe), "--version"], capture_output=True, text=True, timeout=30)
    source = (ROOT / "kernel" / "src" / "capsim_kinds.f90").read_text()
    code_version = re.search(r"code_version = '([^']+)'", source)
    assert code_version is not None
    assert done.returncode == 0 and done.stdout.strip() == f"capsim {code_version[1]}"


def test_capsmech_names_package_kernel_and_every_database() -> None:
    lines = _capsmech_version()
    assert lines[0] == f"capsmech {__version__}"
    assert lines[1].startswith("kernel: capsim ")
    shown = {line.split(":")[0].removeprefix("database "): line for line in lines[2:]}
    assert list(shown) == list(CATALOG)
    for name, line in shown.items():
        with h5py.File(database_path(name)) as f:
            assert line.endswith(f"grid {decode_str(f.attrs['grid_name'])}, kernel {decode_str(f.attrs['code_version'])}")


def test_a_missing_kernel_is_said_not_hidden(tmp_path: Path) -> None:
    import os

    env = {**os.environ, "CAPSIM": str(tmp_path / "no-such-capsim")}
    lines = _capsmech_version(env)
    assert lines[1].startswith("kernel: capsim not available") and "no-such-capsim" in lines[1]
