"""Objects in a flat-field contrast image: found, separated, and traced as a ring or a silhouette.

Two kinds of object are traced, and each says which it is and where its contour lies:

- a **ring**: a dark membrane line around a transparent interior (capsules, calibration
  beads). Its contour is the line's **mid-line**: the iso-lines at half the line's peak
  contrast are its two edges (marching squares, sub-pixel: :func:`closed_contours`), each outer point
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
from typing import cast

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
#: What an object's mask lacks of its hull is split at necks narrower than twice this (px): a
#: cell's interior opening through a notch of its rim into the waist beside a touching cell is
#: one region with the waist; split there, the interior is told from the waist.
INTERIOR_NECK_PX = 5
#: Parts of one region each at least this fraction of the hull are as many interiors (two cells'
#: joined through notches of their rims facing each other: 0.13-0.46 measured); smaller ones are
#: one cell's interior cut by its own texture (a real cell's three parts: 0.06-0.09).
SEPARATE_INTERIOR_FRACTION = 0.11
#: A ring whose outer edge's perimeter squared over 4 pi its area exceeds this is checked for
#: several light interiors (:func:`light_interiors`): a capsule's outline is round (1.2-1.3 for
#: the films' parachutes), one that enters a touching cell through a notch of its rim is not (5-9).
MAX_RING_ROUNDNESS = 2.0
#: The flag of an object holding several cells' interiors: touching cells, not one capsule.
TOUCHING_FLAG = "touching objects ({} light interiors in one outline: not one capsule)"
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
    """Closed iso-lines of ``field_`` at ``level`` as (x, y) arrays, longest first: those of
    ``skimage.measure.find_contours``, point for point and from the same start.

    Marching squares with linear interpolation along the cell edges. Where no cell of the field
    is a saddle (two diagonal corners above the level, the other two below), matplotlib's own
    contouring (contourpy) gives the same points and joins them into lines in compiled code, at
    a third of the cost (``find_contours`` joins them in Python); each line is then started where
    ``find_contours`` starts it (:func:`_scan_start`). A saddle is resolved differently by the
    two (``find_contours`` always parts the corners above the level, contourpy joins them when
    the cell's mean is above it): a field with one is contoured by ``find_contours`` itself.
    """
    from contourpy import LineType, contour_generator

    z = np.asarray(field_, dtype=np.float64)
    above = z > level
    diagonal = above[:-1, :-1] == above[1:, 1:]
    saddles = diagonal & (above[:-1, 1:] == above[1:, :-1]) & (above[:-1, :-1] != above[:-1, 1:])
    if saddles.any():
        from skimage.measure import find_contours

        contours = [c[:, ::-1] for c in find_contours(z, level) if len(c) > 8 and _same_point(c[0], c[-1])]
        return sorted(contours, key=len, reverse=True)
    # LineType.Separate: a list of (n, 2) arrays, each closed line's first point repeated at its end.
    lines = cast("list[np.ndarray]", contour_generator(z=z, name="serial", line_type=LineType.Separate).lines(level))
    started = [_scan_start(c, z.shape[1]) for c in lines if len(c) > 8 and _same_point(c[0], c[-1])]
    # More than 8 points once those repeated at a grid node are dropped, as find_contours counts
    # them; it lists its lines in the order it began them (their first cell in row-major order),
    # and equally long ones keep that order.
    started = [(line, first) for line, first in started if len(line) > 8]
    return [line for line, _ in sorted(started, key=lambda item: (-len(item[0]), item[1]))]


def _scan_start(line: np.ndarray, columns: int) -> tuple[np.ndarray, int]:
    """A closed iso-line (x, y; its first point repeated at the end) of a field of ``columns``
    columns started where ``find_contours`` starts it: after its segment in the last grid cell
    in row-major order (the one that closes it there); and the row-major index of its first cell
    (where ``find_contours`` began it). Resampled from the same start, a contour gives the same
    points as before the change of contouring code."""
    # A grid node exactly at the level gives a segment of no length, which find_contours drops.
    moved = np.any(line[1:] != line[:-1], axis=1)
    if not moved.all():
        line = np.concatenate([line[:1], line[1:][moved]])
    # A segment's cell holds its midpoint (its ends lie on the cell's sides, where rounding
    # may put a point on a whole row or column a hair to either side).
    middle = (line[:-1] + line[1:]) / 2
    cell = (np.floor(middle[:, 1]) * columns + np.floor(middle[:, 0])).astype(np.intp)
    last = int(np.argmax(cell))
    start = (last + 1) % (len(line) - 1)
    return np.concatenate([line[start:-1], line[:start + 1]]), int(cell.min())


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


def nearest_on_polyline(polyline: np.ndarray, points: np.ndarray, spacing: float = 0.25) -> np.ndarray:
    """The nearest point of a closed ``polyline`` (first point repeated at the end or not) to
    each of ``points``.

    The polyline's segments are cut into pieces of at most ``spacing`` (its vertices kept: the
    same line), and each point is projected on the pieces beside its two nearest piece ends. The
    nearest point of the line lies on one of them unless another part of the line comes within
    ``spacing**2 / (8 d)`` of the same distance d (0.003 px at d = 2.5 px): a projection, exact
    to that, where a dense sampling of the line is exact only to its spacing.
    """
    vertices = polyline[:-1] if len(polyline) > 1 and _same_point(polyline[0], polyline[-1]) else polyline
    step = _next(vertices) - vertices
    pieces = np.maximum(np.ceil(np.hypot(*step.T) / spacing).astype(np.intp), 1)
    segment = np.repeat(np.arange(len(vertices)), pieces)
    fraction = (np.arange(segment.size) - np.repeat(np.cumsum(pieces) - pieces, pieces)) / pieces[segment]
    nodes = vertices[segment] + fraction[:, None] * step[segment]
    n = len(nodes)
    _, nearest = cKDTree(nodes).query(points, k=min(2, n))
    nearest = nearest.reshape(len(points), -1)
    # Pieces (v - 1, v) and (v, v + 1) of each of the nearest ends v; x and y apart (a sum over
    # an axis of two is slow).
    starts = np.concatenate([nearest - 1, nearest], axis=1) % n
    ends = (starts + 1) % n
    ax, ay = nodes[starts, 0], nodes[starts, 1]
    dx, dy = nodes[ends, 0] - ax, nodes[ends, 1] - ay
    qx, qy = points[:, 0, None] - ax, points[:, 1, None] - ay
    t = np.clip((qx * dx + qy * dy) / np.maximum(dx * dx + dy * dy, 1e-300), 0.0, 1.0)
    ex, ey = qx - t * dx, qy - t * dy
    best = (ex * ex + ey * ey).argmin(axis=1)
    pick = np.arange(len(points))
    return np.column_stack([ax[pick, best] + t[pick, best] * dx[pick, best],
                            ay[pick, best] + t[pick, best] * dy[pick, best]])


def _next(values: np.ndarray) -> np.ndarray:
    """``np.roll(values, -1, axis=0)``: each point's successor along a closed line (a slice and
    one row, without np.roll's cost on short arrays)."""
    return np.concatenate([values[1:], values[:1]])


def _previous(values: np.ndarray) -> np.ndarray:
    """``np.roll(values, 1, axis=0)``: each point's predecessor along a closed line."""
    return np.concatenate([values[-1:], values[:-1]])


def polygon_area(points: np.ndarray) -> float:
    """Unsigned area of a closed polygon (shoelace)."""
    x, y = points[:, 0], points[:, 1]
    return float(abs(np.sum(x * _next(y) - _next(x) * y)) / 2)


def polygon_centroid(points: np.ndarray) -> tuple[float, float]:
    """Area centroid of a closed polygon (shoelace formula)."""
    x, y = points[:, 0], points[:, 1]
    xn, yn = _next(x), _next(y)
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
                 smooth: np.ndarray | None = None, box: tuple[slice, slice] | None = None) -> TracedObject | str:
    """Trace one object (its joined ``region``; ``mask``: the pixels above the threshold).

    A ring's edges are traced on a lighter smoothing than the detection's: blur pulls the edge
    back around a parachute's sharp rim (L_p -0.35 px at 1 px, -0.16 px at 0.6 px for a
    28 px deep parachute), while too little lets the noise push the extremes out (+0.3 px
    on L_z without smoothing). A silhouette's outer edge is traced on the detection's
    smoothing: it is where the detection mask ends.

    ``smooth``, the contrast at the detection's smoothing, when the caller has it already.
    ``box``, the (row, column) slices that hold ``region``, when the caller knows them: the
    object is looked for there, not over the whole frame.
    The smoothings are computed on a window around the object, wide enough (6 px beyond the
    crop) to give the whole frame's values there.

    Returns
    -------
    TracedObject, or str
        The reason when no closed contour is found. An object that holds two light interiors
        or more (touching cells: :func:`light_interiors`) is traced and flagged
        (:data:`TOUCHING_FLAG`): not one capsule.
    """
    rows, cols = contrast.shape
    if box is None:
        r_idx, c_idx = np.nonzero(region & mask)
    else:
        r_idx, c_idx = np.nonzero(region[box] & mask[box])
        r_idx, c_idx = r_idx + box[0].start, c_idx + box[1].start
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

        enclosed = [e for e in edges[1:] if points_in_poly(e[::max(1, len(e) // 16)], outer).all()]
        inner = enclosed[0] if enclosed else None
        if inner is not None and _is_interior(inner, outer):
            # Touching cells: two interiors within one outer edge, or an outer edge far from
            # convex (it enters a cell through a notch of its rim) around a mask that holds two.
            interiors = sum(_is_interior(e, outer) for e in enclosed)
            if interiors < 2 and _roundness(outer) > MAX_RING_ROUNDNESS:
                interiors = light_interiors(np.pad(inside, 1))[1]
            touching = TOUCHING_FLAG.format(interiors) if interiors > 1 else ""
            outer = resample(outer, 0.25)
            paired = nearest_on_polyline(inner, outer)
            contour = resample((outer + paired) / 2 + offset, 0.5)
            # The axial extremes from the outer edge, one half line width in: at a parachute's
            # rim the membrane folds back within a few line widths, the inner edge cannot
            # enter the fold and the mid-line there falls short (by 3 px for a 28 px deep
            # parachute); the outer edge stays parallel to the membrane.
            half_width = float(np.median(np.hypot(*(outer - paired).T))) / 2
            # The half-peak edges are the line's only where the interior is as bright as the
            # liquid: a brighter interior pulls the inner edge out, and the mid-line with it.
            normals = outward_normals(contour)
            shift = midline_shift(contrast[w0:w1, v0:v1], contour - np.array([v0, w0]), half_width, normals)
            if math.isfinite(shift):
                if shift != 0.0:
                    contour = contour + shift * normals
                half_width -= shift
            detected = (smooth[r0:r1, c0:c1] if smooth is not None else
                        ndimage.gaussian_filter(contrast[w0:w1, v0:v1], DETECTION_SMOOTHING_PX)[window])
            width = line_width(np.where(sub_region, detected, 0.0), float(np.percentile(detected[inside], 90)))
            return TracedObject("ring", contour, outer + offset, width, peak,
                                float(outer[:, 0].max()) + offset[0] - half_width,
                                float(outer[:, 0].min()) + offset[0] + half_width, columns, flag=touching)
    # A silhouette: its outer edge at the detection level, traced on the detection's own contrast
    # (smoothed DETECTION_SMOOTHING_PX): the iso-line where the object's mask, thresholded on that
    # same contrast, ends. The ring's lighter smoothing sharpens a rim; here it would trace an edge
    # that is not the mask's (faint fringes and appendages come and go with the smoothing).
    detected = (smooth[r0:r1, c0:c1] if smooth is not None else
                ndimage.gaussian_filter(contrast[w0:w1, v0:v1], DETECTION_SMOOTHING_PX)[window])
    body = np.where(sub_region, detected, 0.0)
    level = max(threshold, SILHOUETTE_LEVEL * float(np.percentile(body[inside], 90)))
    crop = np.pad(body, 1)
    filled, interiors = light_interiors(crop > level)
    edges = closed_contours(np.where(filled, np.maximum(crop, level * 1.0001), crop), level)
    if not edges:
        return "no closed contour (object too faint or cut)"
    outer = resample(edges[0], 0.5) + offset
    return TracedObject("silhouette", outer, outer, math.nan, peak, float(outer[:, 0].max()),
                        float(outer[:, 0].min()), columns, flag=TOUCHING_FLAG.format(interiors) if interiors > 1 else "")


def closed_outline(mask: np.ndarray) -> np.ndarray:
    """``mask`` with its holes filled and, where its rim is open, its interior filled too
    (:func:`light_interiors`)."""
    return light_interiors(mask)[0]


def light_interiors(mask: np.ndarray) -> tuple[np.ndarray, int]:
    """``mask`` with its holes and its open light interiors filled, and how many light interiors
    it holds (one for a cell, two for two touching cells).

    A cell with a light interior shows as a dark rim around it; where the rim is faint over a
    few pixels, the rim's mask is a C whose interior opens to the liquid through a notch, and
    filling holes leaves the notch. What the mask lacks of its convex hull is split into regions
    (its holes, and cavities open to the hull's edge), each region at its necks narrower than
    2 :data:`INTERIOR_NECK_PX` (the cores an erosion leaves, grown back within it): a cell's
    interior opening into the waist beside a touching cell is told from the waist. A cavity (or
    such a part of one) whose area is at least :data:`CAVITY_MOUTH_RATIO` times its mouth's
    squared width (its pixels on the hull's edge) and :data:`MIN_ENCLOSED_FRACTION` of the
    hull's area is an interior, and is filled; so is every hole, an interior when as large. A
    parachute's rear (a cavity as wide as it is deep, or wider) and the waist between two
    touching objects open wide and are kept.
    """
    from skimage.measure import label as label_components
    from skimage.morphology import convex_hull_image, disk

    filled = ndimage.binary_fill_holes(mask)
    if filled.sum() < 3:
        return filled, 0
    hull = convex_hull_image(filled)
    rim = hull & ~ndimage.binary_erosion(hull)
    least = MIN_ENCLOSED_FRACTION * hull.sum()
    spaces = hull & ~mask
    regions, count = label_components(spaces, return_num=True, connectivity=1)
    if not count:
        return filled, 0
    neck = disk(INTERIOR_NECK_PX)
    cores, n_cores = label_components(ndimage.binary_erosion(spaces, neck), return_num=True, connectivity=1)
    # Each core's region, and its part: the core grown back within its own region.
    part_region = np.zeros(n_cores + 1, dtype=np.intp)
    part_region[cores[cores > 0]] = regions[cores > 0]
    grown = ndimage.grey_dilation(cores, footprint=neck)
    parts = np.where(spaces & (part_region[grown] == regions), grown, 0)

    def interior(labels: np.ndarray, n: int, ids: np.ndarray) -> np.ndarray:
        """Which of ``ids`` (labels in ``labels``) are interiors: holes or narrow-mouthed cavities."""
        areas = np.bincount(labels.ravel(), minlength=n + 1)[ids]
        mouths = np.bincount(labels[rim], minlength=n + 1)[ids]
        return (areas >= CAVITY_MOUTH_RATIO * mouths ** 2) & (areas >= least)

    # A region with two or more large parts that are interiors (two cells' joined through
    # notches facing each other) counts them all, filled whole; else a region that is an
    # interior whole (a cell's interior and its notch) one, filled whole; else one whose parts are
    # (a cell's interior opening into a waist) one, those parts filled alone.
    ids = np.arange(1, n_cores + 1)
    passing = ids[(part_region[1:] > 0) & interior(parts, n_cores, ids)]
    large = passing[np.bincount(parts.ravel(), minlength=n_cores + 1)[passing] >= SEPARATE_INTERIOR_FRACTION * hull.sum()]
    large_of = np.bincount(part_region[large], minlength=count + 1)
    several = np.flatnonzero(large_of >= 2)
    regions_whole = np.arange(1, count + 1)
    whole = regions_whole[interior(regions, count, regions_whole) & (large_of[1:] < 2)]
    alone = passing[~np.isin(part_region[passing], np.concatenate([whole, several]))]
    found = int(large_of[several].sum()) + len(whole) + len(np.unique(part_region[alone]))
    if found:
        filled = filled | np.isin(regions, np.concatenate([whole, several])) | np.isin(parts, alone)
    return filled, found


def _roundness(outline: np.ndarray) -> float:
    """A closed outline's perimeter squared over 4 pi its area: 1 for a circle."""
    perimeter = float(np.hypot(*(_next(outline) - outline).T).sum())
    return perimeter ** 2 / max(4 * math.pi * polygon_area(outline), 1e-12)


def outward_normals(contour: np.ndarray) -> np.ndarray:
    """Unit outward normals of a closed contour (central differences; either orientation)."""
    tangent = _next(contour) - _previous(contour)
    normal = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    normal /= np.maximum(np.hypot(*normal.T), 1e-12)[:, None]
    x, y = contour[:, 0], contour[:, 1]
    signed_area = np.sum(x * _next(y) - _next(x) * y) / 2
    # (dy, -dx) points out of a counter-clockwise contour (positive signed area).
    return normal if signed_area > 0 else -normal


def midline_shift(contrast: np.ndarray, contour: np.ndarray, half_width: float,
                  normals: np.ndarray | None = None) -> float:
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
    normals = (outward_normals(contour) if normals is None else normals)[::2]
    contour = contour[::2]
    # The sample points (row, column) written straight into one coordinate array.
    coordinates = np.empty((2, len(contour), u.size))
    np.add(contour[:, 1, None], u[None, :] * normals[:, 1, None], out=coordinates[0])
    np.add(contour[:, 0, None], u[None, :] * normals[:, 0, None], out=coordinates[1])
    profiles = bilinear_samples(contrast, coordinates[0], coordinates[1])
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


def bilinear_samples(image: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``image`` at (``rows``, ``cols``), bilinear, points beyond the edge moved onto it:
    ``ndimage.map_coordinates(image, [rows, cols], order=1, mode="nearest")``, by four gathers
    (two thirds of its cost on a line's profiles, some ten thousand points)."""
    if min(image.shape) < 2:
        # One row or column: its edge repeated makes the four neighbours of every point.
        image = np.pad(image, ((0, 1 if image.shape[0] < 2 else 0), (0, 1 if image.shape[1] < 2 else 0)), mode="edge")
    n_rows, n_cols = image.shape
    r = np.clip(rows, 0.0, n_rows - 1)
    c = np.clip(cols, 0.0, n_cols - 1)
    r0 = np.minimum(r.astype(np.intp), n_rows - 2)
    c0 = np.minimum(c.astype(np.intp), n_cols - 2)
    fr, fc = r - r0, c - c0
    flat = np.ascontiguousarray(image, dtype=np.float64).ravel()
    i00 = r0 * n_cols + c0
    i10 = i00 + n_cols
    top = flat[i00] + fc * (flat[i00 + 1] - flat[i00])
    bottom = flat[i10] + fc * (flat[i10 + 1] - flat[i10])
    return top + fr * (bottom - top)


def _is_interior(inner: np.ndarray, outer: np.ndarray) -> bool:
    """Whether ``inner`` (inside ``outer``) bounds a ring's transparent interior, not a speck of texture.

    Only its size counts: a parachute's interior is a crescent, far off the outer centroid.
    """
    a_in, a_out = polygon_area(inner), polygon_area(outer)
    return a_out > 0 and a_in >= MIN_INTERIOR_FRACTION * a_out
