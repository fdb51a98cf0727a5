"""An .rtdc recording whose data live in another file is refused, naming the member: an HDF5
external link, a virtual dataset, or external raw storage would make the reader open whatever
file the recording's author named (an outside campaign's reproducer: an external link was followed)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from capsmech.errors import ExtractionError
from capsmech.imaging.rtdc import read_rtdc

FRAMES = (np.random.default_rng(3).integers(90, 110, size=(4, 40, 120))).astype(np.uint8)


def _other_file(tmp_path: Path) -> Path:
    other = tmp_path / "elsewhere.h5"
    with h5py.File(other, "w") as f:
        f["events/image"] = FRAMES
        f["data"] = FRAMES
    return other


def _recording(tmp_path: Path, how: str) -> Path:
    path = tmp_path / f"{how}.rtdc"
    other = _other_file(tmp_path)
    with h5py.File(path, "w") as f:
        events = f.create_group("events") if how != "external events group" else None
        if how == "plain":
            events["image"] = FRAMES
        elif how == "external link":
            events["image"] = h5py.ExternalLink(str(other), "/data")
        elif how == "external events group":
            f["events"] = h5py.ExternalLink(str(other), "/events")
        elif how == "virtual dataset":
            layout = h5py.VirtualLayout(shape=FRAMES.shape, dtype=FRAMES.dtype)
            layout[...] = h5py.VirtualSource(str(other), "data", shape=FRAMES.shape)
            events.create_virtual_dataset("image", layout)
        elif how == "external storage":
            raw = tmp_path / "raw.bin"
            raw.write_bytes(FRAMES.tobytes())
            events.create_dataset("image", shape=FRAMES.shape, dtype=FRAMES.dtype, external=[(str(raw), 0, FRAMES.nbytes)])
        if events is not None:
            events["frame"] = np.arange(len(FRAMES), dtype=float)
        f.attrs["imaging:pixel size"] = 0.34
    return path


def test_plain_recording_reads(tmp_path: Path) -> None:
    recording = read_rtdc(_recording(tmp_path, "plain"))
    assert len(recording.frames) == len(FRAMES)
    assert np.array_equal(np.asarray(recording.frames[1]), FRAMES[1])


@pytest.mark.parametrize("how,words", [("external link", "external link to"),
                                       ("external events group", "events is an external link"),
                                       ("virtual dataset", "virtual dataset"),
                                       ("external storage", "external files")])
def test_data_in_another_file_is_refused(tmp_path: Path, how: str, words: str) -> None:
    path = _recording(tmp_path, how)
    with pytest.raises(ExtractionError, match=words) as refused:
        read_rtdc(path)
    assert str(path) in str(refused.value)


def test_the_command_says_it_on_one_line(tmp_path: Path) -> None:
    path = _recording(tmp_path, "external link")
    result = subprocess.run([sys.executable, "-m", "capsmech.cli", "extract", str(path), "--out", str(tmp_path / "m.csv")],
                            capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "external link" in lines[0] and "Traceback" not in result.stderr
