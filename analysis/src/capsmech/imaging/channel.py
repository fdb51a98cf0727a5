"""Geometry of the channel: its tilt, the rotation that levels it, and its two walls.

Real channels are never quite horizontal (0.1-2.5 degrees in RT-DC recordings): a wall line
that crosses rows leaves a trace in every per-row statistic and touches the image border. The
tilt is found first, on the background image (walls and nothing else), and every frame is
rotated level before anything is detected. The walls are then found on the levelled
background's row profile: where the glass shows as a band (a thin one, with or without a bright
refraction line beside it, or a thick one), the wall is the band's liquid-side edge, located to a
fraction of a pixel where the darkness changes fastest; where it shows as a thin line (the
interface's own image, 3-5 px), that line's liquid-side edge alike: the glass lies outside the
liquid. Each wall carries its uncertainty, from locating it again in strips of columns. Angles
follow the image's axes: ``tilt_deg = atan(d row / d column)`` with rows counted downwards (a
wall that descends to the right has a positive tilt).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
from scipy import ndimage

from capsmech.imaging.frames import ExtractionError

#: Tilt search: coarse over +-MAX_TILT_DEG, then finer around the best angle.
MAX_TILT_DEG = 5.0
#: Profile bins (px) of the projections the tilt search compares.
_BIN_PX = 0.5


@dataclass(frozen=True)
class Walls:
    """The channel's two walls, rows (y, px) in the levelled frame.

    Attributes
    ----------
    top_row, bottom_row : float
        Rows of the walls: the liquid-side edge of a band (the glass shown in its thickness)
        or of a thin line (the interface's own image), or placed by the user.
    source : str
        How they were found: ``detected``, ``given`` (user's rows),
        ``one wall detected, the other placed at the channel width`` or ``one wall detected, the
        other placed by the objects' symmetry line`` (:func:`axis_from_objects`).
    columns : (int, int) or None
        First and last column of the straight channel, where the detected wall lines lie at
        their rows (:func:`straight_columns`); None: the whole width.
    top_sigma_px, bottom_sigma_px : float
        Standard uncertainty of each row [px] (:func:`wall_uncertainty`); NaN where unknown
        (rows given by the user).
    lines : tuple of float
        Centres of the wall lines (the interface's thin dark image) whose liquid-side edges the
        walls are; empty where the walls are bands' edges, given or placed.
    placed_side : str
        ``top`` or ``bottom``: the wall placed (at the channel width or by the objects' symmetry
        line); '' where both were found or given.
    """

    top_row: float
    bottom_row: float
    source: str = "detected"
    columns: tuple[int, int] | None = None
    top_sigma_px: float = math.nan
    bottom_sigma_px: float = math.nan
    lines: tuple[float, ...] = ()
    placed_side: str = ""

    @property
    def radius_px(self) -> float:
        """Inner tube radius l in pixels: half the distance between the walls."""
        return (self.bottom_row - self.top_row) / 2

    @property
    def axis_row(self) -> float:
        """Row of the tube axis: the walls' mid-line."""
        return (self.bottom_row + self.top_row) / 2

    @property
    def width_px(self) -> float:
        """Channel width in pixels (wall to wall)."""
        return self.bottom_row - self.top_row

    @property
    def width_sigma_px(self) -> float:
        """Standard uncertainty of the width [px] (the two walls' independent errors)."""
        return math.hypot(self.top_sigma_px, self.bottom_sigma_px)

    @property
    def radius_sigma_px(self) -> float:
        """Standard uncertainty of the tube radius [px]."""
        return self.width_sigma_px / 2


def _line_image(image: np.ndarray) -> np.ndarray:
    """Where horizontal-ish lines are: the darkness with its slow variations along y removed."""
    image = np.asarray(image, dtype=np.float32)
    bright = float(np.percentile(image, 90)) or 1.0
    dark = 1 - image / bright
    # Black padding (rows of zeros) is no line: give it the frame's typical darkness.
    dark[image <= 0.05 * bright] = float(np.median(dark))
    return dark - ndimage.gaussian_filter1d(dark, 4.0, axis=0)


def _projection_sharpness(lines: np.ndarray, tilt_deg: float) -> float:
    """How sharp the row profile is after projecting along lines of slope ``tilt_deg``.

    Each pixel goes to the row where its line crosses the centre column (linear weights over
    :data:`_BIN_PX` bins); the sharpness is the between-bin variance of the binned means,
    largest when the walls fall into the fewest bins.
    """
    rows, cols = lines.shape
    y, x = np.mgrid[0:rows, 0:cols]
    yp = (y - (x - (cols - 1) / 2) * math.tan(math.radians(tilt_deg))) / _BIN_PX
    yp -= yp.min()
    i = np.floor(yp).astype(int).ravel()
    w = (yp - np.floor(yp)).ravel()
    v = lines.ravel()
    n = i.max() + 2
    sums = np.bincount(i, (1 - w) * v, n) + np.bincount(i + 1, w * v, n)
    counts = np.bincount(i, 1 - w, n) + np.bincount(i + 1, w, n)
    ok = counts > 0.25 * cols
    means = sums[ok] / counts[ok]
    return float(np.sum(counts[ok] * (means - np.sum(sums[ok]) / np.sum(counts[ok])) ** 2))


def estimate_tilt(background: np.ndarray, max_tilt_deg: float = MAX_TILT_DEG) -> float:
    """Tilt of the walls [deg] (``atan(d row / d column)``), from a background image.

    First the angle that makes the walls' projection along it sharpest (steps of 0.1 deg over
    +-``max_tilt_deg``), then straight lines fitted to the wall lines found near it
    (:func:`_fit_lines`): 0.002 deg on rendered 400x200 px stacks tilted by up to 2.4 deg
    (the tests check 0.05 deg). Without a wall line to fit, the coarse angle.
    """
    lines = _line_image(background)
    coarse = np.arange(-max_tilt_deg, max_tilt_deg + 1e-9, 0.1)
    sharpness = np.array([_projection_sharpness(lines, float(a)) for a in coarse])
    # Angles equally sharp (a level background's walls: +-0.1 deg give the same projection, to
    # rounding) are a plateau: its middle, not whichever rounding favours.
    plateau = coarse[sharpness >= sharpness.max() * (1 - 1e-6)]
    best = float(coarse[int(np.argmin(np.abs(coarse - plateau.mean())))])
    refined = _fit_lines(background, lines, best)
    return best if refined is None else refined


def _fit_lines(background: np.ndarray, lines: np.ndarray, coarse_deg: float, strip_px: int = 8) -> float | None:
    """Tilt [deg] from straight-line fits to the wall lines, found near the coarse tilt.

    Each line's centre is located, to a fraction of a pixel, in strips of ``strip_px`` columns
    (centroid of the strip's darkness above half its peak, within 2 px of the coarse line:
    the other line of a doubled wall lies 2-5 px away);
    a straight line is fitted through them (points off by more than 1 px dropped, refitted),
    and the slopes are averaged, weighted by their number of points. A projection-sharpness
    refinement would be biased towards 0 (unresampled pixels are sharpest); these fits are not.
    """
    rows, cols = lines.shape
    slope0 = math.tan(math.radians(coarse_deg))
    centre = (cols - 1) / 2
    slopes, weights = [], []
    for row0 in wall_lines(level(background, coarse_deg)):
        xs, ys = [], []
        for c0 in range(0, cols - strip_px + 1, strip_px):
            x = c0 + (strip_px - 1) / 2
            guess = row0 + (x - centre) * slope0
            lo, hi = int(round(guess)) - 2, int(round(guess)) + 3
            if lo < 0 or hi > rows:
                continue
            window = lines[lo:hi, c0:c0 + strip_px].mean(axis=1)
            peak = int(np.argmax(window))
            if window[peak] <= 0 or peak in (0, len(window) - 1):
                continue
            xs.append(x)
            ys.append(lo + _peak_centre(window, peak))
        if len(xs) < 4:
            continue
        x_arr, y_arr = np.array(xs), np.array(ys)
        fit = np.polyfit(x_arr, y_arr, 1)
        keep = np.abs(np.polyval(fit, x_arr) - y_arr) < 1.0
        if keep.sum() >= 4:
            fit = np.polyfit(x_arr[keep], y_arr[keep], 1)
            slopes.append(fit[0])
            weights.append(keep.sum())
    if not slopes:
        return None
    return float(math.degrees(math.atan(np.average(slopes, weights=weights))))


def level(image: np.ndarray, tilt_deg: float, order: int = 1) -> np.ndarray:
    """Rotate ``image`` about its centre so that lines of tilt ``tilt_deg`` become horizontal.

    A rotation (not a shear): lengths along the flow are kept. The corners that come from
    outside the frame repeat its edge (they then vanish against a background levelled alike).
    Rows at the centre column keep their place, so wall rows read there stay valid.
    """
    if abs(tilt_deg) < 1e-3:
        return np.asarray(image, dtype=np.float32)
    if order != 1:
        return ndimage.rotate(np.asarray(image, dtype=np.float32), tilt_deg, reshape=False, order=order,
                              mode="nearest")
    # The same bilinear rotation as ndimage.rotate(order=1, mode="nearest") (to 1e-4 grey levels),
    # its sample positions and weights computed once per frame size and tilt: every frame of a
    # stack is rotated by the same angle, and four gathers are 5 times faster than the rotation.
    a, b, c, d, wa, wb, wc, wd = _bilinear_rotation(np.asarray(image).shape, float(tilt_deg))
    flat = np.asarray(image, dtype=np.float32).ravel()
    return (wa * flat[a] + wb * flat[b] + wc * flat[c] + wd * flat[d]).reshape(np.asarray(image).shape)


@lru_cache(maxsize=8)
def _bilinear_rotation(shape: tuple[int, ...], tilt_deg: float) -> tuple[np.ndarray, ...]:
    """Flat indices of the four neighbours and their bilinear weights of every output pixel of
    the rotation about the centre by ``tilt_deg`` (``ndimage.rotate``'s matrix, edge-clamped)."""
    from scipy import special

    rows, cols = int(shape[0]), int(shape[1])
    cos, sin = float(special.cosdg(tilt_deg)), float(special.sindg(tilt_deg))
    centre = (np.array([rows, cols], dtype=float) - 1) / 2
    offset = centre - np.array([[cos, sin], [-sin, cos]]) @ centre
    r, k = np.mgrid[0:rows, 0:cols].astype(float)
    y = np.clip(cos * r + sin * k + offset[0], 0, rows - 1)
    x = np.clip(-sin * r + cos * k + offset[1], 0, cols - 1)
    y0 = np.minimum(np.floor(y).astype(np.intp), max(rows - 2, 0))
    x0 = np.minimum(np.floor(x).astype(np.intp), max(cols - 2, 0))
    fy, fx = (y - y0).astype(np.float32), (x - x0).astype(np.float32)
    first = (y0 * cols + x0).ravel()
    return (first, first + 1, first + cols, first + cols + 1, ((1 - fy) * (1 - fx)).ravel(),
            ((1 - fy) * fx).ravel(), (fy * (1 - fx)).ravel(), (fy * fx).ravel())


def _peak_centre(profile: np.ndarray, peak: int) -> float:
    """Sub-pixel centre of a peak: the centroid of its samples above half its height.

    The span stops where the profile rises again: the two lines of a doubled wall, 2 px
    apart, keep their own centres.
    """
    height = profile[peak]
    lo = hi = peak
    while lo > 0 and height / 2 < profile[lo - 1] <= profile[lo]:
        lo -= 1
    while hi < profile.size - 1 and height / 2 < profile[hi + 1] <= profile[hi]:
        hi += 1
    rows = np.arange(lo, hi + 1)
    weights = profile[lo:hi + 1] - height / 2
    # The half-height samples themselves weigh zero; guard the degenerate one-sample peak.
    return float(np.sum(rows * weights) / np.sum(weights)) if np.sum(weights) > 0 else float(peak)


def wall_lines(background: np.ndarray, min_darkness: float = 0.04, relative: float = 0.1,
               max_width_px: float = 12.0, min_span: float = 0.8) -> list[float]:
    """Rows of the dark horizontal lines of a levelled background, sub-pixel, top to bottom.

    The row profile is each row's median over the columns (a notch or the constriction's end
    does not move it). Broad illumination dips are no lines: the profile's slow part (median
    over 15 rows) is taken off first, and what is left wider than ``max_width_px`` at half its
    prominence (the slight darkening of a channel's middle, 30-50 px wide in RT-DC chips) is
    no line either. Lines fainter than ``min_darkness`` of the bright level, or than
    ``relative`` times the darkest line, are left out, and so are lines that darken less than
    ``min_span`` of the frame's width (:func:`_spans`).
    """
    from scipy.signal import find_peaks

    image = np.asarray(background, dtype=np.float32)
    profile = np.median(image, axis=1)
    bright = float(np.percentile(profile, 90))
    if bright <= 0:
        raise ExtractionError("the frames are black")
    dark = 1 - profile / bright
    padding = profile <= 0.05 * bright
    dark[padding] = float(np.median(dark))
    lines = dark - ndimage.median_filter(dark, size=15, mode="nearest")
    peaks, props = find_peaks(lines, prominence=min_darkness, width=(None, max_width_px))
    if peaks.size == 0:
        return []
    strong = props["prominences"] >= relative * props["prominences"].max()
    # A wall spans the frame; an object lying in every frame (a slow capsule's straight body,
    # part of the background then) spans only part of it.
    spans = _spans(image, bright, peaks)
    strong &= spans >= min_span
    centres: list[float] = []
    for p in peaks[strong]:
        row = _peak_centre(lines, int(p))
        # Two peaks of one doubled line can share their half-height span, hence their centre.
        if not centres or row - centres[-1] > 1.0:
            centres.append(row)
    return centres


def _spans(image: np.ndarray, bright: float, peaks: np.ndarray, strip_px: int = 16) -> np.ndarray:
    """For each line row in ``peaks``: the fraction of the width (strips of ``strip_px`` columns)
    where that row is darker than the rows 3 px above and below by a third of the line's
    darkness over the whole width."""
    rows, cols = image.shape
    n = max(1, cols // strip_px)
    strips = 1 - image[:, :n * strip_px].reshape(rows, n, -1).mean(axis=2) / bright
    whole = 1 - np.median(image, axis=1) / bright
    out = np.zeros(len(peaks))
    for k, p in enumerate(peaks):
        above, below = max(0, p - 3), min(rows - 1, p + 3)
        depth = whole[p] - 0.5 * (whole[above] + whole[below])
        local = strips[p] - 0.5 * (strips[above] + strips[below])
        out[k] = float(np.mean(local > depth / 3)) if depth > 0 else 1.0
    return out


#: A band is at least this much darker than the bright level (the darkening of an RT-DC
#: channel's middle, up to 18 % against the bright bands beside its walls, is none), wider than
#: a line (``wall_lines``' max width), and one of its edges at least is a step: the darkness
#: goes from under 30 % to over 70 % of the band's within EDGE_PX px either side of the half-way
#: row (the channel's middle darkens over 10 px and more; the other edge of a band may run into
#: more glass, a doubled wall's outer band).
MIN_BAND_DARKNESS = 0.25
EDGE_PX = 4


def dark_bands(background: np.ndarray, min_width_px: float = 12.0,
               min_darkness: float = MIN_BAND_DARKNESS) -> list[tuple[float, float]]:
    """Dark horizontal bands wider than a line (a capillary's glass seen as a thick band), top to
    bottom, as (first row, last row) of their edges at half their darkness, sub-pixel; a band cut
    by the image's edge reaches -0.5 or rows - 0.5 there.

    The row profile (median over the columns) is median-filtered over ``2 min_width_px + 1``
    rows: a median keeps a band's edges in place and removes the lines narrower than the
    window; a run of rows darker than ``min_darkness`` longer than ``min_width_px`` is a band,
    its edges where the unfiltered profile crosses half its median darkness (:func:`find_walls`
    moves them to the steepest point, :func:`_edge_row`).
    """
    image = np.asarray(background, dtype=np.float32)
    profile = np.median(image, axis=1)
    bright = float(np.percentile(profile, 90))
    if bright <= 0:
        return []
    dark = 1 - profile / bright
    slow = ndimage.median_filter(dark, size=2 * int(min_width_px) + 1, mode="nearest")
    runs, count = ndimage.label(slow > min_darkness)
    bands = []
    for k in range(1, count + 1):
        idx = np.nonzero(runs == k)[0]
        if idx.size <= min_width_px:
            continue
        half = 0.5 * float(np.median(dark[idx]))
        middle = int(idx[idx.size // 2])
        first, last = _half_crossing(dark, half, middle, -1), _half_crossing(dark, half, middle, +1)
        if _is_step(dark, half, first, -1) or _is_step(dark, half, last, +1):
            bands.append((first, last))
    return bands


def _half_crossing(dark: np.ndarray, half: float, start: int, step: int) -> float:
    """From ``start`` inside a band, outward (``step`` -1: up, +1: down) to where the darkness
    falls below ``half``, interpolated; the image's edge (-0.5 or rows - 0.5) if it never does."""
    rows = len(dark)
    r = start
    while 0 <= r + step < rows and dark[r + step] >= half:
        r += step
    if not 0 <= r + step < rows:
        return -0.5 if step < 0 else rows - 0.5
    a, b = float(dark[r]), float(dark[r + step])
    return r + step * (a - half) / (a - b) if a != b else float(r)


def _is_step(dark: np.ndarray, half: float, edge: float, step: int) -> bool:
    """A band's edge (outward in direction ``step``) is a step - under 30 % of the band's
    darkness ``EDGE_PX`` px outside, over 70 % that far inside - or out of view."""
    rows = len(dark)
    if not 0 <= edge < rows - 1:
        return True
    outside = min(max(int(round(edge + step * EDGE_PX)), 0), rows - 1)
    inside = min(max(int(round(edge - step * EDGE_PX)), 0), rows - 1)
    return bool(dark[outside] < 0.6 * half and dark[inside] > 1.4 * half)


#: A flat-topped dark feature at least this wide at half its depth shows the glass in its
#: thickness (a band): the wall is its liquid-side edge. A narrower one is a line, the
#: interface's own image (how RT-DC chips and the package's renderer show a wall): the wall is
#: its centre. 5.3 px: a 6 px band narrowed by a refraction line against it (5.6 px) is a band;
#: the dclab recordings' wall lines are at most 5.2 px wide where they are flat-topped.
BAND_MIN_WIDTH_PX = 5.55
#: Bands up to this wide are found by :func:`thin_bands`; wider and deep ones by :func:`dark_bands`.
THIN_BAND_MAX_WIDTH_PX = 25.0
#: A band's darkness is flat-topped: its width at 80 % of its depth over its width at half depth
#: is at least this (0.72 for a 6 px band blurred by 1 px; 0.54 for a line's Gaussian bell).
PLATEAU_RATIO = 0.645
#: Columns per strip over which an edge or a line is located again for its uncertainty.
UNCERTAINTY_STRIP_PX = 32
#: The locators' own resolution [px]: a parabola through pixel samples of a blurred step (or a
#: centroid of a line) is biased by the step's sub-pixel phase, up to 0.06 px for a blur of 0.8 px
#: and 0.04 px for 1 px (computed on exact erf steps); added to every wall's uncertainty.
LOCATOR_RESOLUTION_PX = 0.05


def _row_profile(image: np.ndarray) -> np.ndarray:
    """Each row's trimmed mean over the columns (a speck or a notch does not move it; the mean
    of 8-bit values is not quantised as their median is)."""
    from scipy.stats import trim_mean

    return np.asarray(trim_mean(np.asarray(image, dtype=np.float64), 0.2, axis=1), dtype=float)


def _darkness(profile: np.ndarray) -> np.ndarray:
    """``1 - I / bright`` of a row profile (bright: its 90th percentile); black padding rows get
    the profile's median darkness (they are no line)."""
    bright = float(np.percentile(profile, 90))
    if bright <= 0:
        raise ExtractionError("the frames are black")
    dark = 1 - profile / bright
    dark[profile <= 0.05 * bright] = float(np.median(dark))
    return dark


def thin_bands(background: np.ndarray, min_width_px: float = BAND_MIN_WIDTH_PX,
               max_width_px: float = THIN_BAND_MAX_WIDTH_PX, min_darkness: float = 0.08) -> list[tuple[float, float]]:
    """Dark bands from ``min_width_px`` to ``max_width_px`` wide at half their depth (a capillary's
    glass in a thin wall, with or without a bright refraction line beside it), top to bottom, as
    (first, last) rows of their edges (:func:`_edge_row`).

    The darkness profile's slow part (a median over more than twice the widest band) is taken
    off; a peak at least ``min_darkness`` deep is a band when its width between its half-depth
    crossings is in range, unless it holds two minima (a doubled line: two interfaces, each a
    line) or its top is no plateau (:data:`PLATEAU_RATIO`: a line blurred wide). Each side's
    depth is counted from that side's own level (the liquid and the glass beyond the band, or a
    refraction line against it, are not equally bright). A band is told from a line only where
    its plateau is resolved: wider than about 5 times the blur.
    """
    from scipy.signal import find_peaks

    dark = _darkness(_row_profile(background))
    excess = dark - ndimage.median_filter(dark, size=4 * int(max_width_px) + 1, mode="nearest")
    # Darker than the profile's slow level (the liquid's, mostly) too: the liquid between two
    # refraction lines is a peak of the profile, not a band.
    peaks, props = find_peaks(excess, height=min_darkness, prominence=min_darkness)
    bands = []
    for k, peak in enumerate(peaks):
        sides = [_side_level(excess, int(peak), step, int(max_width_px) + 4, props["prominences"][k]) for step in (-1, +1)]
        if excess[peak] - max(sides) < min_darkness:
            continue
        crossings = {}
        for fraction in (0.5, 0.2):
            crossings[fraction] = [_half_crossing(excess, excess[peak] - fraction * (excess[peak] - base), int(peak), step)
                                   for base, step in zip(sides, (-1, +1))]
        first, last = crossings[0.5]
        if not min_width_px <= last - first <= max_width_px:
            continue
        inside = excess[int(math.ceil(first)):int(math.floor(last)) + 1]
        minima, _ = find_peaks(inside, prominence=0.1 * props["prominences"][k])
        if minima.size > 1:
            continue
        # A band's plateau: at a fifth of its depth below the darkest row it is still
        # PLATEAU_RATIO of its width at half depth (a line's bell: 0.54 for a Gaussian).
        if crossings[0.2][1] - crossings[0.2][0] < PLATEAU_RATIO * (last - first):
            continue
        bands.append((_edge_row(dark, first, +1), _edge_row(dark, last, -1)))
    return bands


def _side_level(excess: np.ndarray, peak: int, step: int, reach_px: int, depth: float) -> float:
    """The level beside a dark peak ``depth`` deep, on one side (``step`` -1: above, +1: below):
    walking out of the band, once past half its depth, where the darkness stops falling (by
    less than 5 % of the depth from one row to the next, or rises: a refraction line's
    trough, the liquid's or the glass's level; not a further feature), at most ``reach_px``
    out. Before half the depth the walk is still on the band's plateau or edge."""
    top = float(excess[peak])
    r = peak
    while 0 <= r + step < excess.size and abs(r + step - peak) <= reach_px:
        fall = float(excess[r]) - float(excess[r + step])
        if top - float(excess[r]) > 0.5 * depth and fall < 0.05 * depth:
            break
        r += step
    return float(excess[r])


def _edge_row(dark: np.ndarray, guess: float, into_band: int, reach_px: float = 2.5) -> float:
    """Sub-pixel row of a band's edge near ``guess``: where the darkness changes fastest
    (``into_band`` +1: it rises downwards, the band's upper edge; -1: its lower edge).

    The steepest point, not the half-depth crossing: a bright refraction line against the
    band's edge steepens the step there but moves a half-depth crossing, and so does a slow
    illumination gradient. A parabola through the three differences around the steepest one.
    """
    slope = into_band * np.diff(dark)           # slope[i] lies at row i + 0.5
    rows = np.arange(slope.size) + 0.5
    near = np.nonzero(np.abs(rows - guess) <= reach_px)[0]
    if near.size == 0:
        return float(guess)
    i = int(near[np.argmax(slope[near])])
    if slope[i] <= 0 or i == 0 or i == slope.size - 1:
        return float(guess)
    a, b, c = slope[i - 1], slope[i], slope[i + 1]
    denominator = a - 2 * b + c
    shift = 0.5 * (a - c) / denominator if denominator < 0 else 0.0
    return float(rows[i] + min(max(shift, -0.5), 0.5))


def wall_uncertainty(background: np.ndarray, row: float, kind: str, band_px: float = 0.0,
                     strip_px: int = UNCERTAINTY_STRIP_PX, columns: tuple[int, int] | None = None) -> float:
    """Standard uncertainty [px] of a wall's row found on the whole width.

    The wall is located again, alike, in strips of ``strip_px`` columns: the spread of the
    strips' rows over the square root of their number (the noise, the chip's texture and a
    residual tilt), and, for the edge of a band ``band_px`` wide (``kind`` ``upper edge`` or
    ``lower edge``), half the
    distance between the steepest point and the half-depth crossing of the whole profile (the
    edge's shape: blur, a refraction line) and :data:`LOCATOR_RESOLUTION_PX`, added in quadrature.
    ``kind`` ``line``: a line's centre. NaN when fewer than 3 strips locate it.
    """
    image = np.asarray(background, dtype=np.float32)
    if columns is not None:
        image = image[:, columns[0]:columns[1] + 1]
    rows, cols = image.shape
    n = max(1, cols // strip_px)
    located = []
    for s in range(n):
        dark = _darkness(_row_profile(image[:, s * strip_px:(s + 1) * strip_px if s < n - 1 else cols]))
        located.append(_locate(dark, row, kind))
    found = np.array([r for r in located if math.isfinite(r)])
    spread = float(np.std(found, ddof=1) / math.sqrt(found.size)) if found.size >= 3 else math.nan
    shape = 0.0
    if kind != "line":
        dark = _darkness(_row_profile(image))
        shape = 0.5 * abs(_half_depth_row(dark, row, +1 if kind == "upper edge" else -1, band_px) - row)
    return float(math.sqrt(spread ** 2 + shape ** 2 + LOCATOR_RESOLUTION_PX ** 2)) if math.isfinite(spread) else math.nan


def _locate(dark: np.ndarray, row: float, kind: str) -> float:
    """A wall located again near ``row`` in a strip's darkness profile (NaN if it is not there)."""
    if kind == "line":
        lo = max(0, int(round(row)) - 2)
        window = dark[lo:int(round(row)) + 3] - float(np.min(dark[max(0, lo - 4):int(round(row)) + 7]))
        if window.size < 3:
            return math.nan
        peak = int(np.argmax(window))
        return lo + _peak_centre(window, peak) if window[peak] > 0 else math.nan
    return _edge_row(dark, row, +1 if kind == "upper edge" else -1, reach_px=1.5)


def _half_depth_row(dark: np.ndarray, edge: float, into_band: int, band_px: float, reach_px: int = 4) -> float:
    """Where the darkness crosses half-way between the level ``reach_px`` outside a band's edge
    and the level in the band's middle (``band_px`` wide); the edge itself if it does not."""
    rows = dark.size
    e = int(round(edge))
    outside = dark[min(max(e - into_band * reach_px, 0), rows - 1)]
    inside = dark[min(max(int(round(edge + into_band * band_px / 2)), 0), rows - 1)]
    half = 0.5 * (outside + inside)
    best = edge
    for r in range(max(0, e - reach_px), min(rows - 1, e + reach_px)):
        a, b = dark[r] - half, dark[r + 1] - half
        if a == b or (a > 0) == (b > 0):
            continue
        crossing = r + a / (a - b)
        if best == edge or abs(crossing - edge) < abs(best - edge):
            best = crossing
    return float(best)


#: How far from a line's darkest row [px] its liquid-side edge is looked for: the dclab
#: recordings' wall lines brighten towards the liquid within 4 rows of it.
LINE_EDGE_REACH_PX = 4


def _line_edge(dark: np.ndarray, line_row: float, towards: int, kinds: dict[float, tuple[str, float]]) -> float:
    """The liquid-side edge of the wall line centred near ``line_row`` (``towards`` +1: the liquid
    lies below it, -1: above): where the darkness falls fastest from its darkest row (within 1 px
    of the centre) towards the liquid, within :data:`LINE_EDGE_REACH_PX` (:func:`_edge_row`).
    Records the edge in ``kinds`` (an ``upper``/``lower edge`` of a band as wide as twice its
    distance from the darkest row) for its uncertainty; the centre itself where no fall is found."""
    rows = dark.size
    lo, hi = max(0, int(round(line_row)) - 1), min(rows, int(round(line_row)) + 2)
    darkest = lo + int(np.argmax(dark[lo:hi]))
    reach = LINE_EDGE_REACH_PX / 2
    edge = _edge_row(dark, darkest + towards * reach, -towards, reach_px=reach)
    if edge == darkest + towards * reach or (edge - darkest) * towards <= 0:
        return line_row
    kinds[edge] = ("lower edge" if towards > 0 else "upper edge", 2 * abs(edge - darkest))
    return edge


def find_walls(background: np.ndarray, label: str = "frames", channel_width_px: float | None = None,
               min_darkness: float = 0.04, channel_width_sigma_px: float = 0.0) -> Walls:
    """The channel's two walls in a levelled background image, each with its uncertainty.

    The channel is the widest bright interval between consecutive dark lines or band edges:
    glass shown as a band (:func:`thin_bands`, :func:`dark_bands`), whose liquid-side edge is
    the wall, located where the darkness changes fastest (:func:`_edge_row`); beside a doubled
    wall line it is the inner line that bounds it, read by its liquid-side edge too
    (:func:`_line_edge`), a bright band between two lines of one wall
    is narrower than the channel, and the inside of a band is no candidate. When that interval
    reaches the image's edge, the wall there is outside the view: it is placed at
    ``channel_width_px`` (uncertainty ``channel_width_sigma_px``) from the other, when given.

    Raises
    ------
    ExtractionError
        When no wall line is found, or one wall is out of view and no width is given.
    """
    rows = np.asarray(background).shape[0]
    dark = _darkness(_row_profile(background))
    bands = [(_edge_row(dark, first, +1) if first > -0.5 else first,
              _edge_row(dark, last, -1) if last < rows - 0.5 else last) for first, last in dark_bands(background)]
    bands += [band for band in thin_bands(background)
              if not any(first - 1 < band[1] and band[0] < last + 1 for first, last in bands)]
    bands.sort()
    # An edge is kind 'upper edge' (a band below it) or 'lower edge', with its band's width; a
    # line's centre, 'line' (the line bounding the channel is then read by its liquid-side edge).
    kinds = {edge: (kind, last - first) for first, last in bands
             for edge, kind in ((first, "upper edge"), (last, "lower edge")) if -0.5 < edge < rows - 0.5}
    # A line within a band, or touching it, is part of the glass's picture, not another wall.
    for row in wall_lines(background, min_darkness):
        if not any(first - 1 < row < last + 1 for first, last in bands):
            kinds.setdefault(row, ("line", 0.0))
    lines = sorted(kinds)
    hint = ("; give the walls' rows (--walls ROW1,ROW2) or, for a wall outside the view, "
            "the channel width (--channel-width)")
    if not lines:
        raise ExtractionError(f"{label}: found no channel wall (dark horizontal line) in the background{hint}")
    edges = [-0.5, *lines, rows - 0.5]
    gaps = np.diff(edges)
    for i in range(len(gaps)):
        middle = 0.5 * (edges[i] + edges[i + 1])
        if any(first <= middle <= last for first, last in bands):
            gaps[i] = 0.0                 # inside the glass
    k = int(np.argmax(gaps))
    top, bottom = edges[k], edges[k + 1]
    # A line bounding the channel is read, as a band is, by its liquid-side edge: the glass lies
    # outside the liquid, and the line's far half is its picture, not the liquid's.
    line_rows = []
    if top in kinds and kinds[top][0] == "line":
        line_rows.append(top)
        top = _line_edge(dark, top, +1, kinds)
    if bottom in kinds and kinds[bottom][0] == "line":
        line_rows.append(bottom)
        bottom = _line_edge(dark, bottom, -1, kinds)

    def sigma(row: float) -> float:
        return wall_uncertainty(background, row, *kinds[row])

    placed = "one wall detected, the other placed at the channel width"
    if 0 < k < len(edges) - 2:
        walls = Walls(top, bottom, top_sigma_px=sigma(top), bottom_sigma_px=sigma(bottom), lines=tuple(line_rows))
    elif channel_width_px is None:
        seen = "top" if k > 0 else "bottom"
        raise ExtractionError(f"{label}: only the {seen} wall is in view (line at row "
                              f"{top if k > 0 else bottom:.1f}){hint}")
    elif k == 0 and len(edges) > 2:
        seen_sigma = sigma(bottom)
        walls = Walls(bottom - channel_width_px, bottom, placed, top_sigma_px=math.hypot(seen_sigma, channel_width_sigma_px),
                      bottom_sigma_px=seen_sigma, lines=tuple(line_rows), placed_side="top")
    elif k > 0:
        seen_sigma = sigma(top)
        walls = Walls(top, top + channel_width_px, placed, top_sigma_px=seen_sigma,
                      bottom_sigma_px=math.hypot(seen_sigma, channel_width_sigma_px), lines=tuple(line_rows),
                      placed_side="bottom")
    else:
        raise ExtractionError(f"{label}: found no channel wall in the background{hint}")
    if walls.radius_px < 5:
        raise ExtractionError(f"{label}: the walls found (rows {walls.top_row:.1f}, {walls.bottom_row:.1f}) are too "
                              f"close to be a channel{hint}")
    return walls


#: Strips (columns) in which :func:`straight_columns` looks for the wall lines.
STRAIGHT_STRIP_PX = 16


def straight_columns(background: np.ndarray, walls: Walls, strip_px: int = STRAIGHT_STRIP_PX) -> tuple[int, int] | None:
    """First and last column of the straight channel in a levelled background: where each
    detected wall line lies at its row, or None when it does over the whole width.

    Beyond, the walls leave their rows: the channel widens into its inlet or outlet (an RT-DC
    chip's reservoirs, a capillary's end). What lies there is wall, not a capsule, and the
    tube's model does not hold there. Per strip of ``strip_px`` columns a line is present
    when its row is darker than the rows 3 px above and below by a third of the line's depth
    over the whole width (as :func:`wall_lines` requires of a wall); the ends are then placed to
    the column where the line, averaged over 5 columns, reaches half its depth. Only the ends of
    the view are cut: a notch or a speck on a wall further in is no end. Walls given by the
    user, placed at the channel width or found as a glass band's edge are not looked for.
    """
    image = np.asarray(background, dtype=np.float32)
    rows, cols = image.shape
    if walls.source == "given":
        return None
    bright = float(np.percentile(np.median(image, axis=1), 90))
    n = cols // strip_px
    if bright <= 0 or n < 3:
        return None
    # The walls that are lines: not one placed at the channel width, nor a glass band's edge (a
    # step, not a line: it has no depth against the rows either side).
    rows_in_view = [r for r in walls.lines if 3 <= round(r) <= rows - 4]
    present = np.ones(n, dtype=bool)
    # Per column (a running mean over 5): the line at half its depth or more, to place the ends.
    column_present = np.ones(cols, dtype=bool)
    whole = 1 - np.median(image, axis=1) / bright
    strips = 1 - image[:, :n * strip_px].reshape(rows, n, strip_px).mean(axis=2) / bright
    dark = 1 - image / bright
    for row in rows_in_view:
        r = int(round(row))
        depth = whole[r] - 0.5 * (whole[r - 3] + whole[r + 3])
        if depth <= 0:
            continue
        present &= strips[r] - 0.5 * (strips[r - 3] + strips[r + 3]) > depth / 3
        local = ndimage.uniform_filter1d(dark[r] - 0.5 * (dark[r - 3] + dark[r + 3]), 5, mode="nearest")
        column_present &= local > depth / 2
    if present.all() or not present.any():
        return None
    first_strip = int(np.argmax(present))
    last_strip = n - 1 - int(np.argmax(present[::-1]))
    # The strips beyond the last full one (cols % strip_px columns) follow the last strip.
    first = first_strip * strip_px
    last = cols - 1 if last_strip == n - 1 else (last_strip + 1) * strip_px - 1
    # The ends to the column: the strip's edge moved to where the line starts (stops) in the
    # column profile, within a strip either way.
    if first > 0:
        while first > max(0, (first_strip - 1) * strip_px) and column_present[first - 1]:
            first -= 1
        while first < min(last, (first_strip + 1) * strip_px) and not column_present[first]:
            first += 1
    if last < cols - 1:
        while last < min(cols - 1, (last_strip + 2) * strip_px - 1) and column_present[last + 1]:
            last += 1
        while last > max(first, last_strip * strip_px - 1) and not column_present[last]:
            last -= 1
    if first == 0 and last == cols - 1:
        return None
    return first, last


def parse_walls(text: str) -> tuple[float, float]:
    """``'ROW1,ROW2'`` -> (top, bottom) rows, for ``--walls``.

    Raises
    ------
    ExtractionError
        Unless two different numbers separated by a comma.
    """
    try:
        a, b = (float(part) for part in str(text).split(","))
    except ValueError:
        raise ExtractionError(f"--walls: {text!r} is not two rows ROW1,ROW2 (px, at the image's centre column)") from None
    if not (math.isfinite(a) and math.isfinite(b)) or abs(a - b) < 10:
        raise ExtractionError(f"--walls: {text!r}: the two rows must be finite and at least 10 px apart")
    return min(a, b), max(a, b)


#: The tolerance of a given channel width when the user states none: a nominal width (a chip's
#: design, a capillary's catalogue bore) is rarely better than 2 %.
DEFAULT_WIDTH_TOLERANCE = 0.02


@dataclass(frozen=True)
class WidthCheck:
    """The walls found against the channel width the user gave.

    Attributes
    ----------
    text : str
        For the printout: both widths, which one is used and why.
    disagrees : bool
        The two differ by more than both uncertainties: twice the found width's standard
        uncertainty plus the given width's tolerance.
    verdict : str
        For the measurement CSV's ``width_check`` column: ``agrees``, ``disagrees (...)``,
        ``walls given`` or ``placed (one wall in view)``.
    """

    text: str
    disagrees: bool
    verdict: str


def check_width(walls: Walls, given_px: float, tolerance: float = DEFAULT_WIDTH_TOLERANCE) -> WidthCheck:
    """Compare the walls' width with ``given_px`` (tolerance: a fraction of it).

    The width found is used whenever both walls are in view: it is measured where the capsules
    are, to a fraction of a pixel, while a given width is a nominal one (and carries the pixel
    size's error too). A disagreement beyond both uncertainties is said, not mended: one of the
    two (or the pixel size) is wrong, and only the user can tell which.
    """
    found = walls.width_px
    diff = found - given_px
    pct = 100 * diff / given_px
    tol_px = tolerance * given_px
    head = f"channel width {found:.1f} px found, {given_px:.1f} px given: {pct:+.1f} %"
    if walls.source == "given":
        far = abs(diff) > tol_px
        return WidthCheck(head + (" (more than 10 % apart: check the walls or the width)" if abs(pct) > 10 else "")
                          + "; the walls given are used", far,
                          f"disagrees ({pct:+.1f} %, walls given)" if far else "agrees (walls given)")
    if "placed" in walls.source:
        return WidthCheck(f"channel width {given_px:.1f} px given (tolerance {100 * tolerance:g} %): used to place the "
                          f"wall outside the view; not checked, one wall is in view", False,
                          "placed (one wall in view)")
    sigma = walls.width_sigma_px if math.isfinite(walls.width_sigma_px) else 0.0
    allowed = 2 * sigma + tol_px
    head = (f"channel width {found:.1f} +- {sigma:.1f} px found, {given_px:.1f} px given (tolerance "
            f"{100 * tolerance:g} %): {pct:+.1f} %")
    if abs(diff) > allowed:
        return WidthCheck(head + f", beyond both uncertainties (+-{allowed:.1f} px): the width found is used (the walls "
                          "as imaged, where the capsules are); check the pixel size, the walls on the overlay "
                          "(--overlay) and the width given, or give the walls (--walls ROW1,ROW2)", True,
                          f"disagrees (found {found:.1f} px, given {given_px:.1f} px: {pct:+.1f} %)")
    return WidthCheck(head + ", within the uncertainties: the width found is used", False, "agrees")


def symmetry_line(object_rows: Sequence[float]) -> tuple[float, float, int]:
    """The objects' own symmetry line: the median row of their centroids, its standard error
    and the number of objects (NaN, NaN under 3)."""
    rows = np.asarray([r for r in object_rows if math.isfinite(r)], dtype=float)
    if rows.size < 3:
        return math.nan, math.nan, int(rows.size)
    # The median's standard error, 1.2533 times the mean's for normal scatter.
    return float(np.median(rows)), 1.2533 * float(np.std(rows, ddof=1)) / math.sqrt(rows.size), int(rows.size)


def check_axis(walls: Walls, object_rows: Sequence[float]) -> tuple[str, bool]:
    """Where one wall was placed at the given width: the axis against the objects' own
    symmetry line (:func:`symmetry_line`). Returns the sentence and whether the two
    differ by more than 1 px and twice their combined uncertainty."""
    line, error, count = symmetry_line(object_rows)
    if count < 3:
        return "the axis placed could not be checked against the objects (fewer than 3 traced)", False
    axis_sigma = walls.width_sigma_px / 2 if math.isfinite(walls.width_sigma_px) else 0.0
    off = line - walls.axis_row
    allowed = max(1.0, 2 * math.hypot(error, axis_sigma))
    if abs(off) > allowed:
        return (f"the objects' symmetry line (row {line:.1f}, {count} objects) lies {off:+.1f} px from the axis "
                f"placed at row {walls.axis_row:.1f}: the width given or the wall in view is off", True)
    return f"the objects' symmetry line (row {line:.1f}, {count} objects) confirms the axis placed ({off:+.1f} px)", False


def axis_from_objects(walls: Walls, object_rows: Sequence[float]) -> Walls:
    """The placed wall moved so that the axis is the objects' symmetry line (:func:`symmetry_line`).

    Capsules flowing in a tube are centred on its axis: where the wall placed at the given width
    puts the axis off their symmetry line beyond both uncertainties (:func:`check_axis`), the
    width given (or the pixel size) is off, and the line they share is the better axis. The
    placed wall's uncertainty is then twice the line's standard error and the seen wall's, in
    quadrature.

    Raises
    ------
    ValueError
        When no wall was placed or fewer than 3 objects are traced.
    """
    line, error, count = symmetry_line(object_rows)
    if walls.placed_side not in ("top", "bottom") or count < 3:
        raise ValueError("the axis is taken from the objects only where one wall was placed and 3 objects are traced")
    source = "one wall detected, the other placed by the objects' symmetry line"
    if walls.placed_side == "top":
        sigma = math.hypot(2 * error, walls.bottom_sigma_px)
        return replace(walls, top_row=2 * line - walls.bottom_row, top_sigma_px=sigma, source=source)
    sigma = math.hypot(2 * error, walls.top_sigma_px)
    return replace(walls, bottom_row=2 * line - walls.top_row, bottom_sigma_px=sigma, source=source)
