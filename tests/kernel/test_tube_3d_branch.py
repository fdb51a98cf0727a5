"""Steady branches of the 3D tube and duct models (`capsim --branch-ca --model 3d --integrator
newton`, kernel/src/tube_branch_3d.f90): the wall set up once, the first Ca_s solved as a single
case (from the axisymmetric guess), each next one by Newton-Krylov from the previous steady shape;
where Newton finds no steady shape the step is halved, and the branch's end is recorded as a
bracket of Ca_s in a branch file laid out as the axisymmetric model's.

A continued point is checked against the single case at the same Ca_s (the same steady state,
within what the Newton tolerance leaves), its cost against the single case's, and the branch
file through the workflow's own readers (`capsmech.workflow.runner.run_branch`,
`capsmech.workflow.assembly.critical_rows`, which `scripts/add_folds.py` uses). In `make
validate`: a tube branch past the fold against the axisymmetric database's critical Ca_s.
Units: tube radius (duct half-width) l = 1, mean velocity V = 1.
"""
from __future__ import annotations

import math
import subprocess
from pathlib import Path

import h5py
import pytest

from capsmech.io.case import decode_str, read_case
from capsmech.io.database import load_database
from capsmech.workflow.assembly import critical_rows
from capsmech.workflow.grid import Branch, parse_law
from capsmech.workflow.runner import run_branch

from conftest import assert_usage_error
from test_tube_3d import COARSE_WALL, run_capsim

# The validated small wall (docs/validation/kernel-tube.md, "3D mesh convergence"), for the
# validate run; the cheap tests take the coarse test wall of the other 3D tests.
SMALL_WALL = ["--wall-h-far", "0.2", "--wall-h-centre", "0.1", "--tube-length", "6"]
SIZE = 0.8
BRANCH_CA = ("0.04", "0.05")
# Two Newton solutions of one steady state differ by the residual over the slowest relaxation
# rate: Newton stops at 5e-5 V (or where the quadrature noise stalls it, below 1e-4 V), and the
# slowest mode measured (a/l 0.9, a deep parachute) relaxes at ~0.25 V/l: 4e-4 l. The bound is
# the time-stepped run's steady criterion (lengths and v_c settled to 1e-3 per l/V).
SAME_STATE = 1e-3


def kernel_version(capsim: Path) -> str:
    return subprocess.run([str(capsim), "--version"], capture_output=True, text=True, check=True).stdout.split()[-1]


def model_args(channel: str, level: int, wall: list[str], cache: Path) -> list[str]:
    return ["--flow", "tube", "--model", "3d", "--channel", channel, "--integrator", "newton", "--law", "NH",
            "--a-over-l", str(SIZE), "--level", str(level), *wall, "--wall-cache", str(cache), "--quiet"]


@pytest.fixture(scope="module")
def tube_branch(capsim, tmp_path_factory):
    """Tube, level 2: the branch over BRANCH_CA run by the workflow's runner, and the single
    case at the last Ca_s (same wall cache)."""
    root = tmp_path_factory.mktemp("tube3d_branch")
    cache = root / "cache"
    cache.mkdir()
    version = kernel_version(capsim)
    branch = Branch(parse_law("NH"), SIZE, tuple(float(ca) for ca in BRANCH_CA), ())
    branches = root / "branches"
    summary = branches / branch.relative_path
    args = model_args("tube", 2, COARSE_WALL, cache) + ["--branch-ca", ",".join(BRANCH_CA),
                                                         "--branch-summary", str(summary),
                                                         "--out", str(root / "cases" / "t_Ca{ca}.h5")]
    kind = run_branch(capsim, args, code_version=version, threads=1)
    single = root / "single.h5"
    run_capsim(capsim, model_args("tube", 2, COARSE_WALL, cache) + ["--ca", BRANCH_CA[-1], "--threads", "1",
                                                                    "--out", str(single)])
    cases = [root / "cases" / f"t_Ca{ca}.h5" for ca in BRANCH_CA]
    return {"kind": kind, "branch": branch, "branches": branches, "summary": summary, "version": version,
            "cases": cases, "single": single}


def attrs_of(path: Path) -> dict:
    with h5py.File(path) as f:
        return {key: decode_str(value) if isinstance(value, bytes) else value for key, value in f.attrs.items()}


def test_continued_point_is_the_single_case_steady_state(tube_branch):
    continued, single = read_case(tube_branch["cases"][-1]), read_case(tube_branch["single"])
    assert continued.status == "steady", continued.message
    assert single.status == "steady", single.message
    assert attrs_of(tube_branch["cases"][-1])["Ca_s"] == pytest.approx(float(BRANCH_CA[-1]), rel=1e-15)
    for name in ("L_z", "L_p", "v_c"):
        assert continued.steady_value(name) == pytest.approx(single.steady_value(name), abs=SAME_STATE), name
    # Both are roots to the solver's tolerance (5e-5 V, or the noise stall below 1e-4 V).
    attrs = attrs_of(tube_branch["cases"][-1])
    assert attrs["newton_residual"] < 1e-4
    # The single case's stability check: time stepping reaches this shape (the steady state of
    # test_tube_3d_steady.py), so it is stable.
    assert attrs["stable"] == 1 and attrs["growth_rate"] < 0.1


def test_continued_point_costs_fewer_evaluations_than_the_axisymmetric_guess(tube_branch):
    continued, single = attrs_of(tube_branch["cases"][-1]), attrs_of(tube_branch["single"])
    assert "previous branch point" in continued["initial_guess"]
    assert "axisymmetric" in single["initial_guess"]
    assert continued["velocity_evaluations"] < single["velocity_evaluations"]
    # The first point is solved as a single case would be: from the axisymmetric guess.
    assert "axisymmetric" in attrs_of(tube_branch["cases"][0])["initial_guess"]


def test_branch_file_is_read_by_the_workflow(tube_branch):
    # Both Ca_s are below the fold (no end within the request): the workflow's readers see
    # the axisymmetric branch file's fields.
    assert tube_branch["kind"].startswith("none:")
    rows = critical_rows([tube_branch["branch"]], tube_branch["branches"], tube_branch["version"])
    assert rows["NH"]["a_over_l"] == [SIZE]
    assert math.isnan(rows["NH"]["Ca_s"][0]) and rows["NH"]["kind"][0].startswith("none:")
    with h5py.File(tube_branch["summary"]) as f:
        assert decode_str(f.attrs["model"]) == "3d" and decode_str(f.attrs["channel"]) == "tube"
        assert f.attrs["critical_Ca_s_resolution_rel"] > 0
        log = {name: f["branch"][name][()] for name in ("Ca_s", "L_z", "L_p", "v_c", "source")}
    # The log holds the requested points (no halved step here), with the case files' values.
    assert list(log["Ca_s"]) == [float(ca) for ca in BRANCH_CA]
    assert list(log["source"]) == [0, 1]
    for k, path in enumerate(tube_branch["cases"]):
        case = read_case(path)
        for name in ("L_z", "L_p", "v_c"):
            assert log[name][k] == pytest.approx(case.steady_value(name), rel=1e-12), (name, k)


def test_branch_refuses_the_time_stepped_3d_model(capsim, tmp_path):
    base = {"--flow": "tube", "--model": "3d", "--law": "NH", "--a-over-l": "0.8", "--ca": "0.04",
            "--branch-ca": "0.04,0.06", "--branch-summary": str(tmp_path / "b.h5"),
            "--out": str(tmp_path / "c_{ca}.h5")}
    assert_usage_error(capsim, base, ["--integrator", "rk2"], "--branch-ca", tmp_path / "b.h5")


@pytest.mark.validate
def test_tube_branch_past_the_fold_brackets_the_critical_ca(capsim, tmp_path):
    """NH a/l 0.8 in the tube, level 2: the branch from Ca_s 0.1 ends between two Ca_s within
    the stated resolution, near the axisymmetric database's fold (0.1594 at 64 elements)."""
    cache = tmp_path / "cache"
    cache.mkdir()
    summary = tmp_path / "branch.h5"
    values = ("0.1", "0.14", "0.18", "0.2")
    run_capsim(capsim, model_args("tube", 2, SMALL_WALL, cache) + ["--threads", "1", "--branch-ca", ",".join(values),
                                                                   "--branch-summary", str(summary),
                                                                   "--out", str(tmp_path / "t_Ca{ca}.h5")],
               timeout=3600)
    attrs = attrs_of(summary)
    # The branch ends where a continued shape is flagged not stable (growth rate above the
    # limit), or where Newton-Krylov finds no steady shape, whichever comes first: at level 2
    # (small wall) stability is lost between Ca_s 0.15875 and 0.16 (critical 0.1594), just
    # before the fold (0.1631 measured when unstable shapes did not end a branch).
    assert attrs["critical_kind"] in ("unstable", "fold")
    low, high = attrs["critical_Ca_s_last_steady"], attrs["critical_Ca_s_first_failed"]
    assert low < attrs["critical_Ca_s"] < high
    assert (high - low) / low <= attrs["critical_Ca_s_resolution_rel"] * (1 + 1e-12)
    axi = load_database(Path(__file__).resolve().parents[2] / "analysis/src/capsmech/databases/tube.h5").critical("NH")
    fold = float(axi.loc[axi["a_over_l"] == SIZE, "critical_Ca_s"].iloc[0])
    # The 3D level-2 mesh moves the steady shapes against the axisymmetric model (v_c/V +0.9 %,
    # L_p +0.024 l at Ca_s 0.05: docs/validation/kernel-tube.md), and the fold with them:
    # measured 0.1631 (bracket 0.1625-0.1638), +2.3 %.
    assert attrs["critical_Ca_s"] == pytest.approx(fold, rel=0.05)
    # Every case past the end is the last steady shape, marked continuous elongation.
    past = [ca for ca in values if float(ca) >= high]
    assert past
    for ca in past:
        case = read_case(tmp_path / f"t_Ca{ca}.h5")
        assert case.status == "continuous_elongation"
        assert attrs_of(tmp_path / f"t_Ca{ca}.h5")["branch_critical_Ca_s"] == pytest.approx(attrs["critical_Ca_s"])
