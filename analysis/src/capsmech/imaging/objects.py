"""Objects in a flat-field contrast image: found, separated, and traced as a ring or a silhouette.

Two kinds of object are traced, and each says which it is and where its contour lies:

- a **ring**: a dark membrane line around a transparent interior (capsules, calibration
  beads). Its contour is the line's **mid-line**: the iso-lines at half the line's peak
  contrast are its two edges (``skimage.measure.find_contours``, sub-pixel), each outer point
  paired with the nearest inner one (on the common normal of two parallel curves), their
  midpoint the membrane - the middle of the dark line, as in the paper's manual extraction.
  An interior brighter (or darker) than the liquid moves the inner half-peak edge; the mid-line
  is then moved onto the line's darkness centre, each side's level subtracted on its own side
  (:func:`midline_shift`);
- a **silhouette**: a filled, opaque object (cells, beads seen out of their ring focus). Its
  contour is the **outer edge**: the iso-line of the detection's contrast (smoothed
  :data:`DETECTION_SMOOTHING_PX`) at the detection level, which is where the object mask
  thresholded on that same contrast ends.

An object is a ring when the half-peak iso-lines enclose a transparent interior of at least
:data:`MIN_INTERIOR_FRACTION` of the outer edge's area, else a silhouette.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree
from scipy.stats import trim_mean

#: Gaussian smoothing (px) of the contrast before objects are detected, and before edges are traced.
DETECTION_SMOOTHING_PX = 1.0
CONTOUR_SMOOTHING_PX = 0.6
#: A ring's interior (inside the half-peak inner edge) covers at least this much of its outer edge's area.
MIN_INTERIOR_FRACTION = 0.15
#: A light interior opening through a notch in its rim (:func:`closed_outline`) is a cavity of
#: the object's mask at least this many times its mouth's squared width (a 40 x 30 px interior
#: behind a 10 px gap: 9; a parachute's rear, as wide as deep: under 1) ...
CAVITY_MOUTH_RATIO = 2.0
#: ... and at least this fraction of the object's convex hull (not a rough edge's dent).
MIN_ENCLOSED_FRACTION = 0.05
#: A silhouette's edge: this fraction of its peak contrast (90th percentile of the detection's
#: contrast over its pixels), or the detection threshold if higher.
SILHOUETTE_LEVEL = 0.2

CONTOUR_AT = {"ring": "mid-line of the dark ring", "silhouette": "outer edge of the silhouette"}


@dataclass
class TracedObject:
    """One object of a frame, traced.

    Attributes
    ----------
    kind : {'ring', 'silhouette'}
    contour : (n, 2) array
        (x, y) of the closed contour, px: the ring's mid-line or the silhouette's outer edge.
    outer : (n, 2) array
        The object's outer edge (the same as ``contour`` for a silhouette).
    line_width_px : float
        Full width at half maximum of a ring's line; NaN for a silhouette.
    line_contrast : float
        Peak contrast (90th percentile over the object's pixels).
    x_front, x_rear : float
        Axial extremes of the contour (for a ring, the outer edge's extremes one half line
        width in: see :func:`trace_object`).
    columns : (int, int)
        First and last image column of the object's pixels.
    track : int
        The object's track across frames (``tracking.track_objects``; -1: not tracked).
    x_rear_axis, L_z_px, L_p_px, asymmetry : float
        The object's own measurement (``measurement.measure_trace``; NaN until measured).
    flag : str
        Why this object cannot be measured ('' when it can), whatever the other objects of
        its frame show: each object of a frame with several is measured on its own.
    dropped : str
        Why this object is no capsule's ('' when it is one's, or none was looked for): a piece
        cut by the frame's edge or lying in a wall's band that joins no passage
        (``tracking.settle_pieces``).
    """

    kind: str
    contour: np.ndarray = field(repr=False)
    outer: np.ndarray = field(repr=False)
    line_width_px: float
    line_contrast: float
    x_front: float
    x_rear: float
    columns: tuple[int, int]
    track: int = -1
    x_rear_axis: float = math.nan
    L_z_px: float = math.nan
    L_p_px: float = math.nan
    asymmetry: float = math.nan
    flag: str = ""
    dropped: str = ""

    @property
    def contour_at(self) -> str:
        """Where the contour lies, in words."""
        return CONTOUR_AT[self.kind]

    @cached_property
    def centre(self) -> tuple[float, float]:
        """Area centroid (x, y) of the contour (computed once: the tracker asks for it per link)."""
        return polygon_centroid(self.contour)

    @property
    def extent_px(self) -> float:
        """Extent along the flow of the contour (``x_front - x_rear``)."""
        return self.x_front - self.x_rear

    @property
    def outer_extent_px(self) -> float:
        """Extent along the flow of the outer edge (what a thresholded mask spans)."""
        return float(self.outer[:, 0].max() - self.outer[:, 0].min())


def closed_contours(field_: np.ndarray, level: float) -> list[np.ndarray]:
    """Closed iso-lines of ``field_`` at ``level`` as (x, y) arrays, longest first."""
    from skimage.measure import find_contours

    contours = [c[:, ::-1] for c in find_contours(field_, level) if len(c) > 8 and _same_point(c[0], c[-1])]
    return sorted(contours, key=len, reverse=True)


def _same_point(a: np.ndarray, b: np.ndarray) -> bool:
    """``np.allclose(a, b)`` for two points, without its cost of a few microseconds a call (it is
    called for every contour of every frame)."""
    return all(p == q or abs(p - q) <= 1e-8 + 1e-5 * abs(q) for p, q in zip(a.tolist(), b.tolist()))


def resample(points: np.ndarray, spacing: float) -> np.ndarray:
    """Closed polyline (first point repeated at the end or not) resampled at ``spacing`` by arclength."""
    if not _same_point(points[0], points[-1]):
        points = np.vstack([points, points[:1]])
    seg = np.hypot(*np.diff(points, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(8, int(np.ceil(s[-1] / spacing)))
    t = np.linspace(0, s[-1], n, endpoint=False)
    return np.column_stack([np.interp(t, s, points[:, 0]), np.interp(t, s, points[:, 1])])


def polygon_area(points: np.ndarray) -> float:
    """Unsigned area of a closed polygon (shoelace)."""
    x, y = points[:, 0], points[:, 1]
    return float(abs(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)) / 2)


def polygon_centroid(points: np.ndarray) -> tuple[float, float]:
    """Area centroid of a closed polygon (shoelace formula)."""
    x, y = points[:, 0], points[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = cross.sum() / 2
    if abs(area) < 1e-9:
        return float(x.mean()), float(y.mean())
    return float(((x + xn) * cross).sum() / (6 * area)), float(((y + yn) * cross).sum() / (6 * area))


def line_width(contrast: np.ndarray, peak: float) -> float:
    """Full width at half maximum of a line: area above half its peak over its skeleton's length."""
    from skimage.morphology import skeletonize

    band = contrast > peak / 2
    length = skeletonize(band).sum()
    return float(band.sum() / length) if length else math.inf


def find_objects(smooth: np.ndarray, inside: np.ndarray, detection_sigmas: float, min_area_px: int,
                 wall_rows: tuple[float, ...] = (), wall_band_px: float = 6.0, noise_map: np.ndarray | None = None,
                 ) -> tuple[np.ndarray, np.ndarray, list[int], float]:
    """Dark objects of a smoothed contrast image, inside the channel.

    Pixels above ``detection_sigmas`` noise deviations (median absolute deviation inside the
    channel; where the stack's own noise at each pixel, ``noise_map``, is larger, that one:
    ``background.temporal_noise``), fragments closer than 2 px joined (one faint line breaks
    up), specks smaller than ``min_area_px`` dropped. So are thin streaks along a wall (all their pixels within
    ``wall_band_px`` of a wall row, at most 4 px high): what is left of a wall line that moved
    by a fraction of a pixel between the background and the frame, not an object.

    Returns
    -------
    labels : int array
        Component labels of the joined mask.
    mask : bool array
        The pixels above the threshold.
    keep : list of int
        Labels of the objects kept.
    threshold : float
        The frame's detection threshold (contrast; higher where ``noise_map`` is).
    """
    from skimage.measure import label as label_components

    # Every other pixel of every other row: as good an estimate of the noise, a quarter of the cost.
    values = smooth[::2, ::2][inside[::2, ::2]]
    noise = 1.4826 * float(np.median(np.abs(values - np.median(values)))) if values.size else 0.0
    threshold = max(detection_sigmas * noise, 0.01)
    if noise_map is not None:
        mask = (smooth > np.maximum(threshold, detection_sigmas * noise_map)) & inside
    else:
        mask = (smooth > threshold) & inside
    # Joined and labelled on the mask's bounding box grown by the dilation's reach (the rest of
    # the frame is empty): the same labels, numbered in the same raster order, at a fraction of
    # the whole frame's cost.
    reach = 2
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    r0, c0 = (max(0, int(rows[0]) - reach), max(0, int(cols[0]) - reach)) if rows.size else (0, 0)
    r1, c1 = (int(rows[-1]) + reach + 1, int(cols[-1]) + reach + 1) if rows.size else (1, 1)
    window = (slice(r0, r1), slice(c0, c1))
    joined = ndimage.binary_dilation(mask[window], iterations=reach)
    part, count = label_components(joined, return_num=True, connectivity=2)
    labels = np.zeros(mask.shape, dtype=part.dtype)
    labels[window] = part
    sizes = np.bincount(labels[mask].ravel(), minlength=count + 1)
    keep = []
    for k, box in enumerate(ndimage.find_objects(part), start=1):
        if box is None or sizes[k] < min_area_px:
            continue
        top, bottom = r0 + box[0].start, r0 + box[0].stop - 1
        if bottom - top <= 4 and any(top >= w - wall_band_px and bottom <= w + wall_band_px for w in wall_rows):
            continue
        keep.append(k)
    return labels, mask, keep, threshold


def trace_object(contrast: np.ndarray, region: np.ndarray, mask: np.ndarray, threshold: float,
                 smooth: np.ndarray | None = None) -> TracedObject | str:
    """Trace one object (its joined ``region``; ``mask``: the pixels above the threshold).

    A ring's edges are traced on a lighter smoothing than the detection's: blur pulls the edge
    back around a parachute's sharp rim (L_p -0.35 px at 1 px, -0.16 px at 0.6 px for a
    28 px deep parachute), while too little lets the noise push the extremes out (+0.3 px
    on L_z without smoothing). A silhouette's outer edge is traced on the detection's
    smoothing: it is where the detection mask ends.

    ``smooth``, the contrast at the detection's smoothing, when the caller has it already.
    The smoothings are computed on a window around the object, wide enough (6 px beyond the
    crop) to give the whole frame's values there.

    Returns
    -------
    TracedObject, or str
        The reason when no closed contour is found.
    """
    rows, cols = contrast.shape
    r_idx, c_idx = np.nonzero(region & mask)
    pad, margin = 3, 6
    r0, r1 = max(0, r_idx.min() - pad), min(rows, r_idx.max() + pad + 1)
    c0, c1 = max(0, c_idx.min() - pad), min(cols, c_idx.max() + pad + 1)
    w0, w1 = max(0, r0 - margin), min(rows, r1 + margin)
    v0, v1 = max(0, c0 - margin), min(cols, c1 + margin)
    window = (slice(r0 - w0, r1 - w0), slice(c0 - v0, c1 - v0))
    inside = (region & mask)[r0:r1, c0:c1]
    sub_region = region[r0:r1, c0:c1]
    line = np.where(sub_region, ndimage.gaussian_filter(contrast[w0:w1, v0:v1], CONTOUR_SMOOTHING_PX)[window], 0.0)
    peak = float(np.percentile(line[inside], 90))
    # Zero border: every iso-line of the crop is closed.
    crop = np.pad(line, 1)
    offset = np.array([c0 - 1, r0 - 1])
    columns = (int(c_idx.min()), int(c_idx.max()))
    edges = closed_contours(crop, peak / 2)
    if edges:
        outer = edges[0]
        from skimage.measure import points_in_poly

        inner = next((e for e in edges[1:] if points_in_poly(e[::max(1, len(e) // 16)], outer).all()), None)
        if inner is not None and _is_interior(inner, outer):
            outer = resample(outer, 0.25)
            inner_dense = resample(inner, 0.05)
            # A tree split at the midpoints (not the medians), its boxes not shrunk: on points
            # along a curve it is built and searched faster, and gives the same nearest points.
            _, nearest = cKDTree(inner_dense, leafsize=32, balanced_tree=False, compact_nodes=False).query(outer)
            contour = resample((outer + inner_dense[nearest]) / 2 + offset, 0.5)
            # The axial extremes from the outer edge, one half line width in: at a parachute's
            # rim the membrane folds back within a few line widths, the inner edge cannot
            # enter the fold and the mid-line there falls short (by 3 px for a 28 px deep
            # parachute); the outer edge stays parallel to the membrane.
            half_width = float(np.median(np.hypot(*(outer - inner_dense[nearest]).T))) / 2
            # The half-peak edges are the line's only where the interior is as bright as the
            # liquid: a brighter interior pulls the inner edge out, and the mid-line with it.
            shift = midline_shift(contrast[w0:w1, v0:v1], contour - np.array([v0, w0]), half_width)
            if math.isfinite(shift):
                contour = shifted_along_normal(contour, shift)
                half_width -= shift
            detected = (smooth[r0:r1, c0:c1] if smooth is not None else
                        ndimage.gaussian_filter(contrast[w0:w1, v0:v1], DETECTION_SMOOTHING_PX)[window])
            width = line_width(np.where(sub_region, detected, 0.0), float(np.percentile(detected[inside], 90)))
            return TracedObject("ring", contour, outer + offset, width, peak,
                                float(outer[:, 0].max()) + offset[0] - half_width,
                                float(outer[:, 0].min()) + offset[0] + half_width, columns)
    # A silhouette: its outer edge at the detection level, traced on the detection's own contrast
    # (smoothed DETECTION_SMOOTHING_PX): the iso-line where the object's mask, thresholded on that
    # same contrast, ends. The ring's lighter smoothing sharpens a rim; here it would trace an edge
    # that is not the mask's (faint fringes and appendages come and go with the smoothing).
    detected = (smooth[r0:r1, c0:c1] if smooth is not None else
                ndimage.gaussian_filter(contrast[w0:w1, v0:v1], DETECTION_SMOOTHING_PX)[window])
    body = np.where(sub_region, detected, 0.0)
    level = max(threshold, SILHOUETTE_LEVEL * float(np.percentile(body[inside], 90)))
    crop = np.pad(body, 1)
    filled = closed_outline(crop > level)
    edges = closed_contours(np.where(filled, np.maximum(crop, level * 1.0001), crop), level)
    if not edges:
        return "no closed contour (object too faint or cut)"
    outer = resample(edges[0], 0.5) + offset
    return TracedObject("silhouette", outer, outer, math.nan, peak, float(outer[:, 0].max()),
                        float(outer[:, 0].min()), columns)


def closed_outline(mask: np.ndarray) -> np.ndarray:
    """``mask`` with its holes filled and, where its rim is open, its interior filled too.

    A cell with a light interior shows as a dark rim around it; where the rim is faint over a
    few pixels, the rim's mask is a C whose interior opens to the liquid through a notch, and
    filling holes leaves the notch. What the mask lacks of its convex hull is split into
    cavities; a cavity whose area is at least :data:`CAVITY_MOUTH_RATIO` times its mouth's
    squared width (its pixels on the hull's edge) and :data:`MIN_ENCLOSED_FRACTION` of the
    hull's area is such an interior, and is filled. A parachute's rear (a cavity as wide as it is
    deep, or wider) and the waist between two touching objects open wide and are kept.
    """
    from skimage.measure import label as label_components
    from skimage.morphology import convex_hull_image

    filled = ndimage.binary_fill_holes(mask)
    if filled.sum() < 3:
        return filled
    hull = convex_hull_image(filled)
    rim = hull & ~ndimage.binary_erosion(hull)
    cavities, count = label_components(hull & ~filled, return_num=True, connectivity=1)
    if not count:
        return filled
    areas = np.bincount(cavities.ravel(), minlength=count + 1)
    mouths = np.bincount(cavities[rim], minlength=count + 1)
    interior = [k for k in range(1, count + 1)
                if areas[k] >= CAVITY_MOUTH_RATIO * mouths[k] ** 2 and areas[k] >= MIN_ENCLOSED_FRACTION * hull.sum()]
    return filled | np.isin(cavities, interior) if interior else filled


def outward_normals(contour: np.ndarray) -> np.ndarray:
    """Unit outward normals of a closed contour (central differences; either orientation)."""
    tangent = np.roll(contour, -1, axis=0) - np.roll(contour, 1, axis=0)
    normal = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    normal /= np.maximum(np.hypot(*normal.T), 1e-12)[:, None]
    x, y = contour[:, 0], contour[:, 1]
    signed_area = np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) / 2
    # (dy, -dx) points out of a counter-clockwise contour (positive signed area).
    return normal if signed_area > 0 else -normal


def shifted_along_normal(contour: np.ndarray, shift: float) -> np.ndarray:
    """The closed contour moved ``shift`` px outward along its normals (inward when negative)."""
    if not math.isfinite(shift) or shift == 0.0:
        return contour
    return contour + shift * outward_normals(contour)


def midline_shift(contrast: np.ndarray, contour: np.ndarray, half_width: float) -> float:
    """How far (px, outward positive) a ring's darkness centre lies from ``contour``, its mid-line
    between the half-peak edges: the interquartile mean over the contour of the line's centroid
    across it (robust to the few points where a parachute's fold enters the profile, and less
    noisy than the median).

    Across the line the contrast is sampled along each point's normal (``contrast`` unsmoothed:
    a smoothing would spread the line over a curved path), and the level of each side is
    subtracted on its own side of the line - the interior's (inner end of the profile) inside,
    the liquid's outside - before the darkness's centroid is taken over +-3 sigma of the line:
    an interior brighter or darker than the liquid then no longer moves the centre, as it moves
    the half-peak inner edge (a 4 % brighter interior: +0.12 px outward for a 1.2 px line). A few
    iterations put the step between the sides at the centre found. What is left is the step's
    own blur, which weighs on the inner side: -delta s^2 / (2 A) px for a step delta of blur s
    under a line of area A (-0.02 px for the 4 % interior). NaN when the profiles say nothing
    (a line too faint or too wide for the sampled span).
    """
    sigma = max(2 * half_width / 2.355, 0.5)
    span = 3.5 * sigma + 1.5
    u = np.arange(-span, span + 1e-9, 0.25)
    # One profile a pixel of the contour (its points lie 0.5 px apart): the line's pixels all
    # enter, at half the cost.
    normals = outward_normals(contour)[::2]
    contour = contour[::2]
    # The sample points (row, column) written straight into the coordinate array map_coordinates reads.
    coordinates = np.empty((2, len(contour), u.size))
    np.add(contour[:, 1, None], u[None, :] * normals[:, 1, None], out=coordinates[0])
    np.add(contour[:, 0, None], u[None, :] * normals[:, 0, None], out=coordinates[1])
    profiles = ndimage.map_coordinates(contrast, coordinates, order=1, mode="nearest")
    ends = np.abs(u) > span - 1.5
    inner_level = profiles[:, ends & (u < 0)].mean(axis=1)[:, None]
    outer_level = profiles[:, ends & (u > 0)].mean(axis=1)[:, None]
    centre: np.ndarray = np.zeros((len(contour), 1))
    for _ in range(3):
        darkness = profiles - np.where(u[None, :] < centre, inner_level, outer_level)
        weight = np.where(np.abs(u[None, :] - centre) <= 3 * sigma, darkness, 0.0)
        total = weight.sum(axis=1, keepdims=True)
        found = total > 0
        centre = np.where(found, (weight * u).sum(axis=1, keepdims=True) / np.where(found, total, 1.0), 0.0)
        centre = np.clip(centre, -sigma, sigma)
    good = found[:, 0]
    if good.sum() < max(8, len(contour) // 4):
        return math.nan
    return float(trim_mean(centre[good, 0], 0.25))


def _is_interior(inner: np.ndarray, outer: np.ndarray) -> bool:
    """Whether ``inner`` (inside ``outer``) bounds a ring's transparent interior, not a speck of texture.

    Only its size counts: a parachute's interior is a crescent, far off the outer centroid.
    """
    a_in, a_out = polygon_area(inner), polygon_area(outer)
    return a_out > 0 and a_in >= MIN_INTERIOR_FRACTION * a_out
