"""A user's first kernel run reaches the steady state the shipped shear database holds.

`capsim --flow shear --law NH --ca 0.01 --out x.h5` and nothing else: before, the kernel stepped
explicitly (dt 7e-4) without bending stiffness and ended at max_time, D12 6.7 % above the small-
deformation limit (a node-scale ripple). Its shear defaults are now the database's model choices,
read here from the shipped database's own grid (the record of how its rows were made), not typed.
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from capsmech.io.case import read_case
from capsmech.io.catalog import database_path
from capsmech.io.database import load_database
from capsmech.workflow.grid import KERNEL_SHEAR_IMPLICIT_BELOW_CA_S

CA_S = 0.01
#: One thread: an OpenMP team on a busy 2-core machine spins (10 times the CPU for this run).
ONE_THREAD = {**os.environ, "OMP_NUM_THREADS": "1"}


@pytest.fixture(scope="module")
def shear_paper():
    return load_database(database_path("shear-paper"))


def _help_default(capsim: Path, option: str) -> str:
    text = subprocess.run([str(capsim), "--help"], capture_output=True, text=True, check=True, timeout=60).stdout
    line = next(line for line in text.splitlines() if line.startswith(f"  {option} "))
    match = re.search(r"\(default: (.+)\)$", line)
    assert match, line
    return match.group(1)


def test_the_kernel_s_shear_defaults_are_the_database_s_model_choices(capsim, shear_paper):
    settings = shear_paper.grid["shear"]["settings"]
    kb = _help_default(capsim, "--kb")
    assert float(kb.split()[0]) == settings["k_b"] and kb.endswith("0 in the tube"), kb
    rule = re.search(r"implicit below Ca_s ([0-9.e-]+)", _help_default(capsim, "--integrator"))
    assert rule and float(rule.group(1)) == settings["implicit_below_Ca_s"]
    # The workflow states the base model where a grid leaves the choice to the kernel's rule.
    assert float(rule.group(1)) == KERNEL_SHEAR_IMPLICIT_BELOW_CA_S


@pytest.mark.parametrize("ca, implicit", [(0.0699, True), (0.07, False)])
def test_auto_steps_implicitly_below_the_threshold_only(capsim, tmp_path, shear_paper, ca, implicit):
    out = tmp_path / "case.h5"
    subprocess.run([str(capsim), "--flow", "shear", "--law", "NH", "--ca", str(ca), "--level", "1", "--t-max", "0.05",
                    "--quiet", "--out", str(out)], check=True, timeout=60, env=ONE_THREAD)
    with h5py.File(out) as f:
        # The implicit steps' summary counts them; RK2's says nothing of steps.
        assert ("implicit steps" in f.attrs["message"].decode()) == implicit
        assert f.attrs["k_b"] == shear_paper.grid["shear"]["settings"]["k_b"]


@pytest.mark.parametrize("how", ["flag", "namelist"])
def test_a_bending_stiffness_given_as_zero_is_kept(capsim, tmp_path, how):
    out = tmp_path / "case.h5"
    args = ["--flow", "shear", "--law", "NH", "--ca", "0.2", "--level", "1", "--t-max", "0.05", "--quiet", "--out", str(out)]
    if how == "flag":
        args += ["--kb", "0"]
    else:
        (tmp_path / "run.nml").write_text("&capsim kb = 0 /\n")
        args += ["--namelist", str(tmp_path / "run.nml")]
    subprocess.run([str(capsim), *args], check=True, timeout=60, env=ONE_THREAD)
    with h5py.File(out) as f:
        assert f.attrs["k_b"] == 0.0


def _kill_once_checkpointed(argv: list[str], checkpoint: Path, limit_s: float = 60.0) -> None:
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=ONE_THREAD)
    try:
        deadline = time.monotonic() + limit_s
        while not checkpoint.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert checkpoint.exists(), "the run wrote no checkpoint"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()


def test_a_plain_shear_run_reaches_the_database_row(capsim, tmp_path, shear_paper):
    """The plain run, after a run of the former defaults (RK2, k_b 0) killed with its checkpoint
    on disk: that checkpoint is not resumed (other options), and the plain run is steady at the
    D12 of the database row, on the row's own check level within the row's stated time error."""
    out = tmp_path / "x.h5"
    checkpoint = Path(f"{out}.ckpt")
    _kill_once_checkpointed([str(capsim), "--flow", "shear", "--law", "NH", "--ca", str(CA_S), "--integrator", "rk2",
                             "--kb", "0", "--checkpoint-every", "0.2", "--quiet", "--out", str(out)], checkpoint)

    plain = subprocess.run([str(capsim), "--flow", "shear", "--law", "NH", "--ca", str(CA_S), "--out", str(out)],
                           capture_output=True, text=True, timeout=300, env=ONE_THREAD)
    assert plain.returncode == 0, plain.stderr
    assert "signature differs" in plain.stderr and "resumed" not in plain.stdout
    case = read_case(out)
    assert case.status == "steady", case.message

    grid = shear_paper.grid["shear"]
    table = shear_paper.law("NH")
    row = int(np.flatnonzero(np.isclose(table.columns["Ca_s"], CA_S))[0])
    assert table.status[row] == "steady"
    # The rows hold the finer level of the grid's mesh check; the plain run is on the level of
    # the grid's cases, whose D12 the row keeps as D12_mesh_check.
    assert int(grid["settings"]["level"]) == case.mesh_level != int(table.columns["mesh_level"][row])
    level_d12 = table.columns["D12_mesh_check"][row]
    time_error = table.columns["D12_time_error_rel"][row]
    assert case.steady_value("D12") == pytest.approx(level_d12, rel=time_error)
