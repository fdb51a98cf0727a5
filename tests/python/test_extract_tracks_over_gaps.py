"""A dropped frame does not split a track (issue 20): tracks remember a capsule over a few
missing camera frames, counted from the frames' times, and its velocity comes from the times.

- dclab's fmt-hdf5_reference_2025 recording (tests/data/real_frames/, GPL-2.0-or-later): a real
  RT-DC recording that keeps only some camera frames; its first two pages are 3 camera frames
  apart (two dropped) and show the same red cell, whose position the acquisition software
  measured itself (``pos_x`` of events 0 and 2 in meta.json);
- the film capsule_left_gap.mkv (written by the ffmpeg program, tests/data/video/), with more
  frames removed here;
- dclab's fmt-hdf5_fl_2018 (tests/data/rtdc/): events hundreds of camera frames apart are never
  linked.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from capsmech.imaging.extraction import (
    FrameStack,
    extract_stack,
    fit_velocity,
    measure_capsules,
    read_frame_times,
    read_frames,
)

DATA = Path(__file__).resolve().parents[1] / "data"
REFERENCE = DATA / "real_frames" / "fmt-hdf5_reference_2025"
MKV = DATA / "video" / "capsule_left_gap.mkv"


def trace_near(result, x: float):
    (trace,) = [t for t in result.traces if abs(t.centre[0] - x) < 15]
    return trace


def test_a_cell_three_camera_frames_on_keeps_its_track_and_its_speed_from_the_times():
    meta = json.loads((REFERENCE / "meta.json").read_text())
    stack = read_frames([REFERENCE / "frames.tif"])
    stack.times_s = read_frame_times(REFERENCE / "frame_times.csv", len(stack))
    channel, results = extract_stack(stack, frame_rate=meta["frame_rate_hz"])
    events = {e["event"]: e for e in meta["events"]}
    pixel = meta["pixel_size_um"]
    # The acquisition's own positions [um -> px] of the cell on pages 0 and 1 (events 0 and 2),
    # and of the cell entering behind it on page 1 (event 1).
    first, later, behind = (trace_near(results[events[k]["page"]], events[k]["pos_x"] / pixel) for k in (0, 2, 1))
    assert results[1].time_s - results[0].time_s == pytest.approx(3 / meta["frame_rate_hz"], rel=0.01)
    assert first.track == later.track                # two frames dropped: one cell, one track
    assert behind.track != first.track               # the cell behind it: a track of its own
    times = np.array([results[0].time_s, results[1].time_s])
    speed, _ = fit_velocity(times, np.array([first.centre[0], later.centre[0]]))
    reference = (events[2]["pos_x"] - events[0]["pos_x"]) / pixel / (times[1] - times[0])
    assert speed == pytest.approx(reference, rel=0.03)            # 15.4 mm/s
    # Over the page index (one frame interval a page) it would be three times too fast.
    by_index = (later.centre[0] - first.centre[0]) * meta["frame_rate_hz"]
    assert by_index / speed == pytest.approx(3.0, rel=0.01)


@pytest.mark.parametrize("removed", [[], [4], [4, 7, 8], [3, 13, 14, 15]])
def test_frames_removed_from_a_film_leave_one_capsule_at_its_speed(removed):
    """The film (10 px a frame in -x, 1000 frames/s, frames 10 and 11 dropped by its maker) with
    up to three frames in a row more removed: still one capsule, 10 px/ms from the times."""
    film = read_frames([MKV], flow_direction="left")
    times = film.frame_times()
    keep = [k for k in range(len(film)) if k not in removed]
    stack = FrameStack([film.frames[k] for k in keep], [film.labels[k] for k in keep], frame_rate=1000.0,
                       times_s=times[keep], flow_direction="left")
    _, results = extract_stack(stack)
    tracked = {t.track for r in results for t in r.traces if t.columns[0] < 240}    # the dirt: x > 250
    assert len(tracked) == 1
    (capsule,) = [c for c in measure_capsules(results, 1000.0) if c.ok]
    assert len(capsule.frames) == len(keep)
    assert capsule.v_c_px_s == pytest.approx(10_000.0, rel=0.003)


def test_a_gap_longer_than_the_memory_ends_the_track():
    """Five frames missing (more than TRACK_MEMORY_FRAMES = 3): two tracks."""
    film = read_frames([MKV], flow_direction="left")
    times = film.frame_times()
    keep = [k for k in range(len(film)) if not 3 <= k <= 7]        # 5 frames removed, 6 intervals
    stack = FrameStack([film.frames[k] for k in keep], [film.labels[k] for k in keep], frame_rate=1000.0,
                       times_s=times[keep], flow_direction="left")
    _, results = extract_stack(stack)
    assert len({t.track for r in results for t in r.traces if t.columns[0] < 240}) == 2


def test_events_far_apart_are_never_linked():
    """dclab's fmt-hdf5_fl_2018: 7 events, 5 to 234 camera frames apart: each object its own track."""
    stack = read_frames([DATA / "rtdc" / "fmt-hdf5_fl_2018.rtdc"])
    assert np.diff(stack.frame_numbers).min() > 4
    _, results = extract_stack(stack)
    traces = [t for r in results for t in r.traces]
    assert len(traces) >= 7 and len({t.track for t in traces}) == len(traces)
