"""Measuring one frame's capsule, and the frame's record: lengths, symmetry, focus.

:class:`FrameResult` is what a frame shows (its flag, what was traced, the lengths);
:class:`ExtractionSettings` the thresholds. The lengths follow the paper: L_z the contour's
axial extent, L_p from its rear-most point to its rear crossing of the tube axis; the symmetry
is the mean distance between the upper half and the mirrored lower half over L_z / 2.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from capsmech.imaging.objects import TracedObject


@dataclass(frozen=True)
class ExtractionSettings:
    """Thresholds of the extraction (defaults suit 1-4 px membrane lines, tube radius > 20 px)."""

    detection_sigmas: float = 6.0
    min_area_px: int = 30
    max_line_width_px: float = 10.0
    focus_ratio: float = 1.6
    max_asymmetry: float = 0.05
    min_good_frames: int = 3


#: The default thresholds (an immutable instance, shared as a default argument).
DEFAULT_SETTINGS = ExtractionSettings()


@dataclass
class FrameResult:
    """What one frame shows. ``flag`` is empty for a good (measured) frame, else the reason.

    ``kind`` and ``contour_at`` say what was traced (``ring``: the mid-line of a dark ring;
    ``silhouette``: the outer edge of a filled object); ``extent_px`` is the traced
    contour's extent along the flow, ``outer_extent_px`` the outer edge's; ``traces`` holds
    every object of the frame (several when the flag says so), for the overlays.
    """

    index: int
    label: str
    flag: str = ""
    objects: int = 0
    time_s: float = math.nan
    kind: str = ""
    contour_at: str = ""
    line_width_px: float = math.nan
    line_contrast: float = math.nan
    object_x: float = math.nan
    x_front: float = math.nan
    x_rear: float = math.nan
    x_rear_axis: float = math.nan
    extent_px: float = math.nan
    outer_extent_px: float = math.nan
    L_z_px: float = math.nan
    L_p_px: float = math.nan
    centroid_x: float = math.nan
    centroid_y: float = math.nan
    asymmetry: float = math.nan
    passage: int = -1
    contour: np.ndarray | None = field(default=None, repr=False)
    traces: list[TracedObject] = field(default_factory=list, repr=False)

    @property
    def good(self) -> bool:
        return not self.flag


def rear_axis_crossing(contour: np.ndarray, axis_row: float) -> float:
    """x of the contour's rear-most crossing of the axis (linear interpolation); NaN if none."""
    closed = np.vstack([contour, contour[:1]])
    d = closed[:, 1] - axis_row
    idx = np.nonzero(np.sign(d[:-1]) != np.sign(d[1:]))[0]
    if idx.size == 0:
        return math.nan
    t = d[idx] / (d[idx] - d[idx + 1])
    xs = closed[idx, 0] + t * (closed[idx + 1, 0] - closed[idx, 0])
    return float(xs.min())


def asymmetry(contour: np.ndarray, axis_row: float, half_length: float) -> float:
    """Mean distance between the upper half and the mirrored lower half (larger way), / half_length."""
    upper = contour[contour[:, 1] <= axis_row]
    lower = contour[contour[:, 1] >= axis_row].copy()
    if len(upper) < 4 or len(lower) < 4:
        return math.inf
    lower[:, 1] = 2 * axis_row - lower[:, 1]
    d_ul = cKDTree(lower).query(upper)[0].mean()
    d_lu = cKDTree(upper).query(lower)[0].mean()
    return float(max(d_ul, d_lu) / half_length)


def cut_flag(object_columns: tuple[int, int], columns: int, view: tuple[int, int] | None = None) -> str:
    """Why an object spanning ``object_columns`` is cut: it reaches the image's left or right
    border, or the end of the straight channel (``view``: its first and last column, None: the
    whole width of ``columns``); '' when it is not cut."""
    first, last = view if view is not None else (0, columns - 1)
    for reached, end, border in ((object_columns[0] <= first + 1, first, first == 0),
                                 (object_columns[1] >= last - 1, last, last == columns - 1)):
        if reached:
            return ("touches the image border" if border else
                    f"touches the end of the straight channel (column {end}: the walls leave their rows beyond)")
    return ""


def measure_trace(trace: TracedObject, axis_row: float, columns: int, settings: ExtractionSettings,
                  view: tuple[int, int] | None = None) -> None:
    """Measure one traced object on its own (its lengths, symmetry and flag, set on ``trace``).

    Its flag: cut by the image's left or right edge or by the end of the straight channel
    (``view``, see :func:`cut_flag`), the tracing's own (touching objects), a line wider than
    ``settings.max_line_width_px``, no crossing of the tube axis, or asymmetric.
    """
    trace.L_z_px = trace.x_front - trace.x_rear
    trace.x_rear_axis = rear_axis_crossing(trace.contour, axis_row)
    trace.L_p_px = max(0.0, trace.x_rear_axis - trace.x_rear) if math.isfinite(trace.x_rear_axis) else math.nan
    trace.asymmetry = asymmetry(trace.contour, axis_row, trace.L_z_px / 2)
    cut = cut_flag(trace.columns, columns, view)
    if cut:
        trace.flag = cut
    elif trace.flag:
        pass    # the tracing's own (touching objects: not one capsule)
    elif trace.kind == "ring" and trace.line_width_px > settings.max_line_width_px:
        trace.flag = f"out of focus (line {trace.line_width_px:.1f} px wide > {settings.max_line_width_px:g})"
    elif not math.isfinite(trace.x_rear_axis):
        trace.flag = "contour does not cross the tube axis (capsule off the axis)"
    elif trace.asymmetry > settings.max_asymmetry:
        trace.flag = f"asymmetric ({trace.asymmetry:.3f} > {settings.max_asymmetry} of L_z/2)"



def _focus_flag(trace, width: float, contrast: float, ratio: float) -> str:
    """Why an outline (a frame's or one of its objects') is out of focus against the stack's
    median line width and contrast, or '' when it is in focus."""
    if trace.kind == "silhouette":
        return "out of focus (no transparent interior, the stack's other capsules are rings)"
    if trace.line_width_px > ratio * width:
        return f"out of focus (line {trace.line_width_px:.1f} px wide, stack median {width:.1f} px)"
    if trace.line_contrast < contrast / ratio:
        return f"out of focus (line contrast {trace.line_contrast:.3f}, stack median {contrast:.3f})"
    return ""

def flag_out_of_focus(results: Sequence[FrameResult], settings: ExtractionSettings) -> None:
    """Flag the frames whose line is much wider or fainter than the stack's traced rings'.

    Defocus spreads the line's darkness: it widens and fades, and a strongly blurred ring
    fills its interior (it then reads as a silhouette). The reference is the median over the
    frames that gave a ring contour; it needs three of them. Stacks of silhouettes are not
    tested (their edge has no width to compare).
    """
    reference = [r for r in results if r.contour is not None and r.kind == "ring"]
    if len(reference) < 3:
        return
    width = float(np.median([r.line_width_px for r in reference]))
    contrast = float(np.median([r.line_contrast for r in reference]))
    for r in results:
        # The objects of a frame with several, each on its own.
        for t in r.traces if len(r.traces) > 1 else []:
            if not t.flag:
                t.flag = _focus_flag(t, width, contrast, settings.focus_ratio)
        if r.objects == 0 or r.flag.startswith("out of focus"):
            continue
        r.flag = _focus_flag(r, width, contrast, settings.focus_ratio) or r.flag
        if r.flag.startswith("out of focus"):
            # A blurred outline's centroid is no position to track by: the object's pixels are.
            r.contour = None
            r.centroid_x = r.centroid_y = math.nan


