"""Rectangular duct: the fully developed (Poiseuille) flow and the closed P1 wall mesh.

``bin/duct_probe`` (kernel/tests/duct_probe.f90) measures; this file asserts. The flow is
checked against published values (Shah & London 1978), against an independent solution (the
double cosine series of the Poisson problem, summed here with numpy), and against exact
identities (mean velocity, force balance on the walls, no slip). The mesh is checked for
topology, exact geometry, element quality, the tube's grading, and the Poiseuille data
integrated over it.

Units: duct half-width w = 1, half-height h = aspect, mean velocity U = 1, viscosity mu = 1.
"""
from __future__ import annotations

import math
import subprocess

import numpy as np
import pytest

from conftest import assert_usage_error, run_keyed_probe

# Ring spacing over edge length (equilateral triangles), and the tube's grading: element size
# h_centre over |z| <= 1, h_far beyond |z| = 2, a C1 smoothstep between (kernel/src/tube_wall_mesh.f90).
RING_STEP = math.sqrt(3.0) / 2.0
CENTRE_HALF_LENGTH = 1.0
GRADING_LENGTH = 1.0
# Edge grading of the lateral rings (duct_wall_mesh, grade_edges): segment sizes grow linearly
# from EDGE_MIN_SIZE of the uniform size at a corner over EDGE_ZONE of a side's parameter, and a
# side has 1 / (1 - EDGE_ZONE (1 - EDGE_MIN_SIZE)) times the segments of a uniform one.
EDGE_MIN_SIZE = 0.15
EDGE_ZONE = 0.3
EDGE_SEGMENT_FACTOR = 1.0 / (1.0 - EDGE_ZONE * (1.0 - EDGE_MIN_SIZE))


def run_duct_probe(*args: object, check: bool = True, timeout: float = 60) -> dict[str, float | str]:
    """Run ``bin/duct_probe ARGS`` and parse its "key value" lines (numbers as float)."""
    return run_keyed_probe("duct_probe", *args, check=check, timeout=timeout)


def double_series_velocity(x: float, y: float, w: float, h: float, n_odd: int = 2001) -> float:
    """u / U from the eigenfunction expansion of mu Laplacian(u) = -G on the rectangle:
    u = G sum_{m,n odd} 16 (-1)^((m+n)/2-1) cos(m pi x / 2w) cos(n pi y / 2h) / (pi^2 m n lambda_mn),
    lambda_mn = (m pi / 2w)^2 + (n pi / 2h)^2, and its mean sum 64 / (pi^4 m^2 n^2 lambda_mn).
    Independent of the kernel's single (hyperbolic) series; converges like 1/n_odd^3 here."""
    m = np.arange(1, 2 * n_odd, 2, dtype=float)
    lam = (m[:, None] * math.pi / (2 * w)) ** 2 + (m[None, :] * math.pi / (2 * h)) ** 2
    sign = (-1.0) ** ((m - 1) / 2)
    mean = np.sum(64.0 / (math.pi**4 * m[:, None] ** 2 * m[None, :] ** 2 * lam))
    cx = sign * np.cos(m * math.pi * x / (2 * w)) / m
    cy = sign * np.cos(m * math.pi * y / (2 * h)) / m
    return float(np.sum(16.0 / math.pi**2 * cx[:, None] * cy[None, :] / lam) / mean)


@pytest.fixture(scope="module", params=[1.0, 0.5], ids=["square", "aspect0.5"])
def flow(request):
    return request.param, run_duct_probe("flow", request.param)


# ---------------------------------------------------------------------------------------
# Flow
# ---------------------------------------------------------------------------------------

# Shah & London (1978), Laminar Flow Forced Convection in Ducts, rectangular ducts,
# fully developed flow: u_max / u_m and f Re (Fanning f, Re on the hydraulic diameter
# D_h = 4 A / P) for aspect ratios 1 and 0.5, given to 4 and 5 decimals.
PUBLISHED = {1.0: (2.0963, 14.22708), 0.5: (1.9918, 15.54806)}


def test_centre_velocity_and_friction_match_published_values(flow):
    aspect, r = flow
    u_max, f_re = PUBLISHED[aspect]
    w, h = r["half_width"], r["half_height"]
    assert r["centre_velocity"] == pytest.approx(u_max, abs=5e-5)
    # Mean wall shear G A / P, so f Re = 2 tau D_h / (mu U) = 8 G (w h)^2 / (w + h)^2.
    assert 8 * r["pressure_gradient"] * (w * h) ** 2 / (w + h) ** 2 == pytest.approx(f_re, abs=6e-6)


def test_series_mean_is_the_mean_velocity(flow):
    _, r = flow
    # Gauss-Legendre over the cross-section of the velocity series, against U = 1; the
    # truncation of every series is far below the check.
    assert abs(r["mean_gauss_96"] - 1.0) < 1e-10
    assert abs(r["mean_gauss_96"] - r["mean_gauss_48"]) < 1e-12
    assert r["mean_gauss_bound_96"] < 1e-13 and r["mean_series_bound"] < 1e-15
    assert r["centre_velocity_bound"] < 1e-13


def test_velocity_matches_an_independent_double_series(flow):
    aspect, r = flow
    for k in range(1, 7):
        x, y = r[f"pt{k}_x"], r[f"pt{k}_y"]
        assert r[f"pt{k}_u"] == pytest.approx(double_series_velocity(x, y, 1.0, aspect), abs=1e-8)
        # The gradient series is the termwise derivative of the velocity series.
        assert r[f"pt{k}_dudx"] == pytest.approx(r[f"pt{k}_dudx_fd"], abs=1e-8)
        assert r[f"pt{k}_dudy"] == pytest.approx(r[f"pt{k}_dudy_fd"], abs=1e-8)


def test_velocity_vanishes_on_the_walls(flow):
    _, r = flow
    assert r["wall_velocity_max"] == 0.0 and r["corner_gradient"] == 0.0
    # Approaching the wall the series goes to zero with the wall shear as its slope:
    # u(wall - delta n) = -delta du/dn + O(delta^2), so the slope error falls like delta.
    assert r["slope_error_1e-7"] < 1e-6 * r["wall_shear_max"]
    assert 300 < r["slope_error_1e-4"] / r["slope_error_1e-7"] < 3000


def test_wall_shear_balances_the_pressure_gradient(flow):
    _, r = flow
    # Integral of du/dn around the perimeter = -G A (a unit length of duct in equilibrium).
    error_64 = abs(r["wall_shear_integral_64"] + r["pressure_force"])
    error_128 = abs(r["wall_shear_integral_128"] + r["pressure_force"])
    assert error_128 < 2e-8 * r["pressure_force"]
    assert error_128 < error_64


def test_traction_on_side_wall_and_entry_section(flow):
    _, r = flow
    # Side wall x = w (n = e_x): f = -p n + (du/dn) e_z, du/dn < 0 (the wall holds the fluid back).
    assert r["side_traction_x"] == pytest.approx(-r["side_pressure"], rel=1e-14)
    assert r["side_traction_y"] == 0.0
    assert r["side_traction_z"] < 0
    assert r["side_traction_z"] == pytest.approx(r["side_slope"], rel=1e-6)
    # Entry section (n = -e_z): f = p e_z - (du/dx, du/dy, 0).
    assert r["inlet_traction_z"] == pytest.approx(r["inlet_pressure"], rel=1e-14)
    assert r["inlet_traction_x"] == pytest.approx(-r["inlet_dudx_fd"], abs=1e-8)
    assert r["inlet_traction_y"] == pytest.approx(-r["inlet_dudy_fd"], abs=1e-8)


# ---------------------------------------------------------------------------------------
# Wall mesh
# ---------------------------------------------------------------------------------------

def element_size(z: float, h_far: float, h_centre: float) -> float:
    t = min(max((abs(z) - CENTRE_HALF_LENGTH) / GRADING_LENGTH, 0.0), 1.0)
    return h_centre + (h_far - h_centre) * t * t * (3.0 - 2.0 * t)


def nint(value: float) -> int:
    """Fortran NINT (halves away from zero) for positive values."""
    return math.floor(value + 0.5)


def check_closed_exact_graded_mesh(r, length: float, h_far: float, h_centre: float, aspect: float,
                                   segment_factor: float = 1.0) -> None:
    """The duct wall mesh's topology, exact geometry, tags, ring placement and node counts
    (segment_factor times the uniform segments a side), the Poiseuille data on it, and the wall
    operator's slots: what holds with and without the edge grading."""
    n, n_tri = r["n_nodes"], r["n_tri"]
    w, h = 1.0, aspect
    # Closed, consistently oriented 2-manifold of genus 0.
    assert r["unmatched_edges"] == 0 and r["duplicated_edges"] == 0
    assert r["euler_characteristic"] == 2 and n_tri == 2 * n - 4
    assert r["adjacency_entries"] == 3 * n_tri
    # Every triangle's normal points out of the fluid (away from the axis on the side walls,
    # -e_z / +e_z on the entry / exit sections).
    assert r["inward_normals"] == 0
    # Flat faces: area and volume exact to rounding (the volume is signed: positive outward).
    assert r["area"] == pytest.approx(4 * (w + h) * length + 8 * w * h, rel=1e-12)
    assert r["volume"] == pytest.approx(4 * w * h * length, rel=1e-12)
    assert r["face_error"] < 1e-12
    assert r["half_width"] == w and r["half_height"] == h
    # Tags as the tube's: side wall, entry, exit, rims (the end rings).
    assert r["n_side"] + r["n_inlet"] + r["n_outlet"] + r["n_rim"] == n
    assert r["n_inlet"] == r["n_outlet"] > 0
    assert r["n_rim_inlet"] == r["ring_nodes_0"]
    # Grading: the tube's rings exactly, spaced by ring_step h(z), with
    # max(2, nint(segment_factor side / h(z))) segments a side (odd rings: corner + midpoints, one more).
    assert r["ring_z_tube_difference"] < 1e-12
    n_rings = int(r["n_rings"])
    z = [r[f"ring_z_{k}"] for k in range(n_rings)]
    assert z[0] == -length / 2 and z[-1] == length / 2
    for k in range(n_rings - 1):
        z_mid = 0.5 * (z[k] + z[k + 1])
        assert 0.9 < (z[k + 1] - z[k]) / (RING_STEP * element_size(z_mid, h_far, h_centre)) < 1.1
    for k in range(n_rings):
        size = element_size(z[k], h_far, h_centre)
        segments = sum(max(2, nint(segment_factor * side / size)) for side in (2 * w, 2 * h, 2 * w, 2 * h))
        assert r[f"ring_nodes_{k}"] == segments + (4 if k % 2 else 0)
    # Poiseuille data integrated over the mesh (7-point rule): the flux through each section
    # is U A, and the exact traction exerts no net force on the closed surface (measured:
    # flux within 2.1e-6, force within 6e-5; the rule meets the r^2 log r corners of the flow).
    assert r["inlet_flux"] == pytest.approx(-4 * w * h, rel=1e-5)
    assert r["outlet_flux"] == pytest.approx(4 * w * h, rel=1e-5)
    assert abs(r["net_force_x"]) < 1e-12 * r["pressure_drop_force"]
    assert abs(r["net_force_y"]) < 1e-12 * r["pressure_drop_force"]
    assert abs(r["net_force_z"]) < 2e-4 * r["pressure_drop_force"]
    # wall_single_layer's operator takes the mesh as it is, with one mapped slot per face
    # that a node shares beyond its own: each rim node the section's, each node of a long edge
    # (the four corners of every inner ring) the second side face's, and the eight box
    # corners both.
    assert r["operator_nodes"] == n
    assert r["operator_slots"] == r["n_rim"] + 4 * (n_rings - 2) + 8
    assert r["operator_area"] == pytest.approx(r["area"], rel=1e-12)


@pytest.mark.parametrize(
    "length, h_far, h_centre, aspect",
    [(4.0, 0.28, 0.28, 1.0), (8.0, 0.28, 0.14, 1.0), (4.0, 0.2, 0.2, 0.5), (8.0, 0.28, 0.14, 0.5),
     (4.0, 0.28, 0.28, 2.0)],
)
def test_mesh_is_closed_exact_graded_and_well_shaped(length, h_far, h_centre, aspect):
    r = run_duct_probe("mesh", length, h_far, h_centre, aspect)
    check_closed_exact_graded_mesh(r, length, h_far, h_centre, aspect)
    # Element quality (1 = equilateral for the aspect ratio).
    assert r["side_min_angle_deg"] > 25 and r["side_max_aspect_ratio"] < 1.8
    assert r["section_min_angle_deg"] > 15 and r["section_max_aspect_ratio"] < 2.6
    assert r["max_neighbour_size_ratio"] < 1.7
    assert r["h_centre_mean"] == pytest.approx(h_centre, rel=0.05)


@pytest.mark.parametrize(
    "length, h_far, h_centre, aspect",
    [(4.0, 0.28, 0.28, 1.0), (8.0, 0.28, 0.14, 0.5), (4.0, 0.28, 0.28, 2.0), (4.0, 0.35, 0.35, 1.0)],
)
def test_edge_graded_mesh_is_closed_exact_and_long_in_z_at_the_edges(length, h_far, h_centre, aspect):
    # The lateral rings graded towards the long edges: the same surface and rings, more nodes a
    # side, and triangles long in z next to the edges (measured, L 4-8, h 0.14-0.35, aspect
    # 0.5-2: side angles >= 7.2 degrees, aspect ratios <= 4.9; section triangles, which meet
    # the graded rims, >= 4.8 degrees and <= 7.5; neighbours within 1.78).
    r = run_duct_probe("mesh", length, h_far, h_centre, aspect, 1)
    check_closed_exact_graded_mesh(r, length, h_far, h_centre, aspect, EDGE_SEGMENT_FACTOR)
    uniform = run_duct_probe("mesh", length, h_far, h_centre, aspect, 0)
    assert r["n_nodes"] > uniform["n_nodes"] and r["n_tri"] > uniform["n_tri"]
    assert r["side_min_angle_deg"] > 6.5 and r["side_max_aspect_ratio"] < 5.5
    assert r["section_min_angle_deg"] > 4.3 and r["section_max_aspect_ratio"] < 8.5
    assert r["max_neighbour_size_ratio"] < 1.9
    # The graded zones hold smaller segments: the mean centre edge is shorter than h_centre.
    assert r["h_centre_mean"] < uniform["h_centre_mean"]


@pytest.mark.parametrize(
    "args, message",
    [((4.0, 2.0, 0.1, 1.0), "element sizes"), ((4.0, 0.5, 0.1, 0.5), "element sizes"),
     ((4.0, 0.1, 0.1, 0.05), "aspect"), ((-1.0, 0.2, 0.2, 1.0), "length")],
)
def test_invalid_mesh_parameters_are_reported(args, message):
    r = run_duct_probe("mesh", *args, check=False)
    assert r["returncode"] != 0
    assert message in str(r["stderr"])


# ---------------------------------------------------------------------------------------
# The 3D capsule model in the square duct (capsim --channel square)
# ---------------------------------------------------------------------------------------

# Square duct, U = 1, w = 1: the published u_max / U and f Re (D_h = 2 w) give the pressure
# gradient G = 2 f Re U mu / D_h^2; the flow has the constant Laplacian -G / mu.
SQUARE_U_MAX = PUBLISHED[1.0][0]
SQUARE_G = 2 * PUBLISHED[1.0][1] / 2.0**2
# A coarse wall and a short duct keep the run to a few seconds (the capsule ends 2.75 w
# before each end section).
SQUARE_RUN = ["--flow", "tube", "--model", "3d", "--channel", "square", "--law", "NH", "--ca", "0.05",
              "--level", "2", "--wall-h-far", "0.5", "--wall-h-centre", "0.28", "--tube-length", "6",
              "--threads", "1", "--quiet"]


@pytest.fixture(scope="module")
def square_run(capsim, tmp_path_factory):
    """A small, nearly rigid capsule (a/w = 0.25, Ca_s 0.05) in the square duct, briefly."""
    import h5py

    root = tmp_path_factory.mktemp("square_duct")
    out = root / "square.h5"
    subprocess.run([str(capsim), *SQUARE_RUN, "--a-over-l", "0.25", "--t-max", "0.15",
                    "--wall-cache", str(root), "--out", str(out)], check=True, timeout=120)
    with h5py.File(out) as f:
        return {"attrs": dict(f.attrs), "v_c": f["history/v_c"][()], "t": f["history/t"][()], "a": 0.25}


def text(value: object) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def test_square_duct_case_records_the_channel(square_run):
    attrs = square_run["attrs"]
    assert text(attrs["channel"]) == "square"
    assert attrs["aspect"] == 1.0
    assert text(attrs["length_scale"]) == "w (duct half-width)"


def test_unstressed_capsule_moves_with_the_duct_flow(square_run):
    # At t = 0 the membrane carries no load, so the capsule's centroid moves with the volume
    # mean of the undisturbed flow: u_max + a^2 Laplacian(u) / 10 exactly for a flow of
    # constant Laplacian (mean-value property). Measured: -5.1e-4 (the level-2 polyhedron).
    a = square_run["a"]
    assert square_run["v_c"][0] == pytest.approx(SQUARE_U_MAX - SQUARE_G * a**2 / 10, rel=1.5e-3)


def test_nearly_rigid_capsule_translates_at_the_faxen_velocity(square_run):
    # Once the membrane has taken its load, the nearly rigid capsule translates at the Faxen
    # velocity of a sphere, u_max + a^2 Laplacian(u) / 6 = 2.0963 - 1.1856 (a/w)^2, the wall's
    # reflection being of higher order in a/w. Measured at t = 0.15: +4.0e-4, with v_c
    # settled to 5e-5 over the last rows.
    a = square_run["a"]
    v_c = square_run["v_c"]
    assert abs(v_c[-1] - v_c[-2]) < 5e-4
    assert v_c[-1] == pytest.approx(SQUARE_U_MAX - SQUARE_G * a**2 / 6, rel=2e-3)


@pytest.mark.parametrize(
    "override, field",
    [(["--model", "axi"], "--channel"), (["--channel", "oval"], "--channel"),
     (["--aspect", "2"], "--aspect"), (["--channel", "rect", "--aspect", "0.05"], "--aspect")],
)
def test_channel_options_are_checked(capsim, tmp_path, override, field):
    out = tmp_path / "refused.h5"
    base = {"--flow": "tube", "--model": "3d", "--channel": "square", "--law": "NH", "--a-over-l": "0.25",
            "--ca": "0.05", "--out": str(out)}
    assert_usage_error(capsim, base, override, field, out)


# ---------------------------------------------------------------------------------------
# The wall alone: the duct's Poiseuille flow from the wall integral equation
# ---------------------------------------------------------------------------------------

# (aspect, element size) -> (velocity error / u_max, pressure gradient error) bounds; measured
# (L = 4, uniform elements, 7-point rule everywhere off the wall): square 5.4e-3, 1.33e-3,
# 4.6e-4 and 0.68 %, 0.18 %, 0.064 %; aspect 0.5 2.0e-3, 5.3e-4 and 0.24 %, 0.065 %. Without
# the long edges' maps (one traction shared by two faces at 90 degrees) the square's velocity
# errors were 3.9e-2, 1.7e-2, 9e-3.
WALL_POISEUILLE = {
    (1.0, 0.5): (7e-3, 1e-2), (1.0, 0.35): (2e-3, 3e-3), (1.0, 0.25): (6e-4, 1e-3),
    (0.5, 0.25): (2.6e-3, 3.5e-3), (0.5, 0.18): (7e-4, 1e-3),
}


@pytest.fixture(scope="module")
def wall_poiseuille():
    return {key: run_duct_probe("poiseuille", 4.0, key[1], key[1], key[0]) for key in WALL_POISEUILLE}


@pytest.mark.parametrize("key", list(WALL_POISEUILLE), ids=lambda k: f"aspect{k[0]}-h{k[1]}")
def test_wall_equation_returns_the_duct_poiseuille_flow(wall_poiseuille, key):
    # The total flow in the closed duct: u = 0 on the side walls and the Poiseuille profile on
    # the end sections. The traction the wall equation returns must give, through the single
    # layer plus the sections' double layer, the Poiseuille velocity inside (points at z = 0
    # and 0.37, from the axis to 0.7 of the way to a corner), and its normal part the pressure
    # gradient G; the published u_max checks the whole chain at the axis.
    aspect, _ = key
    r = wall_poiseuille[key]
    velocity_bound, gradient_bound = WALL_POISEUILLE[key]
    u_max = PUBLISHED[aspect][0]
    assert r["velocity_error_max"] < velocity_bound * u_max
    assert r["u_centre"] == pytest.approx(u_max, rel=velocity_bound + 1e-4)
    assert r["pressure_gradient"] == pytest.approx(r["pressure_gradient_exact"], rel=gradient_bound)


@pytest.mark.parametrize("aspect, sizes", [(1.0, (0.5, 0.35, 0.25)), (0.5, (0.25, 0.18))])
def test_wall_poiseuille_error_falls_at_second_order_or_faster(wall_poiseuille, aspect, sizes):
    # Measured orders: square 3.9 and 3.1, aspect 0.5 4.1 (P1 traction, exact geometry).
    for coarse, fine in zip(sizes, sizes[1:]):
        ratio = wall_poiseuille[(aspect, coarse)]["velocity_error_max"] / wall_poiseuille[(aspect, fine)]["velocity_error_max"]
        assert ratio > (coarse / fine) ** 2


# The wall shear next to the long edges, where u grows like r^2 log r from a corner and the wall
# shear like d log d with the distance d from the edge, which a uniform P1 traction follows to
# order 1 only. Largest nodal error of the wall shear over |z| <= L/2 - 1 (long edges left out:
# there it is 0 on both faces), relative to the largest wall shear; uniform lateral rings
# against rings graded towards the long edges (duct_probe ... EDGES = 1). Measured, square,
# L = 4, h 0.35 / 0.25 / 0.18: uniform 4.05 / 3.15 / 2.36 % (order 0.75, 0.88), graded
# 1.43 / 0.85 / 0.51 % (order 1.56, 1.56), with 27-29 % more nodes.
WALL_SHEAR_GRADED = {0.35: 1.7e-2, 0.25: 1.0e-2}


def relative_shear_error(r) -> float:
    return float(r["shear_error_max"]) / float(r["shear_scale"])


@pytest.fixture(scope="module")
def wall_poiseuille_graded():
    return {size: run_duct_probe("poiseuille", 4.0, size, size, 1.0, 1) for size in WALL_SHEAR_GRADED}


def test_edge_grading_makes_the_wall_shear_converge_faster(wall_poiseuille, wall_poiseuille_graded):
    for size, bound in WALL_SHEAR_GRADED.items():
        graded, uniform = wall_poiseuille_graded[size], wall_poiseuille[(1.0, size)]
        assert relative_shear_error(graded) < bound
        assert relative_shear_error(graded) < 0.45 * relative_shear_error(uniform)
        # The velocity inside and the pressure gradient stay within the uniform mesh's bounds
        # (measured: velocity 7.3e-4, 2.3e-4 of u_max; G -0.14 %, -0.077 %).
        velocity_bound, gradient_bound = WALL_POISEUILLE[(1.0, size)]
        assert graded["velocity_error_max"] < min(velocity_bound * PUBLISHED[1.0][0], uniform["velocity_error_max"])
        assert graded["pressure_gradient"] == pytest.approx(graded["pressure_gradient_exact"], rel=gradient_bound)
    coarse, fine = (relative_shear_error(wall_poiseuille_graded[size]) for size in WALL_SHEAR_GRADED)
    assert coarse / fine > (0.35 / 0.25) ** 1.3


@pytest.mark.validate
@pytest.mark.parametrize("aspect, bounds", [(1.0, (1.7e-2, 1.0e-2, 6.5e-3)), (0.5, (3.5e-2, 2.6e-2, 1.6e-2))],
                         ids=["square", "aspect0.5"])
def test_edge_graded_wall_shear_at_three_element_sizes(aspect, bounds):
    """The wall shear's largest error at h 0.35, 0.25, 0.18, uniform and edge-graded rings.
    Measured: square uniform 4.05 / 3.15 / 2.36 %, graded 1.43 / 0.85 / 0.51 %; aspect 0.5
    uniform 5.96 / 4.59 / 3.35 %, graded 2.98 / 2.22 / 1.30 %; graded order 1.56 (square) and
    1.63 (aspect 0.5) from 0.25 to 0.18. About 2 minutes on one loaded thread."""
    sizes = (0.35, 0.25, 0.18)
    errors = []
    for size, bound in zip(sizes, bounds):
        graded = run_duct_probe("poiseuille", 4.0, size, size, aspect, 1, timeout=600)
        uniform = run_duct_probe("poiseuille", 4.0, size, size, aspect, 0, timeout=600)
        errors.append(relative_shear_error(graded))
        assert errors[-1] < bound
        assert errors[-1] < 0.55 * relative_shear_error(uniform)
        assert graded["velocity_error_max"] < uniform["velocity_error_max"]
    assert errors[1] / errors[2] > (0.25 / 0.18) ** 1.3


@pytest.mark.validate
@pytest.mark.parametrize("size", [0.2, 0.3])
def test_small_sphere_on_the_duct_axis_moves_at_the_faxen_velocity(capsim, tmp_path, size):
    """A small, nearly rigid capsule (Ca_s 0.05, level 3, wall 0.28 / 0.14 w over 6 w) on the
    square duct's axis: v_c/U within 1 % of 2.0963 - 1.1856 (a/w)^2 (the Faxen velocity of a
    sphere; the wall's reflection is of higher order in a/w), and the drop below u_max within
    5 % of the Faxen term. Measured at a/w 0.3, t = 0.3: v_c 1.99041 (+0.041 %), drop
    1.1765 (a/w)^2 (-0.77 %), settled to 2e-5; 112 s on one loaded thread."""
    import h5py

    out = tmp_path / "sphere.h5"
    run = [str(capsim), "--flow", "tube", "--model", "3d", "--channel", "square", "--law", "NH",
           "--a-over-l", str(size), "--ca", "0.05", "--level", "3", "--wall-h-far", "0.28", "--wall-h-centre", "0.14",
           "--tube-length", "6", "--wall-cache", str(tmp_path), "--t-max", "0.3", "--threads", "1", "--quiet",
           "--out", str(out)]
    subprocess.run(run, check=True, timeout=1800)
    with h5py.File(out) as f:
        v_c = f["history/v_c"][()]
    faxen = SQUARE_U_MAX - SQUARE_G * size**2 / 6
    assert abs(v_c[-1] - v_c[-2]) < 1e-3 * v_c[-1]
    assert v_c[-1] == pytest.approx(faxen, rel=0.01)
    assert (SQUARE_U_MAX - v_c[-1]) / size**2 == pytest.approx(SQUARE_G / 6, rel=0.05)
