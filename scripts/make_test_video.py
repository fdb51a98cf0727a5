#!/usr/bin/env python3
"""Write the test video tests/data/video/capsule_left_gap.mkv with the ffmpeg program.

A capsule (the tube database's NH profile, a/l 0.85, Ca_s 0.05) drawn over a real recorded
background (dclab's fmt-hdf5_reference_2025, tests/data/real_frames/: its walls, dirt and
illumination) moving 10 px a frame in -x (right to left, its rear facing +x), 20 frames at
1000 frames/s with frames 10 and 11 dropped (the frames after them are stamped 2 ms later):
FFV1, lossless 8-bit grey, in Matroska. capsmech reads videos with PyAV; this file is written
by the ffmpeg command-line program (by default the static build that the imageio-ffmpeg
wheel ships), so reader and writer are not the same code.

    .venv/bin/python scripts/make_test_video.py [--ffmpeg PATH]

The frames are :func:`frames` below (tests/python/test_video.py draws them again to compare).
"""
from __future__ import annotations

import argparse
import subprocess
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
OUT = REPO / "tests" / "data" / "video" / "capsule_left_gap.mkv"
BACKGROUND = REPO / "tests" / "data" / "real_frames" / "fmt-hdf5_reference_2025" / "background.png"
#: The recorded channel: inner wall lines at rows 6.02 and 74.35 (meta.json's survey).
AXIS_ROW, RADIUS_PX = 40.19, 34.16
N_FRAMES, DROPPED, STEP_PX, RATE = 20, (10, 11), 10.0, 1000.0


def outline() -> np.ndarray:
    """The capsule's outline (in l), its rear (the parachute) facing +x: it moves in -x."""
    from capsmech.imaging.rendering import outline_from_meridian
    from capsmech.io.catalog import database_path
    from capsmech.io.database import load_database

    rows = load_database(database_path("tube-paper")).law("NH").steady_rows()
    i = int(np.argmin(np.abs(rows["a_over_l"] - 0.85) + np.abs(rows["Ca_s"] - 0.05)))
    return outline_from_meridian(rows["profile_r"][i], rows["profile_z"][i]) * np.array([-1.0, 1.0])


def frames() -> tuple[np.ndarray, np.ndarray]:
    """The film's frames (kept ones only) and their frame numbers (gaps where frames were dropped)."""
    import imageio.v3 as iio

    from capsmech.imaging.rendering import FrameStyle, render_on_background

    background = iio.imread(BACKGROUND).astype(float)
    style = FrameStyle(tube_radius_px=RADIUS_PX, axis_row=AXIS_ROW)
    rng = np.random.default_rng(3)
    shape = outline()
    numbers = np.array([k for k in range(N_FRAMES) if k not in DROPPED])
    drawn = [render_on_background(background, [(shape, 280.0 - STEP_PX * k)], style, rng, noise=1.5) for k in numbers]
    return np.stack(drawn), numbers


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ffmpeg", help="the ffmpeg program (default: imageio-ffmpeg's)")
    options = parser.parse_args()
    ffmpeg = options.ffmpeg
    if ffmpeg is None:
        import imageio_ffmpeg

        ffmpeg = imageio_ffmpeg.get_ffmpeg_exe()
    film, numbers = frames()
    rows, cols = film.shape[1:]
    # Input frame n is stamped with its own frame number: the dropped frames leave a gap.
    skips = np.diff(numbers - np.arange(len(numbers)), prepend=0)
    stamps = "+".join(f"{int(skip)}*gte(N\\,{i})" for i, skip in enumerate(skips) if skip)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    subprocess.run([ffmpeg, "-y", "-hide_banner", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "gray",
                    "-s", f"{cols}x{rows}", "-r", f"{RATE:g}", "-i", "-",
                    "-vf", f"setpts=(N+{stamps or '0'})/({RATE:g}*TB)", "-fps_mode", "passthrough",
                    "-c:v", "ffv1", "-pix_fmt", "gray", "-an", str(OUT)], input=film.tobytes(), check=True)
    print(f"wrote {OUT} ({OUT.stat().st_size} bytes, frames {list(numbers)})")


if __name__ == "__main__":
    main()
