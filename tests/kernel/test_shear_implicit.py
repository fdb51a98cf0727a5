"""Linearly implicit (ROS2 Rosenbrock-W) steps of the 3D capsule in shear, --integrator implicit,
against the explicit RK2 path that built the databases.

The steady shape is a property of the model, not of the integrator: both paths must reach the
same D12, L1, L2 and theta. How close: the steady criterion stops a run once D12 has varied by
less than shape_tol = 5e-3 of itself over one time unit, so two correct runs that stop at
different times may differ by up to that much; we ask for 2e-3 (measured with the step
tolerance 2e-4 a: at most 1.4e-3, theta at lambda = 5; 6.3e-4 at lambda = 1).
Each case runs on one thread (OpenMP and OpenBLAS) at mesh level 2 (162 nodes): about a
second at lambda = 1, 5-8 s at lambda = 5 (the GMRES solve of every velocity evaluation).
"""
from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import h5py
import pytest

from capsmech.io.case import read_case

from conftest import assert_usage_error, cached_capsim, uninterrupted_and_resumed

ONE_THREAD = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
STEADY_REL_TOL = 2e-3
SHAPE = ("D12", "L1", "L2", "theta")


@pytest.fixture(scope="module")
def run_shear(capsim, tmp_path_factory):
    """Run capsim --flow shear once per distinct argument list (level 2, one thread); return the path."""
    return cached_capsim(capsim, tmp_path_factory.mktemp("shear_implicit"), "--flow", "shear", "--level", "2",
                         "--threads", "1", timeout=300, env=ONE_THREAD)


def velocity_evaluations(path: Path) -> int:
    """Velocity evaluations of a run: counted by an implicit run (its message), 2 per RK2 step."""
    case = read_case(path)
    found = re.search(r"(\d+) velocity evaluations", case.message)
    if found:
        return int(found.group(1))
    with h5py.File(path) as f:
        dt = float(f.attrs["dt"])
    return 2 * round(case.history["t"][-1] / dt)


@pytest.mark.parametrize("law_args", [
    ("--law", "NH", "--ca", "0.05"),
    ("--law", "NH", "--ca", "0.2"),
    ("--law", "GH", "--nu-s", "0.5", "--ca", "0.05"),
    ("--law", "NH", "--kb", "0.01", "--ca", "0.05"),
    ("--law", "NH", "--lambda", "5", "--ca", "0.05"),
    pytest.param(("--law", "NH", "--lambda", "0.2", "--ca", "0.05"), marks=pytest.mark.validate),
], ids=["NH-0.05", "NH-0.2", "GH0.5-0.05", "NH-kb0.01-0.05", "NH-lambda5-0.05", "NH-lambda0.2-0.05"])
def test_implicit_reaches_the_rk2_steady_shape(run_shear, law_args):
    # RK2 named: --integrator auto takes implicit steps below Ca_s 0.07.
    rk2 = read_case(run_shear(*law_args, "--integrator", "rk2"))
    implicit = read_case(run_shear(*law_args, "--integrator", "implicit"))
    assert rk2.status == implicit.status == "steady", implicit.message
    for name in SHAPE:
        assert implicit.steady_value(name) == pytest.approx(rk2.steady_value(name), rel=STEADY_REL_TOL), name
    # The implicit step puts the volume back after every step (RK2: flux-free velocities).
    assert abs(implicit.history["volume"][-1] / implicit.history["volume"][0] - 1) < 1e-10


def test_implicit_needs_fewer_velocity_evaluations_at_small_ca(run_shear):
    # RK2's step is bound to 0.5 Ca h_min by the membrane stiffness (dt = 1.4e-3 at Ca_s 0.01,
    # level 2); the implicit step only by accuracy. Measured: 2900 against 332 evaluations.
    args = ("--law", "NH", "--ca", "0.01")
    rk2, implicit = run_shear(*args, "--integrator", "rk2"), run_shear(*args, "--integrator", "implicit")
    assert read_case(implicit).status == read_case(rk2).status == "steady"
    for name in SHAPE:
        assert read_case(implicit).steady_value(name) == pytest.approx(read_case(rk2).steady_value(name),
                                                                        rel=STEADY_REL_TOL), name
    assert velocity_evaluations(rk2) >= 5 * velocity_evaluations(implicit)
    # At lambda = 5, Ca_s 0.05 (where an evaluation is a GMRES solve) measured 842 against 328;
    # at lambda = 1, Ca_s 0.05 only 610 against 477: the step there is bound by accuracy too.
    args = ("--law", "NH", "--lambda", "5", "--ca", "0.05")
    assert velocity_evaluations(run_shear(*args, "--integrator", "rk2")) >= \
        2 * velocity_evaluations(run_shear(*args, "--integrator", "implicit"))


def test_implicit_kill_and_resume_reaches_the_same_steady_shape(capsim, tmp_path, monkeypatch):
    # At level 3, the steady shape after one kill; test_resume_exact has the bit-for-bit check
    # (several kills, every dataset) on a coarser mesh.
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    args = ["--flow", "shear", "--law", "NH", "--ca", "0.01", "--level", "3", "--integrator", "implicit",
            "--threads", "1", "--quiet"]
    a, b = uninterrupted_and_resumed(capsim, args, tmp_path, timeout=300)
    assert a.status == b.status == "steady"
    for name in SHAPE:
        assert b.steady_value(name) == pytest.approx(a.steady_value(name), rel=STEADY_REL_TOL), name


BAD_INPUTS = [
    (["--integrator", "newton"], "--integrator"),
    (["--integrator", "euler"], "--integrator"),
    (["--integrator", "implicit", "--dt", "-1"], "--dt"),
]


@pytest.mark.parametrize("override,field", BAD_INPUTS, ids=["newton", "unknown", "implicit-dt"])
def test_bad_integrator_exits_2_naming_the_field(capsim, tmp_path, override, field):
    out = tmp_path / "x.h5"
    base = {"--flow": "shear", "--law": "NH", "--ca": "0.1", "--out": str(out)}
    assert_usage_error(capsim, base, override, field, out)


@pytest.mark.validate
def test_level_3_implicit_matches_rk2_with_far_fewer_evaluations(capsim, tmp_path):
    # The bench's level (bench/bench_shear_implicit.py). Measured: Ca_s 0.05, D12 and theta
    # within 1.6e-4 and 1.0e-3 of RK2's (2430 against 824 evaluations); Ca_s 0.01, 5786 against
    # 342 evaluations, D12 within 2.2e-4 (theta 1.8e-3: the orientation of a capsule with
    # D12 = 0.02 is the least determined measure, so it is checked at Ca_s 0.05 only).
    def run(*args: str) -> Path:
        out = tmp_path / f"{len(list(tmp_path.iterdir()))}.h5"
        subprocess.run([str(capsim), "--flow", "shear", "--law", "NH", "--level", "3", *args, "--threads", "1",
                        "--quiet", "--out", str(out)], check=True, timeout=1800, env=ONE_THREAD)
        return out

    rk2, implicit = run("--ca", "0.05", "--integrator", "rk2"), run("--ca", "0.05", "--integrator", "implicit")
    for name in SHAPE:
        assert read_case(implicit).steady_value(name) == pytest.approx(read_case(rk2).steady_value(name),
                                                                        rel=STEADY_REL_TOL), name
    rk2, implicit = run("--ca", "0.01", "--integrator", "rk2"), run("--ca", "0.01", "--integrator", "implicit")
    assert read_case(implicit).steady_value("D12") == pytest.approx(read_case(rk2).steady_value("D12"),
                                                                     rel=STEADY_REL_TOL)
    assert velocity_evaluations(rk2) >= 10 * velocity_evaluations(implicit)
