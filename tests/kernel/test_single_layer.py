"""Single-layer potential: translating sphere, convergence order."""
from __future__ import annotations

import math

import pytest


def test_mesh_levels_are_closed_icospheres(probe):
    deficits = []
    for level, nodes in [(2, 162), (3, 642), (4, 2562)]:
        r = probe("mesh", level)
        assert r["n_nodes"] == nodes and r["n_tri"] == 2 * nodes - 4
        assert r["unmatched_edges"] == 0          # closed, consistently oriented
        assert r["volume"] > 0                    # outward orientation
        assert r["h_max"] / r["h_min"] < 1.25     # near-uniform triangles for the time step
        deficits.append(1 - r["volume"] / (4 * math.pi / 3))
    # Inscribed polyhedron: the volume deficit is O(h^2), a factor 4 per level.
    assert deficits[-1] < 3e-3
    for coarse, fine in zip(deficits, deficits[1:]):
        assert coarse / fine == pytest.approx(4.0, rel=0.1)


def test_sphere_with_uniform_traction_translates_at_stokes_velocity(probe):
    # U = 2 a f / (3 mu); the error (flat triangles + quadrature) must fall at least as O(h^2).
    errors = [probe("translate", level, 4, 0)["max_rel_error"] for level in (2, 3, 4)]
    assert errors[-1] < 1e-3
    for coarse, fine in zip(errors, errors[1:]):
        order = math.log(coarse / fine, 2)
        assert order > 1.9, f"convergence order {order:.2f} < 2 (errors {errors})"
