""".rtdc files stream (issue 20): frames are read from the file a chunk of events at a time,
never events/image whole, so a file of gigabytes is measured in bounded memory.

The file tested has the layout of a real one: dclab's fmt-hdf5_mask-contour_2018 excerpt
(tests/data/rtdc/, GPL-2.0-or-later), its events/image copied with the original's chunks and
gzip filter, its real pages repeated to 600 events (12 MB of images, gzip-compressed on disk),
with its root attributes and a frame index 250 camera frames apart.
"""
from __future__ import annotations

import tracemalloc
from pathlib import Path

import h5py
import numpy as np
import pytest

from capsmech.imaging.frames import read_frames
from capsmech.imaging.rtdc import read_rtdc

SOURCE = Path(__file__).resolve().parents[1] / "data" / "rtdc" / "fmt-hdf5_mask-contour_2018.rtdc"
EVENTS = 600


@pytest.fixture(scope="module")
def large_rtdc(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("rtdc") / "large.rtdc"
    with h5py.File(SOURCE) as source, h5py.File(path, "w") as out:
        image = source["events/image"]
        pages = image[...]
        out.attrs.update(dict(source.attrs))
        big = out.create_dataset("events/image", shape=(EVENTS, *image.shape[1:]), dtype=image.dtype,
                                 chunks=image.chunks, compression=image.compression,
                                 compression_opts=image.compression_opts)
        for start in range(0, EVENTS, len(pages)):
            stop = min(EVENTS, start + len(pages))
            big[start:stop] = pages[:stop - start]
        out["events/frame"] = 250.0 * np.arange(EVENTS)
    return path


def test_pages_are_read_a_chunk_at_a_time(large_rtdc, monkeypatch):
    """Every read of events/image is one chunk of events (2 in this layout), never the whole
    dataset, and the pages are the file's own."""
    reads: list[int] = []
    original = h5py.Dataset.__getitem__

    def counting(dataset, key):
        out = original(dataset, key)
        if dataset.name == "/events/image" and Path(dataset.file.filename) == large_rtdc:
            reads.append(int(np.prod(np.shape(out)[:-2])) if np.ndim(out) == 3 else 1)
        return out

    monkeypatch.setattr(h5py.Dataset, "__getitem__", counting)
    stack = read_frames([large_rtdc])
    assert len(stack) == EVENTS
    with h5py.File(SOURCE) as source:
        pages = source["events/image"][...]
    for k in (0, 1, 5, 333, EVENTS - 1):
        assert np.array_equal(stack.frames[k], pages[k % len(pages)])
    chunk = 2
    assert reads and max(reads) <= chunk, max(reads)


def test_reading_every_page_keeps_memory_bounded(large_rtdc):
    """Walking through all 600 pages (12 MB of images) holds a few frames at a time: the peak
    of Python's allocations stays under 1 MB."""
    recording = read_rtdc(large_rtdc)
    image_bytes = int(np.prod(recording.frames.shape)) * recording.frames.dtype.itemsize
    tracemalloc.start()
    try:
        total = 0.0
        for frame in recording.frames:
            total += float(frame[40, 100])
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert image_bytes == 12_000_000
    assert peak < 1e6, peak
    assert total > 0


def test_mirrored_recording_stays_lazy(large_rtdc):
    """Flow in -x: the pages are mirrored as they are read, not copied mirrored up front."""
    right = read_frames([large_rtdc])
    left = read_frames([large_rtdc], flow_direction="left")
    assert type(left.frames) is type(right.frames) and not isinstance(left.frames, list)
    assert np.array_equal(left.frames[7], right.frames[7][:, ::-1])
