"""The stability check of the 3D steady solver (`--model 3d --integrator newton`,
kernel/src/tube_steady_3d.f90, estimate_growth_rate): the rightmost eigenvalue of the
linearised time-stepped dynamics at the Newton shape, by Jacobi-Davidson with the stiffness
preconditioner, each Jacobian product a difference that no switch of the quadrature rules
spoils, the converged pair confirmed by a fresh product.

The estimate is checked against what it claims: the growth (or decay) rate of a small
perturbation along its eigenvector, measured by the model's own RK2 time stepping from the
steady shape (bin/tube3d_stability_probe), the steady shape's own drift removed by stepping it
unperturbed alongside. Units: tube radius l = 1, mean velocity V = 1.
"""
from __future__ import annotations

import h5py
import pytest

from capsmech.io.case import decode_str

from conftest import run_keyed_probe
from test_tube_3d import COARSE_WALL, run_capsim, tube_3d_args

# NH a/l 0.8, Ca_s 0.05 at level 2 on the coarse test wall: the 3D tests' Newton case.
SIZE, CA = 0.8, 0.05
# A Ritz pair counts as converged when its residual is below this (V/l; tube_steady_3d's
# growth_tol, a tenth of the 0.1 V/l flag limit).
GROWTH_TOL = 1e-2
# The estimate's evaluation budget (tube_steady_3d's growth_budget), checked before each
# expansion, and the most that one expansion (two products of up to three evaluations) and the
# confirming product (up to three) add past it.
GROWTH_BUDGET = 300 + 6 + 3


@pytest.fixture(scope="module")
def newton_case(capsim, tmp_path_factory):
    root = tmp_path_factory.mktemp("tube3d_stability")
    out = root / "newton.h5"
    run_capsim(capsim, tube_3d_args(SIZE, CA, 2, COARSE_WALL, root, out) + ["--integrator", "newton"])
    with h5py.File(out) as f:
        return dict(f.attrs)


def test_growth_rate_converges_within_its_budget(newton_case):
    # The estimate converges (stable is 1 or 0, not -1 unknown), its Ritz pair's residual,
    # confirmed by a fresh product, is within the tolerance, and its cost within the budget.
    assert newton_case["stable"] in (0, 1)
    assert newton_case["growth_rate_residual"] <= GROWTH_TOL
    assert 0 < newton_case["growth_rate_evaluations"] <= GROWTH_BUDGET
    assert newton_case["stable"] == int(newton_case["growth_rate"] <= 0.1)


# The validated small wall of the 3D branch tests (h far 0.2, h at the capsule 0.1, length 6).
SMALL_WALL = ["--wall-h-far", "0.2", "--wall-h-centre", "0.1", "--tube-length", "6"]


@pytest.mark.validate
@pytest.mark.parametrize("ca,wall", [(0.05, COARSE_WALL), (0.06, SMALL_WALL)], ids=["coarse-0.05", "small-0.06"])
def test_growth_rate_is_the_rate_time_stepping_measures(tmp_path, ca, wall):
    """A perturbation of 2e-3 l along the estimate's eigenvector, time-stepped by RK2 for 2 l/V
    (NH a/l 0.8, level 2): its norm grows or decays at the estimated rate. Measured on the
    small wall at Ca_s 0.06: estimate +0.0780 V/l, time stepping +0.0755 V/l."""
    h_far, h_centre, length = wall[1], wall[3], wall[5]
    values = run_keyed_probe("tube3d_stability_probe", 2, SIZE, ca, length, h_far, h_centre, tmp_path, 2e-3, 2.0,
                             timeout=1800)
    assert values["steady"] == 1
    assert values["growth_residual"] <= GROWTH_TOL
    # The estimate is an eigenvalue to within its residual; the measured slope's own error
    # (the velocity's quadrature noise, ~1e-5 V, against a perturbation of ~1e-2 l over 2 l/V)
    # is smaller.
    assert values["measured_rate"] == pytest.approx(values["growth_rate"], abs=GROWTH_TOL)
    # Where the rate is outside the tolerance, the perturbation grows or decays with its sign.
    if abs(values["growth_rate"]) > GROWTH_TOL:
        assert (values["norm_ratio"] > 1) == (values["growth_rate"] > 0)


@pytest.mark.validate
def test_branch_ends_where_its_shapes_lose_stability(capsim, tmp_path):
    """NH a/l 0.8 in the tube, level 2, small wall, over Ca_s 0.06, 0.1, 0.14, 0.16: the shape at
    0.16 converges from the branch but is flagged not stable (measured +0.1445 V/l), so the
    branch does not go on from it; the bisection brackets the loss of stability (measured:
    0.15875, +0.078 V/l, and 0.16, +0.145 V/l) and the branch file records it as the
    axisymmetric branch records its end (critical_Ca_s, critical_kind, critical_message)."""
    cache = tmp_path / "cache"
    cache.mkdir()
    summary = tmp_path / "branch.h5"
    values = ("0.06", "0.1", "0.14", "0.16")
    run_capsim(capsim, ["--flow", "tube", "--model", "3d", "--channel", "tube", "--integrator", "newton",
                        "--law", "NH", "--a-over-l", str(SIZE), "--level", "2", *SMALL_WALL,
                        "--wall-cache", str(cache), "--quiet", "--threads", "1",
                        "--branch-ca", ",".join(values), "--branch-summary", str(summary),
                        "--out", str(tmp_path / "t_Ca{ca}.h5")], timeout=3600)
    with h5py.File(summary) as f:
        attrs = {key: decode_str(value) if isinstance(value, bytes) else value for key, value in f.attrs.items()}
        growth = f["branch/growth_rate"][...]
        ca = f["branch/Ca_s"][...]
    assert attrs["critical_kind"] == "unstable"
    assert "loses stability" in attrs["critical_message"]
    low, high = attrs["critical_Ca_s_last_steady"], attrs["critical_Ca_s_first_failed"]
    assert low < attrs["critical_Ca_s"] < high
    assert (high - low) / low <= attrs["critical_Ca_s_resolution_rel"] * (1 + 1e-12)
    # Every point the branch carried is not flagged (growth rate at most the 0.1 V/l limit), and
    # the last one is the bracket's lower end.
    assert (growth <= 0.1).all()
    assert ca[-1] == pytest.approx(low)
    # The case past the end is the last stable shape, as past a fold.
    case = tmp_path / "t_Ca0.16.h5"
    with h5py.File(case) as f:
        assert decode_str(f.attrs["status"]) == "continuous_elongation"
        assert f.attrs["branch_critical_Ca_s"] == pytest.approx(attrs["critical_Ca_s"])
