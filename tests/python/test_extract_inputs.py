"""``capsmech extract`` refuses bad inputs before any work (issue 25, item 4): one
``capsmech: error:`` line naming the option or file, exit 2, no traceback, nothing written.

Each case runs the command as a user would (a subprocess) on the shipped rendered film
(data/examples/frames/capsule_NH.tif).
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
FILM = REPO / "data" / "examples" / "frames" / "capsule_NH.tif"


def run_extract(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "capsmech.cli", "extract", *args], capture_output=True, text=True,
                          timeout=300)


def assert_refused(run: subprocess.CompletedProcess, *names: str) -> None:
    assert run.returncode == 2, (run.returncode, run.stderr)
    assert "Traceback" not in run.stderr
    errors = [line for line in run.stderr.splitlines() if line.startswith("capsmech: error:")]
    assert len(errors) == 1, run.stderr
    for name in names:
        assert name in errors[0], errors[0]


def test_out_is_a_directory(tmp_path):
    folder = tmp_path / "results"
    folder.mkdir()
    assert_refused(run_extract(str(FILM), "--out", str(folder)), "--out", str(folder), "is a directory")
    assert list(tmp_path.iterdir()) == [folder] and not list(folder.iterdir())      # no .tmp, contours, frames


def test_overlay_is_an_existing_file(tmp_path):
    existing = tmp_path / "overlay.png"
    existing.write_bytes(b"not a folder")
    out = tmp_path / "m.csv"
    assert_refused(run_extract(str(FILM), "--out", str(out), "--overlay", str(existing)), "--overlay", str(existing))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["overlay.png"]           # the CSV not written


def test_tiff_cut_to_half_is_unreadable(tmp_path):
    half = tmp_path / "half.tif"
    data = FILM.read_bytes()
    half.write_bytes(data[: len(data) // 2])
    run = run_extract(str(half), "--out", str(tmp_path / "m.csv"))
    assert_refused(run, str(half), "unreadable")
    assert not (tmp_path / "m_frames.csv").exists()


@pytest.mark.parametrize("option,value", [("--min-frames", "-3"), ("--min-frames", "0"), ("--max-asymmetry", "nan"),
                                          ("--max-asymmetry", "-0.1"), ("--max-line-width", "-1"),
                                          ("--max-line-width", "inf")])
def test_meaningless_thresholds(tmp_path, option, value):
    assert_refused(run_extract(str(FILM), "--out", str(tmp_path / "m.csv"), f"{option}={value}"), option)
    assert not list(tmp_path.iterdir())
