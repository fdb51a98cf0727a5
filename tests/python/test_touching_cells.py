"""Two touching cells with light interiors are not measured as one capsule, and never as a C.

Drawn by tests/python/event_frames.py (not the package's renderer): two elliptic rings (its
optics: a Gaussian line, 45 % absorption, around an interior 8 % brighter than the liquid)
touching along the flow, 24 x 20 px next to 22 x 19 px or 14 x 12 px, on the same row or 8 px
apart across the flow; each rim closed or fading to a tenth of its darkness over a 30 deg arc
(20 deg more of fade) facing the other cell's waist, away from it, or across the contact; camera
noise 2 grey levels of 200; sub-pixel placements.

- Where each cell keeps an interior of its own (both rims closed, or a notch opening an interior
  into the waist beside the other cell, where the outline used to be a C of 28-51 % of its hull):
  the object is flagged, not measured ("touching objects (2 light interiors ...)"), and its frame
  says so.
- Whatever the notches, no object is traced as a C and left unflagged: what is measured covers at
  least 85 % of its convex hull. (Interiors joined through notches facing each other across the contact, or
  both opening into one waist wider than the neck between them, are traced as one closed outline
  of both: 3 of the 72 pairs the two tests draw, 91-94 % of their hull.)
"""
from __future__ import annotations

import numpy as np
import pytest
from event_frames import Optics, capsule_transmission
from scipy import ndimage
from scipy.spatial import ConvexHull

from capsmech.imaging.channel import Walls
from capsmech.imaging.extraction import analyse_contrast
from capsmech.imaging.objects import DETECTION_SMOOTHING_PX, TracedObject, find_objects, polygon_area, trace_object

OPTICS = Optics(shape=(100, 200), interior_gain=0.08, ring_absorption=0.45, ring_width_px=1.06, noise=2.0)
LEVEL = 200.0
BIG = (24.0, 20.0)


def touching_pair(notch_a: float | None, notch_b: float | None, other: tuple[float, float], across_px: float,
                  seed: int) -> np.ndarray:
    """Contrast (1 - I / liquid) of two cells touching along x; ``notch_*`` the direction [deg] of
    each rim's faint arc (None: closed)."""
    rng = np.random.default_rng(seed)
    a = (70.0 + rng.uniform(-0.5, 0.5), 50.0 + rng.uniform(-0.5, 0.5))
    b = (a[0] + BIG[0] + other[0] + rng.uniform(-0.5, 0.5), 50.0 + across_px + rng.uniform(-0.5, 0.5))
    light = LEVEL * capsule_transmission(OPTICS.shape, a, BIG, OPTICS, None if notch_a is None else (30.0, notch_a))
    light *= capsule_transmission(OPTICS.shape, b, other, OPTICS, None if notch_b is None else (30.0, notch_b))
    return 1 - np.rint(light + rng.normal(0.0, OPTICS.noise, light.shape)) / LEVEL


def traced(contrast: np.ndarray) -> TracedObject:
    smooth = ndimage.gaussian_filter(contrast, DETECTION_SMOOTHING_PX)
    labels, mask, keep, threshold = find_objects(smooth, np.ones(contrast.shape, bool), 6.0, 30)
    assert len(keep) == 1
    result = trace_object(contrast, labels == keep[0], mask, threshold, smooth)
    assert isinstance(result, TracedObject), result
    return result


#: (notch of the left cell, notch of the right one): each keeps an interior of its own.
SEPARATE = [(None, None), (0.0, None), (45.0, None), (-60.0, None), (90.0, 90.0), (180.0, 0.0)]
#: Notches facing each other across the contact, or both into one waist.
JOINED = [(0.0, 180.0), (30.0, 150.0), (60.0, 120.0)]
PLACES = [(other, across) for other in [(22.0, 19.0), (14.0, 12.0)] for across in (0.0, 8.0)]


@pytest.mark.parametrize("notches", SEPARATE, ids=[f"{a}-{b}" for a, b in SEPARATE])
def test_touching_cells_each_with_its_interior_are_not_one_capsule(notches):
    for k, (other, across) in enumerate(PLACES):
        flag = traced(touching_pair(*notches, other, across, seed=k)).flag
        assert flag.startswith("touching objects (2 light interiors"), (other, across, flag)


@pytest.mark.parametrize("notches", SEPARATE + JOINED, ids=[f"{a}-{b}" for a, b in SEPARATE + JOINED])
def test_touching_cells_are_never_traced_as_a_c(notches):
    for k, (other, across) in enumerate(PLACES):
        result = traced(touching_pair(*notches, other, across, seed=10 + k))
        if not result.flag:
            assert polygon_area(result.outer) >= 0.85 * ConvexHull(result.outer).volume, (other, across)


def test_the_frame_says_why_its_touching_cells_are_not_measured():
    """Through the frame's analysis: one object, flagged, and the frame with it; no lengths."""
    contrast = touching_pair(45.0, None, (22.0, 19.0), 0.0, seed=3)
    result = analyse_contrast(contrast, Walls(5.0, 95.0, "given"))
    assert result.objects == 1 and result.traces[0].flag.startswith("touching objects")
    assert result.flag.startswith("touching objects") and np.isnan(result.L_z_px), result.flag
