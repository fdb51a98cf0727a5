"""Viscosity ratio lambda = inner/outer viscosity in the 3D shear solver (issue 6, part 1).

The double layer and the interface equation are measured by bin/double_layer_probe; the
coupled runs by bin/capsim at mesh level 2 (162 nodes) and Ca_s = 0.02, where a case to steady
state takes 10-40 s on one core. Level-3 and large-lambda runs are behind `validate`.
"""
from __future__ import annotations

import math
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest

from capsmech.io.case import read_case

from conftest import REPO, assert_usage_error, run_killed_and_resumed

PROBE = REPO / "bin" / "double_layer_probe"


def probe(*args: object) -> dict[str, float]:
    if not PROBE.exists():
        pytest.fail(f"{PROBE} is missing: run `make build` first")
    result = subprocess.run([str(PROBE), *map(str, args)], capture_output=True, text=True, check=True, timeout=300)
    return {k: float(v) for k, v in (line.split() for line in result.stdout.splitlines())}


def rates(errors: list[float], h: list[float]) -> list[float]:
    return [math.log(errors[k] / errors[k + 1]) / math.log(h[k] / h[k + 1]) for k in range(len(errors) - 1)]


@pytest.fixture(scope="module")
def shear_case(capsim, tmp_path_factory):
    """Run capsim shear (NH, one thread) once per argument list; return the case file path."""
    cache: dict[tuple[str, ...], Path] = {}
    root = tmp_path_factory.mktemp("lambda")

    def run(*args: str) -> Path:
        if args not in cache:
            out = root / f"case{len(cache)}.h5"
            subprocess.run([str(capsim), "--flow", "shear", "--law", "NH", *args, "--threads", "1", "--quiet",
                            "--out", str(out)], check=True, timeout=900)
            cache[args] = out
        return cache[args]

    return run


# --- the lambda = 1 path ------------------------------------------------------------------

def test_lambda_one_takes_the_old_path_bit_for_bit(shear_case):
    # At lambda = 1 the explicit formula is taken unchanged: the histories are identical, not
    # merely close (the databases computed before the option existed stay valid).
    args = ("--ca", "0.2", "--level", "2", "--t-max", "1")
    with h5py.File(shear_case(*args)) as a, h5py.File(shear_case(*args, "--lambda", "1")) as b:
        assert a.attrs["lambda"] == b.attrs["lambda"] == 1.0
        for name in a["history"]:
            assert np.array_equal(a["history"][name][()], b["history"][name][()]), name
        assert np.array_equal(a["mesh/nodes"][()], b["mesh/nodes"][()])


@pytest.mark.parametrize("dlambda,bound", [(1e-12, 1e-11), (1e-6, 1e-6)])
def test_interface_equation_tends_to_the_explicit_formula(dlambda, bound):
    # The GMRES path at lambda = 1 + d against the explicit formula at lambda = 1 (capsule
    # velocity at an ellipsoidal shape, NH, Ca = 0.2): they differ by O(d), i.e. by round-off
    # at d = 1e-12 (measured 5e-13) and by 3e-7 at d = 1e-6.
    m = probe("lambda-one", 2, dlambda)
    assert m["max_rel_difference"] < bound


# --- the double layer on a sphere -----------------------------------------------------------

@pytest.fixture(scope="module")
def sphere_levels():
    return [2, 3, 4]


def test_gauss_identity_raw_quadrature_is_first_order(sphere_levels):
    # What is tested: M_i = 1/(8 pi) PV int T(y - x_i) . n(y) dS_y computed by the kernel's
    # quadrature WITHOUT the singularity subtraction, against the Gauss identity M = -I/2
    # (max over nodes and tensor entries). On flat triangles the error is first order, not
    # second: at a vertex of the inscribed polyhedron the interior cone falls short of a
    # half-space by an angle O(h), and the PV integral over the polyhedron is that cone's
    # tensor. Measured 0.108, 0.054, 0.027 (levels 2-4): order 1.0. This is why the operator
    # the solver uses takes the -1/2 from the identity of the smooth surface (next tests).
    runs = [probe("identity", level) for level in sphere_levels]
    errors = [r["identity_max_error"] for r in runs]
    order = rates(errors, [r["h_max"] for r in runs])
    assert errors[-1] < 0.03
    assert all(0.9 < p < 1.2 for p in order), order


def test_gauss_identity_off_the_surface_is_second_order(sphere_levels):
    # The same integral at points off the surface, where the identity gives -I inside and 0
    # outside, exactly for the polyhedron too: what is left is the error of the far-field
    # (vertex) rule that the solver uses. Measured at the centre 3.4e-2, 8.6e-3, 2.2e-3
    # (levels 2-4), order 2.0; at (0.1, 0.2, 0.5) the same; outside at (0.2, 0.1, 1.5)
    # 1.3e-3, 2.9e-4, 7.0e-5.
    runs = [probe("identity-off", level) for level in sphere_levels]
    h = [r["h_max"] for r in runs]
    for key in ("centre_max_error", "inside_max_error", "outside_max_error"):
        errors = [r[key] for r in runs]
        assert all(p > 1.8 for p in rates(errors, h)), (key, errors)
    assert runs[-1]["centre_max_error"] < 3e-3


def test_double_layer_of_the_normal_is_second_order(sphere_levels):
    # The subtracted operator on a non-trivial density: on the unit sphere D[n] = +n/2 exactly
    # (n = y; the +1 eigenvalue of 2D that the Wielandt deflation removes). Measured max
    # errors 3.3e-2, 8.5e-3, 2.2e-3 (levels 2-4): order 1.95-1.98.
    runs = [probe("normal", level) for level in sphere_levels]
    errors = [r["normal_max_error"] for r in runs]
    order = rates(errors, [r["h_max"] for r in runs])
    assert errors[-1] < 3e-3
    assert all(p > 1.8 for p in order), order


def test_rigid_body_motions_are_eigenfunctions():
    # D[U + Omega x y] = -(U + Omega x x)/2 on the sphere and on an ellipsoid (1.3, 0.8, 1).
    # With the subtraction this holds to round-off on any mesh: (u(y) - u(x)) . T(y - x) = 0
    # for u(y) - u(x) = Omega x (y - x), and the constant part is the exact identity. A wrong
    # sign or a missing term shows here at O(1).
    m = probe("rigid", 3)
    assert m["rigid_sphere_max_error"] < 1e-13
    assert m["rigid_ellipsoid_max_error"] < 1e-13


@pytest.mark.parametrize("lam", [1e-3, 0.2, 5.0, 1e3])
def test_uniform_load_translates_a_sphere_at_stokes_speed_whatever_lambda(lam):
    # A uniform load f on a sphere is the traction of a rigid sphere in Stokes flow: the
    # interface translates at U = 2 a f / (3 mu) and the inner fluid moves rigidly, whatever
    # lambda. The interface equation must return that (its error is the single layer's, 2.6e-3
    # at level 3), and GMRES with the deflation converges from the right-hand side in a few
    # applications even at lambda = 1e-3 and 1e3 (measured 6-8).
    m = probe("translate", 3, lam)
    assert m["translate_max_rel_error"] < 5e-3
    assert m["residual"] < 1e-8
    assert m["applications"] <= 12


def test_deflation_keeps_the_flux_of_the_discretisation():
    # The discrete single layer carries a small net flux through the membrane (0.13 % of
    # |u| x area here: NH, Ca 0.2, ellipsoid, level 3, volume correction off). Undeflated, the
    # interface equation amplifies it by up to (1+lambda)/(2 lambda): measured 8.5 % at
    # lambda = 1e-3, and 12 GMRES applications; deflated 0.16 % and 9.
    on = probe("capsule", 3, 1e-3, 1)
    off = probe("capsule", 3, 1e-3, 0)
    assert abs(on["relative_flux"]) < 2 * abs(on["rhs_relative_flux"])
    assert abs(off["relative_flux"]) > 20 * abs(on["relative_flux"])
    assert on["applications"] < off["applications"]


# --- capsules in shear ----------------------------------------------------------------------

SMALL_CA = "0.02"
LAMBDAS = ["0.2", "1", "5"]


def steady_d12_slope(shear_case, lam: str) -> float:
    case = read_case(shear_case("--ca", SMALL_CA, "--level", "2", "--lambda", lam))
    assert case.status == "steady", case.message
    assert abs(case.history["volume"][-1] / case.history["volume"][0] - 1) < 0.005
    return case.steady_value("D12") / float(SMALL_CA)


def test_small_deformation_slope_does_not_depend_on_lambda(shear_case):
    # Barthes-Biesel & Rallison (1981): D12/Ca_s -> (5/4)(2+nu_s)/(1+nu_s) = 25/12 for NH at
    # leading order in Ca_s, whatever lambda; lambda enters at the next order. Level 2,
    # Ca_s = 0.02, measured 2.044 (lambda 0.2), 2.039 (1), 1.998 (5). Tolerances: lambda = 1
    # within 3 % of 25/12 (the level-2 discretisation error is -2.1 %; level 3 gives 2.08);
    # the other lambdas within 3 % of the lambda = 1 value on the same mesh, which bounds the
    # higher-order correction in Ca_s (-2.0 % at lambda = 5, Ca_s = 0.02; -0.55 % at 0.01, see
    # the validate test) and cancels the discretisation error common to all lambda.
    slopes = {lam: steady_d12_slope(shear_case, lam) for lam in LAMBDAS}
    assert slopes["1"] == pytest.approx(25 / 12, rel=0.03)
    for lam in ("0.2", "5"):
        assert slopes[lam] == pytest.approx(slopes["1"], rel=0.03), slopes


def time_to_90_percent(path: Path) -> float:
    case = read_case(path)
    d12, t = np.asarray(case.history["D12"]), np.asarray(case.history["t"])
    target = 0.9 * case.steady_value("D12")
    k = int(np.argmax(d12 >= target))
    # Linear interpolation between the two records around the crossing.
    return float(t[k - 1] + (target - d12[k - 1]) * (t[k] - t[k - 1]) / (d12[k] - d12[k - 1]))


def test_transient_slows_down_as_the_inner_fluid_thickens(shear_case):
    # The steady shape hardly depends on lambda (above), the way to it does: the membrane
    # relaxes against the inner viscosity too. Time to 90 % of the steady D12 (Ca_s = 0.02,
    # level 2), measured 0.15, 0.20, 0.50 / gamma_dot for lambda = 0.2, 1, 5.
    t90 = {lam: time_to_90_percent(shear_case("--ca", SMALL_CA, "--level", "2", "--lambda", lam)) for lam in LAMBDAS}
    assert t90["0.2"] < t90["1"] < t90["5"], t90
    assert t90["5"] > 2 * t90["1"], t90


def test_case_file_records_lambda(shear_case):
    with h5py.File(shear_case("--ca", SMALL_CA, "--level", "2", "--lambda", "0.2")) as f:
        assert f.attrs["lambda"] == 0.2


def test_kill_and_resume_with_lambda(capsim, tmp_path):
    # A run with lambda /= 1 killed and resumed ends where an uninterrupted one does. Not bit for bit: GMRES restarts from a different initial guess
    # after the resume, so velocities differ within the solver tolerance (1e-8 of |b|).
    args = ["--flow", "shear", "--law", "NH", "--ca", "0.05", "--level", "2", "--lambda", "5", "--threads", "1",
            "--quiet"]
    reference = tmp_path / "ref.h5"
    subprocess.run([str(capsim), *args, "--out", str(reference)], check=True, timeout=300)
    resumed = tmp_path / "resumed.h5"
    run_killed_and_resumed(capsim, args, resumed)
    a, b = read_case(reference), read_case(resumed)
    assert a.status == b.status == "steady"
    assert b.steady_value("D12") == pytest.approx(a.steady_value("D12"), rel=1e-6)


# --- the flag -------------------------------------------------------------------------------

BAD_LAMBDAS = [["--lambda", "0"], ["--lambda", "-1"], ["--lambda", "abc"], ["--lambda", "nan"], ["--lambda", ""],
               ["--lambda", "1e9"]]


@pytest.mark.parametrize("override", BAD_LAMBDAS, ids=[v for _, v in BAD_LAMBDAS])
def test_bad_lambda_exits_2_naming_the_flag(capsim, tmp_path, override):
    out = tmp_path / "x.h5"
    base = {"--flow": "shear", "--law": "NH", "--ca": "0.1", "--out": str(out)}
    assert_usage_error(capsim, base, override, "--lambda", out)


def test_lambda_one_is_accepted_in_the_tube(capsim, tmp_path):
    out = tmp_path / "tube.h5"
    subprocess.run([str(capsim), "--flow", "tube", "--law", "NH", "--ca", "0.1", "--a-over-l", "0.5",
                    "--n-meridian", "16", "--t-max", "0.05", "--lambda", "1", "--quiet", "--out", str(out)],
                   check=True, timeout=120)
    with h5py.File(out) as f:
        assert f.attrs["lambda"] == 1.0


def test_help_names_the_flag(capsim):
    result = subprocess.run([str(capsim), "--help"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0 and "--lambda" in result.stdout


# --- long runs (make validate) --------------------------------------------------------------

@pytest.mark.validate
@pytest.mark.parametrize("lam", ["0.2", "5"])
def test_lambda_dependence_of_the_slope_vanishes_with_ca(shear_case, lam):
    # The lambda-dependent part of D12/Ca_s is a higher-order correction in Ca_s: its deviation
    # from the lambda = 1 slope falls when Ca_s halves (level 2, measured +0.22 % -> +0.05 % at
    # lambda = 0.2, -2.0 % -> -0.55 % at lambda = 5, Ca_s 0.02 -> 0.01).
    def slope(ca, la):
        case = read_case(shear_case("--ca", ca, "--level", "2", "--lambda", la))
        assert case.status == "steady", case.message
        return case.steady_value("D12") / float(ca)

    dev = {ca: slope(ca, lam) / slope(ca, "1") - 1 for ca in ("0.01", "0.02")}
    assert abs(dev["0.01"]) < 0.7 * abs(dev["0.02"]) + 2e-3, dev


@pytest.mark.validate
@pytest.mark.parametrize("lam", [
    pytest.param("0.2", marks=pytest.mark.xfail(reason=(
        "open problem (README, 'Viscosity ratio'): at lambda = 0.2 on level 3, Ca_s = 0.01-0.02, D12 "
        "leaves its plateau (2.08 Ca_s) after t ~ 1 and oscillates between 2.07 and 2.27 Ca_s; no steady "
        "state by t = 4.7"), strict=False)),
    "5",
])
def test_small_deformation_slope_level_3(shear_case, lam):
    # Level 3 (642 nodes), Ca_s = 0.01: lambda = 1 gives 2.075, lambda = 5 2.057 (-1.2 % from 25/12).
    case = read_case(shear_case("--ca", "0.01", "--level", "3", "--lambda", lam))
    assert case.status == "steady", case.message
    assert case.steady_value("D12") / 0.01 == pytest.approx(25 / 12, rel=0.03)
