"""Exact resume (issue 25, item 1): a run killed at random moments, several times, and resumed
from its checkpoints ends with a case file equal bit for bit to the uninterrupted run's (every
dataset, every attribute but wall_time_s), for every integrator and model: shear RK2 and
implicit (ROS2 with a reused Jacobian and step-size control), tube axisymmetric RK2 and implicit
(linearly implicit Euler with a reused Jacobian, step halving and cap), tube 3D, and the
viscosity ratio's iterative solves (their initial guesses are state too). The checkpoint holds
what the next step depends on beyond the positions (case_output, format CAPSCKP3); what it does
not hold (the Jacobian and its LU) is recomputed at the positions and step where it was made.

The axisymmetric Newton continuation writes no checkpoint: a killed run starts afresh and,
being deterministic, ends exactly as the uninterrupted one (tested here too)."""
from __future__ import annotations

import signal
import subprocess
import time
import zlib
from pathlib import Path

import h5py
import pytest

from conftest import assert_same_case_file, run_killed_repeatedly

ONE_THREAD = ["--threads", "1", "--quiet"]

#: name: (arguments, kills). Each takes a few seconds on one core.
CASES = {
    "shear_rk2": (["--flow", "shear", "--law", "NH", "--ca", "0.05", "--level", "2", "--integrator", "rk2",
                   "--t-max", "3"], 3),
    "shear_implicit": (["--flow", "shear", "--law", "NH", "--ca", "0.05", "--level", "2", "--integrator", "implicit",
                        "--t-max", "8"], 3),
    "tube_axi_implicit": (["--flow", "tube", "--law", "NH", "--a-over-l", "0.9", "--ca", "0.05", "--n-meridian", "48",
                           "--integrator", "implicit"], 3),
    "tube_axi_rk2": (["--flow", "tube", "--law", "NH", "--a-over-l", "0.6", "--ca", "0.1", "--n-meridian", "24",
                      "--integrator", "rk2", "--t-max", "1"], 3),
    "tube_3d": (["--flow", "tube", "--model", "3d", "--law", "NH", "--a-over-l", "0.6", "--ca", "0.1", "--level", "2",
                 "--wall-h-far", "0.28", "--wall-h-centre", "0.14", "--tube-length", "6", "--t-max", "0.2"], 2),
}
#: The viscosity ratio and bending on top (slower).
SLOW_CASES = {
    "shear_implicit_lambda": (["--flow", "shear", "--law", "NH", "--ca", "0.05", "--level", "2", "--lambda", "3",
                               "--integrator", "implicit", "--t-max", "4"], 3),
    "shear_rk2_lambda": (["--flow", "shear", "--law", "NH", "--ca", "0.1", "--level", "2", "--lambda", "0.5",
                          "--integrator", "rk2", "--t-max", "1"], 3),
    "tube_axi_implicit_lambda_kb": (["--flow", "tube", "--law", "NH", "--a-over-l", "0.8", "--ca", "0.1",
                                     "--n-meridian", "32", "--lambda", "3", "--kb", "0.01", "--integrator", "implicit"],
                                    3),
    "tube_3d_lambda": (["--flow", "tube", "--model", "3d", "--law", "NH", "--a-over-l", "0.6", "--ca", "0.1",
                        "--level", "2", "--wall-h-far", "0.28", "--wall-h-centre", "0.14", "--tube-length", "6",
                        "--lambda", "2", "--t-max", "0.2"], 2),
}


def check_exact_resume(capsim: Path, tmp_path: Path, name: str, args: list[str], kills: int) -> None:
    if "3d" in args:     # the wall's LU, built by the first run, loaded by the others
        (tmp_path / "wall-cache").mkdir()
        args = [*args, "--wall-cache", str(tmp_path / "wall-cache")]
    args = [*args, *ONE_THREAD]
    reference = tmp_path / "reference.h5"
    started = time.perf_counter()
    subprocess.run([str(capsim), *args, "--out", str(reference)], check=True, timeout=600)
    lived = time.perf_counter() - started
    # What the kills interrupt is the time stepping: the 3D wall's LU (most of the reference
    # run: 3.5 of 4.9 s) is built by that run and loaded from the cache by the others, so it
    # does not count (under a parallel make test, a kill planned within the whole run's time
    # came after the resumed run had finished).
    with h5py.File(reference) as f:
        lived -= float(f.attrs.get("wall_setup_s", 0.0)) if "3d" in args else 0.0
    resumed = tmp_path / "resumed.h5"
    # The kills together take at most half the uninterrupted run's stepping time past the checkpoints.
    run_killed_repeatedly(capsim, args, resumed, kills, seed=zlib.crc32(name.encode()),
                          within=max(0.1, 0.5 * lived / kills))
    assert_same_case_file(reference, resumed)


@pytest.mark.parametrize("name", CASES)
def test_resume_after_random_kills_is_bit_exact(capsim, tmp_path, name):
    check_exact_resume(capsim, tmp_path, name, *CASES[name])


@pytest.mark.slow
@pytest.mark.parametrize("name", SLOW_CASES)
def test_resume_with_viscosity_ratio_and_bending_is_bit_exact(capsim, tmp_path, name):
    check_exact_resume(capsim, tmp_path, name, *SLOW_CASES[name])


def test_killed_newton_continuation_reruns_exactly(capsim, tmp_path):
    args = ["--flow", "tube", "--law", "NH", "--a-over-l", "0.6", "--ca", "0.004", "--n-meridian", "48",
            "--integrator", "newton", *ONE_THREAD]
    reference = tmp_path / "reference.h5"
    started = time.perf_counter()
    subprocess.run([str(capsim), *args, "--out", str(reference)], check=True, timeout=600)
    lived = time.perf_counter() - started
    out = tmp_path / "rerun.h5"
    proc = subprocess.Popen([str(capsim), *args, "--checkpoint-every", "0.1", "--out", str(out)])
    time.sleep(0.5 * lived)
    assert proc.poll() is None, "the run finished before the kill: make the case longer"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not out.exists()
    subprocess.run([str(capsim), *args, "--checkpoint-every", "0.1", "--out", str(out)], check=True, timeout=600)
    assert_same_case_file(reference, out)
