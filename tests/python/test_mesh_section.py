"""capsmech.imaging.mesh_section: the plane section of a triangulated closed surface, checked on
ellipsoids (the section y = 0 of x^2/A^2 + y^2/B^2 + z^2/C^2 = 1 is the ellipse of semi-axes A
along x and C along z) and against the 3D kernel's own half section (/profile)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from capsmech.imaging.mesh_section import SectionError, plane_section


def ellipsoid_mesh(semi_axes, n: int = 4000, seed: int = 0):
    """Nodes on an ellipsoid (random directions) and the triangles of their convex hull."""
    rng = np.random.default_rng(seed)
    directions = rng.standard_normal((n, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    nodes = directions * np.asarray(semi_axes)
    return nodes, ConvexHull(nodes).simplices


def polygon_area(points: np.ndarray) -> float:
    x, y = points.T
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


@pytest.mark.parametrize("n", [2000, 8000])
def test_section_of_an_ellipsoid_is_its_ellipse(n):
    A, B, C = 0.8, 0.6, 1.4
    nodes, triangles = ellipsoid_mesh((A, B, C), n)
    section = plane_section(nodes, triangles)          # y = 0: columns (z, x)
    z, x = section.T
    # The points lie on chords of the surface: inside the ellipse, by the chord sag O(h^2).
    level = (x / A) ** 2 + (z / C) ** 2
    h = np.sqrt(4 * np.pi * A * C / n)                 # typical edge
    assert np.all(level <= 1 + 1e-12) and np.all(level > 1 - 2 * h)
    assert polygon_area(section) == pytest.approx(np.pi * A * C, rel=2 * h)
    # ... and go round it once: the polar angle turns through 2 pi, step by small step.
    steps = np.angle(np.exp(1j * np.diff(np.arctan2(x, z), append=np.arctan2(x[0], z[0]))))
    assert abs(abs(steps.sum()) - 2 * np.pi) < 1e-9 and np.abs(steps).max() < 0.5

def test_error_of_the_area_falls_as_h_squared():
    errors = []
    for n in (1000, 4000, 16000):
        nodes, triangles = ellipsoid_mesh((1.0, 1.0, 1.0), n)
        errors.append(np.pi - polygon_area(plane_section(nodes, triangles)))
    assert errors[0] > errors[1] > errors[2] > 0
    rate = np.log(errors[0] / errors[2]) / np.log(16)   # error ~ n^-rate, h^2 ~ 1/n
    assert 0.7 < rate < 1.3


def test_a_plane_that_misses_is_an_error():
    nodes, triangles = ellipsoid_mesh((1.0, 1.0, 1.0), 500)
    with pytest.raises(SectionError, match="misses"):
        plane_section(nodes, triangles, offset=1.5)


def test_two_bodies_are_refused():
    a, ta = ellipsoid_mesh((1.0, 1.0, 1.0), 300)
    b, tb = ellipsoid_mesh((1.0, 1.0, 1.0), 300, seed=1)
    nodes = np.vstack([a, b + [0.0, 0.0, 3.0]])
    with pytest.raises(SectionError, match="more than one curve"):
        plane_section(nodes, np.vstack([ta, tb + len(a)]))
