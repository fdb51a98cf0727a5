"""The ring tracing's building blocks against their references, and the traced lengths with them.

The tracing's three costliest steps have fast forms in ``capsmech.imaging.objects``; each is held
against what it replaces, an independent reference:

- the iso-lines (:func:`closed_contours`): ``skimage.measure.find_contours``'s, point for point,
  from the same start and in the same order, on smooth random fields with and without saddle cells;
- the nearest point of the inner edge (:func:`nearest_on_polyline`): the projection on every
  segment of the line (brute force), on rings drawn by tests/python/capillary_films.py and on a
  zigzag line whose nearest vertices are not the ends of its nearest segment;
- the profiles across the line (:func:`bilinear_samples`): ``ndimage.map_coordinates`` (order 1,
  mode nearest), points beyond the image's edge included.

Then the traced lengths of capillary_films' rings (interior 0 and 4 % brighter) with the fast
blocks against those traced with the references (find_contours, the inner edge sampled every
0.05 px and its nearest sample, map_coordinates): the same within 0.01 px (measured: at most
0.0047 px on L_z and 0.0011 px on L_p over the 1000 frames of ``bench_extract.py --film``).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from capillary_films import MEMBRANE, SHAPE, capsule_transmission, pool_capsules, section_px
from scipy import ndimage
from scipy.spatial import cKDTree
from skimage.measure import find_contours
from traced_ring import traced_ring

from capsmech.imaging import objects
from capsmech.imaging.measurement import rear_axis_crossing
from capsmech.imaging.objects import (
    bilinear_samples,
    closed_contours,
    nearest_on_polyline,
    resample,
)

L_PX = 60.0
LEVEL, NOISE = 200.0, 3.0


def _reference_contours(field: np.ndarray, level: float) -> list[np.ndarray]:
    """find_contours' closed lines of more than 8 points as (x, y), longest first."""
    lines = [c[:, ::-1] for c in find_contours(field, level) if len(c) > 8 and np.allclose(c[0], c[-1])]
    return sorted(lines, key=len, reverse=True)


def _has_saddle(field: np.ndarray, level: float) -> bool:
    above = field > level
    return bool((((above[:-1, :-1] == above[1:, 1:]) & (above[:-1, 1:] == above[1:, :-1]))
                 & (above[:-1, :-1] != above[:-1, 1:])).any())


def test_the_iso_lines_are_find_contours_point_for_point():
    """200 smooth random fields (zero border, as a tracing crop), levels from the 30th to the 80th
    percentile: the same lines, points, starts and order; both paths (with and without a saddle)
    are exercised."""
    rng = np.random.default_rng(3)
    kinds = {True: 0, False: 0}
    for trial in range(200):
        field = ndimage.gaussian_filter(rng.random((30 + trial % 40, 40 + trial % 31)), 1.5 + trial % 3)
        field = np.pad(field.astype(np.float32), 1)
        level = float(np.percentile(field[1:-1, 1:-1], 30 + trial % 50))
        kinds[_has_saddle(field, level)] += 1
        expected, found = _reference_contours(field, level), closed_contours(field, level)
        assert [len(c) for c in found] == [len(c) for c in expected], trial
        for a, b in zip(expected, found):
            assert np.abs(a - b).max() < 1e-9, trial
    assert min(kinds.values()) >= 20, kinds


def _ring_contrast(capsule_index: int, interior_gain: float, rng: np.random.Generator) -> np.ndarray:
    """1 - I / I_liquid of one pool capsule drawn by capillary_films' optics, with camera noise."""
    capsule = pool_capsules("NH")[capsule_index]
    outline = section_px(capsule, L_PX)
    centre = np.array([240.0, 80.0]) + rng.uniform(-0.5, 0.5, 2)
    light = LEVEL * capsule_transmission(outline, cKDTree(outline), centre, replace(MEMBRANE, interior_gain=interior_gain))
    return 1 - np.rint(light + rng.normal(0.0, NOISE, SHAPE)) / LEVEL


def _brute_nearest(polyline: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Each point projected on every segment of the closed polyline, the nearest kept."""
    closed = np.vstack([polyline, polyline[:1]])
    a, d = closed[:-1], np.diff(closed, axis=0)
    q = points[:, None, :] - a[None]
    t = np.clip((q * d[None]).sum(axis=2) / np.maximum((d * d).sum(axis=1), 1e-300)[None], 0.0, 1.0)
    projected = a[None] + t[..., None] * d[None]
    best = ((points[:, None, :] - projected) ** 2).sum(axis=2).argmin(axis=1)
    return projected[np.arange(len(points)), best]


def test_the_nearest_point_of_the_inner_edge_is_the_projection_on_the_line():
    """The half-peak edges of 4 drawn rings (outer points every 0.25 px) and a zigzag line whose
    nearest vertices are not the ends of its nearest segment: the nearest points of the
    brute-force projection, to 1e-9 px."""
    rng = np.random.default_rng(8)
    for index in (0, 6, 12, 18):
        contrast = _ring_contrast(index, 0.04, rng)
        line = ndimage.gaussian_filter(contrast, objects.CONTOUR_SMOOTHING_PX)
        box = line[80 - 70:80 + 70, 240 - 90:240 + 90]
        edges = closed_contours(np.pad(box, 1), float(np.percentile(box[box > 0.1], 90)) / 2)
        outer, inner = resample(edges[0], 0.25), edges[1][:-1]
        assert np.abs(nearest_on_polyline(inner, outer) - _brute_nearest(inner, outer)).max() < 1e-9, index
    # A marching-squares zigzag (as on a drawn ring's rear): a 1 px segment 0.065 px out of line
    # with its neighbours. Seen from 3.5 px its ends are farther than the next vertices, and the
    # segments beside the two nearest vertices miss the nearest point by 0.76 px.
    side = np.array([[0.0, -3.8], [0.0, -2.8], [0.0, -1.8], [0.0, -0.8], [0.065, -0.5], [0.065, 0.5], [0.0, 0.8],
                     [0.0, 1.8], [0.0, 2.8], [0.0, 3.8]])
    polygon = np.vstack([side, [[6.0, 3.8], [6.0, -3.8]]])
    points = np.column_stack([np.full(25, -3.5), np.linspace(-0.3, 0.3, 25)])
    assert np.abs(nearest_on_polyline(polygon, points) - _brute_nearest(polygon, points)).max() < 1e-9


def test_the_profiles_are_map_coordinates_bilinear():
    """Random float32 images (and one of a single row), points up to 3 px beyond every edge:
    ``map_coordinates(order=1, mode='nearest')`` to 1e-6 of the image's range."""
    rng = np.random.default_rng(1)
    for shape in [(70, 130), (1, 9), (9, 1), (2, 2)]:
        image = rng.random(shape).astype(np.float32)
        rows = rng.uniform(-3, shape[0] + 2, (50, 40))
        cols = rng.uniform(-3, shape[1] + 2, (50, 40))
        expected = ndimage.map_coordinates(image, np.array([rows, cols]), order=1, mode="nearest")
        assert np.abs(bilinear_samples(image, rows, cols) - expected).max() < 1e-6, shape


def _dense_nearest(polyline: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The reference pairing: the line sampled every 0.05 px, each point's nearest sample."""
    dense = resample(polyline, 0.05)
    return dense[cKDTree(dense).query(points)[1]]


@pytest.mark.parametrize("interior_gain", [0.0, 0.04])
def test_the_traced_lengths_are_those_of_the_reference_blocks(interior_gain, monkeypatch):
    """6 pool capsules drawn by capillary_films: L_z, L_p (from the axis row of the drawing) and
    the line width traced with the fast blocks and with the references, within 0.01 px."""
    rng = np.random.default_rng(21)
    contrasts = [_ring_contrast((5 * k) % 24, interior_gain, rng) for k in range(6)]
    fast = [traced_ring(c) for c in contrasts]
    monkeypatch.setattr(objects, "closed_contours", _reference_contours)
    monkeypatch.setattr(objects, "nearest_on_polyline", _dense_nearest)
    monkeypatch.setattr(objects, "bilinear_samples", lambda image, rows, cols: ndimage.map_coordinates(
        image, np.array([rows, cols]), order=1, mode="nearest"))
    reference = [traced_ring(c) for c in contrasts]
    for a, b in zip(fast, reference):
        assert a.extent_px == pytest.approx(b.extent_px, abs=0.01)
        L_p_fast, L_p_reference = (rear_axis_crossing(t.contour, 80.0) - t.x_rear for t in (a, b))
        assert L_p_fast == pytest.approx(L_p_reference, abs=0.01)
        assert a.line_width_px == pytest.approx(b.line_width_px, abs=1e-9)
