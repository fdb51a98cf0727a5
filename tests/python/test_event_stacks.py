"""Films and event stacks: independent snapshots are measured one by one, a film is tracked, and a
capsule still deforming along its passage is not measured as a steady shape.

Frames are drawn by tests/python/event_frames.py (its own optics, apart from the package's
renderer). An event stack is what a cytometer exports: each frame another capsule, at a place
and of a size of its own, written as a plain TIFF given a regular frame rate - nothing in the
file says that the frames are not a film.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import tifffile
from event_frames import Optics, event_stack, film

from capsmech.api import extract
from capsmech.cli.main import main

RATE = 1000.0
REAL = Path(__file__).resolve().parents[1] / "data" / "real_frames"


def test_an_event_stack_gives_one_shape_per_event_and_no_velocity(tmp_path, capsys):
    """30 unrelated capsules (half-lengths 16-28 px, anywhere between x = 90 and 390): no track
    across frames, no velocity, no flow direction from their positions (the frames are not
    mirrored); each event's L_z is its own drawn 2a within 1 px; the command says so."""
    frames, truth = event_stack(30, Optics(noise=2.0), seed=3)
    tiff = tmp_path / "events.tif"
    tifffile.imwrite(tiff, frames)
    found = extract(tiff, pixel_size=1.0, frame_rate=RATE)
    assert found.channel.independent_events.startswith("independent events")
    assert found.channel.flow_direction == "right" and "mirrored" not in found.channel.flow_check
    assert all(len(cap.frames) == 1 for cap in found.measurements)
    assert len({t.track for r in found.results for t in r.traces}) == sum(len(r.traces) for r in found.results)
    assert found.capsules["v_c"].isna().all()
    measured = [cap for cap in found.measurements if cap.ok]
    assert len(measured) >= 25
    for cap in measured:
        assert "no velocity" in cap.note
        assert cap.L_z_px == pytest.approx(2 * truth[cap.frames[0], 1], abs=1.0)
    out = tmp_path / "m.csv"
    assert main(["extract", str(tiff), "--pixel-size", "1", "--frame-rate", "1000", "--out", str(out)]) == 0
    assert "independent events" in capsys.readouterr().out


@pytest.mark.skipif(not REAL.is_dir(), reason="tests/data/real_frames/ is not there")
@pytest.mark.parametrize("recording", ["fmt-hdf5_fl_2018", "fmt-hdf5_mask-contour_2018", "fmt-hdf5_reference_2025",
                                       "fmt-hdf5_image-mask-blood_2021"])
def test_real_cytometer_exports_read_as_a_plain_tiff_are_events(recording):
    """dclab's recorded events (tests/data/real_frames/, GPL-2.0-or-later: 6-10 pages, cells and
    beads a few to hundreds of camera frames apart) as a TIFF with only a frame rate: events, no
    velocity, the frames not mirrored."""
    meta = json.loads((REAL / recording / "meta.json").read_text())
    found = extract(REAL / recording / "frames.tif", pixel_size=meta["pixel_size_um"], frame_rate=meta["frame_rate_hz"])
    assert found.channel.independent_events.startswith("independent events")
    assert found.channel.flow_direction == "right"
    assert found.capsules["v_c"].astype(float).isna().all()
    assert all(len(cap.frames) == 1 for cap in found.measurements)


def test_a_steady_film_keeps_its_track_and_its_velocity():
    """The same optics, one capsule crossing at 6 px a frame (6 mm/s at 1 um a pixel, 1000 frames/s):
    a film, one capsule over its frames, v_c within 0.5 %, L_z = 50 px drawn within 1 px, steady."""
    frames = film(80, -10.0, 6.0, (25.0, 22.0), Optics(noise=2.0), seed=4)
    found = _extract(frames)
    assert found.channel.independent_events == ""
    assert found.channel.flow_direction == "right"
    (row,) = found.capsules.to_dict("records")
    assert row["flag"] == "", row["reason"]
    assert row["frames"] >= 75
    assert row["v_c"] == pytest.approx(6.0, rel=0.005)
    assert row["L_z"] == pytest.approx(50.0, abs=1.0)


def test_a_film_running_the_other_way_is_still_a_film():
    """The steady film mirrored (flow in -x): recognised as a film, mirrored, measured."""
    frames = film(80, -10.0, 6.0, (25.0, 22.0), Optics(noise=2.0), seed=6)[:, :, ::-1]
    found = _extract(frames)
    assert found.channel.independent_events == ""
    assert found.channel.flow_direction == "left"
    assert found.capsules["v_c"].iloc[0] == pytest.approx(6.0, rel=0.005)


def test_a_capsule_still_growing_along_its_passage_is_flagged_not_steady():
    """L_z grows by 6 px (12 %) over its 80 frames, 0.075 px a frame: the trend stands far above the
    frames' scatter (about 0.1 px), and the capsule is not measured as a steady shape."""
    frames = film(80, -10.0, 6.0, (25.0, 22.0), Optics(noise=2.0), seed=4, growth_px=3.0)
    found = _extract(frames)
    (row,) = found.capsules.to_dict("records")
    assert row["flag"] == "not_steady"
    assert row["reason"].startswith("not steady: L_z changes by +")
    change = float(row["reason"].split("by ")[1].split(" px")[0])
    assert change == pytest.approx(6.0 * (found.measurements[0].good_frames[-1] - found.measurements[0].good_frames[0])
                                   / 79, rel=0.15)


def _extract(frames: np.ndarray):
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        tiff = Path(tmp) / "film.tif"
        tifffile.imwrite(tiff, frames)
        found = extract(tiff, pixel_size=1.0, frame_rate=RATE)
    assert not math.isnan(found.capsules["L_z"].iloc[0])
    return found
