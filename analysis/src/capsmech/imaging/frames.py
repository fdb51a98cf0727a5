"""Reading frames: image files and stacks into one grey stack, with their calibration and times.

What the files say is kept: the pixel size and frame interval of an ImageJ TIFF, and the time of
each frame when a ``--frame-times`` CSV gives it (real recordings skip frames: a stack of events
hundreds of camera frames apart is not a film at the nominal rate, and a velocity from the frame
index would mean nothing).
"""
from __future__ import annotations

import csv
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np

from capsmech.errors import ExtractionError

#: Most pixels (frames x rows x columns) read into memory from files that are decoded whole: 2^30,
#: 1 GB of 8-bit pages and 4 GB as float32 (a 480x160 film of 10,000 frames is 0.77e9). An
#: .rtdc recording streams page by page and has no such limit.
MAX_STACK_PIXELS = 2**30
#: Largest frame [pixels]: 2^25, 5792 x 5792, beyond the largest microscope cameras' 5120 x 5120.
MAX_FRAME_PIXELS = 2**25


def check_pixel_count(path: Path, frames: int, shape: tuple[int, ...], already: int = 0) -> None:
    """Refuse, before decoding, frames too large or too many to hold in memory."""
    frame_pixels = int(np.prod(shape[:2], dtype=np.int64))
    if frame_pixels > MAX_FRAME_PIXELS:
        raise ExtractionError(f"{path}: frames of {shape[1]}x{shape[0]} px are larger than any camera's "
                              f"({MAX_FRAME_PIXELS:,} pixels at most); crop them")
    total = already + frames * frame_pixels
    if total > MAX_STACK_PIXELS:
        raise ExtractionError(f"{path}: {frames} frames of {shape[1]}x{shape[0]} px bring the stack to {total:,} pixels, "
                              f"more than one extraction holds ({MAX_STACK_PIXELS:,}); split or crop the stack")


@dataclass
class FrameStack:
    """Grey frames and what their files say about them.

    Attributes
    ----------
    frames : sequence of 2-D arrays
        One grey image per frame (original dtype for grey files, float32 for colour ones): a
        list, or for a single ``.rtdc`` file a sequence that reads each frame from the file when
        it is asked for (``rtdc.RtdcFrames``: bounded memory).
    labels : list of str
        ``file`` or ``file[page]`` for each frame, for messages and reports.
    frame_rate : float or None
        Frames per second from the files' metadata (ImageJ ``finterval`` or ``fps``).
    pixel_size_um : float or None
        Pixel size from the metadata (ImageJ TIFF resolution with a micron unit).
    times_s : array or None
        Time of each frame [s] when known (a frame-times file, an .rtdc's ``events/time``);
        None: frame number / frame rate.
    frame_numbers : array or None
        Each frame's number in frame intervals when the file says it (a video's presentation
        times, an .rtdc's camera frame index): gaps are kept, and a frame rate given by the
        user still scales them. None: 0, 1, 2, ...
    background : 2-D array or None
        The empty channel as the file gives it (an .rtdc's ``events/image_bg``), as read.
    background_source : str
        Where ``background`` comes from, in words.
    channel_width_um : float or None
        The channel's nominal width from the metadata (an .rtdc's ``setup:channel width``).
    notes : list of str
        What the readers had to do that the user should know (frames dropped, ...).
    flow_direction : {'right', 'left', 'auto'}
        As asked of :func:`read_frames` ('left': the frames are mirrored; 'auto': found from the
        motion by ``extraction.extract_stack``, which mirrors them when they move in -x).
    """

    frames: Sequence[np.ndarray]
    labels: list[str]
    frame_rate: float | None = None
    pixel_size_um: float | None = None
    times_s: np.ndarray | None = None
    frame_numbers: np.ndarray | None = None
    background: np.ndarray | None = None
    background_source: str = ""
    channel_width_um: float | None = None
    notes: list[str] = field(default_factory=list)
    flow_direction: str = "right"

    def frame_times(self, frame_rate: float | None = None) -> np.ndarray:
        """Time of each frame [s]: the stack's own times, else frame number / frame rate."""
        if self.times_s is not None:
            return np.asarray(self.times_s, dtype=float)
        rate = frame_rate or self.frame_rate
        if not rate:
            raise ExtractionError("frame_rate: required (the files carry no frame interval)")
        numbers = self.frame_numbers if self.frame_numbers is not None else np.arange(len(self.frames))
        return np.asarray(numbers, dtype=float) / rate

    def __len__(self) -> int:
        return len(self.frames)


_IMAGE_SUFFIXES = {".tif", ".tiff", ".png", ".jpg", ".jpeg", ".bmp", ".gif"}
#: Recordings read by their own readers (``rtdc``, ``video``); a folder lists images only.
_RTDC_SUFFIXES = {".rtdc"}


def _natural_key(path: Path) -> list[object]:
    """Sort key in which frame_2 comes before frame_10."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", str(path))]


def expand_frame_paths(paths: Sequence[str | Path]) -> list[Path]:
    """Files named on the command line: glob patterns expanded, directories listed, in order.

    Raises
    ------
    ExtractionError
        When a name matches nothing or a directory holds no image.
    """
    out: list[Path] = []
    for name in paths:
        path = Path(name)
        if path.is_dir():
            files = sorted((p for p in path.iterdir() if p.suffix.lower() in _IMAGE_SUFFIXES), key=_natural_key)
            if not files:
                raise ExtractionError(f"{path}: directory holds no image file ({', '.join(sorted(_IMAGE_SUFFIXES))})")
            out += files
        elif path.exists():
            out.append(path)
        elif any(ch in str(name) for ch in "*?["):
            matches = sorted(Path().glob(str(name)) if not path.is_absolute() else
                             Path(path.anchor).glob(str(path.relative_to(path.anchor))), key=_natural_key)
            if not matches:
                raise ExtractionError(f"{name}: no file matches this pattern")
            out += matches
        else:
            raise ExtractionError(f"{path}: no such file")
    return out


def _to_grey(image: np.ndarray, label: str) -> np.ndarray:
    """A 2-D grey image from grey, RGB or RGBA data."""
    from skimage.color import rgb2gray, rgba2rgb

    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[-1] == 4:
        return rgb2gray(rgba2rgb(image)).astype(np.float32)
    if image.ndim == 3 and image.shape[-1] == 3:
        return rgb2gray(image).astype(np.float32)
    raise ExtractionError(f"{label}: an image of shape {image.shape} is neither grey (rows, columns) nor RGB")


class _TiffComplaints:
    """Collect what tifffile logs while it reads (it logs a damaged file instead of raising)."""

    def __init__(self) -> None:
        import logging

        self.messages: list[str] = []
        self.handler = logging.Handler(logging.WARNING)
        self.handler.emit = lambda record: self.messages.append(record.getMessage())  # type: ignore[method-assign]
        self.logger = logging.getLogger("tifffile")

    def __enter__(self) -> _TiffComplaints:
        self.propagate, self.logger.propagate = self.logger.propagate, False
        self.logger.addHandler(self.handler)
        return self

    def __exit__(self, *exc: object) -> None:
        self.logger.removeHandler(self.handler)
        self.logger.propagate = self.propagate


def _tiff_frames(path: Path, already: int = 0) -> tuple[list[np.ndarray], float | None, float | None]:
    """Frames of a (multi-page) TIFF, and the frame rate and pixel size [um] of its metadata.

    A damaged file (cut short: pages missing, or fewer than its ImageJ metadata announce) is
    refused rather than read as the pages that are left.
    """
    import tifffile

    with _TiffComplaints() as complaints, tifffile.TiffFile(path) as tif:
        series = tif.series[0]
        axes = series.axes
        image_shape = tuple(int(n) for n, axis in zip(series.shape, axes) if axis in "YX")
        if len(image_shape) == 2:
            pages = int(np.prod([n for n, axis in zip(series.shape, axes) if axis not in "YXS"], dtype=np.int64))
            check_pixel_count(path, pages, image_shape, already)
        data = series.asarray()
        frame_rate = pixel_um = None
        meta = tif.imagej_metadata or {}
        announced = int(meta.get("images", 0) or 0)
        if meta.get("finterval"):
            frame_rate = 1.0 / float(meta["finterval"])
        elif meta.get("fps"):
            frame_rate = float(meta["fps"])
        unit = str(meta.get("unit", "")).lower()
        x_resolution = tif.pages.first.tags.get("XResolution")
        if x_resolution is not None and unit in ("um", "micron", "µm", "\\u00b5m"):
            num, den = x_resolution.value
            if num > 0 and den > 0:
                pixel_um = den / num
    damage = [m for m in complaints.messages if any(w in m.lower() for w in ("invalid", "corrupt", "truncat"))]
    if damage:
        raise ExtractionError(f"{path}: unreadable TIFF (damaged or cut short: {damage[0].split('> ')[-1]})")
    colour = "S" in axes
    # Every axis other than the image's own (Y, X, and the colour samples S) counts frames.
    frame_shape = data.shape[-3:] if colour else data.shape[-2:]
    data = data.reshape((-1, *frame_shape))
    if announced > data.shape[0]:
        raise ExtractionError(f"{path}: unreadable TIFF (its metadata announce {announced} images, "
                              f"{data.shape[0]} are in the file: cut short?)")
    return [_to_grey(frame, str(path)) for frame in data], frame_rate, pixel_um


def _read_file(path: Path, stack: FrameStack, mirror: bool,
               already: int = 0) -> tuple[Sequence[np.ndarray], np.ndarray | None, np.ndarray | None]:
    """One file's frames, its frame numbers and times when it has them; its metadata into ``stack``
    (``already``: the pixels the stack holds before this file, for :func:`check_pixel_count`).

    An ``.rtdc`` file's frames come as a lazy sequence, mirrored already when ``mirror``; the
    other files' as a list, as read.
    """
    import imageio.v3 as iio

    suffix = path.suffix.lower()
    if suffix in _RTDC_SUFFIXES:
        from capsmech.imaging.rtdc import read_rtdc

        rec = read_rtdc(path, mirror)
        stack.frame_rate = stack.frame_rate or rec.frame_rate
        stack.pixel_size_um = stack.pixel_size_um or rec.pixel_size_um
        stack.channel_width_um = stack.channel_width_um or rec.channel_width_um
        if rec.background is not None and stack.background is None:
            stack.background, stack.background_source = rec.background, f"{path.name}: events/image_bg (median)"
        return rec.frames, rec.frame_numbers, rec.times_s
    from capsmech.imaging.video import VIDEO_SUFFIXES, read_video

    if suffix in VIDEO_SUFFIXES:
        video = read_video(path)
        stack.frame_rate = stack.frame_rate or video.frame_rate
        if video.dropped:
            stack.notes.append(f"{path}: {video.dropped} damaged frame(s) left out (file cut short?)")
        return video.frames, video.frame_numbers, None
    if suffix in (".tif", ".tiff"):
        frames, rate, pixel = _tiff_frames(path, already)
        stack.frame_rate = stack.frame_rate or rate
        stack.pixel_size_um = stack.pixel_size_um or pixel
        return frames, None, None
    image = iio.imread(path)
    if image.ndim == 3 and image.shape[-1] not in (3, 4):
        return [_to_grey(f, str(path)) for f in image], None, None   # an animated format: one image per page
    return [_to_grey(image, str(path))], None, None


def _check_size(frame: np.ndarray, path: Path, page: int, stack: FrameStack | None) -> None:
    """Refuse a frame of another size than the stack's first, or too small to hold a channel."""
    if stack is not None and stack.frames and frame.shape != stack.frames[0].shape:
        raise ExtractionError(f"{path}: frame {page} is {frame.shape[1]}x{frame.shape[0]} px, "
                              f"the first frame ({stack.labels[0]}) is "
                              f"{stack.frames[0].shape[1]}x{stack.frames[0].shape[0]} px")
    if frame.shape[0] < 16 or frame.shape[1] < 16:
        raise ExtractionError(f"{path}: frame {page} is only {frame.shape[1]}x{frame.shape[0]} px")


def read_frames(paths: Sequence[str | Path], flow_direction: str = "right",
                progress: Callable[[str], None] | None = None) -> FrameStack:
    """Read recordings into one grey stack: image files (multi-page TIFF, PNG, ... 8 or 16 bit,
    grey or colour), ``.rtdc`` files (:mod:`capsmech.imaging.rtdc`) and videos
    (:mod:`capsmech.imaging.video`).

    Parameters
    ----------
    paths : sequence of str or Path
        Files, directories or glob patterns (see :func:`expand_frame_paths`), in frame order.
    flow_direction : {'right', 'left', 'auto'}
        'left' mirrors every frame so that the flow goes in +x; 'auto' reads them as they are
        (the direction is found from the motion later: ``extraction.extract_stack``).
    progress : callable, optional
        Called with a short progress text.

    Returns
    -------
    FrameStack
        With the files' calibration; frame times and numbers from the files where every frame
        has them (an .rtdc's ``events/time`` / ``frame``, a video's presentation times).

    Raises
    ------
    ExtractionError
        For unreadable files, images that are not 2-D grey or RGB, or frames of different sizes.
    """
    if flow_direction not in ("right", "left", "auto"):
        raise ExtractionError(f"flow direction must be 'right', 'left' or 'auto', got {flow_direction!r}")
    stack = FrameStack([], [], flow_direction=flow_direction)
    numbers: list[np.ndarray | None] = []
    times: list[np.ndarray | None] = []
    files = expand_frame_paths(paths)
    for path in files:
        try:
            held = sum(int(f.shape[0]) * int(f.shape[1]) for f in stack.frames[:1]) * len(stack.frames)
            frames, file_numbers, file_times = _read_file(path, stack, mirror=flow_direction == "left", already=held)
        except ExtractionError:
            raise
        except Exception as err:  # noqa: BLE001 - any reader failure is the file's problem
            raise ExtractionError(f"{path}: cannot read as an image: {err}") from None
        numbers.append(file_numbers)
        times.append(file_times)
        lazy = not isinstance(frames, list)
        if lazy and len(files) == 1:
            # A recording read as it is asked for (an .rtdc file): kept lazy, so that a file of
            # gigabytes streams through the extraction; its pages all have the dataset's shape.
            _check_size(frames[0], path, 0, None)
            stack.frames = frames
            stack.labels = [f"{path}[{page}]" for page in range(len(frames))]
            continue
        if not lazy and frames:
            check_pixel_count(path, len(frames), frames[0].shape, held)
        for page, frame in enumerate(frames):
            _check_size(frame, path, page, stack)
            cast(list, stack.frames).append(frame[:, ::-1] if flow_direction == "left" and not lazy else frame)
            stack.labels.append(f"{path}[{page}]" if len(frames) > 1 else str(path))
        if progress is not None:
            progress(f"read {len(stack)} frames")
    if not stack.frames:
        raise ExtractionError("no frame to read")
    # A file's own numbering and times hold for the stack when it is the only file.
    if len(numbers) == 1:
        stack.frame_numbers, stack.times_s = numbers[0], times[0]
    if stack.background is not None and flow_direction == "left":
        stack.background = stack.background[:, ::-1]
    return stack


def mirror_frames(frames: Sequence[np.ndarray]) -> Sequence[np.ndarray]:
    """The frames mirrored left to right: a lazy recording stays lazy (it mirrors as it reads)."""
    from capsmech.imaging.rtdc import RtdcFrames

    if isinstance(frames, RtdcFrames):
        return RtdcFrames(frames.path, frames.events, not frames.mirror)
    return [np.ascontiguousarray(f[:, ::-1]) for f in frames]


def read_frame_times(path: str | Path, count: int) -> np.ndarray:
    """Times [s] of ``count`` frames from a CSV: a ``time_s`` (or ``time``, ``time [s]``) column.

    One row per frame in page order, or a ``page`` column that says which frame each row is
    (rows for the same page, e.g. several events on one camera frame, must agree; the first
    is taken). The times must increase.

    Raises
    ------
    ExtractionError
        Naming the file, when a column is missing, a frame has no time or the times do not increase.
    """
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8") as handle:
            rows = list(csv.DictReader(line for line in handle if not line.startswith("#")))
    except OSError as err:
        raise ExtractionError(f"{path}: cannot read the frame times: {err}") from None
    if not rows:
        raise ExtractionError(f"{path}: no frame time in the file")
    column = next((c for c in ("time_s", "time [s]", "time") if c in rows[0]), None)
    if column is None:
        raise ExtractionError(f"{path}: no time column (time_s, 'time [s]' or time); columns: {', '.join(rows[0])}")
    times = np.full(count, np.nan)
    try:
        for k, row in enumerate(rows):
            page = int(row["page"]) if "page" in row and row["page"] != "" else k
            if 0 <= page < count and np.isnan(times[page]):
                times[page] = float(row[column])
    except ValueError as err:
        raise ExtractionError(f"{path}: {err}") from None
    missing = np.nonzero(np.isnan(times))[0]
    if missing.size:
        raise ExtractionError(f"{path}: no time for frame(s) {', '.join(map(str, missing[:5]))} of {count}")
    if np.any(np.diff(times) <= 0):
        raise ExtractionError(f"{path}: the frame times must increase")
    return times
