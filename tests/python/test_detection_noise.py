"""Only objects that are there: detection against the stack's own noise, and pieces cut by the
frame's edge that make no capsule of their own.

Frames are drawn by tests/python/event_frames.py (its own optics, apart from the package's
renderer: walls with refraction lines, a gradient, dirt, a chip that shakes by a fraction of a
pixel) or taken from real recordings: the median of dclab's recorded pages
(tests/data/real_frames/, GPL-2.0-or-later) as the empty channel, with fresh camera noise.

Measured when this was written: every noise-only stack below gives 0 frames with an object. The
real backgrounds gave 120 of 120 before (a static speck beside a wall was read as a moving
object's trace); a chip shaking by 0.05-0.2 px gave 1 to 65 of 120 along the walls against the
frame's noise alone, 0 against the stack's own (``background.temporal_noise``).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import tifffile
from event_frames import Optics, film, noise_stack

from capsmech.api import extract
from capsmech.imaging.extraction import FrameStack, extract_stack, measure_capsules

REAL = Path(__file__).resolve().parents[1] / "data" / "real_frames"
RATE = 1000.0


def stack_of(frames: np.ndarray) -> FrameStack:
    return FrameStack(list(frames), [f"f[{k}]" for k in range(len(frames))], frame_rate=RATE)


def frames_with_objects(frames: np.ndarray) -> int:
    _, results = extract_stack(stack_of(frames))
    return sum(r.objects > 0 for r in results)


@pytest.mark.parametrize("sigma", [2.0, 4.0])
@pytest.mark.parametrize("jitter_px", [0.0, 0.1])
def test_noise_only_stacks_with_a_gradient_dirt_and_a_shaking_chip_show_no_object(sigma, jitter_px):
    """120 frames of the empty channel (12 % gradient, 12 specks of dirt, walls with refraction
    lines): 0 frames with an object measured; at most 1 of 120 allowed."""
    frames = noise_stack(120, Optics(noise=sigma), seed=11, jitter_px=jitter_px)
    assert frames_with_objects(frames) <= 1


@pytest.mark.skipif(not REAL.is_dir(), reason="tests/data/real_frames/ is not there")
@pytest.mark.parametrize("recording,sigma", [("fmt-hdf5_mask-contour_2018", 2.0),
                                             ("fmt-hdf5_reference_2025", 2.0),
                                             ("fmt-hdf5_reference_2025", 4.0),
                                             ("fmt-hdf5_fl_wide-channel_2023", 2.0),
                                             ("fmt-hdf5_image-mask-blood_2021", 4.0)])
def test_noise_only_stacks_on_real_backgrounds_show_no_object(recording, sigma):
    """A real empty channel (the median of a recording's pages: its walls, its dirt, what is left
    of its cells as static specks) with fresh noise: 0 of 120 frames with an object measured."""
    pages = tifffile.imread(REAL / recording / "frames.tif").astype(float)
    frames = noise_stack(120, Optics(noise=sigma), seed=5, background=np.median(pages, axis=0))
    assert frames_with_objects(frames) <= 1


@pytest.mark.parametrize("interior_gain", [0.03, 0.08])
def test_a_capsule_in_a_noisy_shaking_stack_is_still_found_and_measured(interior_gain):
    """The same optics as the noise-only stacks (sigma 4, the chip shaking by 0.1 px): a ring of
    half-length 25 px crossing at 6 px a frame, its interior 3 or 8 % brighter than the liquid
    (a light interior over a pixel in a sixth of the frames must not pass for noise there), is
    found in every frame and measured (L_z = 50 px drawn, v_c = 6 px a frame)."""
    frames = film(60, 60.0, 6.0, (25.0, 22.0), Optics(noise=4.0, interior_gain=interior_gain), seed=2,
                  jitter_px=0.1)
    _, results = extract_stack(stack_of(frames))
    assert all(r.objects >= 1 for r in results)
    (capsule,) = measure_capsules(results, RATE)
    assert capsule.ok, capsule.problem
    assert capsule.L_z_px == pytest.approx(50.0, abs=1.0)
    assert capsule.v_c_px_s == pytest.approx(6.0 * RATE, rel=0.01)


def test_a_piece_at_the_frame_edge_is_no_capsule_and_does_not_rename_the_real_one(tmp_path):
    """A capsule enters at the left edge (its first frames cut: they join its track); in the last
    two frames the front of the next one shows at the left edge, far behind it: dropped with the
    reason, and the one capsule keeps the file's name as its id."""
    frames = film(40, -18.0, 8.0, (25.0, 22.0), Optics(noise=2.0), seed=3,
                  others=[(38, -20.0, (25.0, 22.0), math.nan), (39, -12.0, (25.0, 22.0), math.nan)])
    tiff = tmp_path / "passage.tif"
    tifffile.imwrite(tiff, frames)
    found = extract(tiff, pixel_size=1.0, frame_rate=RATE)
    assert list(found.capsules["id"]) == ["passage"]
    assert found.capsules["flag"].iloc[0] == ""
    (capsule,) = found.measurements
    assert capsule.frames[0] == 0                       # the entering pieces joined its passage
    pieces = [t for r in found.results[38:] for t in r.traces if t.centre[0] < 30]
    assert pieces and all(t.track == -1 and "not a capsule of its own" in t.dropped for t in pieces)


def test_an_object_in_a_wall_band_is_no_capsule_of_its_own(tmp_path):
    """A small dark speck drifting along the top wall (3 px from its edge) in 5 frames of a
    capsule's passage: not a second capsule; the capsule keeps the file's name."""
    top = Optics().walls[0]
    speck = [(k, 150.0 + 3.0 * k, (8.0, 2.5), top + 3.0) for k in range(10, 15)]
    frames = film(40, 60.0, 6.0, (25.0, 22.0), Optics(noise=2.0), seed=8, others=speck)
    tiff = tmp_path / "walls.tif"
    tifffile.imwrite(tiff, frames)
    found = extract(tiff, pixel_size=1.0, frame_rate=RATE)
    assert list(found.capsules["id"]) == ["walls"] and found.capsules["flag"].iloc[0] == ""
    specks = [t for r in found.results[10:15] for t in r.traces if t.centre[1] < top + 10]
    assert specks and all(t.track == -1 and "wall's band" in t.dropped for t in specks)
