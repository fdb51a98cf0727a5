"""Passages and tracks: which frames show the same capsule, and what each capsule measures.

- Passages (:func:`assign_passages`): the single capsule of consecutive frames, one passage
  until an empty frame, a gap in the frames' times or a jump back against the flow; a passage
  numbers the frames of the per-frame report.
- Tracks (:func:`track_objects`): every traced object, several per frame included, linked from
  frame to frame by an optimal assignment (``scipy.optimize.linear_sum_assignment``) on the
  distance from where it should be (moved along the flow by the stack's typical step), with
  gates: no step back against the flow, none across the channel, none longer than the gate.
  Each track is one capsule, measured over its good frames (:func:`measure_capsules`), also
  when other capsules are in view at the same time.
- The flow's direction (:func:`flow_steps`): the objects' steps between consecutive frames,
  matched without assuming a direction.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from capsmech.imaging.measurement import DEFAULT_SETTINGS, ExtractionSettings, FrameResult
from capsmech.imaging.objects import TracedObject


@dataclass
class CapsuleMeasurement:
    """One capsule's passage through the field of view, measured over its good frames.

    Lengths in pixels; ``v_c_px_s`` in pixels per second; spreads are standard deviations
    over the good frames, ``v_c_se_px_s`` the standard error of the fitted slope. ``passage``
    is the capsule's track number; ``trace`` its object in the ``representative`` frame.
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
    trace: TracedObject | None = field(default=None, repr=False)

    @property
    def ok(self) -> bool:
        return not self.problem


def gap_limit(results: Sequence[FrameResult], max_gap: float = 1.5, frame_rate: float | None = None,
              max_skipped: int = 10) -> float:
    """The longest step between frames [s] that is no gap (inf when the frames have no times).

    A gap: a step longer than ``max_gap`` times the stack's median step, or than
    ``max_skipped`` frame intervals (1 / ``frame_rate``).
    """
    steps = np.diff(np.array([r.time_s for r in results]))
    if not (steps.size and np.all(np.isfinite(steps))):
        return math.inf
    limit = max_gap * float(np.median(steps))
    return min(limit, max_skipped / frame_rate) if frame_rate else limit


def assign_passages(results: Sequence[FrameResult], jump_px: float, max_gap: float = 1.5,
                    frame_rate: float | None = None, max_skipped: int = 10) -> None:
    """Number the capsules' passages: a new one after an empty frame, a gap or a jump against the flow.

    A gap in the frames' times: a step longer than ``max_gap`` times the stack's median step,
    or than ``max_skipped`` frame intervals (1 / ``frame_rate``) - frames recorded apart (real
    recordings keep only the frames with an event) show different objects, while a camera
    that keeps every other frame still shows one capsule's passage.
    """
    limit = gap_limit(results, max_gap, frame_rate, max_skipped)
    steps = np.diff(np.array([r.time_s for r in results]))
    passage, last_x, inside = -1, math.nan, False
    for k, r in enumerate(results):
        if r.objects == 0:
            inside, last_x = False, math.nan
            continue
        if k and steps[k - 1] > limit:
            inside, last_x = False, math.nan
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


def _observations(results: Sequence[FrameResult]) -> dict[int, list[tuple[FrameResult, TracedObject]]]:
    """Each track's (frame, object) pairs, in frame order."""
    by_track: dict[int, list[tuple[FrameResult, TracedObject]]] = {}
    for r in results:
        for t in r.traces:
            if t.track >= 0:
                by_track.setdefault(t.track, []).append((r, t))
    return by_track


def measure_capsules(results: Sequence[FrameResult], frame_rate: float,
                     settings: ExtractionSettings = DEFAULT_SETTINGS) -> list[CapsuleMeasurement]:
    """Measure each capsule - each track (:func:`track_objects`) - over its good frames.

    Several capsules in view at once are each measured on their own: an object is a good
    observation of its track when its own flag (``TracedObject.flag``: border, focus, axis,
    symmetry) is empty, whatever the other objects of the frame show. Lengths are the medians
    over the good observations, with their standard deviations; v_c is the least-squares slope
    of the contour's centroid against the frames' times (gaps honoured), with its standard error.
    """
    capsules = []
    for track, observed in sorted(_observations(results).items()):
        good = [(r, t) for r, t in observed if not t.flag]
        cap = CapsuleMeasurement(track, [r.index for r, _ in observed], [r.index for r, _ in good])
        if len(good) < settings.min_good_frames:
            flags = sorted({t.flag.split(" (")[0] for _, t in observed if t.flag})
            cap.problem = (f"{len(good)} good frame(s) of {len(observed)} (need {settings.min_good_frames}); "
                           f"the others: {', '.join(flags) or 'none'}")
            capsules.append(cap)
            continue
        lz = np.array([t.L_z_px for _, t in good])
        lp = np.array([t.L_p_px for _, t in good])
        cap.L_z_px, cap.L_z_spread_px = float(np.median(lz)), float(np.std(lz, ddof=1))
        cap.L_p_px, cap.L_p_spread_px = float(np.median(lp)), float(np.std(lp, ddof=1))
        # The frames' own times where known (gaps honoured), else index / frame rate.
        times = np.array([r.time_s if math.isfinite(r.time_s) else r.index / frame_rate for r, _ in good])
        cap.v_c_px_s, cap.v_c_se_px_s = fit_velocity(times, np.array([t.centre[0] for _, t in good]))
        if not cap.v_c_px_s > 0:
            cap.problem = f"the capsule does not move with the flow (+x): v_c = {cap.v_c_px_s:.3g} px/s"
        # The frame whose lengths are nearest the medians shows the capsule the row describes.
        misfit = np.abs(lz - cap.L_z_px) / max(cap.L_z_px, 1) + np.abs(lp - cap.L_p_px) / max(cap.L_z_px, 1)
        best = int(np.argmin(misfit))
        cap.representative, cap.trace = good[best][0].index, good[best][1]
        capsules.append(cap)
    return capsules


def flow_steps(results: Sequence[FrameResult], max_step_px: float, max_cross_px: float,
               max_step_s: float = math.inf) -> np.ndarray:
    """Steps along x [px] of the objects between consecutive frames, whichever way they go.

    Each frame's objects are matched to the next frame's by an optimal assignment on their
    distance (no direction assumed), links longer than ``max_step_px`` along x or ``max_cross_px``
    across left out; the sign of the median step is the flow's direction in the frames.
    """
    from scipy.optimize import linear_sum_assignment

    steps: list[float] = []
    for before, after in zip(results[:-1], results[1:]):
        if (not before.traces or not after.traces or after.index != before.index + 1
                or after.time_s - before.time_s > max_step_s):
            continue
        dx = np.array([[c.centre[0] - p.centre[0] for c in after.traces] for p in before.traces])
        dy = np.array([[c.centre[1] - p.centre[1] for c in after.traces] for p in before.traces])
        cost = np.where((np.abs(dx) <= max_step_px) & (np.abs(dy) <= max_cross_px), np.hypot(dx, dy), 1e9)
        for i, j in zip(*linear_sum_assignment(cost)):
            if cost[i, j] < 1e9:
                steps.append(float(dx[i, j]))
    return np.array(steps)


def track_objects(results: Sequence[FrameResult], max_step_px: float, max_cross_px: float,
                  back_px: float = 2.0, max_step_s: float = math.inf) -> int:
    """Give every traced object a track number (``TracedObject.track``); return the number of tracks.

    Consecutive frames no more than ``max_step_s`` apart in time (:func:`gap_limit`) are linked
    object to object: the cost of a link is the distance between the later object and the earlier one
    moved by the typical step (the median of the links made so far, 0 at first); a link
    backwards by more than ``back_px``, longer than ``max_step_px`` along the flow or
    ``max_cross_px`` across it is not made. Objects left unlinked start a new track. Two frames
    of one passage (:func:`assign_passages`) with one object each are linked without the gates.
    """
    from scipy.optimize import linear_sum_assignment

    tracks = 0
    steps: list[float] = []
    previous: list = []
    previous_frame: FrameResult | None = None
    for r in results:
        current = list(r.traces)
        linked = (previous_frame is not None and bool(previous) and bool(current)
                  and r.index == previous_frame.index + 1
                  and not (r.time_s - previous_frame.time_s > max_step_s))
        if (linked and previous_frame is not None and len(previous) == len(current) == 1
                and r.passage == previous_frame.passage >= 0):
            # One object in each of two frames of one passage: the same capsule, whatever the
            # gates say (an object entering at the border, a blurred frame, move its centre).
            current[0].track = previous[0].track
        elif linked:
            step = float(np.median(steps)) if steps else 0.0
            cost = np.full((len(previous), len(current)), 1e9)
            for i, p in enumerate(previous):
                for j, c in enumerate(current):
                    dx, dy = c.centre[0] - p.centre[0], c.centre[1] - p.centre[1]
                    if -back_px <= dx <= max_step_px and abs(dy) <= max_cross_px:
                        cost[i, j] = math.hypot(dx - step, dy)
            rows, cols = linear_sum_assignment(cost)
            for i, j in zip(rows, cols):
                if cost[i, j] < 1e9:
                    current[j].track = previous[i].track
                    steps.append(current[j].centre[0] - previous[i].centre[0])
        for c in current:
            if c.track < 0:
                c.track = tracks
                tracks += 1
        previous, previous_frame = current, r
    return tracks
