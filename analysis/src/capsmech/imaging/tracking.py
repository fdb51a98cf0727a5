"""Passages and tracks: which frames show the same capsule, and what each capsule measures.

- Passages (:func:`assign_passages`): the single capsule of consecutive frames, one passage
  until an empty frame, more than a few missing camera frames or a jump back against the flow;
  a passage numbers the frames of the per-frame report.
- Tracks (:func:`track_objects`): every traced object, several per frame included, linked from
  frame to frame by an optimal assignment (``scipy.optimize.linear_sum_assignment``) on the
  distance from where it should be (moved along the flow by its step per frame), with gates: no
  step back against the flow, none across the channel, none longer than the gate. A track
  survives up to :data:`TRACK_MEMORY_FRAMES` missing frames (dropped by the camera, counted from
  the frames' times; or frames where the capsule was not found), as trackpy's ``memory`` - a
  trackpy-like linker written out here, trackpy not being a dependency. Each track is one
  capsule, measured over its good frames (:func:`measure_capsules`), also when other capsules
  are in view at the same time.
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
from capsmech.io.contours import resample_curve


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
    contour_noise_px: float = math.nan
    problem: str = ""
    trace: TracedObject | None = field(default=None, repr=False)

    @property
    def ok(self) -> bool:
        return not self.problem


#: A capsule missed in up to this many frames in a row (frames the camera dropped, or frames in
#: which it was not detected) keeps its track (trackpy's ``memory``): a dropped frame must not
#: make two capsules of one.
TRACK_MEMORY_FRAMES = 3


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


def frame_interval(results: Sequence[FrameResult], frame_rate: float | None = None) -> float:
    """The camera's frame interval [s]: 1 / ``frame_rate``, else the median step of the frames'
    times (a film that drops a few frames keeps its median); NaN when the frames have no times."""
    if frame_rate:
        return 1.0 / frame_rate
    steps = np.diff(np.array([r.time_s for r in results]))
    steps = steps[np.isfinite(steps) & (steps > 0)]
    return float(np.median(steps)) if steps.size else math.nan


def frames_apart(before: FrameResult, after: FrameResult, interval_s: float) -> int:
    """How many camera frames ``after`` comes after ``before``: from their times where both have
    one (dropped frames counted), else from their page numbers."""
    if math.isfinite(interval_s) and math.isfinite(before.time_s) and math.isfinite(after.time_s):
        return max(1, round((after.time_s - before.time_s) / interval_s))
    return after.index - before.index


def assign_passages(results: Sequence[FrameResult], jump_px: float, interval_s: float = math.nan,
                    memory: int = TRACK_MEMORY_FRAMES) -> None:
    """Number the capsules' passages: a new one after an empty frame, a gap or a jump against the flow.

    A gap: more than ``memory`` camera frames missing between two frames (:func:`frames_apart`;
    ``interval_s`` the frame interval). Real recordings keep only the frames with an event, so
    frames recorded far apart show different objects; a film that dropped a frame or two still
    shows one capsule's passage.
    """
    passage, last_x, inside = -1, math.nan, False
    for k, r in enumerate(results):
        if r.objects == 0:
            inside, last_x = False, math.nan
            continue
        if k and frames_apart(results[k - 1], r, interval_s) > memory + 1:
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
    of the contour's centroid against the frames' times (gaps honoured), with its standard error;
    ``contour_noise_px`` the tracing noise of one frame's contour, from the spread of the good
    frames' contours (:func:`contour_noise`).
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
        cap.contour_noise_px = contour_noise([t.contour for _, t in good])
        capsules.append(cap)
    return capsules


def _distances_to(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Each point's distance to a closed polygon (its nearest segment)."""
    a = polygon
    b = np.roll(polygon, -1, axis=0)
    ab = b - a
    length2 = np.maximum(np.sum(ab ** 2, axis=1), 1e-12)
    ap = points[:, None, :] - a[None, :, :]
    t = np.clip(np.sum(ap * ab[None], axis=2) / length2[None], 0.0, 1.0)
    nearest = a[None] + t[..., None] * ab[None]
    return np.sqrt(np.min(np.sum((points[:, None, :] - nearest) ** 2, axis=2), axis=1))


def contour_noise(contours: Sequence[np.ndarray], points: int = 64) -> float:
    """A single frame's contour noise [px], from the spread of one capsule's contours over its
    good frames (NaN with fewer than three).

    In a steady passage the frames show one shape, moved along the channel: the contours,
    their centroids put on one another, differ by the tracing alone. Each contour's normal
    distance to the next one's (``points`` points evenly spaced along it) is the difference of
    two independent tracings, so its rms over the points and the pairs, over sqrt(2), is one
    tracing's noise. Unlike the two halves' difference (``capsmech.inversion.noise``), it also
    sees the errors the halves share, e.g. an outline that breathes with the pixel grid.
    """
    usable = [np.asarray(c, dtype=float) for c in contours if c is not None and len(c) >= 8]
    if len(usable) < 3:
        return math.nan
    centred = [c - c.mean(axis=0) for c in usable]
    squares = []
    for one, other in zip(centred[:-1], centred[1:]):
        squares.append(_distances_to(resample_curve(one, points, closed=True), other) ** 2)
    return float(np.sqrt(np.mean(np.concatenate(squares)) / 2.0))


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


@dataclass
class _TrackEnd:
    """Where a track was last seen: its frame, its object and its step per frame [px] (NaN: none yet)."""

    frame: FrameResult
    trace: TracedObject
    step_px: float = math.nan


def track_objects(results: Sequence[FrameResult], max_step_px: float, max_cross_px: float,
                  back_px: float = 2.0, interval_s: float = math.nan, memory: int = TRACK_MEMORY_FRAMES) -> int:
    """Give every traced object a track number (``TracedObject.track``); return the number of tracks.

    Gap closing as trackpy's ``memory`` does it: a track last seen ``n`` camera frames back
    (:func:`frames_apart`: from the frames' times, so that dropped frames count) can take an
    object of the current frame while ``n <= memory + 1``. The cost of a link is the distance
    between the object and where the track should be: its last position moved by ``n`` times
    its own step per frame (else the median step per frame of the links made so far, else 0).
    A link backwards by more than ``back_px``, longer than ``n * max_step_px`` along the flow or
    ``max_cross_px`` across it is not made. Tracks seen more recently are linked first, each
    group by an optimal assignment (``scipy.optimize.linear_sum_assignment``); objects left
    unlinked start a new track. Two consecutive frames of one passage (:func:`assign_passages`)
    with one object each are linked without the gates (an object entering at the border, a
    blurred frame, move its centre).
    """
    from scipy.optimize import linear_sum_assignment

    tracks = 0
    steps: list[float] = []
    ends: dict[int, _TrackEnd] = {}
    previous: FrameResult | None = None
    for r in results:
        current = list(r.traces)
        if (previous is not None and len(current) == 1 and len(previous.traces) == 1
                and r.index == previous.index + 1 and r.passage == previous.passage >= 0):
            _extend(ends, previous.traces[0].track, r, current[0], interval_s, steps)
        apart = {track: frames_apart(end.frame, r, interval_s) for track, end in ends.items()}
        for n in sorted({n for n in apart.values() if 1 <= n <= memory + 1}):
            free = [c for c in current if c.track < 0]
            candidates = [track for track, m in apart.items() if m == n and ends[track].frame is not r]
            if not free or not candidates:
                continue
            typical = float(np.median(steps)) if steps else 0.0
            cost = np.full((len(candidates), len(free)), 1e9)
            for i, track in enumerate(candidates):
                end = ends[track]
                expected = n * (end.step_px if math.isfinite(end.step_px) else typical)
                for j, c in enumerate(free):
                    dx, dy = c.centre[0] - end.trace.centre[0], c.centre[1] - end.trace.centre[1]
                    if -back_px <= dx <= n * max_step_px and abs(dy) <= max_cross_px:
                        cost[i, j] = math.hypot(dx - expected, dy)
            for i, j in zip(*linear_sum_assignment(cost)):
                if cost[i, j] < 1e9:
                    _extend(ends, candidates[i], r, free[j], interval_s, steps)
        for c in current:
            if c.track < 0:
                c.track = tracks
                ends[tracks] = _TrackEnd(r, c)
                tracks += 1
        # Tracks not seen for more than ``memory`` frames are over.
        ends = {t: e for t, e in ends.items() if frames_apart(e.frame, r, interval_s) <= memory + 1}
        previous = r
    return tracks


def _extend(ends: dict[int, _TrackEnd], track: int, frame: FrameResult, trace: TracedObject, interval_s: float,
            steps: list[float]) -> None:
    """Link ``trace`` (in ``frame``) to ``track``: its number, the track's new end and step per frame."""
    end = ends[track]
    n = max(1, frames_apart(end.frame, frame, interval_s))
    step = (trace.centre[0] - end.trace.centre[0]) / n
    trace.track = track
    ends[track] = _TrackEnd(frame, trace, step)
    steps.append(step)
