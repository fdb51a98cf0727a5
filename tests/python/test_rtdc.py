"""``.rtdc`` recordings read directly (issue 20, item 5): frames, calibration, times, background
and the acquisition's reference masks / contours, on excerpts of dclab's real test files
(tests/data/rtdc/, GPL-2.0-or-later, see its README.md).

The same recordings were converted to TIFF by scripts/fetch_real_frames.py (its own h5py code,
tests/data/real_frames/): the frames and times read here are checked against those, and the
traced objects against the file's own masks.
"""
from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tifffile

from capsmech.api import extract
from capsmech.imaging.frames import read_frames
from capsmech.imaging.rtdc import read_rtdc, read_rtdc_reference

DATA = Path(__file__).resolve().parents[1] / "data"
RTDC = DATA / "rtdc"
REAL = DATA / "real_frames"


def frame_times_csv(name: str) -> dict[int, float]:
    with open(REAL / name / "frame_times.csv", newline="") as handle:
        return {int(row["frame"]): float(row["time_s"]) for row in csv.DictReader(handle)}


@pytest.mark.parametrize("name,pixel,rate", [("fmt-hdf5_fl_2018", 0.34, 1600.0),
                                             ("fmt-hdf5_mask-contour_2018", 0.34, 4000.0),
                                             ("fmt-hdf5_raw-cytoshot-exported", 0.2645, 3412.259457345452)])
def test_frames_calibration_and_times_are_the_files(name, pixel, rate):
    stack = read_frames([RTDC / f"{name}.rtdc"])
    pages = tifffile.imread(REAL / name / "frames.tif")
    assert len(stack) == min(len(pages), len(read_rtdc(RTDC / f"{name}.rtdc").frames))
    for frame, page in zip(stack.frames, pages):
        assert np.array_equal(frame, page)
    assert stack.pixel_size_um == pytest.approx(pixel, rel=1e-6)
    assert stack.frame_rate == pytest.approx(rate, rel=1e-9)
    assert stack.channel_width_um == 20.0
    # Times: events/time where the file has it, else the camera frame / frame rate; the gaps
    # (hundreds of camera frames between events) are kept.
    expected = frame_times_csv(name)
    times = stack.frame_times()
    assert stack.frame_numbers is not None
    assert times == pytest.approx([expected[int(n)] for n in stack.frame_numbers], abs=2e-6)
    assert np.all(np.diff(stack.frame_numbers) > 1)


def test_zstd_compressed_file_needs_and_gets_hdf5plugin():
    import h5py

    with h5py.File(RTDC / "fmt-hdf5_raw-cytoshot-exported.rtdc") as handle:
        assert "32015" in handle["events/image"]._filters     # zstd: not one of h5py's own filters
    assert read_rtdc(RTDC / "fmt-hdf5_raw-cytoshot-exported.rtdc").frames.shape == (4, 80, 320)


def test_background_from_events_image_bg():
    path = RTDC / "fmt-hdf5_image-bg_2020.rtdc"
    recording = read_rtdc(path)
    import h5py

    with h5py.File(path) as handle:
        image_bg = handle["events/image_bg"][...]
    assert recording.background is not None
    assert np.array_equal(recording.background, np.median(image_bg, axis=0).astype(np.float32))
    # No walls in view: given as the image's edges, the file's background is the one used.
    found = extract(path, walls="0,79")
    assert "events/image_bg" in found.channel.background_source
    assert found.pixel_size_um == pytest.approx(0.34) and found.frame_rate == 2000.0
    assert list(found.frames["time_s"]) == pytest.approx(list(recording.times_s), abs=1e-7)


@pytest.mark.parametrize("name", ["fmt-hdf5_fl_2018", "fmt-hdf5_mask-contour_2018"])
def test_traced_extent_matches_the_files_masks(name):
    """Extracted straight from the .rtdc: the traced object's extent along the flow within
    max(line width, 2 px) of the file's own mask in at least 80 % of the single-object frames;
    the reference contour (events/contour, where given) spans the mask's columns."""
    path = RTDC / f"{name}.rtdc"
    found = extract(path)
    reference = read_rtdc_reference(path)
    assert reference.masks is not None
    cols = reference.masks.shape[2]
    checked = within = 0
    for event, mask in enumerate(reference.masks):
        columns = np.nonzero(mask.any(axis=0))[0]
        if columns.min() <= 0 or columns.max() >= cols - 1:
            continue
        if reference.contours is not None:
            xs = reference.contours[event][:, 0]
            assert xs.min() == columns.min() and xs.max() == columns.max()
        result = found.results[reference.event_page[event]]
        centre, extent = (columns.min() + columns.max()) / 2, columns.max() - columns.min() + 1
        near = [t for t in result.traces if abs((t.outer[:, 0].min() + t.outer[:, 0].max()) / 2 - centre) < extent / 2]
        checked += 1
        if near:
            trace = near[0]
            tolerance = max(trace.line_width_px if np.isfinite(trace.line_width_px) else 0.0, 2.0)
            within += abs(trace.outer_extent_px - extent) <= tolerance
    assert checked >= 5 and within >= 0.8 * checked, (within, checked)
    assert found.pixel_size_um == pytest.approx(0.34, rel=1e-6)
    # Every frame's time is the file's (each event hundreds of camera frames after the last).
    stack = read_frames([path])
    assert list(found.frames["time_s"]) == pytest.approx(list(stack.frame_times()), abs=1e-7)


def test_command_line_reads_an_rtdc_file(tmp_path):
    path = RTDC / "fmt-hdf5_fl_2018.rtdc"
    out = tmp_path / "m.csv"
    run = subprocess.run([sys.executable, "-m", "capsmech.cli", "extract", str(path), "--out", str(out)],
                         capture_output=True, text=True, timeout=120)
    assert "Traceback" not in run.stderr
    # Seven separate events (hundreds of camera frames apart): no capsule is followed over three
    # frames, so nothing is measured (exit 1), and the per-frame report says so frame by frame.
    assert run.returncode == 1, run.stderr
    assert "pixel 0.34 um, 1600 frames/s" in run.stdout
    assert "flow direction right: assumed" in run.stdout
    with open(tmp_path / "m_frames.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    frames = read_rtdc(path).frame_numbers
    assert [float(r["time [s]"]) for r in rows] == pytest.approx(list(frames / 1600.0))
    assert sum(1 for r in rows if r["traced objects"]) == 7
