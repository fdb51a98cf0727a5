"""Reading video files (AVI, MP4, MKV, MOV, ...) with PyAV, FFmpeg's Python binding.

PyAV (``av``, pinned in requirements.txt) decodes whatever FFmpeg decodes and gives each frame's
presentation time from the container, so that a film with dropped or skipped frames keeps its
gaps; imageio's own video plugin is a wrapper around the same library, so PyAV is used directly.

Grey is taken as it was recorded: the luma plane of YUV video, the grey of 8- and 16-bit grey
formats, and for palette (many uncompressed AVIs) or RGB frames the common value when the three
channels agree, else their luminance. A packet the demuxer marks corrupt (a file cut off in the
middle of a frame) is dropped and counted, not decoded into a half-black frame.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capsmech.errors import ExtractionError

#: File name endings read as video.
VIDEO_SUFFIXES = {".avi", ".mp4", ".m4v", ".mov", ".mkv", ".webm", ".mpg", ".mpeg", ".wmv", ".ogv"}


@dataclass
class Video:
    """The frames of a video file and their times.

    Attributes
    ----------
    frames : list of 2-D arrays
        Grey frames (uint8, or uint16 for 16-bit grey video).
    frame_numbers : array
        Each frame's presentation time in units of the nominal frame interval (0, 1, 2, ... for
        a film without gaps; a skipped frame leaves a step of 2).
    frame_rate : float or None
        The stream's nominal frame rate (its average rate, else 1 / time base).
    dropped : int
        Corrupt (truncated) packets that were left out.
    """

    frames: list[np.ndarray]
    frame_numbers: np.ndarray
    frame_rate: float | None
    dropped: int = 0


def _grey(frame) -> np.ndarray:
    """A decoded PyAV frame as a 2-D grey array."""
    name = frame.format.name
    if name.startswith(("yuv", "yuvj", "nv12", "nv21", "gray")) and not name.startswith("gray16"):
        return frame.to_ndarray(format="gray")
    if name.startswith("gray16"):
        return frame.to_ndarray(format="gray16le")
    rgb = frame.to_ndarray(format="rgb24")
    if np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 0], rgb[..., 2]):
        return np.ascontiguousarray(rgb[..., 0])
    from skimage.color import rgb2gray

    return (255.0 * rgb2gray(rgb)).astype(np.float32)


def read_video(path: str | Path) -> Video:
    """Decode every frame of a video file's first video stream, with its time.

    Raises
    ------
    ExtractionError
        Naming the file: not a container FFmpeg reads, no video stream, or no decodable frame.
    """
    import av

    path = Path(path)
    try:
        container = av.open(str(path))
    except (av.FFmpegError, OSError, ValueError) as err:
        raise ExtractionError(f"{path}: cannot read as a video: {err}") from None
    frames: list[np.ndarray] = []
    times: list[float] = []
    dropped = 0
    with container:
        if not container.streams.video:
            raise ExtractionError(f"{path}: the file has no video stream")
        stream = container.streams.video[0]
        rate = float(stream.average_rate) if stream.average_rate else None
        if not rate and stream.time_base:
            rate = 1.0 / float(stream.time_base)
        try:
            for packet in container.demux(stream):
                if packet.is_corrupt:
                    dropped += 1
                    continue
                for frame in packet.decode():
                    frames.append(_grey(frame))
                    times.append(float(frame.time) if frame.time is not None else float(len(times)) / (rate or 1.0))
        except av.FFmpegError as err:
            if not frames:
                raise ExtractionError(f"{path}: cannot decode the video: {err}") from None
            dropped += 1
    if not frames:
        raise ExtractionError(f"{path}: no frame could be decoded")
    t = np.asarray(times)
    numbers = (t - t[0]) * rate if rate else np.arange(len(frames), dtype=float)
    return Video(frames, numbers, rate, dropped)
