"""The stack background on short films whose objects sit or follow one another (issue 20):
robust where a pixel is free in some frames, and said untrustworthy - its objects flagged, not
measured - where no frame shows it free.

Real frames: dclab's fmt-hdf5_reference_2025 recording (tests/data/real_frames/,
GPL-2.0-or-later), reordered into short films; its acquisition's own background
(background.png, events/image_bg) and reference masks (masks.npz) are the truths.
"""
from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile

from capsmech.imaging.extraction import UNTRUSTED_FLAG, FrameStack, extract_stack

REFERENCE = Path(__file__).resolve().parents[1] / "data" / "real_frames" / "fmt-hdf5_reference_2025"
#: Rows between the channel's inner wall lines (6.0 and 74.4), clear of them.
CHANNEL = slice(10, 70)


@pytest.fixture(scope="module")
def recording():
    pages = tifffile.imread(REFERENCE / "frames.tif")
    background = iio.imread(REFERENCE / "background.png").astype(np.float32)
    masks = np.load(REFERENCE / "masks.npz")
    extents = {}
    for mask, page in zip(masks["masks"], masks["page"]):
        columns = np.nonzero(mask.any(axis=0))[0]
        extents.setdefault(int(page), []).append((int(columns.min()), int(columns.max())))
    return pages, background, extents


def film(pages, order, background=None):
    stack = FrameStack([pages[k] for k in order], [f"page{k}" for k in order], frame_rate=3443.66)
    return extract_stack(stack, background=background)


def reference_extent(extents, page: int, x: float) -> int:
    (first, last), = [(a, b) for a, b in extents[page] if a <= x <= b]
    return last - first + 1


def test_a_cell_sitting_in_most_frames_is_left_out_of_the_background(recording):
    """Page 2's red cell in 4 of 6 frames: the plain temporal median keeps it (84 grey levels
    off the acquisition's background); the background from the frames where it is not there
    matches the acquisition's, and the cell is traced to its mask's extent in every frame."""
    pages, truth, extents = recording
    order = [2, 2, 2, 2, 0, 4]
    plain = np.median(pages[order].astype(np.float32), axis=0)
    assert np.abs(plain - truth)[CHANNEL].max() > 50
    channel, results = film(pages, order)
    assert channel.background_source == "temporal median" and channel.background_check == ""
    difference = np.abs(channel.background - truth)[CHANNEL]
    assert np.median(difference) < 3 and difference.max() < 12          # 8-bit grey, noise ~2
    for r in results[:4]:
        (trace,) = r.traces
        extent = reference_extent(extents, 2, trace.centre[0])
        assert abs(trace.outer_extent_px - extent) <= 2, (trace.outer_extent_px, extent)


def test_where_no_frame_is_free_the_objects_are_flagged_not_measured(recording):
    """Pages 1, 2 and 5 show red cells over the same columns (116-168): in a film of just those
    no frame shows the spot free. The background there cannot be trusted; every object over it
    carries the flag, and the cell elsewhere (page 1, columns 261-311) is measured to its mask.
    Given the acquisition's background, the same objects are traced to their masks."""
    pages, truth, extents = recording
    order = [1, 2, 5, 2, 1, 5]
    channel, results = film(pages, order)
    assert "background not trusted" in channel.background_check
    spot = [t for r in results for t in r.traces if 116 <= t.centre[0] <= 168]
    assert len(spot) == 6 and all(t.flag == UNTRUSTED_FLAG for t in spot)
    assert results[1].flag == UNTRUSTED_FLAG and results[3].flag == UNTRUSTED_FLAG
    elsewhere = [t for r in results for t in r.traces if t.centre[0] > 250]
    assert len(elsewhere) == 2 and all(t.flag != UNTRUSTED_FLAG for t in elsewhere)
    assert all(abs(t.outer_extent_px - reference_extent(extents, 1, t.centre[0])) <= 2 for t in elsewhere)
    channel, results = film(pages, order, background=truth)
    assert channel.background_check == "" and channel.background_source == "given"
    for r, page in zip(results, order):
        for t in r.traces:
            if 116 <= t.centre[0] <= 168:
                assert t.flag != UNTRUSTED_FLAG
                assert abs(t.outer_extent_px - reference_extent(extents, page, t.centre[0])) <= 2
