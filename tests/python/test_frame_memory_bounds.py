"""Frames too large or too many for memory are refused before they are decoded.

The outside campaign's reproducer: a 4 MB compressed TIFF of 60 frames of 8000x8000 px grew to
4.2 GB of memory with no output. Its pages are checked from the file's header now."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tifffile

from capsmech.errors import ExtractionError
from capsmech.imaging import frames as frames_module
from capsmech.imaging.frames import MAX_FRAME_PIXELS, MAX_STACK_PIXELS, read_frames


def _bomb(path: Path, pages: int, rows: int, columns: int) -> Path:
    """A zlib-compressed TIFF of blank pages: megabytes on disk, gigabytes decoded."""
    page = np.zeros((rows, columns), dtype=np.uint8)
    with tifffile.TiffWriter(path) as tif:          # one series of `pages` pages, written page by page
        tif.write((page for _ in range(pages)), shape=(pages, rows, columns), dtype=np.uint8, compression="zlib")
    return path


def test_a_compressed_stack_of_huge_frames_is_refused_without_decoding(tmp_path: Path) -> None:
    path = _bomb(tmp_path / "bomb.tif", 60, 4000, 4500)           # the reproducer's 60 frames were 8000x8000
    assert path.stat().st_size < 20 * 2**20
    assert 60 * 4000 * 4500 > MAX_STACK_PIXELS
    result = subprocess.run(["/usr/bin/time", "-f", "%M", sys.executable, "-m", "capsmech.cli", "extract", str(path),
                             "--pixel-size", "0.5um", "--frame-rate", "1000", "--out", str(tmp_path / "m.csv")], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert lines[0].startswith("capsmech: error: ") and "more than one extraction holds" in lines[0], result.stderr
    assert int(lines[-1]) < 1_000_000          # peak RSS [kB]: nothing decoded (4 GB before)


def test_a_frame_larger_than_any_camera_is_refused(tmp_path: Path) -> None:
    side = int(MAX_FRAME_PIXELS**0.5) + 8
    path = _bomb(tmp_path / "wide.tif", 1, side, side)
    with pytest.raises(ExtractionError, match="larger than any camera"):
        read_frames([path])


def test_the_limit_counts_the_whole_stack_over_files(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Files read one by one add up: the file that brings the stack past the limit is named."""
    monkeypatch.setattr(frames_module, "MAX_STACK_PIXELS", 3 * 64 * 64)
    paths = []
    for k in range(4):
        paths.append(tmp_path / f"f{k}.tif")
        tifffile.imwrite(paths[-1], np.full((64, 64), 100, dtype=np.uint8))
    assert len(read_frames(paths[:3])) == 3
    with pytest.raises(ExtractionError, match=r"f3\.tif: 1 frames of 64x64 px bring the stack to 16,384 pixels"):
        read_frames(paths)
