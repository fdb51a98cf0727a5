"""One wall out of view: the other is placed at the width given, and where that puts the axis off
the objects' own symmetry line beyond both uncertainties, the placed wall is moved to make that
line the axis, the frames are measured against it, and the report and the CSV column say so.

Films drawn by tests/python/glass_walls.py (its own optics: an 8 px glass band with a refraction
line, tilt 0.4 deg, a 10 % gradient, noise 3 grey levels), with an elliptical ring (a capsule seen
in the tube, 64 x 52 px) centred on the axis, moving 10 px a frame; the top wall cut off by the
frame. Truth: the axis lies 50 px above the bottom interface.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.special import erf

sys.path.insert(0, str(Path(__file__).resolve().parent))

from glass_walls import Glass, film  # noqa: E402

from capsmech.imaging.channel import Walls, axis_from_objects  # noqa: E402
from capsmech.imaging.extraction import FrameStack, extract_stack  # noqa: E402

CUT = 45          # rows cut off the top: the top wall (rows 22-30) is out of view


def cut_film(frames: int = 8) -> tuple[np.ndarray, float]:
    """The film with the top wall cut off, and the true axis row in it."""
    top, width = 30.0, 100.0
    tilt_deg = 0.4
    stack, _, bottom = film(Glass(8.0, "liquid", tilt_deg=tilt_deg, gradient=0.1, noise=3.0), frames=frames, seed=11,
                            top=top, width=width)
    rows, cols = stack.shape[1:]
    y, x = np.mgrid[0:rows, 0:cols].astype(float)
    axis = top + width / 2
    out = []
    for k in range(frames):
        # On the tilted tube's axis (the rows given are the centre column's).
        centre = 60.0 + 10 * k
        row = axis + (centre - (cols - 1) / 2) * np.tan(np.radians(tilt_deg))
        # Distance to the ellipse (semi-axes 32 x 26 px), to first order: level set over its gradient.
        u, v = (x - centre) / 32.0, (y - row) / 26.0
        distance = (np.hypot(u, v) - 1) / np.hypot(u / 32.0, v / 26.0).clip(1e-6) * np.hypot(u, v).clip(1e-6)
        ring = 0.5 * (erf((1.25 - distance) / 1.414) + erf((1.25 + distance) / 1.414))
        out.append(np.clip(stack[k] * (1 - 0.5 * ring), 0, 255))
    return np.stack(out).astype(np.uint8)[:, CUT:], bottom - width / 2 - CUT


def run(given_px: float):
    frames, axis = cut_film()
    stack = FrameStack(list(frames), [f"f{k}" for k in range(len(frames))], frame_rate=1000.0)
    channel, results = extract_stack(stack, channel_width_px=given_px, channel_width_tolerance=0.01)
    return channel, results, axis


@pytest.mark.parametrize("error_px", [-9.4, 9.4])
def test_an_axis_placed_off_the_objects_is_moved_to_their_symmetry_line(error_px):
    # The width given 9.4 px off: the axis placed 4.7 px off the true one.
    channel, results, axis = run(100.0 + error_px)
    walls = channel.walls
    assert walls.source == "one wall detected, the other placed by the objects' symmetry line"
    assert walls.axis_row == pytest.approx(axis, abs=0.5)
    assert walls.width_px == pytest.approx(100.0, abs=1.0)
    # Its uncertainty is stated, and holds the truth.
    assert 0 < walls.top_sigma_px < 1.5 and abs(walls.width_px - 100.0) <= 3 * walls.width_sigma_px + 0.2
    assert channel.width_disagrees and channel.width_verdict.startswith("axis from the objects' symmetry line")
    assert "the top wall is moved to row" in channel.width_check
    # Measured against that axis: the ring is symmetric about it.
    measured = [r for r in results if r.good]
    assert len(measured) >= 0.5 * len(results), [r.flag for r in results]
    assert not any("asymmetric" in r.flag for r in measured)


def test_an_axis_placed_on_the_objects_is_kept():
    channel, _, axis = run(100.0)
    assert "placed at the channel width" in channel.walls.source
    assert channel.walls.axis_row == pytest.approx(axis, abs=0.5)
    assert not channel.width_disagrees and "confirms the axis placed" in channel.width_check


def test_the_placed_wall_moves_with_the_symmetry_line_and_carries_its_error():
    placed = Walls(-20.0, 80.0, "one wall detected, the other placed at the channel width", None, 2.0, 0.1,
                   placed_side="top")
    rows = [34.7 + d for d in (-0.3, -0.1, 0.0, 0.1, 0.3)]
    moved = axis_from_objects(placed, rows)
    assert moved.bottom_row == 80.0 and moved.axis_row == pytest.approx(34.7)
    # Twice the median's standard error (1.2533 sigma / sqrt n) and the seen wall's, in quadrature.
    expected = np.hypot(2 * 1.2533 * np.std(rows, ddof=1) / np.sqrt(5), 0.1)
    assert moved.top_sigma_px == pytest.approx(expected)
    with pytest.raises(ValueError):
        axis_from_objects(placed, rows[:2])
