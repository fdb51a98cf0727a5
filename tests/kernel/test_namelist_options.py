"""The namelist reads the options of capsim's option table, each value as its flag reads it.

The names are derived from the flags (`--dt-factor` is `dt_factor`), so that an option added to
the table is a namelist variable too; before, the reader knew 15 hand-listed names. Checked here
against the flags themselves: the same case file bit for bit, the same refusals.
"""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from conftest import datasets

ONE_THREAD = {**os.environ, "OMP_NUM_THREADS": "1"}
#: Options the former reader did not know, with values away from their defaults.
OPTIONS = {"--flow": "shear", "--law": "GH", "--nu-s": "0.3", "--ca": "0.2", "--level": "1", "--t-max": "0.1",
           "--dt-factor": "0.4", "--record-every": "0.02", "--integrator": "implicit", "--steady-tol": "2e-3",
           "--volume-correction": "off", "--max-length": "2.5", "--kb": "0.001", "--prestress": "0.02"}


def namelist_text(options: dict[str, str], out: Path) -> str:
    items = [f"{flag[2:].replace('-', '_')} = '{value}'" if not value[0].isdigit() else
             f"{flag[2:].replace('-', '_')} = {value}" for flag, value in options.items()]
    return "&capsim\n " + ",\n ".join([*items, f"out = '{out}'"]) + "\n/\n"


def run(capsim: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(capsim), *args, "--quiet"], capture_output=True, text=True, timeout=120, env=ONE_THREAD)


def test_a_namelist_of_table_options_is_the_flags_run(capsim, tmp_path):
    by_flags, by_namelist = tmp_path / "flags.h5", tmp_path / "namelist.h5"
    assert run(capsim, *[a for kv in OPTIONS.items() for a in kv], "--out", str(by_flags)).returncode == 0
    nml = tmp_path / "run.nml"
    nml.write_text(namelist_text(OPTIONS, by_namelist))
    result = run(capsim, "--namelist", str(nml))
    assert result.returncode == 0, result.stderr
    flags, namelist = datasets(by_flags), datasets(by_namelist)
    assert flags.keys() == namelist.keys()
    for name in flags:
        assert np.array_equal(flags[name], namelist[name]), name


@pytest.mark.parametrize("item,flag", [("level = 1.5", "--level"), ("integrator = 'euler'", "--integrator"),
                                       ("volume_correction = maybe", "--volume-correction"),
                                       ("dt_factor = 0", "--dt-factor")])
def test_a_value_the_flag_refuses_is_refused_in_the_namelist(capsim, tmp_path, item, flag):
    out = tmp_path / "x.h5"
    nml = tmp_path / "run.nml"
    nml.write_text(f"&capsim\n flow = 'shear', law = 'NH', ca = 0.1,\n {item}, out = '{out}'\n/\n")
    result = run(capsim, "--namelist", str(nml))
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1 and flag in lines[0], result.stderr
    assert not out.exists()


@pytest.mark.parametrize("item,words", [("bogus = 1", ["line 2", "unknown name bogus"]),
                                        ("namelist = 'other.nml'", ["line 2", "unknown name namelist"]),
                                        ("ca 0.2", ["line 2", "ca without"])])
def test_what_is_no_option_is_refused_naming_its_line(capsim, tmp_path, item, words):
    nml = tmp_path / "run.nml"
    nml.write_text(f"&capsim flow = 'shear', law = 'NH',\n {item}, out = '{tmp_path / 'x.h5'}' /\n")
    result = run(capsim, "--namelist", str(nml))
    assert result.returncode == 2 and all(w in result.stderr for w in words), result.stderr
