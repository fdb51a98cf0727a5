"""Videos read with PyAV (issue 20, item 5): frames, frame times from the container, and the
whole extraction on a film (tests/data/video/, see its README.md).

- ``capsule_left_gap.mkv``: written by the ffmpeg program (scripts/make_test_video.py, FFV1,
  lossless grey), not by the library that reads it: a capsule drawn over a real recorded channel,
  moving in -x at 10 px a frame, 1000 frames/s, frames 10 and 11 dropped (one capsule, one track);
- ``dclab_fl-image-bright_2017_imaq.avi``: a real uncompressed 8-bit AVI of an RT-DC instrument
  (dclab's test data, GPL-2.0-or-later), cut short in the middle of its 8th frame by its
  publishers; scripts/fetch_real_frames.py decoded its frames with its own AVI parser into
  tests/data/real_frames/fmt-tdms_fl-image-bright_2017/frames.tif.
"""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import tifffile

from capsmech.api import extract
from capsmech.imaging.frames import read_frames
from capsmech.imaging.rendering import drawn_lengths

REPO = Path(__file__).resolve().parents[2]
VIDEO = REPO / "tests" / "data" / "video"
MKV = VIDEO / "capsule_left_gap.mkv"
AVI = VIDEO / "dclab_fl-image-bright_2017_imaq.avi"


def film_script():
    spec = importlib.util.spec_from_file_location("make_test_video", REPO / "scripts" / "make_test_video.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_frames_and_times_come_from_the_container():
    script = film_script()
    drawn, numbers = script.frames()
    stack = read_frames([MKV])
    assert len(stack) == len(drawn) == 18
    assert all(np.array_equal(a, b) for a, b in zip(stack.frames, drawn))          # lossless: bit for bit
    assert stack.frame_rate == pytest.approx(1000.0)
    # The two dropped frames leave a gap of 3 ms between frames 9 and 10 (presentation times).
    assert stack.frame_numbers == pytest.approx(numbers)
    assert stack.frame_times() == pytest.approx(numbers / 1000.0)


def test_film_measured_with_its_gap_and_direction_found():
    script = film_script()
    # As seen once the frames are mirrored (flow in +x): the outline mirrored back.
    L_z, L_p = (length * script.RADIUS_PX for length in drawn_lengths(script.outline() * np.array([-1.0, 1.0])))
    found = extract(MKV, pixel_size=0.2675)
    assert found.channel.flow_direction == "left" and "from the motion" in found.channel.flow_check
    measured = found.capsules[found.capsules["flag"] == ""]
    # Two dropped frames do not split the capsule (the tracks remember it over the gap): one
    # capsule, one row, over all 18 frames of the film.
    assert len(measured) == 1
    (row,) = [row for _, row in measured.iterrows()]
    assert row["frames"] == row["good_frames"] == 18
    assert row["L_z"] / 0.2675 == pytest.approx(L_z, abs=0.5)
    assert row["L_p"] / 0.2675 == pytest.approx(L_p, abs=0.5)
    # 10 px a frame at 1000 frames/s: 2.675 mm/s over the container's times; over the frame
    # index (the gap ignored) the same positions would give 3.12 mm/s.
    assert row["v_c"] == pytest.approx(2.675, rel=0.005)
    assert all(track == 0 for track in found.frames["passage"])


def test_real_avi_cut_short_keeps_its_complete_frames():
    stack = read_frames([AVI])
    pages = tifffile.imread(REPO / "tests" / "data" / "real_frames" / "fmt-tdms_fl-image-bright_2017" / "frames.tif")
    assert len(stack) == len(pages) == 7
    assert all(np.array_equal(a, b) for a, b in zip(stack.frames, pages))
    assert stack.notes and "1 damaged frame(s) left out" in stack.notes[0]
    # The AVI's header says 30 frames/s (the instrument's placeholder); a rate given by the
    # user scales the container's frame numbers.
    assert stack.frame_rate == pytest.approx(30.0)
    assert stack.frame_times(2000.0) == pytest.approx(np.arange(7) / 2000.0)


def test_not_a_video_is_refused_naming_the_file(tmp_path):
    from capsmech.imaging.frames import ExtractionError

    bad = tmp_path / "film.mp4"
    bad.write_bytes(b"\x00" * 1000)
    with pytest.raises(ExtractionError, match="film.mp4"):
        read_frames([bad])
