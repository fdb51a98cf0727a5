"""Flow direction from the motion, and each capsule measured on its own when several are in view
(issue 20, items 3 and 4), on capsules drawn over a real recorded channel (dclab's
fmt-hdf5_reference_2025 background: its walls, tilt and dirt; tests/data/real_frames/).

Truths are the drawn ones: the profiles' lengths, 10 or 5 px a frame at 1000 frames/s.
"""
from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from capsmech.imaging.extraction import FrameStack, extract_stack, measure_capsules
from capsmech.imaging.rendering import FrameStyle, drawn_lengths, outline_from_meridian, render_on_background
from capsmech.io.catalog import database_path
from capsmech.io.database import load_database

BACKGROUND = Path(__file__).resolve().parents[1] / "data" / "real_frames" / "fmt-hdf5_reference_2025" / "background.png"
#: The recorded channel's inner wall lines are at rows 6.02 and 74.35 (meta.json's survey).
STYLE = FrameStyle(tube_radius_px=34.16, axis_row=40.19)
MIRROR = np.array([-1.0, 1.0])


@pytest.fixture(scope="module")
def outlines():
    rows = load_database(database_path("tube-paper")).law("NH").steady_rows()

    def outline(a_over_l: float, Ca_s: float) -> np.ndarray:
        i = int(np.argmin(np.abs(rows["a_over_l"] - a_over_l) + np.abs(rows["Ca_s"] - Ca_s)))
        return outline_from_meridian(rows["profile_r"][i], rows["profile_z"][i])

    return outline(0.85, 0.05), outline(0.9, 0.12)


def film(capsules_at, seed: int = 1) -> list[np.ndarray]:
    background = iio.imread(BACKGROUND).astype(float)
    rng = np.random.default_rng(seed)
    return [render_on_background(background, capsules, STYLE, rng, noise=1.5) for capsules in capsules_at]


def stack(frames, direction: str) -> FrameStack:
    return FrameStack([f[:, ::-1] if direction == "left" else f for f in frames], [str(k) for k in range(len(frames))],
                      frame_rate=1000.0, flow_direction=direction)


def lengths_px(outline: np.ndarray) -> tuple[float, float]:
    return tuple(length * STYLE.tube_radius_px for length in drawn_lengths(outline))


@pytest.fixture(scope="module")
def leftward(outlines):
    """A capsule moving in -x (its parachute rear facing +x), 10 px a frame."""
    return film([[(outlines[0] * MIRROR, 285.0 - 10.0 * k)] for k in range(20)])


def test_flow_direction_found_from_the_motion(outlines, leftward):
    L_z, L_p = lengths_px(outlines[0])
    channel, results = extract_stack(stack(leftward, "auto"))
    assert channel.flow_direction == "left" and "from the motion" in channel.flow_check
    (capsule,) = [c for c in measure_capsules(results, 1000.0) if c.ok]
    assert len(capsule.good_frames) >= 17
    assert capsule.L_z_px == pytest.approx(L_z, abs=0.5) and capsule.L_p_px == pytest.approx(L_p, abs=0.5)
    assert capsule.v_c_px_s == pytest.approx(10_000.0, rel=0.01)
    # The same film mirrored is found moving right, unmirrored.
    channel, results = extract_stack(stack([f[:, ::-1] for f in leftward], "auto"))
    assert channel.flow_direction == "right" and "from the motion" in channel.flow_check
    assert [c.L_z_px for c in measure_capsules(results, 1000.0) if c.ok] == pytest.approx([L_z], abs=0.5)


def test_given_flow_direction_checked_against_the_motion(leftward):
    channel, _ = extract_stack(stack(leftward, "left"))
    assert "given, confirmed by the motion" in channel.flow_check
    channel, results = extract_stack(stack(leftward, "right"))
    assert "the objects move the other way" in channel.flow_check
    assert not any(c.ok for c in measure_capsules(results, 1000.0))


def test_several_capsules_in_view_are_each_measured(outlines):
    """Two capsules of different sizes in every frame, 140 px apart: each is its own track,
    measured over its own frames (before, every frame was only "2 capsules": nothing measured)."""
    frames = film([[(outlines[0], 60.0 + 5.0 * k), (outlines[1], 200.0 + 5.0 * k)] for k in range(14)], seed=2)
    channel, results = extract_stack(stack(frames, "auto"))
    assert channel.flow_direction == "right"
    assert all(r.flag == "2 capsules" for r in results)
    capsules = [c for c in measure_capsules(results, 1000.0) if c.ok]
    assert len(capsules) == 2
    for capsule, outline in zip(sorted(capsules, key=lambda c: c.L_z_px), outlines):
        L_z, L_p = lengths_px(outline)
        assert len(capsule.good_frames) == 14
        assert capsule.L_z_px == pytest.approx(L_z, abs=0.5) and capsule.L_p_px == pytest.approx(L_p, abs=0.5)
        assert capsule.v_c_px_s == pytest.approx(5000.0, rel=0.01)
        assert capsule.trace is not None and capsule.trace.flag == ""
