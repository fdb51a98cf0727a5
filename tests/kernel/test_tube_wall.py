"""Tube wall: the closed P1 mesh of the tube boundary and its single-layer operator.

``bin/wall_probe`` (kernel/tests/wall_probe.f90) measures; this file asserts. The physics
checks follow DESIGN.md ("Tube wall alone"): the wall integral equation for the total
Poiseuille flow in the closed tube returns the wall shear stress 4 mu V / l and the pressure
gradient -8 mu V / l^2, and the velocity it gives inside is 2 V (1 - r^2 / l^2), with errors
falling with the element size. A point force inside the tube (the paper's disturbance
formulation, the one the capsule solver uses) is checked against exact integral identities.

Units: tube radius l = 1, mean velocity V = 1, viscosity mu = 1.
"""
from __future__ import annotations

import math

import pytest

from conftest import run_keyed_probe

# Quadrature of the wall matrix: Duffy order on touching triangles.
DUFFY = 4
# velocity_at: the 7-point rule everywhere (isolates the discretisation error), or the
# per-step default (vertex rule beyond 0.5 tube radii).
ALL_GAUSS = 100.0
DEFAULT_MID_RADIUS = 0.5


def run_wall_probe(*args: object, check: bool = True) -> dict[str, float | str]:
    """Run ``bin/wall_probe ARGS`` and parse its "key value" lines (numbers as float)."""
    return run_keyed_probe("wall_probe", *args, check=check, timeout=120)


# ---------------------------------------------------------------------------------------
# Mesh
# ---------------------------------------------------------------------------------------

@pytest.mark.parametrize(
    "length, h_far, h_centre",
    [(4.0, 0.28, 0.28), (4.0, 0.14, 0.14), (8.0, 0.28, 0.14), (8.0, 0.14, 0.07)],
)
def test_mesh_is_closed_oriented_and_sized(length, h_far, h_centre):
    r = run_wall_probe("mesh", length, h_far, h_centre)
    n, n_tri = r["n_nodes"], r["n_tri"]
    # Closed, consistently oriented 2-manifold of genus 0: every directed edge (a, b) appears
    # once and its reverse once; V - E + F = 2; the CSR adjacency lists every corner.
    assert r["unmatched_edges"] == 0 and r["duplicated_edges"] == 0
    assert r["euler_characteristic"] == 2 and n_tri == 2 * n - 4
    assert r["adjacency_entries"] == 3 * n_tri
    # Normals out of the fluid: positive signed volume, a little below pi L (inscribed).
    assert 0 < r["volume_exact"] - r["volume"] < 0.02 * r["volume_exact"]
    assert 0 < r["area_exact"] - r["area"] < 0.01 * r["area_exact"]
    # Nodes exactly on the cylinder and in the disk planes; rims shared by both.
    assert r["radius_error"] < 1e-12 and r["disk_plane_error"] < 1e-12
    assert r["n_cylinder"] + r["n_inlet"] + r["n_outlet"] + r["n_rim"] == n
    assert r["n_inlet"] == r["n_outlet"] and r["n_rim_inlet"] == r["n_rim"] / 2
    assert r["n_rim"] / 2 == round(2 * math.pi / h_far)
    # Element size h_centre over |z| < 1, h_far beyond the grading, smooth in between.
    assert r["h_centre_mean"] == pytest.approx(h_centre, rel=0.05)
    if h_far != h_centre:
        assert r["h_far_mean"] == pytest.approx(h_far, rel=0.05)
    assert r["min_angle_deg"] > 30
    assert r["max_neighbour_size_ratio"] < 1.3


def test_invalid_mesh_parameters_are_reported():
    r = run_wall_probe("mesh", 4.0, 2.0, 0.1, check=False)
    assert r["returncode"] != 0
    assert "element sizes" in r["stderr"]


# ---------------------------------------------------------------------------------------
# Matrix and off-wall evaluation
# ---------------------------------------------------------------------------------------

def test_matrix_null_vectors_and_continuity():
    r = run_wall_probe("matrix", 4.0, 0.2, 0.2, DUFFY)
    # A uniform pressure on the closed wall moves nothing; a single-layer velocity has no net
    # flux through it. Both hold for the continuous operator; the discrete ones to ~4e-4.
    assert r["normal_traction_velocity_rel"] < 1e-3
    assert r["flux_of_single_layer_rel"] < 1e-3
    # Each matrix row (Duffy on the node's triangles) is the limit of velocity_at (adaptive)
    # at points approaching the node: the single layer is continuous across the wall.
    approach = [r["row_vs_limit_0.04h"], r["row_vs_limit_0.02h"], r["row_vs_limit_0.01h"]]
    assert approach[0] > approach[1] > approach[2]
    assert r["row_vs_limit_extrapolated"] < 2e-3


def test_velocity_at_quadrature():
    # Against a brute-force rule (7-point rule on 4^6 sub-triangles), at 1 to 0.05 element
    # sizes from the wall: adaptive quadrature alone, then with the per-step vertex far field.
    exact = run_wall_probe("quadrature", 4.0, 0.28, 0.28, ALL_GAUSS)
    assert exact["quadrature_error_max"] < 1e-7
    default = run_wall_probe("quadrature", 4.0, 0.28, 0.28, DEFAULT_MID_RADIUS)
    assert default["quadrature_error_max"] < 3e-3


# ---------------------------------------------------------------------------------------
# Tube wall alone: total Poiseuille flow in the closed tube
# ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def poiseuille_runs():
    """L = 4, uniform h = 0.28, 0.2, 0.14 (444, 904, 1848 nodes; matrix order up to 5544)."""
    return {h: run_wall_probe("poiseuille", 4.0, h, h, DUFFY, 1, ALL_GAUSS) for h in (0.28, 0.2, 0.14)}


def test_poiseuille_wall_traction(poiseuille_runs):
    finest = poiseuille_runs[0.14]
    # Cylinder away from the ends (|z| <= L/2 - 1): f = -p e_r - 4 e_z, p = -8 z (zero mean
    # wall pressure from the gauge), no azimuthal component.
    assert finest["shear_error_max"] < 0.01 * 4          # below 0.25 % of 4 mu V / l
    assert finest["pressure_gradient"] == pytest.approx(-8.0, rel=5e-3)
    assert finest["pressure_error_max"] < 0.02
    assert abs(finest["pressure_offset"]) < 1e-3
    assert finest["azimuthal_traction_max"] < 1e-4
    assert abs(finest["mean_normal_traction"]) < 1e-8
    # Disk centres: f = +-p e_z with p = -+ 4 L.
    assert finest["inlet_centre_traction_error"] < 0.02 * 16
    assert finest["outlet_centre_traction_error"] < 0.02 * 16


def test_poiseuille_errors_fall_with_element_size(poiseuille_runs):
    hs = sorted(poiseuille_runs, reverse=True)
    shear = [poiseuille_runs[h]["shear_error_max"] for h in hs]
    gradient = [abs(poiseuille_runs[h]["pressure_gradient"] + 8.0) for h in hs]
    velocity = [poiseuille_runs[h]["velocity_error_max"] for h in hs]
    assert shear[0] > shear[1] > shear[2]
    # Measured order 3 for the wall shear (0.032, 0.011, 0.0036).
    assert math.log(shear[0] / shear[2]) / math.log(hs[0] / hs[2]) > 2.0
    assert gradient[0] > gradient[1] > gradient[2]
    assert velocity[0] > velocity[2]


def test_poiseuille_interior_velocity(poiseuille_runs):
    # u = 2 (1 - r^2) e_z at r = 0, 0.5, 0.8 (z = 0 and z = 0.37).
    finest = poiseuille_runs[0.14]
    for key in ("r0.0", "r0.5", "r0.8"):
        for plane in ("0", "1"):
            assert finest[f"velocity_error_{key}_{plane}"] < 3e-3
    assert finest["u_axis"] == pytest.approx(2.0, abs=3e-3)


def test_factorisation_is_cached(tmp_path):
    args = ("poiseuille", 4.0, 0.28, 0.28, DUFFY, 1, ALL_GAUSS, tmp_path)
    first = run_wall_probe(*args)
    assert first["from_cache"] == 0 and str(first["cache_message"]).startswith("written")
    files = list(tmp_path.glob("tube_wall_*.lu"))
    assert len(files) == 1 and not list(tmp_path.glob("*.tmp*"))
    second = run_wall_probe(*args)
    assert second["from_cache"] == 1
    for key in ("shear_error_max", "pressure_gradient", "velocity_error_max", "rcond"):
        assert second[key] == first[key]
    # A truncated file is not trusted: recomputed and rewritten.
    files[0].write_bytes(files[0].read_bytes()[:100000])
    third = run_wall_probe(*args)
    assert third["from_cache"] == 0 and third["shear_error_max"] == first["shear_error_max"]
    # Another mesh, another file.
    run_wall_probe("poiseuille", 4.0, 0.28, 0.2, DUFFY, 1, ALL_GAUSS, tmp_path)
    assert len(list(tmp_path.glob("tube_wall_*.lu"))) == 2


# ---------------------------------------------------------------------------------------
# Disturbance of a point force (the capsule solver's formulation)
# ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("h, work_tol", [(0.2, 1e-3), (0.14, 5e-4)])
def test_point_force_integral_identities(h, work_tol):
    r = run_wall_probe("pointforce", 4.0, h, h, DEFAULT_MID_RADIUS)
    # F + int_B f+ dS = 0 and no torque about the point force.
    assert r["force_balance_error"] < 1e-3
    assert r["torque_error"] < 1e-3
    # Reciprocal theorem with Poiseuille flow: int_disks v_inf . f+ dS = -F . v_inf(x0).
    assert r["disk_work_rel_error"] < work_tol
    # Long-tube limit: the disks carry the pressure rise, the cylinder the rest of F_z = 1.
    assert r["cylinder_axial_force"] == pytest.approx(-1.0 - r["disk_work_exact"], abs=0.03)
    # velocity_at's per-step far field (vertex rule beyond 0.5) against the 7-point rule.
    assert r["velocity_at_vs_all_7_point"] < 1e-2
