"""The outline of a 3D case in the plane y = 0, as the assembly takes it into a tube or duct
database: the section of the membrane mesh, both poles included wherever the mesh's nodes lie.

The kernel's own ``/profile`` of a 3D case keeps the nodes near the plane and lost the front or
rear pole of 19 of duct-dev's 54 steady rows; a measured contour (the section a microscope
sees) has both. Checked on a sphere triangulated by its convex hull, turned so that no node lies
on the plane or on the axis: the outline is the sphere's great circle, up to the chords.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from capsmech.workflow.assembly import mid_plane_meridian

RADIUS = 0.8


def sphere_mesh(points: int = 400, turn_degrees: float = 7.0) -> tuple[np.ndarray, np.ndarray]:
    """Nodes on a sphere (a Fibonacci lattice, turned so that none lies on y = 0 or on the z axis)
    and the triangles of their convex hull."""
    k = np.arange(points) + 0.5
    polar = np.arccos(1 - 2 * k / points)
    azimuth = math.pi * (1 + 5 ** 0.5) * k
    unit = np.column_stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)])
    nodes = RADIUS * Rotation.from_euler("xyz", [turn_degrees, 2 * turn_degrees, 0.0], degrees=True).apply(unit)
    return nodes, ConvexHull(nodes).simplices


def test_the_outline_runs_from_the_front_pole_to_the_rear_pole_on_the_axis():
    nodes, triangles = sphere_mesh()
    assert np.abs(nodes[:, 1]).min() > 1e-6 and np.hypot(nodes[:, 0], nodes[:, 1]).min() > 1e-3
    r, z = mid_plane_meridian(nodes, triangles)
    # Both ends on the axis, the front (larger z) first, every other point on the side x > 0.
    assert r[0] == 0.0 and r[-1] == 0.0 and z[0] > 0 > z[-1]
    assert np.all(r[1:-1] > 0)
    # On the great circle up to the chords of the mesh (edges ~0.08 R: sagitta below 0.1 %).
    distance = np.hypot(r, z)
    assert np.all(distance <= RADIUS * (1 + 1e-12)) and np.all(distance > RADIUS * 0.99)
    assert math.isclose(z[0] - z[-1], 2 * RADIUS, rel_tol=0.01)
    # The half-outline's points follow the circle from one pole to the other.
    angle = np.arctan2(r, z)
    assert np.all(np.diff(angle) > 0)


def test_a_node_on_the_axis_gives_its_pole_once():
    nodes, triangles = sphere_mesh(turn_degrees=0.0)
    # Unturned, the lattice has no node on the axis but some near the plane; put the first and
    # last nodes (those nearest the poles) on it exactly, as a symmetric kernel mesh has them.
    nodes[0] = [0.0, 0.0, nodes[0, 2]]
    nodes[-1] = [0.0, 0.0, nodes[-1, 2]]
    r, z = mid_plane_meridian(nodes, ConvexHull(nodes).simplices)
    steps = np.hypot(np.diff(r), np.diff(z))
    assert np.all(steps > 0)
    assert r[0] == 0.0 and r[-1] == 0.0
