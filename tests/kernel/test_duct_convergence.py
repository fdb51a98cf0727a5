"""Mesh convergence of the 3D steady solver in the square duct, and the duct against the
circular tube for a small capsule (`make validate`: about 3 minutes on one core).

1. NH a/w 0.8, Ca_s 0.05, solved by Newton-Krylov at capsule levels 2, 3 and 4 on the wall of
   the tube's level-2..4 study (element size 0.2 w far, 0.1 w over |z| < 1, duct length 6 w):
   the differences between successive levels must shrink (docs/theory/duct.md, "Mesh
   convergence"). The duct has no published capsule value; the same runs in the circular tube
   are held against the axisymmetric model, the tube's converged reference.
2. A capsule much smaller than the channel (a 0.4, Ca_s 0.2, level 2): it feels the flow's
   centreline velocity and its quadratic part u_max - (G/4) r^2, G = -Lap(u) (square duct:
   u_max 2.0963, G 7.1135; tube: 2 and 8), so the duct at Ca_s and the tube at Ca_s G_duct /
   G_tube load the membrane alike and must give the same shape and the same lag
   (u_max - v_c) / G, up to the walls' different reflections and the duct flow's quartic,
   non-axisymmetric terms.
Units: half-width w (radius l) = 1, mean velocity V = 1.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

import h5py
import pytest

from capsmech.io.case import read_case

WALL = ["--wall-h-far", "0.2", "--wall-h-centre", "0.1", "--tube-length", "6"]
SIZE, CA = 0.8, 0.05
LEVELS = (2, 3, 4)
# Square duct (docs/theory/duct.md, Shah & London): u_max / U and f Re, G = 2 f Re U / D_h^2, D_h = 2 w.
DUCT_U_MAX = 2.0963
DUCT_G = 2 * 14.22708 / 2.0**2
TUBE_U_MAX, TUBE_G = 2.0, 8.0
SMALL_SIZE, SMALL_CA = 0.4, 0.2


def steady_case(capsim: Path, cache: Path, out: Path, channel: str, size: float, ca: float, level: int) -> dict:
    args = [str(capsim), "--flow", "tube", "--model", "3d", "--integrator", "newton", "--law", "NH",
            "--a-over-l", repr(size), "--ca", repr(ca), "--level", str(level), *WALL, "--wall-cache", str(cache),
            "--threads", "1", "--quiet", "--out", str(out)]
    if channel != "tube":
        args += ["--channel", channel]
    result = subprocess.run(args, capture_output=True, text=True, timeout=1800)
    assert result.returncode == 0, result.stdout + result.stderr
    case = read_case(out)
    assert case.status == "steady", case.message
    with h5py.File(out) as f:
        residual = float(f.attrs["newton_residual"])
    # Newton stops at 5e-5 V, or accepts a stalled line search below 1e-4 V.
    assert residual < 1e-4
    return {name: case.steady_value(name) for name in ("L_z", "L_p", "v_c")}


@pytest.fixture(scope="module")
def runs(capsim, tmp_path_factory):
    root = tmp_path_factory.mktemp("duct_convergence")
    return {(channel, level): steady_case(capsim, root, root / f"{channel}_{level}.h5", channel, SIZE, CA, level)
            for channel in ("square", "tube") for level in LEVELS}


@pytest.fixture(scope="module")
def axisymmetric(capsim, tmp_path_factory):
    """The axisymmetric model on a converged meridian (192 elements)."""
    out = tmp_path_factory.mktemp("duct_convergence_axi") / "axi.h5"
    subprocess.run([str(capsim), "--flow", "tube", "--law", "NH", "--a-over-l", repr(SIZE), "--ca", repr(CA),
                    "--n-meridian", "192", "--threads", "1", "--quiet", "--out", str(out)], check=True, timeout=600)
    case = read_case(out)
    return {name: case.steady_value(name) for name in ("L_z", "L_p", "v_c")}


# Largest allowed |f4 - f3| / |f3 - f2| per quantity. Measured in the duct: L_z 0.097,
# L_p 0.32, v_c 0.19 (orders 3.4, 1.6, 2.4 in the element size); in the tube 0.18, 0.40, 0.27.
# Order 1 would give 0.5.
CONTRACTION = {"L_z": 0.3, "L_p": 0.5, "v_c": 0.4}


@pytest.mark.validate
@pytest.mark.parametrize("channel", ["square", "tube"])
@pytest.mark.parametrize("name", ["L_z", "L_p", "v_c"])
def test_level_differences_shrink(runs, channel, name):
    f2, f3, f4 = (runs[(channel, level)][name] for level in LEVELS)
    assert (f3 - f2) * (f4 - f3) > 0, (f2, f3, f4)  # monotone
    assert abs(f4 - f3) < CONTRACTION[name] * abs(f3 - f2), (f2, f3, f4)


@pytest.mark.validate
def test_level_4_within_the_issue_tolerance_in_the_duct(runs):
    # The level-3 to level-4 change bounds the level-4 error where the order exceeds 1 (it is
    # 1.6 to 3.4 here): measured L_z 1e-4, L_p 4.2e-3 (2.4 %), v_c/V 1.3e-3 (0.09 %).
    level3, level4 = runs[("square", 3)], runs[("square", 4)]
    assert level4["L_z"] == pytest.approx(level3["L_z"], rel=1e-3)
    assert level4["v_c"] == pytest.approx(level3["v_c"], rel=3e-3)
    assert level4["L_p"] == pytest.approx(level3["L_p"], rel=0.04)


@pytest.mark.validate
def test_tube_level_4_agrees_with_the_axisymmetric_model(runs, axisymmetric):
    # The same solver and mesh in the tube, against the tube's converged axisymmetric model:
    # measured at level 4 L_z +0.16 %, L_p +0.0013 l (+0.8 %), v_c/V +0.17 % (the issue's 1 %);
    # the error falls from level 2 to 4 (L_p +0.024, +0.0078, +0.0013 l).
    level4 = runs[("tube", 4)]
    for name in ("L_z", "L_p", "v_c"):
        assert level4[name] == pytest.approx(axisymmetric[name], rel=0.01), name
    errors = [abs(runs[("tube", level)]["L_p"] - axisymmetric["L_p"]) for level in LEVELS]
    assert errors[0] > errors[1] > errors[2]


@pytest.mark.validate
def test_small_capsule_in_the_duct_behaves_as_in_the_tube_at_equal_load(capsim, tmp_path):
    # Level 2 in both: the capsule mesh is the same, so its error largely cancels in the
    # comparison. Measured: L_z -0.06 %, L_p +0.09 %, lag +0.7 % (duct against tube at the
    # equivalent Ca_s). At the same Ca_s instead, L_p differs by 6 %: the load mapping matters.
    duct = steady_case(capsim, tmp_path, tmp_path / "duct.h5", "square", SMALL_SIZE, SMALL_CA, 2)
    tube = steady_case(capsim, tmp_path, tmp_path / "tube.h5", "tube", SMALL_SIZE, SMALL_CA * DUCT_G / TUBE_G, 2)
    assert duct["L_z"] == pytest.approx(tube["L_z"], rel=5e-3)
    assert duct["L_p"] == pytest.approx(tube["L_p"], rel=0.02)
    lag_duct = (DUCT_U_MAX - duct["v_c"]) / DUCT_G
    lag_tube = (TUBE_U_MAX - tube["v_c"]) / TUBE_G
    # The walls differ: the tube's reflection raises a rigid sphere's v_c by 0.55 % of V at
    # a 0.4 (Haberman & Sayre against Faxen), 4 % of the lag; the duct's is not known.
    assert lag_duct == pytest.approx(lag_tube, rel=0.03)
