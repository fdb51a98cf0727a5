"""From microscope frames to tube measurements: walls, capsule contour, L_z, L_p, v_c.

Frame convention: the tube axis runs along the image's x (columns) and the flow goes in +x,
so the capsule's front is at the largest x (mirror the frames first when it goes in -x). The
capillary's walls are dark horizontal lines; the capsule's membrane is a dark closed line.

Per stack
    ``find_walls``: the two walls are the two most prominent dark rows of the stack's
    median row profile (each row's median over columns, whatever the capsule does); their
    centres, to a fraction of a pixel (centroid of the peak above half its height), give the
    tube radius (half their distance) and the axis (their mid-line).
Per frame (``analyse_frame``)
    1. Background: each row's median over the columns (the walls are horizontal; the capsule
       fills less than half of each row), and the contrast c = 1 - I / background, which is
       the membrane's absorption alone (light is absorbed multiplicatively).
    2. Objects: c smoothed (Gaussian, 1 px) above a threshold of 6 noise deviations (median
       absolute deviation) inside the tube, fragments closer than 2 px joined, specks smaller
       than ``min_area_px`` dropped. None: ``no capsule``; more than one: ``N capsules``;
       one whose pixels reach the image's left or right edge: ``touches the image border``.
    3. Line width: the area of the line above half its peak contrast over its skeleton's
       length (the full width at half maximum). A frame whose line is wider than
       ``max_line_width_px``, or than ``focus_ratio`` times the stack's median width, is
       ``out of focus``.
    4. Mid-line contour: ``skimage.measure.find_contours`` traces the line's two edges (iso-
       lines at half its peak contrast, linearly interpolated: sub-pixel); each point of the
       outer edge is paired with the nearest point of the inner edge (for two parallel curves
       that pair lies on the common normal) and their midpoint is the membrane, the middle of
       the dark line as in the paper's manual extraction.
    5. Lengths: L_z = x_max - x_min of the contour; L_p = x(rear point on the axis) - x_min,
       the rear axis point being the contour's rear crossing of the axis (linear
       interpolation). Symmetry: the mean distance between the upper half and the mirrored
       lower half (both ways, the larger), over L_z / 2; above ``max_asymmetry`` the frame is
       ``asymmetric``.
Per capsule (``measure_capsules``)
    Frames are grouped into passages (a capsule crossing the field: a new one starts after a
    frame with no capsule, or when the object jumps back against the flow). Lengths are the
    median over the passage's good frames, with their standard deviation as spread; v_c is
    the slope of the least-squares line through the contour's area centroid against time,
    with its standard error. A passage with fewer than ``min_good_frames`` good frames is not
    measured and says why.
"""
from __future__ import annotations

import math
import re
import sys
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from capsmech.errors import CapsmechError

#: Gaussian smoothing (px) of the contrast before objects are detected, and before edges are traced.
DETECTION_SMOOTHING_PX = 1.0
CONTOUR_SMOOTHING_PX = 0.6


class ExtractionError(CapsmechError, ValueError):
    """Frames that cannot be read or measured; the message names the file and the problem."""


# ---------------------------------------------------------------------------
# Reading frames
# ---------------------------------------------------------------------------


@dataclass
class FrameStack:
    """Grey frames and what their files say about them.

    Attributes
    ----------
    frames : list of 2-D arrays
        One grey image per frame (original dtype for grey files, float32 for colour ones).
    labels : list of str
        ``file`` or ``file[page]`` for each frame, for messages and reports.
    frame_rate : float or None
        Frames per second from the files' metadata (ImageJ ``finterval`` or ``fps``).
    pixel_size_um : float or None
        Pixel size from the metadata (ImageJ TIFF resolution with a micron unit).
    """

    frames: list[np.ndarray]
    labels: list[str]
    frame_rate: float | None = None
    pixel_size_um: float | None = None

    def __len__(self) -> int:
        return len(self.frames)


_IMAGE_SUFFIXES = {".tif", ".tiff", ".png", ".jpg", ".jpeg", ".bmp", ".gif"}


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


def _tiff_frames(path: Path) -> tuple[list[np.ndarray], float | None, float | None]:
    """Frames of a (multi-page) TIFF, and the frame rate and pixel size [um] of its metadata."""
    import tifffile

    with tifffile.TiffFile(path) as tif:
        series = tif.series[0]
        data = series.asarray()
        axes = series.axes
        frame_rate = pixel_um = None
        meta = tif.imagej_metadata or {}
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
    colour = "S" in axes
    # Every axis other than the image's own (Y, X, and the colour samples S) counts frames.
    frame_shape = data.shape[-3:] if colour else data.shape[-2:]
    data = data.reshape((-1, *frame_shape))
    return [_to_grey(frame, str(path)) for frame in data], frame_rate, pixel_um


def read_frames(paths: Sequence[str | Path], flow_direction: str = "right",
                progress: Callable[[str], None] | None = None) -> FrameStack:
    """Read image files (multi-page TIFF, PNG, ... 8 or 16 bit, grey or colour) into one stack.

    Parameters
    ----------
    paths : sequence of str or Path
        Files, directories or glob patterns (see :func:`expand_frame_paths`), in frame order.
    flow_direction : {'right', 'left'}
        'left' mirrors every frame so that the flow goes in +x.
    progress : callable, optional
        Called with a short progress text.

    Raises
    ------
    ExtractionError
        For unreadable files, images that are not 2-D grey or RGB, or frames of different sizes.
    """
    import imageio.v3 as iio

    if flow_direction not in ("right", "left"):
        raise ExtractionError(f"flow direction must be 'right' or 'left', got {flow_direction!r}")
    stack = FrameStack([], [])
    for path in expand_frame_paths(paths):
        try:
            if path.suffix.lower() in (".tif", ".tiff"):
                frames, rate, pixel = _tiff_frames(path)
                stack.frame_rate = stack.frame_rate or rate
                stack.pixel_size_um = stack.pixel_size_um or pixel
            else:
                image = iio.imread(path)
                if image.ndim == 3 and image.shape[-1] not in (3, 4):
                    frames = list(image)   # an animated format: one image per page
                else:
                    frames = [image]
                frames = [_to_grey(f, str(path)) for f in frames]
        except ExtractionError:
            raise
        except Exception as err:  # noqa: BLE001 - any reader failure is the file's problem
            raise ExtractionError(f"{path}: cannot read as an image: {err}") from None
        for page, frame in enumerate(frames):
            if stack.frames and frame.shape != stack.frames[0].shape:
                raise ExtractionError(f"{path}: frame {page} is {frame.shape[1]}x{frame.shape[0]} px, "
                                      f"the first frame ({stack.labels[0]}) is "
                                      f"{stack.frames[0].shape[1]}x{stack.frames[0].shape[0]} px")
            if frame.shape[0] < 16 or frame.shape[1] < 16:
                raise ExtractionError(f"{path}: frame {page} is only {frame.shape[1]}x{frame.shape[0]} px")
            stack.frames.append(frame[:, ::-1] if flow_direction == "left" else frame)
            stack.labels.append(f"{path}[{page}]" if len(frames) > 1 else str(path))
        if progress is not None:
            progress(f"read {len(stack)} frames")
    if not stack.frames:
        raise ExtractionError("no frame to read")
    return stack


# ---------------------------------------------------------------------------
# Walls
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Walls:
    """The capillary's two walls: rows (y, px) of the centres of their dark lines."""

    top_row: float
    bottom_row: float

    @property
    def radius_px(self) -> float:
        """Inner tube radius l in pixels: half the distance between the walls."""
        return (self.bottom_row - self.top_row) / 2

    @property
    def axis_row(self) -> float:
        """Row of the tube axis: the walls' mid-line."""
        return (self.bottom_row + self.top_row) / 2


def _peak_centre(profile: np.ndarray, peak: int) -> float:
    """Sub-pixel centre of a peak: the centroid of its samples above half its height."""
    height = profile[peak]
    lo = hi = peak
    while lo > 0 and profile[lo - 1] > height / 2:
        lo -= 1
    while hi < profile.size - 1 and profile[hi + 1] > height / 2:
        hi += 1
    rows = np.arange(lo, hi + 1)
    weights = profile[lo:hi + 1] - height / 2
    # The half-height samples themselves weigh zero; guard the degenerate one-sample peak.
    return float(np.sum(rows * weights) / np.sum(weights)) if np.sum(weights) > 0 else float(peak)


def find_walls(frames: Sequence[np.ndarray], label: str = "frames", min_darkness: float = 0.05,
               max_frames: int = 64) -> Walls:
    """Find the two tube walls of a stack (horizontal dark lines).

    Parameters
    ----------
    frames : sequence of 2-D arrays
        The stack (at most ``max_frames`` evenly spread frames are used).
    label : str
        Name of the stack, for messages.
    min_darkness : float
        A wall must darken its row by at least this fraction of the background.

    Raises
    ------
    ExtractionError
        When fewer than two dark rows stand out.
    """
    from scipy.signal import find_peaks

    picks = np.unique(np.linspace(0, len(frames) - 1, min(len(frames), max_frames)).round().astype(int))
    # Median over columns: the walls span every column, the capsule less than half of them.
    profile = np.median(np.stack([np.median(np.asarray(frames[k], dtype=np.float32), axis=1) for k in picks]), axis=0)
    bright = float(np.percentile(profile, 90))
    if bright <= 0:
        raise ExtractionError(f"{label}: the frames are black")
    darkness = 1 - profile / bright
    peaks, props = find_peaks(darkness, prominence=min_darkness)
    if peaks.size < 2:
        raise ExtractionError(f"{label}: found {peaks.size} tube wall(s), need 2: the frames must show the "
                              "capillary's two walls as horizontal dark lines (tube axis along x)")
    two = np.sort(peaks[np.argsort(props["prominences"])[-2:]])
    walls = Walls(*(_peak_centre(darkness, int(p)) for p in two))
    if walls.radius_px < 5:
        raise ExtractionError(f"{label}: the two darkest rows ({two[0]}, {two[1]}) are too close to be the tube walls")
    return walls


# ---------------------------------------------------------------------------
# One frame
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class ExtractionSettings:
    """Thresholds of the extraction (defaults suit 1-4 px membrane lines, tube radius > 20 px)."""

    detection_sigmas: float = 6.0
    min_area_px: int = 30
    max_line_width_px: float = 10.0
    focus_ratio: float = 1.6
    max_asymmetry: float = 0.05
    min_good_frames: int = 3


@dataclass
class FrameResult:
    """What one frame shows. ``flag`` is empty for a good (measured) frame, else the reason."""

    index: int
    label: str
    flag: str = ""
    objects: int = 0
    line_width_px: float = math.nan
    line_contrast: float = math.nan
    object_x: float = math.nan
    x_front: float = math.nan
    x_rear: float = math.nan
    x_rear_axis: float = math.nan
    L_z_px: float = math.nan
    L_p_px: float = math.nan
    centroid_x: float = math.nan
    centroid_y: float = math.nan
    asymmetry: float = math.nan
    passage: int = -1
    contour: np.ndarray | None = field(default=None, repr=False)

    @property
    def good(self) -> bool:
        return not self.flag


def _contrast(image: np.ndarray) -> np.ndarray:
    """1 - I / background with the background each row's median (walls included, so they vanish)."""
    image = np.asarray(image, dtype=np.float32)
    background = np.median(image, axis=1)
    background = np.maximum(background, max(float(background.max()) * 1e-3, 1e-12))
    return 1 - image / background[:, None]


def _closed_contours(field_: np.ndarray, level: float) -> list[np.ndarray]:
    """Closed iso-lines of ``field_`` at ``level`` as (x, y) arrays, longest first."""
    from skimage.measure import find_contours

    contours = [c[:, ::-1] for c in find_contours(field_, level) if len(c) > 8 and np.allclose(c[0], c[-1])]
    return sorted(contours, key=len, reverse=True)


def _resample(points: np.ndarray, spacing: float) -> np.ndarray:
    """Closed polyline (first point repeated at the end or not) resampled at ``spacing`` by arclength."""
    if not np.allclose(points[0], points[-1]):
        points = np.vstack([points, points[:1]])
    seg = np.hypot(*np.diff(points, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(8, int(np.ceil(s[-1] / spacing)))
    t = np.linspace(0, s[-1], n, endpoint=False)
    return np.column_stack([np.interp(t, s, points[:, 0]), np.interp(t, s, points[:, 1])])


def _polygon_centroid(points: np.ndarray) -> tuple[float, float]:
    """Area centroid of a closed polygon (shoelace formula)."""
    x, y = points[:, 0], points[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = cross.sum() / 2
    if abs(area) < 1e-9:
        return float(x.mean()), float(y.mean())
    return float(((x + xn) * cross).sum() / (6 * area)), float(((y + yn) * cross).sum() / (6 * area))


def _rear_axis_crossing(contour: np.ndarray, axis_row: float) -> float:
    """x of the contour's rear-most crossing of the axis (linear interpolation); NaN if none."""
    closed = np.vstack([contour, contour[:1]])
    d = closed[:, 1] - axis_row
    idx = np.nonzero(np.sign(d[:-1]) != np.sign(d[1:]))[0]
    if idx.size == 0:
        return math.nan
    t = d[idx] / (d[idx] - d[idx + 1])
    xs = closed[idx, 0] + t * (closed[idx + 1, 0] - closed[idx, 0])
    return float(xs.min())


def _asymmetry(contour: np.ndarray, axis_row: float, half_length: float) -> float:
    """Mean distance between the upper half and the mirrored lower half (larger way), / half_length."""
    upper = contour[contour[:, 1] <= axis_row]
    lower = contour[contour[:, 1] >= axis_row].copy()
    if len(upper) < 4 or len(lower) < 4:
        return math.inf
    lower[:, 1] = 2 * axis_row - lower[:, 1]
    d_ul = cKDTree(lower).query(upper)[0].mean()
    d_lu = cKDTree(upper).query(lower)[0].mean()
    return float(max(d_ul, d_lu) / half_length)


def _line_width(contrast: np.ndarray, peak: float) -> float:
    """Full width at half maximum of a line: area above half its peak over its skeleton's length."""
    from skimage.morphology import skeletonize

    band = contrast > peak / 2
    length = skeletonize(band).sum()
    return float(band.sum() / length) if length else math.inf


def analyse_frame(image: np.ndarray, walls: Walls, index: int = 0, label: str = "",
                  settings: ExtractionSettings = ExtractionSettings()) -> FrameResult:
    """Find the capsule in one frame and measure its mid-line contour (see the module docstring).

    Parameters
    ----------
    image : 2-D array
        Grey frame, flow in +x.
    walls : Walls
        The stack's walls.
    index, label : int, str
        Frame number and name, copied into the result.
    settings : ExtractionSettings

    Returns
    -------
    FrameResult
        With ``flag`` set (and no lengths) when the frame cannot be measured; the out-of-focus
        test against the other frames is :func:`flag_out_of_focus`'s.
    """
    from skimage.measure import label as label_components

    result = FrameResult(index=index, label=label)
    rows, cols = image.shape
    contrast = _contrast(image)
    smooth = ndimage.gaussian_filter(contrast, DETECTION_SMOOTHING_PX)
    # The capsule lies between the walls; outside them only dirt and the glass can show.
    inside = np.zeros_like(smooth, dtype=bool)
    margin = 3
    inside[max(0, int(walls.top_row) - margin):min(rows, int(np.ceil(walls.bottom_row)) + margin + 1)] = True
    values = smooth[inside]
    noise = 1.4826 * float(np.median(np.abs(values - np.median(values))))
    threshold = max(settings.detection_sigmas * noise, 0.01)
    mask = (smooth > threshold) & inside
    # Join fragments of one faint line; then drop specks.
    joined = ndimage.binary_dilation(mask, iterations=2)
    labels, count = label_components(joined, return_num=True, connectivity=2)
    sizes = np.bincount(labels[mask].ravel(), minlength=count + 1)
    keep = [k for k in range(1, count + 1) if sizes[k] >= settings.min_area_px]
    result.objects = len(keep)
    if not keep:
        result.flag = "no capsule"
        return result
    # Width first: a strongly blurred line breaks up into faint pieces that are one capsule.
    widths, peaks = [], []
    for k in keep:
        region = labels == k
        peaks.append(float(np.percentile(smooth[region & mask], 90)))
        widths.append(_line_width(np.where(region, smooth, 0.0), peaks[-1]))
    result.line_width_px = float(np.median(widths))
    result.line_contrast = float(np.median(peaks))
    if result.line_width_px > settings.max_line_width_px:
        result.flag = f"out of focus (line {result.line_width_px:.1f} px wide > {settings.max_line_width_px:g})"
        return result
    # The border first: a capsule cut by it may fall apart into several arcs.
    objects = np.isin(labels, keep) & mask
    object_columns = np.nonzero(objects.any(axis=0))[0]
    result.object_x = float(np.nonzero(objects)[1].mean())
    if object_columns.min() <= 1 or object_columns.max() >= cols - 2:
        result.flag = "touches the image border"
        return result
    if len(keep) > 1:
        result.flag = f"{len(keep)} capsules"
        return result
    region = labels == keep[0]
    r_idx, c_idx = np.nonzero(region & mask)
    # The edges are traced on a lighter smoothing than the detection's: blur pulls the edge
    # back around the parachute's sharp rim (L_p -0.35 px at 1 px, -0.16 px at 0.6 px for a
    # 28 px deep parachute), while too little lets the noise push the extremes out (+0.3 px
    # on L_z without smoothing).
    line = np.where(region, ndimage.gaussian_filter(contrast, CONTOUR_SMOOTHING_PX), 0.0)
    peak = float(np.percentile(line[region & mask], 90))
    pad = 3
    r0, r1 = max(0, r_idx.min() - pad), min(rows, r_idx.max() + pad + 1)
    c0, c1 = max(0, c_idx.min() - pad), min(cols, c_idx.max() + pad + 1)
    crop = line[r0:r1, c0:c1]
    # Zero border: every iso-line of the crop is closed.
    crop = np.pad(crop, 1)
    edges = _closed_contours(crop, peak / 2)
    if len(edges) < 2:
        result.flag = "no interior (line too thick for the capsule, or capsule not closed)"
        return result
    outer = edges[0]
    from skimage.measure import points_in_poly

    inner = next((e for e in edges[1:] if points_in_poly(e[::max(1, len(e) // 16)], outer).all()), None)
    if inner is None:
        result.flag = "no interior (line too thick for the capsule, or capsule not closed)"
        return result
    outer = _resample(outer, 0.25)
    inner_dense = _resample(inner, 0.05)
    _, nearest = cKDTree(inner_dense).query(outer)
    contour = (outer + inner_dense[nearest]) / 2 + np.array([c0 - 1, r0 - 1])
    contour = _resample(contour, 0.5)
    result.contour = contour
    # The axial extremes from the outer edge, one half line width in: at the parachute's rim
    # the membrane folds back within a few line widths, the inner edge cannot enter the
    # fold and the mid-line there falls short (by 3 px for a 28 px deep parachute); the
    # outer edge stays parallel to the membrane (at 1 px smoothing, rear-most point of a 28 px
    # deep parachute: mid-line +3.3 px, outer edge +0.3 px; +0.16 px at 0.6 px).
    half_width = float(np.median(np.hypot(*(outer - inner_dense[nearest]).T))) / 2
    result.x_front = float(outer[:, 0].max()) + c0 - 1 - half_width
    result.x_rear = float(outer[:, 0].min()) + c0 - 1 + half_width
    result.x_rear_axis = _rear_axis_crossing(contour, walls.axis_row)
    result.L_z_px = result.x_front - result.x_rear
    result.L_p_px = max(0.0, result.x_rear_axis - result.x_rear)
    result.centroid_x, result.centroid_y = _polygon_centroid(contour)
    result.asymmetry = _asymmetry(contour, walls.axis_row, result.L_z_px / 2)
    if not math.isfinite(result.x_rear_axis):
        result.flag = "contour does not cross the tube axis (capsule off the axis)"
    elif result.asymmetry > settings.max_asymmetry:
        result.flag = f"asymmetric ({result.asymmetry:.3f} > {settings.max_asymmetry} of L_z/2)"
    return result


def flag_out_of_focus(results: Sequence[FrameResult], settings: ExtractionSettings) -> None:
    """Flag the frames whose line is much wider or fainter than the stack's measured frames'.

    Defocus spreads the line's darkness: it widens and fades (a strongly blurred line also
    breaks up into pieces, which would otherwise read as several capsules). The reference is
    the median over the frames that gave a contour; it needs three of them.
    """
    reference = [r for r in results if r.contour is not None]
    if len(reference) < 3:
        return
    width = float(np.median([r.line_width_px for r in reference]))
    contrast = float(np.median([r.line_contrast for r in reference]))
    for r in results:
        if r.objects == 0 or r.flag.startswith("out of focus"):
            continue
        if r.line_width_px > settings.focus_ratio * width:
            r.flag = f"out of focus (line {r.line_width_px:.1f} px wide, stack median {width:.1f} px)"
        elif r.line_contrast < contrast / settings.focus_ratio:
            r.flag = f"out of focus (line contrast {r.line_contrast:.3f}, stack median {contrast:.3f})"
        if r.flag.startswith("out of focus"):
            r.contour = None


# ---------------------------------------------------------------------------
# Capsules: passages, lengths, velocity
# ---------------------------------------------------------------------------


@dataclass
class CapsuleMeasurement:
    """One capsule's passage through the field of view, measured over its good frames.

    Lengths in pixels; ``v_c_px_s`` in pixels per second; spreads are standard deviations
    over the good frames, ``v_c_se_px_s`` the standard error of the fitted slope.
    """

    passage: int
    frames: list[int]
    good_frames: list[int]
    L_z_px: float = math.nan
    L_z_spread_px: float = math.nan
    L_p_px: float = math.nan
    L_p_spread_px: float = math.nan
    v_c_px_s: float = math.nan
    v_c_se_px_s: float = math.nan
    representative: int = -1
    problem: str = ""

    @property
    def ok(self) -> bool:
        return not self.problem


def assign_passages(results: Sequence[FrameResult], jump_px: float) -> None:
    """Number the capsules' passages: a new one after an empty frame or a jump against the flow."""
    passage, last_x, inside = -1, math.nan, False
    for r in results:
        if r.objects == 0:
            inside, last_x = False, math.nan
            continue
        # The contour's centroid where there is one, else the mean column of the object's pixels
        # (a capsule entering at the border): enough to see a jump back against the flow.
        x = r.centroid_x if math.isfinite(r.centroid_x) else r.object_x
        if not inside or (math.isfinite(x) and math.isfinite(last_x) and x < last_x - jump_px):
            passage += 1
        inside = True
        r.passage = passage
        if math.isfinite(x):
            last_x = x


def fit_velocity(times: np.ndarray, positions: np.ndarray) -> tuple[float, float]:
    """Least-squares slope of position against time and its standard error (NaN below 3 points)."""
    if times.size < 2:
        return math.nan, math.nan
    t = times - times.mean()
    sxx = float(np.sum(t * t))
    slope = float(np.sum(t * (positions - positions.mean())) / sxx)
    if times.size < 3:
        return slope, math.nan
    residual = positions - positions.mean() - slope * t
    return slope, float(math.sqrt(np.sum(residual ** 2) / (times.size - 2) / sxx))


def measure_capsules(results: Sequence[FrameResult], frame_rate: float,
                     settings: ExtractionSettings = ExtractionSettings()) -> list[CapsuleMeasurement]:
    """Group frames into passages and measure each capsule over its good frames."""
    by_passage: dict[int, list[FrameResult]] = {}
    for r in results:
        if r.passage >= 0:
            by_passage.setdefault(r.passage, []).append(r)
    capsules = []
    for passage, frames in sorted(by_passage.items()):
        good = [r for r in frames if r.good]
        cap = CapsuleMeasurement(passage, [r.index for r in frames], [r.index for r in good])
        if len(good) < settings.min_good_frames:
            flags = sorted({r.flag.split(" (")[0] for r in frames if r.flag})
            cap.problem = (f"{len(good)} good frame(s) of {len(frames)} (need {settings.min_good_frames}); "
                           f"the others: {', '.join(flags) or 'none'}")
            capsules.append(cap)
            continue
        lz = np.array([r.L_z_px for r in good])
        lp = np.array([r.L_p_px for r in good])
        cap.L_z_px, cap.L_z_spread_px = float(np.median(lz)), float(np.std(lz, ddof=1))
        cap.L_p_px, cap.L_p_spread_px = float(np.median(lp)), float(np.std(lp, ddof=1))
        times = np.array([r.index for r in good], dtype=float) / frame_rate
        cap.v_c_px_s, cap.v_c_se_px_s = fit_velocity(times, np.array([r.centroid_x for r in good]))
        if not cap.v_c_px_s > 0:
            cap.problem = f"the capsule does not move with the flow (+x): v_c = {cap.v_c_px_s:.3g} px/s"
        # The frame whose lengths are nearest the medians shows the capsule the row describes.
        misfit = np.abs(lz - cap.L_z_px) / max(cap.L_z_px, 1) + np.abs(lp - cap.L_p_px) / max(cap.L_z_px, 1)
        cap.representative = good[int(np.argmin(misfit))].index
        capsules.append(cap)
    return capsules


def extract(stack: FrameStack, settings: ExtractionSettings = ExtractionSettings(),
            progress: Callable[[int, int], None] | None = None,
            walls: Walls | None = None) -> tuple[Walls, list[FrameResult]]:
    """Walls of the stack and every frame's analysis (out-of-focus and passages included)."""
    walls = walls or find_walls(stack.frames, stack.labels[0])
    results = []
    for k, image in enumerate(stack.frames):
        results.append(analyse_frame(image, walls, k, stack.labels[k], settings))
        if progress is not None:
            progress(k + 1, len(stack))
    flag_out_of_focus(results, settings)
    assign_passages(results, jump_px=0.25 * walls.radius_px)
    return walls, results


def progress_printer(stream=sys.stderr, every: int = 25) -> Callable[[int, int], None] | None:
    """A progress line on ``stream`` for long stacks, only when it is a terminal."""
    if not stream.isatty():
        return None

    def show(done: int, total: int) -> None:
        if done % every == 0 or done == total:
            stream.write(f"\rcapsmech extract: frame {done}/{total}")
            if done == total:
                stream.write("\n")
            stream.flush()

    return show


def iter_good(results: Iterable[FrameResult]) -> Iterable[FrameResult]:
    """The good frames of a result list."""
    return (r for r in results if r.good)
