"""Reading real-time deformability cytometry recordings (``.rtdc``, HDF5).

An ``.rtdc`` file (the format of ZELLMECHANIK DRESDEN's instruments and of the dclab library)
is HDF5 with one dataset per event feature under ``events/``: ``image`` (event, row, column;
8-bit grey), optionally ``image_bg`` (the acquisition's rolling background per event),
``frame`` (the camera frame index), ``time`` [s], ``mask`` (the acquisition's object mask) and
``contour/<event>`` ((n, 2) x, y points of its contour); the calibration is in the root
attributes ``imaging:pixel size`` [um], ``imaging:frame rate`` [1/s] and ``setup:channel width``
[um]. Some files are compressed with HDF5 filters h5py does not ship (bitshuffle, zstd):
``hdf5plugin`` registers them on import.

Read with h5py (already the package's HDF5 library) and hdf5plugin; dclab itself is not needed.
Events that share one camera frame (several objects in view) share one page of the stack;
pages are in time order.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from capsmech.errors import ExtractionError


@dataclass
class RtdcRecording:
    """The frames of an ``.rtdc`` file and what the file says about them.

    Attributes
    ----------
    frames : (pages, rows, columns) uint8 array
        One image per distinct camera frame, in time order.
    frame_numbers : array
        Camera frame index of each page (``events/frame``; else the event index).
    times_s : array or None
        Time of each page [s] (``events/time``); None when the file has none.
    pixel_size_um, frame_rate, channel_width_um : float or None
        Root attributes ``imaging:pixel size``, ``imaging:frame rate``, ``setup:channel width``.
    background : 2-D array or None
        Median over the events of ``events/image_bg`` (the acquisition's background).
    event_page : array
        For each event of the file, the page that shows it.
    """

    frames: np.ndarray
    frame_numbers: np.ndarray
    times_s: np.ndarray | None
    pixel_size_um: float | None
    frame_rate: float | None
    channel_width_um: float | None
    background: np.ndarray | None
    event_page: np.ndarray = field(repr=False)


def _attr(attrs, key: str) -> float | None:
    value = attrs.get(key)
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if np.isfinite(number) and number > 0 else None


def _open(path: Path):
    import h5py
    import hdf5plugin  # noqa: F401 - registers the bitshuffle / zstd / lz4 filters with HDF5

    try:
        return h5py.File(path, "r")
    except OSError as err:
        raise ExtractionError(f"{path}: cannot read as an .rtdc (HDF5) file: {err}") from None


def read_rtdc(path: str | Path) -> RtdcRecording:
    """Read an ``.rtdc`` file's images, calibration, frame times and background.

    Raises
    ------
    ExtractionError
        Naming the file: not HDF5, no ``events/image``, or data that cannot be decoded.
    """
    path = Path(path)
    with _open(path) as handle:
        events = handle.get("events")
        if events is None or "image" not in events:
            raise ExtractionError(f"{path}: an .rtdc file without events/image (no frames to measure)")
        try:
            images = np.asarray(events["image"][...])
            count = images.shape[0]
            frame = np.asarray(events["frame"][...], dtype=float) if "frame" in events else np.arange(count, dtype=float)
            time = np.asarray(events["time"][...], dtype=float) if "time" in events else None
            image_bg = np.asarray(events["image_bg"][...]) if "image_bg" in events else None
        except (OSError, ValueError, KeyError) as err:
            raise ExtractionError(f"{path}: cannot decode the events: {err}") from None
        attrs = dict(handle.attrs)
    if images.ndim != 3 or count == 0:
        raise ExtractionError(f"{path}: events/image has shape {images.shape}, not (events, rows, columns)")
    if frame.shape != (count,) or (time is not None and time.shape != (count,)):
        raise ExtractionError(f"{path}: events/frame or events/time does not have one value per event")
    # One page per distinct camera frame, in time order (some files are not).
    order = np.lexsort((np.arange(count), time if time is not None else frame))
    key = (time if time is not None else frame)[order]
    first = np.ones(count, dtype=bool)
    first[1:] = (key[1:] != key[:-1]) | (frame[order][1:] != frame[order][:-1])
    page_of_sorted = np.cumsum(first) - 1
    event_page = np.empty(count, dtype=int)
    event_page[order] = page_of_sorted
    picks = order[first]
    background = None
    if image_bg is not None and image_bg.shape == images.shape:
        background = np.median(image_bg, axis=0).astype(np.float32)
    return RtdcRecording(images[picks], frame[picks], time[picks] if time is not None else None,
                         _attr(attrs, "imaging:pixel size"), _attr(attrs, "imaging:frame rate"),
                         _attr(attrs, "setup:channel width"), background, event_page)


@dataclass
class RtdcReference:
    """The acquisition software's own segmentation of each event, for checks.

    Attributes
    ----------
    event_page : array
        The page (of :func:`read_rtdc`'s frames) each event lies on.
    masks : (events, rows, columns) bool array or None
        ``events/mask``.
    contours : list of (n, 2) arrays or None
        ``events/contour/<event>``: x, y [px].
    """

    event_page: np.ndarray
    masks: np.ndarray | None
    contours: list[np.ndarray] | None


def read_rtdc_reference(path: str | Path) -> RtdcReference:
    """The reference masks and contours of an ``.rtdc`` file, with the page of each event."""
    path = Path(path)
    recording = read_rtdc(path)
    with _open(path) as handle:
        events = handle["events"]
        masks = np.asarray(events["mask"][...]).astype(bool) if "mask" in events else None
        contours = None
        if "contour" in events:
            group = events["contour"]
            contours = [np.asarray(group[str(k)][...], dtype=float) for k in range(len(recording.event_page))]
    return RtdcReference(recording.event_page, masks, contours)
