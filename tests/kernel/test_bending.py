"""Bending stiffness (--kb k_b, issue 6): the discrete Helfrich energy
E = (K_B/2) int (kappa_1 + kappa_2 - c0)**2 dA, c0 the reference sphere's curvature, in 3D
(membrane_bending) and on the meridian (axisymmetric_bending), with forces as its gradient.

- Forces are -grad E (central differences), carry no net force or torque.
- A sphere inflated from radius a to R feels the continuum load -dE/dR = 16 pi K_B (1 - R/a)/a,
  converging at second order in 3D (levels 2-4) and in the axisymmetric model.
- The 3D and axisymmetric energies of one spheroid converge to the continuum integral.
- k_b = 0 is the base model bit for bit; bad values exit with code 2 naming --kb.
"""
from __future__ import annotations

import copy
import math
import subprocess

import numpy as np
import pytest

from capsmech.io.case import read_case
from capsmech.workflow.grid import GridError, Law, expand_cases, load_grid, parse_law, validate_grid

from conftest import NEUTRAL_FLOW_ARGS, REPO, _executable, assert_neutral_effect_is_base, run_quiet


def bending_probe(*args: object) -> dict[str, float]:
    result = subprocess.run([str(_executable("bending_probe")), *map(str, args)],
                            capture_output=True, text=True, check=True)
    return {k: float(v) for k, v in (line.split() for line in result.stdout.splitlines())}


def continuum_energy(b: float, c: float) -> float:
    """(1/2) int (kappa_s + kappa_phi - 2)**2 dA on the spheroid r = b sin t, z = c cos t."""
    t = np.linspace(0.0, math.pi, 20001)
    speed = np.sqrt(b**2 * np.cos(t)**2 + c**2 * np.sin(t)**2)
    kappa_s = b * c / speed**3
    kappa_phi = c / (b * speed)
    integrand = 0.5 * (kappa_s + kappa_phi - 2.0)**2 * 2 * math.pi * b * np.sin(t) * speed
    return float(np.sum(0.5 * (integrand[1:] + integrand[:-1]) * np.diff(t)))


@pytest.mark.parametrize("level,amp", [(1, 0.05), (2, 0.03)])
def test_3d_forces_are_the_energy_gradient(level, amp):
    r = bending_probe("fd", level, amp)
    assert r["fd_max_error_rel"] < 1e-6          # central differences, eps = 1e-6
    assert r["net_force_rel"] < 1e-12            # translation invariance
    assert r["net_torque_rel"] < 1e-12           # rotation invariance
    assert r["energy"] == pytest.approx(r["energy_recomputed"], rel=1e-13)


@pytest.mark.parametrize("n,amp", [(16, 0.03), (64, 0.01)])
def test_axisymmetric_forces_are_the_energy_gradient(n, amp):
    r = bending_probe("axi-fd", n, amp)
    assert r["fd_max_error_rel"] < 1e-6
    assert r["net_axial_force_rel"] < 1e-12


@pytest.mark.parametrize("kind,size", [("sphere", 3), ("axi-sphere", 32)])
def test_reference_sphere_is_force_free(kind, size):
    r = bending_probe(kind, size, 1.0)
    assert r["max_force"] < 1e-12 and r["energy"] < 1e-14


def test_inflated_sphere_load_converges_at_second_order_3d():
    radius = 1.2
    exact = 16 * math.pi * (1 - radius)       # -dE/dR, K_B = a = 1
    runs = [bending_probe("sphere", level, radius) for level in (2, 3, 4)]
    errors = [abs(r["radial_force_sum"] / exact - 1) for r in runs]
    # Measured: 6.4e-3, 1.6e-3, 4.0e-4 (order 2.0).
    for e0, e1 in zip(errors, errors[1:]):
        assert math.log2(e0 / e1) > 1.8
    assert errors[-1] < 1e-3
    # Node by node (on the Voronoi areas) the load is the Laplace-like pressure 4 K_B (1-R)/R**2
    # within 4.3, 2.0, 1.4 % (the icosahedral mesh's irregularity).
    pointwise = [r["pressure_max_rel_error"] for r in runs]
    assert pointwise[0] > pointwise[1] > pointwise[2] and pointwise[2] < 0.02


def test_inflated_sphere_load_converges_at_second_order_axisymmetric():
    radius = 1.2
    exact = 16 * math.pi * (1 - radius)
    errors = [abs(bending_probe("axi-sphere", n, radius)["radial_force_sum"] / exact - 1) for n in (32, 64, 128)]
    for e0, e1 in zip(errors, errors[1:]):
        assert math.log2(e0 / e1) > 1.8


def test_3d_and_axisymmetric_energies_agree_on_a_spheroid():
    b, c = 0.8, 1.4
    exact = continuum_energy(b, c)
    e3d = [abs(bending_probe("spheroid", level, b, c)["energy"] / exact - 1) for level in (2, 3, 4)]
    eaxi = [abs(bending_probe("axi-spheroid", n, b, c)["energy"] / exact - 1) for n in (32, 64, 128)]
    # Measured: 3D 8.5e-4, 3.9e-4, 1.2e-4; axisymmetric 1.3e-2, 3.2e-3, 8.1e-4.
    assert e3d[0] > e3d[1] > e3d[2] and e3d[2] < 3e-4
    assert eaxi[0] > eaxi[1] > eaxi[2] and eaxi[2] < 2e-3
    e3, ea = (bending_probe("spheroid", 4, b, c)["energy"], bending_probe("axi-spheroid", 128, b, c)["energy"])
    assert abs(e3 / ea - 1) < 2e-3


def test_incremental_tube_jacobian_follows_the_wider_bending_stencil(probe):
    # With bending a node's force depends on the nodes two away, so the incremental Jacobian
    # re-integrates six elements per column: it must equal differences of full velocity
    # evaluations (measured 3e-7, the bending-stiffened noise; with the elastic stencil of four
    # elements the difference is 4e-2).
    r = probe("tube-jacobian", 0.3, 0.01, 0.05)
    assert r["max_rel_difference"] < 1e-5


# The tube only: in shear a run without --kb takes the shear database's k_b (3e-4), so --kb 0
# is the base model there by definition (no bending force is set up for k_b = 0).
@pytest.mark.parametrize("flow_args", NEUTRAL_FLOW_ARGS[1:], ids=["tube"])
def test_zero_kb_is_the_base_model_bit_for_bit(capsim, tmp_path, flow_args):
    assert_neutral_effect_is_base(capsim, tmp_path, flow_args, "--kb", "k_b")


def test_bending_stiffness_flattens_the_parachute(capsim, tmp_path):
    # NH, a/l = 0.9, Ca_s = 0.05, axisymmetric tube. Measured (n_meridian 64):
    #   k_b 0:    L_z 1.8962, L_p 0.1761, v_c/V 1.2194
    #   k_b 0.01: L_z 1.9249, L_p 0.0339, v_c/V 1.2301
    #   k_b 0.05: L_z 1.9909, L_p 0,      v_c/V 1.2102
    cases = [read_case(run_quiet(capsim, tmp_path / f"kb{kb}.h5", "--flow", "tube", "--law", "NH", "--a-over-l", 0.9,
                            "--ca", 0.05, "--kb", kb)) for kb in (0, 0.01, 0.05)]
    assert all(c.status == "steady" for c in cases), [c.message for c in cases]
    assert [c.effects["kb"] for c in cases] == [0, 0.01, 0.05]   # the case attribute k_b, read back
    depth = [c.steady_value("L_p") for c in cases]
    assert depth[0] > 0.1 and depth[0] > depth[1] > depth[2] and depth[2] < 0.01
    # The bending-stiffened capsule resists the rear's inversion and is pulled longer.
    length = [c.steady_value("L_z") for c in cases]
    assert length[0] < length[1] < length[2]


def test_bending_stiffness_reduces_shear_deformation(capsim, tmp_path):
    # NH, Ca_s 0.1, level 2: D12 0.1960 (k_b 0) -> 0.1799 (k_b 0.01); level 3: 0.1986 -> 0.1831,
    # and 0.1142 at k_b 0.1. A stiffer membrane deforms less at the same Ca_s.
    cases = [read_case(run_quiet(capsim, tmp_path / f"kb{kb}.h5", "--flow", "shear", "--law", "NH", "--ca", 0.1,
                            "--level", 2, "--kb", kb)) for kb in (0, 0.01)]
    assert all(c.status == "steady" for c in cases), [c.message for c in cases]
    d12 = [c.steady_value("D12") for c in cases]
    assert 0.85 * d12[0] < d12[1] < 0.97 * d12[0]


def test_automatic_step_follows_the_bending_stiffness(capsim, tmp_path):
    # k_b = 1 at level 2: the elastic step (0.5 Ca h_min = 0.0138) breaks the mesh within
    # t = 0.11; the bending bound 0.5 Ca h_min**3 / k_b (measured limit: 1.2 Ca h_min**3 / k_b)
    # keeps it smooth (t_max 0.5, ~500 steps).
    case = read_case(run_quiet(capsim, tmp_path / "stiff.h5", "--flow", "shear", "--law", "NH", "--ca", 0.1,
                          "--level", 2, "--kb", 1, "--t-max", 0.5))
    assert case.status == "max_time", case.message
    assert np.all(np.isfinite(case.history["D12"])) and case.history["max_stretch"].max() < 1.1


@pytest.mark.parametrize("value", ["-0.01", "1.5", "abc", "nan"])
def test_bad_kb_is_refused(capsim, tmp_path, value):
    result = subprocess.run([str(capsim), "--flow", "shear", "--law", "NH", "--ca", "0.05",
                             "--kb", value, "--out", str(tmp_path / "x.h5")], capture_output=True, text=True)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("capsim: error: --kb"), result.stderr
    assert not (tmp_path / "x.h5").exists()


def test_grid_law_key_adds_kb_as_a_database_dimension():
    law = parse_law("GH_nu0.5+kb0.01")
    assert law == Law("GH_nu0.5+kb0.01", "GH", nu_s=0.5, effects=(("kb", 0.01),))
    assert law.kernel_args() == ["--law", "GH", "--nu-s", "0.5", "--kb", "0.01"]
    grid = copy.deepcopy(load_grid(REPO / "config" / "smoke.yaml"))
    grid["tube"]["laws"] = ["NH", "NH+kb0.01"]
    grid["shear"]["laws"] = ["NH+kb0.01"]
    validate_grid(grid, "kb.yaml")
    assert all("--kb" in case.kernel_args() for case in expand_cases(grid, "shear"))
    grid["tube"]["laws"] = ["NH+kb2"]
    with pytest.raises(GridError, match=r"tube.laws\[0\]: law key 'NH\+kb2': kb must lie in \[0, 1\]"):
        validate_grid(grid, "kb.yaml")
