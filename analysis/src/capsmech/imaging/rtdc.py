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

Files run to gigabytes: the images are read as they are asked for (:class:`RtdcFrames`), one
HDF5 chunk of events at a time (a compressed chunk is decompressed whole whatever is sliced
from it, so a chunk is the natural unit), and only the small per-event features (frame, time)
are read whole. The acquisition's background is the median of a bounded sample of its
``image_bg`` events.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import overload

import numpy as np

from capsmech.errors import ExtractionError

#: Events read at once from a contiguous (unchunked) events/image: a bounded block.
BLOCK_EVENTS = 32
#: At most this many events (evenly spread) of events/image_bg enter the background's median.
MAX_BACKGROUND_EVENTS = 101


class RtdcFrames(Sequence[np.ndarray]):
    """The pages of an ``.rtdc`` file's ``events/image``, read from the file when asked for.

    Memory stays bounded whatever the file's size: the block of events (one HDF5 chunk along
    the events, else :data:`BLOCK_EVENTS`) that holds the last page asked for is all that is
    kept. Pages are read in any order; in page order each block is read once.

    Parameters
    ----------
    path : Path
    events : array of int
        The event shown on each page.
    mirror : bool
        Mirror every page (flow in -x turned to +x).
    """

    def __init__(self, path: Path, events: np.ndarray, mirror: bool = False) -> None:
        self.path = Path(path)
        self.events = np.asarray(events, dtype=int)
        self.mirror = mirror
        self._handle = None
        self._block_start = -1
        self._block: np.ndarray | None = None
        with _open(self.path) as handle:
            dataset = handle["events/image"]
            self.shape = (len(self.events), *dataset.shape[1:])
            self.dtype = dataset.dtype
            self.block_events = int(dataset.chunks[0]) if dataset.chunks else BLOCK_EVENTS

    def __len__(self) -> int:
        return len(self.events)

    @overload
    def __getitem__(self, index: int) -> np.ndarray: ...

    @overload
    def __getitem__(self, index: slice) -> list[np.ndarray]: ...

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[k] for k in range(*index.indices(len(self)))]
        page = int(index) + (len(self) if index < 0 else 0)
        if not 0 <= page < len(self):
            raise IndexError(f"page {index} of {len(self)}")
        event = int(self.events[page])
        start = event - event % self.block_events
        if self._block is None or start != self._block_start:
            self._block = None                   # free the old block before reading the next
            self._block = self._read(start, min(start + self.block_events, self._count()))
            self._block_start = start
        image = self._block[event - start]
        return np.ascontiguousarray(image[:, ::-1]) if self.mirror else image.copy()

    def _count(self) -> int:
        return int(self._dataset().shape[0])

    def _dataset(self):
        if self._handle is None:
            self._handle = _open(self.path)
        return self._handle["events/image"]

    def _read(self, start: int, stop: int) -> np.ndarray:
        try:
            return np.asarray(self._dataset()[start:stop])
        except (OSError, ValueError) as err:
            raise ExtractionError(f"{self.path}: cannot decode events/image[{start}:{stop}]: {err}") from None

    def close(self) -> None:
        """Close the file (it is opened again when a page is asked for)."""
        if self._handle is not None:
            self._handle.close()
        self._handle, self._block, self._block_start = None, None, -1

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001 - the interpreter may be shutting down
            pass


@dataclass
class RtdcRecording:
    """The frames of an ``.rtdc`` file and what the file says about them.

    Attributes
    ----------
    frames : RtdcFrames
        One image per distinct camera frame, in time order, read when asked for.
    frame_numbers : array
        Camera frame index of each page (``events/frame``; else the event index).
    times_s : array or None
        Time of each page [s] (``events/time``); None when the file has none.
    pixel_size_um, frame_rate, channel_width_um : float or None
        Root attributes ``imaging:pixel size``, ``imaging:frame rate``, ``setup:channel width``.
    background : 2-D array or None
        Median of ``events/image_bg`` (the acquisition's background) over its events, at most
        :data:`MAX_BACKGROUND_EVENTS` of them evenly spread.
    event_page : array
        For each event of the file, the page that shows it.
    """

    frames: RtdcFrames
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
        handle = h5py.File(path, "r")
    except OSError as err:
        raise ExtractionError(f"{path}: cannot read as an .rtdc (HDF5) file: {err}") from None
    try:
        _refuse_data_elsewhere(handle, path)
    except ExtractionError:
        handle.close()
        raise
    return handle


#: The members of ``events`` that are read.
READ_EVENTS = ("image", "image_bg", "frame", "time")


def _refuse_data_elsewhere(handle, path: Path) -> None:
    """An ExtractionError if what is read lives in another file: an external link, a virtual
    dataset (its sources are other files) or external raw storage. A recording is one file; one
    that points elsewhere would make the reader open whatever its author named."""
    import h5py

    links = [("events", handle.get("events", getlink=True))]
    events = handle.get("events") if not isinstance(links[0][1], h5py.ExternalLink) else None
    if events is not None:
        links += [(f"events/{name}", events.get(name, getlink=True)) for name in READ_EVENTS if name in events]
    for name, link in links:
        if isinstance(link, h5py.ExternalLink):
            raise ExtractionError(f"{path}: {name} is an external link to {link.filename!r}; a recording's data must "
                                  "be in its own file")
        item = handle.get(name)
        if isinstance(item, h5py.Dataset) and (item.is_virtual or item.external):
            kind = "a virtual dataset (its data are in other files)" if item.is_virtual else \
                "stored in external files"
            raise ExtractionError(f"{path}: {name} is {kind}; a recording's data must be in its own file")


def read_rtdc(path: str | Path, mirror: bool = False) -> RtdcRecording:
    """Read an ``.rtdc`` file's calibration, frame times and background; its images when asked for.

    Parameters
    ----------
    path : str or Path
    mirror : bool
        Mirror the pages left to right (the background is returned as recorded).

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
        shape = events["image"].shape
        count = shape[0] if len(shape) == 3 else 0
        try:
            frame = np.asarray(events["frame"][...], dtype=float) if "frame" in events else np.arange(count, dtype=float)
            time = np.asarray(events["time"][...], dtype=float) if "time" in events else None
            background = _background(events["image_bg"], shape) if "image_bg" in events else None
            # The first image decoded now: a filter that cannot be read fails here, not mid-way.
            if count:
                events["image"][0]
        except (OSError, ValueError, KeyError) as err:
            raise ExtractionError(f"{path}: cannot decode the events: {err}") from None
        attrs = dict(handle.attrs)
    if len(shape) != 3 or count == 0:
        raise ExtractionError(f"{path}: events/image has shape {shape}, not (events, rows, columns)")
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
    return RtdcRecording(RtdcFrames(path, picks, mirror), frame[picks], time[picks] if time is not None else None,
                         _attr(attrs, "imaging:pixel size"), _attr(attrs, "imaging:frame rate"),
                         _attr(attrs, "setup:channel width"), background, event_page)


def _background(image_bg, shape: tuple[int, ...]) -> np.ndarray | None:
    """Median of ``events/image_bg`` over at most :data:`MAX_BACKGROUND_EVENTS` events, evenly
    spread (the acquisition's background changes slowly; a bounded sample keeps memory bounded)."""
    if image_bg.shape != shape:
        return None
    picks = np.unique(np.linspace(0, shape[0] - 1, min(shape[0], MAX_BACKGROUND_EVENTS)).round().astype(int))
    return np.median(np.stack([np.asarray(image_bg[int(k)]) for k in picks]), axis=0).astype(np.float32)


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
