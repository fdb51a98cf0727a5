"""Capsule in a circular tube, 3D model (`--model 3d`, kernel/src/tube_capsule.f90).

The 3D model is checked against physics (a nearly rigid sphere on the axis moves at the
Haberman & Sayre velocity), against the axisymmetric model (the same problem solved on the
meridian), and for its engineering (the wall LU is cached and reused, bad flags exit 2).

Fast tests use a coarse problem: capsule level 2 (162 nodes), wall elements 0.28 l far /
0.14 l centre, tube length 6 l (1393 wall nodes), NH, a/l = 0.4, Ca_s = 0.05. That one run
(about 70 s of CPU) serves the Haberman-Sayre, axisymmetric and cache tests.
Units: tube radius l = 1, mean velocity V = 1.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

import h5py
import pytest

from capsmech.io.case import read_case

from conftest import assert_usage_error
from test_tube import haberman_sayre_velocity

COARSE_WALL = ["--wall-h-far", "0.28", "--wall-h-centre", "0.14", "--tube-length", "6"]
STIFF_SIZE, STIFF_CA = 0.4, 0.05


def run_capsim(capsim: Path, args: list[str], timeout: float = 1200) -> subprocess.CompletedProcess:
    result = subprocess.run([str(capsim), *args], capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, result.stdout + result.stderr
    return result


def tube_3d_args(size: float, ca: float, level: int, wall: list[str], cache: Path | None, out: Path) -> list[str]:
    """capsim flags of an NH 3D tube case; cache None: the default cache directory."""
    cache_args = [] if cache is None else ["--wall-cache", str(cache)]
    return ["--flow", "tube", "--model", "3d", "--law", "NH", "--a-over-l", str(size), "--ca", str(ca),
            "--level", str(level), *wall, *cache_args, "--threads", "1", "--out", str(out)]


@pytest.fixture(scope="module")
def coarse_run(capsim, tmp_path_factory):
    """The coarse 3D case to steady state, with a fresh wall cache directory."""
    root = tmp_path_factory.mktemp("tube3d")
    cache = root / "cache"
    cache.mkdir()
    out = root / "coarse.h5"
    result = run_capsim(capsim, tube_3d_args(STIFF_SIZE, STIFF_CA, 2, COARSE_WALL, cache, out) + ["--t-max", "10"])
    return {"case": read_case(out), "path": out, "cache": cache, "stdout": result.stdout, "root": root}


@pytest.fixture(scope="module")
def axi_reference(capsim, tmp_path_factory):
    """The axisymmetric model at the same point (24 meridian elements: against 48, v_c/V
    differs by 3e-5 and L_z by 1e-3 l here, far below the 3D level-2 error)."""
    out = tmp_path_factory.mktemp("tube_axi") / "axi.h5"
    run_capsim(capsim, ["--flow", "tube", "--law", "NH", "--a-over-l", str(STIFF_SIZE), "--ca", str(STIFF_CA),
                        "--n-meridian", "24", "--threads", "1", "--quiet", "--out", str(out)])
    return read_case(out)


@pytest.mark.slow
def test_nearly_rigid_capsule_moves_at_the_haberman_sayre_velocity(coarse_run):
    # A small capsule (a/l = 0.4) at Ca_s = 0.05 is nearly rigid: the axisymmetric model puts
    # its v_c/V 0.5 % below the rigid sphere's (1.7871 against 1.7965), the deformation's
    # share; Ca_s = 1e-3 as in the axisymmetric test would need ~50x more explicit steps
    # (dt ~ Ca h). Measured: 1.7880 (-0.47 %).
    case = coarse_run["case"]
    assert case.status == "steady", case.message
    assert case.steady_value("v_c") == pytest.approx(haberman_sayre_velocity(STIFF_SIZE), rel=0.01)
    # DESIGN.md: volume conserved to 0.5 % over a run.
    assert abs(case.history["volume"][-1] / case.history["volume"][0] - 1) < 5e-3


@pytest.mark.slow
def test_3d_agrees_with_the_axisymmetric_model(coarse_run, axi_reference):
    # Measured at level 2: v_c/V 1.7880 vs 1.7871 (0.05 %), L_z 0.7534 vs 0.7536 (0.03 %),
    # L_p 0.0557 vs 0.0533 l. The tolerances leave room for the level-2 discretisation
    # (capsule edge 0.12 l); the parachute depth is a small difference of two lengths, so it
    # is compared in l, at a tenth of the capsule's edge length.
    case = coarse_run["case"]
    assert case.status == "steady" and axi_reference.status == "steady"
    assert case.steady_value("v_c") == pytest.approx(axi_reference.steady_value("v_c"), rel=5e-3)
    assert case.steady_value("L_z") == pytest.approx(axi_reference.steady_value("L_z"), rel=0.01)
    assert case.steady_value("L_p") > 0.02 and axi_reference.steady_value("L_p") > 0.02
    assert case.steady_value("L_p") == pytest.approx(axi_reference.steady_value("L_p"), abs=0.012)


@pytest.mark.slow
def test_case_file_has_mesh_and_meridian_profile(coarse_run):
    case = coarse_run["case"]
    assert case.mesh["nodes"].shape == (162, 3) and case.mesh["triangles"].shape == (320, 3)
    r, z = case.profile["r"], case.profile["z"]
    # Section y = 0, x > 0, front first: starts near the front on the axis, ends at the rear.
    assert (r >= 0).all() and r.max() == pytest.approx(case.steady_value("r_max"), rel=0.05)
    assert z[0] == pytest.approx(z.max(), abs=1e-3) and z[-1] < 0 < z[0]
    # The membrane's own single layer of the run: the default, the full 7-point quadrature.
    with h5py.File(coarse_run["path"]) as f:
        value = f.attrs["self_quadrature"]
        assert (value.decode() if isinstance(value, bytes) else value) == "full"


@pytest.mark.slow
def test_wall_lu_is_cached_and_reused(capsim, coarse_run):
    cache = coarse_run["cache"]
    files = sorted(cache.iterdir())
    # One factorisation file, written atomically (no temporary left behind).
    assert [f.suffix for f in files] == [".lu"], files
    with h5py.File(coarse_run["path"]) as f:
        assert f.attrs["wall_from_cache"] == 0
    out = coarse_run["root"] / "again.h5"
    result = run_capsim(capsim, tube_3d_args(STIFF_SIZE, STIFF_CA, 2, COARSE_WALL, cache, out) + ["--t-max", "0.06"])
    assert "cache: loaded" in result.stdout
    with h5py.File(out) as f:
        assert f.attrs["wall_from_cache"] == 1
    assert sorted(cache.iterdir()) == files
    # The loaded factors are the computed ones: the first steps repeat bit for bit (row 1 is
    # the first record after t = 0, at the same step in both runs).
    again = read_case(out)
    first = coarse_run["case"]
    k = 1
    assert len(again.history["t"]) > k and again.history["t"][k] == first.history["t"][k]
    for name in ("L_z", "v_c", "volume"):
        assert again.history[name][k] == first.history[name][k]


BAD_3D_INPUTS = [
    (["--wall-h-far", "0"], "--wall-h-far"),
    (["--wall-h-far", "fine"], "--wall-h-far"),
    (["--wall-h-far", "2"], "--wall-h-far"),
    (["--wall-h-centre", "0.01"], "--wall-h-centre"),
    (["--wall-h-centre", "0.3"], "--wall-h-centre"),
    (["--wall-h-far", "0.02", "--wall-h-centre", "0.02"], "--wall-h-centre"),
    (["--wall-cache", "/nonexistent/capsmech-cache"], "--wall-cache"),
    (["--tube-length", "2"], "--tube-length"),
    (["--model", "2d"], "--model"),
    (["--self-quadrature", "exact"], "--self-quadrature"),
    (["--model", "axi", "--self-quadrature", "full"], "--self-quadrature"),
    (["--flow", "shear", "--self-quadrature", "full"], "--self-quadrature"),
]


@pytest.mark.parametrize("override,field", BAD_3D_INPUTS, ids=[" ".join(o) for o, _ in BAD_3D_INPUTS])
def test_bad_3d_tube_input_exits_2_naming_the_field(capsim, tmp_path, override, field):
    out = tmp_path / "x.h5"
    base = {"--flow": "tube", "--model": "3d", "--law": "NH", "--ca": "0.05", "--a-over-l": "0.8",
            "--wall-cache": str(tmp_path), "--out": str(out)}
    assert_usage_error(capsim, base, override, field, out)


# ---------------------------------------------------------------------------------------
# make validate: 3D against the axisymmetric model at the points, within 1 % at level 4.
# Level 3 does not resolve the parachute to 1 % (L_p +4.7 % at (0.8, 0.05), +16 % at
# (0.9, 0.1)); its convergence towards the axisymmetric model is the next test's. The wall is
# the one the measured runs used, 0.2 / 0.1 l over 6 l: refining it to the paper's 0.14 / 0.07
# l moved level 3 at (0.9, 0.1) by -0.13 % (v_c/V), +0.8 % (L_p), -0.12 % (L_z) at t = 2.8,
# and 10 l against 6 l moved level 2 by -0.17 %, +0.07 %, -0.15 % (README). The reference is
# the converged axisymmetric model (192 meridian elements; the default 64 is 0.6 % high on L_p
# at a/l 0.9). Measured: (0.8, 0.05) +0.17 %, +0.92 %, +0.17 % (2611 s); (0.9, 0.1) +0.66 %,
# -0.40 %, -0.06 % (v_c/V, L_p, L_z; 4542 s, steady at t = 10.4), on one loaded core.
# ---------------------------------------------------------------------------------------

VALIDATE_WALL = ["--wall-h-far", "0.2", "--wall-h-centre", "0.1", "--tube-length", "6"]


@pytest.mark.validate
@pytest.mark.parametrize("size,ca", [(0.8, 0.05), (0.9, 0.1)])
def test_3d_matches_axisymmetric_at_the_paper_points(capsim, tmp_path, size, ca):
    axi_out = tmp_path / "axi.h5"
    run_capsim(capsim, ["--flow", "tube", "--law", "NH", "--a-over-l", str(size), "--ca", str(ca), "--n-meridian", "192",
                        "--threads", "1", "--quiet", "--out", str(axi_out)], timeout=3600)
    axi = read_case(axi_out)
    out = tmp_path / "3d.h5"
    run_capsim(capsim, tube_3d_args(size, ca, 4, VALIDATE_WALL, None, out) + ["--t-max", "15", "--quiet"],
               timeout=6 * 3600)
    case = read_case(out)
    assert case.status == "steady" and axi.status == "steady", case.message
    for name in ("L_z", "L_p", "v_c"):
        assert case.steady_value(name) == pytest.approx(axi.steady_value(name), rel=0.01), name


@pytest.mark.validate
def test_3d_converges_to_the_axisymmetric_model_with_the_capsule_mesh(capsim, tmp_path):
    """a/l 0.8, Ca_s 0.05 (NH), one wall (0.2/0.1 l over 6 l), levels 2 and 3 to steady state:
    the differences to the converged axisymmetric model (96 meridian elements; 192 changes
    L_p by 1e-5 l) of L_p and v_c/V shrink at least twofold per level, i.e. at least first
    order in the element size. Measured (README "3D mesh convergence"): L_p +0.0240 -> +0.0079
    (x3.0; level 4 +0.0016), v_c/V +0.89 % -> +0.33 % (x2.7; level 4 +0.17 %); 10-20 min."""
    axi_out = tmp_path / "axi.h5"
    run_capsim(capsim, ["--flow", "tube", "--law", "NH", "--a-over-l", "0.8", "--ca", "0.05", "--n-meridian", "96",
                        "--threads", "1", "--quiet", "--out", str(axi_out)], timeout=1200)
    axi = read_case(axi_out)
    wall = ["--wall-h-far", "0.2", "--wall-h-centre", "0.1", "--tube-length", "6"]
    errors = {}
    for level in (2, 3):
        out = tmp_path / f"level{level}.h5"
        run_capsim(capsim, tube_3d_args(0.8, 0.05, level, wall, None, out) + ["--quiet"], timeout=3600)
        case = read_case(out)
        assert case.status == "steady", case.message
        errors[level] = {name: abs(case.steady_value(name) - axi.steady_value(name)) for name in ("L_p", "v_c")}
    for name in ("L_p", "v_c"):
        assert errors[3][name] < 0.5 * errors[2][name], (name, errors)
