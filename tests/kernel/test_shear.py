"""Capsule in simple shear flow: the capsim executable against theory and published values.

Each case is run once per session (cached) at mesh level 3 (642 nodes) unless stated.
"""
from __future__ import annotations

import math
import subprocess

import h5py
import numpy as np
import pytest

from capsmech.inversion.small_deformation import d12_slope as small_deformation_slope
from capsmech.io.case import read_case

from conftest import assert_usage_error, cached_capsim, run_killed_and_resumed


@pytest.fixture(scope="session")
def run_case(capsim, tmp_path_factory):
    """Run capsim once per distinct argument list; return the case file path."""
    return cached_capsim(capsim, tmp_path_factory.mktemp("shear"))


def law_flags(law: str, nu_s: object) -> list[str]:
    """--nu-s for GH only: capsim refuses it with another law (NH has K_s = 3 G_s, nu_s 0.5)."""
    return ["--nu-s", str(nu_s)] if law == "GH" else []


# Level 3 with implicit steps, as the databases take below Ca_s 0.07 (config/paper.yaml): NH
# stops in its plateau at t = 3.3, D12/Ca_s = 2.084 (+0.05 %). GH nu_s 0.2 at level 3 grows the
# node-scale mode of issue 23 (item 1) from t ~ 3 (D12 +-8 % by t = 10, implicit steps; RK2 NH
# as well): it has no steady state by the limit estimate of kernel 0.3.2 (max_time at t = 60,
# 8 min), and its level-3 check waits for that fix; level 2 stays smooth, 3.4 % below the
# slope (mesh error).
@pytest.mark.parametrize("law,nu_s,level,rel", [
    ("NH", 0.5, "3", 0.03),
    ("GH", 0.2, "2", 0.04),
])
def test_small_deformation_limit(run_case, law, nu_s, level, rel):
    # NH has K_s = 3 G_s, the nu_s = 0.5 value of the formula: D12/Ca_s -> 25/12.
    ca = 0.01
    case = read_case(run_case("--flow", "shear", "--law", law, *law_flags(law, nu_s), "--ca", str(ca),
                              "--level", level, "--integrator", "implicit"))
    assert case.status == "steady", case.message
    d12 = case.steady_value("D12")
    assert d12 / ca == pytest.approx(small_deformation_slope(nu_s), rel=rel)
    assert math.degrees(case.steady_value("theta")) == pytest.approx(45.0, abs=2.0)
    assert abs(case.history["volume"][-1] / case.history["volume"][0] - 1) < 0.005


def test_nh_moderate_capillary_number_matches_paper(run_case):
    # Paper section 4.3: D12 = 0.38 for NH near Ca_s = 0.27, so D12 ~ 0.38-0.40 at Ca_s = 0.3.
    case = read_case(run_case("--flow", "shear", "--law", "NH", "--ca", "0.3", "--level", "3"))
    assert case.status == "steady", case.message
    assert 0.38 <= case.steady_value("D12") <= 0.40
    # Tank-treading capsules align closer to the flow as Ca grows.
    assert 15 < math.degrees(case.steady_value("theta")) < 35
    assert abs(case.history["volume"][-1] / case.history["volume"][0] - 1) < 0.005


@pytest.mark.parametrize("law,nu_s,expected", [
    ("NH", "0.5", {"continuous_elongation"}),
    ("GH", "0", {"continuous_elongation", "failed"}),
])
def test_strong_flow_reports_no_steady_state(run_case, law, nu_s, expected):
    # At Ca_s = 3 neither law reaches a steady shape: the NH capsule stretches past L1 = 3a,
    # the GH nu_s = 0 membrane (K_s = G_s) folds at the tips until its elements break down.
    # Such runs carry a status and a reason, and no steady numbers.
    # (GH nu_s = 0 at Ca_s = 0.6, which the paper reports as elongating, stays steady in
    # this model at levels 3 and 4, D12 = 0.516 / 0.520; see the README.)
    path = run_case("--flow", "shear", "--law", law, *law_flags(law, nu_s), "--ca", "3", "--level", "3", "--t-max", "30")
    case = read_case(path)
    assert case.status in expected, case.message
    assert case.message
    with h5py.File(path) as f:
        assert "steady" not in f
    assert case.history["t"][-1] < 30                    # decided before the time limit
    with pytest.raises(Exception, match=case.status):
        case.steady_value("D12")


@pytest.mark.parametrize("ca", ["0.6", "0.3"])
def test_steady_state_is_the_limit_within_its_stated_time_error(run_case, ca):
    # Issue 23, item 2. The old rule (D12 varies by < 5e-3 over one time unit) stopped in the
    # slow decay after the overshoot: +1.5 % at Ca_s 0.6, +0.4 % at 0.3 (levels 2 and 3). The
    # steady row now waits for the estimated remaining change of D12 (capsule_model's
    # limit_estimate) to fall below 5e-4 and records it as time_error_rel. Reference: the mean
    # D12 over t = 10-20 of a run that never stops (--steady-tol 1e-12), level 2.
    path = run_case("--flow", "shear", "--law", "NH", "--ca", ca, "--level", "2")
    case = read_case(path)
    assert case.status == "steady", case.message
    with h5py.File(path) as f:
        time_error = float(f.attrs["time_error_rel"])
        assert f.attrs["time_error_measure"] in (b"D12", "D12")
    assert 0 < time_error < 1e-3
    long_run = read_case(run_case("--flow", "shear", "--law", "NH", "--ca", ca, "--level", "2",
                                  "--t-max", "20", "--steady-tol", "1e-12"))
    assert long_run.status == "max_time"
    late = long_run.history["t"] >= 10
    limit = float(np.mean(long_run.history["D12"][late]))
    d12 = case.steady_value("D12")
    assert abs(d12 / limit - 1) <= 2 * time_error          # honest: within twice the estimate
    assert abs(d12 / limit - 1) < 1e-3                      # the old bias (0.4-1.5 %) is gone


def test_case_file_layout(run_case):
    path = run_case("--flow", "shear", "--law", "NH", "--ca", "0.3", "--level", "3")
    with h5py.File(path) as f:
        assert f.attrs["schema_version"] == 1
        assert f["mesh/nodes"].shape == (642, 3)            # Fortran (3, n) reads as (n, 3)
        assert f["mesh/triangles"].shape == (1280, 3)
        assert f["mesh/triangles"][()].min() == 0          # 0-based for Python
        assert f["steady/D12"].attrs["units"] in (b"1", "1")
        y, z = f["profile/y"][()], f["profile/z"][()]
        # The shear-plane contour spans the capsule: its extent is about 2 L1 along the major axis.
        extent = np.max(np.hypot(y - y.mean(), z - z.mean()))
        assert extent == pytest.approx(f["steady/L1"][()], rel=0.05)


BAD_INPUTS = [
    (["--ca", "-1"], "--ca"),
    (["--ca", "0"], "--ca"),
    (["--ca", "abc"], "--ca"),
    (["--ca", "nan"], "--ca"),
    (["--nu-s", "1.0", "--law", "GH"], "--nu-s"),
    (["--nu-s", "-1.5", "--law", "GH"], "--nu-s"),
    (["--law", "XX"], "--law"),
    (["--flow", "couette"], "--flow"),
    (["--level", "9"], "--level"),
    (["--threads", "-2"], "--threads"),
    (["--dt", "-0.1"], "--dt"),
    (["--t-max", "0"], "--t-max"),
    (["--C", "-1", "--law", "SK"], "--C"),
    (["--bogus", "1"], "--bogus"),
    (["--out", "/nonexistent-dir/x.h5"], "--out"),
    (["--out", ""], "--out"),
]


@pytest.mark.parametrize("override,field", BAD_INPUTS, ids=[f for _, f in BAD_INPUTS])
def test_bad_input_exits_2_naming_the_field(capsim, tmp_path, override, field):
    out = tmp_path / "x.h5"
    base = {"--flow": "shear", "--law": "NH", "--ca": "0.1", "--out": str(out)}
    assert_usage_error(capsim, base, override, field, out)


def test_missing_out_exits_2(capsim):
    result = subprocess.run([str(capsim), "--flow", "shear", "--law", "NH", "--ca", "0.1"],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and "--out" in result.stderr


def test_namelist_input(capsim, tmp_path):
    out = tmp_path / "nml.h5"
    nml = tmp_path / "run.nml"
    nml.write_text(f"&capsim\n flow='shear', law='GH', nu_s=0.2, ca=0.3, level=2, t_max=0.5,\n out='{out}'\n/\n")
    subprocess.run([str(capsim), "--namelist", str(nml), "--quiet"], check=True, timeout=120)
    case = read_case(out)
    assert (case.law, case.nu_s, case.Ca_s, case.mesh_level) == ("GH", 0.2, 0.3, 2)
    assert case.status == "max_time"        # t_max = 0.5 is too short for a steady state
    assert case.steady == {}


def test_kill_and_resume_gives_the_same_result(capsim, tmp_path):
    # Ca_s 0.3: steady at t = 7.5. (Ca_s 0.05 at level 3 with RK2 steps, the case until kernel
    # 0.3.1, grows the node-scale mode of issue 23 and ends max_time under the limit estimate.)
    args = ["--flow", "shear", "--law", "NH", "--ca", "0.3", "--level", "3", "--threads", "1", "--quiet"]
    reference = tmp_path / "ref.h5"
    subprocess.run([str(capsim), *args, "--out", str(reference)], check=True, timeout=300)

    resumed = tmp_path / "resumed.h5"
    run_killed_and_resumed(capsim, args, resumed)
    a, b = read_case(reference), read_case(resumed)
    assert a.status == b.status == "steady"
    assert b.steady_value("D12") == pytest.approx(a.steady_value("D12"), rel=1e-10)
    assert len(a.history["t"]) == len(b.history["t"])
