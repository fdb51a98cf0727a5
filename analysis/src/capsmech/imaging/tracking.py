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
- Film or events (:func:`independent_events`): a cytometer keeps only the frames with an event,
  and a stack of them exported with regular frame times looks like a film. In a film, an
  object keeps its size from frame to frame and its step from one frame to the next; the
  snapshots of unrelated cells do neither. Events are each measured as one shape
  (:func:`track_events`): no tracks across frames, no velocity.
- Pieces (:func:`settle_pieces`): an object cut by the frame's edge (or the straight channel's
  end) joins the track of a whole capsule seen beside it, or is dropped with the reason: a
  piece is never a capsule of its own.
- Steadiness (:func:`steadiness`): a capsule whose L_z still changes along its passage (its
  trend over the frames against its scatter) is not measured as a steady shape.
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
    is the capsule's track number; ``trace`` its object in the ``representative`` frame;
    ``note`` what a measured capsule's numbers lack, in words (an independent event: no velocity).
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
    note: str = ""

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
                     settings: ExtractionSettings = DEFAULT_SETTINGS,
                     independent_events: bool = False) -> list[CapsuleMeasurement]:
    """Measure each capsule - each track (:func:`track_objects`) - over its good frames.

    Several capsules in view at once are each measured on their own: an object is a good
    observation of its track when its own flag (``TracedObject.flag``: border, focus, axis,
    symmetry) is empty, whatever the other objects of the frame show. Lengths are the medians
    over the good observations, with their standard deviations; v_c is the least-squares slope
    of the contour's centroid against the frames' times (gaps honoured), with its standard error;
    ``contour_noise_px`` the tracing noise of one frame's contour, from the spread of the good
    frames' contours (:func:`contour_noise`). A capsule whose L_z still changes along its passage
    is not measured (:func:`steadiness`).

    With ``independent_events`` (:func:`independent_events`), each object is a capsule of one
    snapshot: its own lengths, no spread, no velocity (NaN, said in ``note``).
    """
    if independent_events:
        return [_measure_event(track, observed) for track, observed in sorted(_observations(results).items())]
    capsules = []
    for track, observed in sorted(_observations(results).items()):
        good = [(r, t) for r, t in observed if not t.flag]
        # A frame counts once, also when pieces of the capsule joined its track there.
        cap = CapsuleMeasurement(track, list(dict.fromkeys(r.index for r, _ in observed)),
                                 list(dict.fromkeys(r.index for r, _ in good)))
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
        else:
            cap.problem = steadiness(times, lz)
        # The frame whose lengths are nearest the medians shows the capsule the row describes.
        misfit = np.abs(lz - cap.L_z_px) / max(cap.L_z_px, 1) + np.abs(lp - cap.L_p_px) / max(cap.L_z_px, 1)
        best = int(np.argmin(misfit))
        cap.representative, cap.trace = good[best][0].index, good[best][1]
        cap.contour_noise_px = contour_noise([t.contour for _, t in good])
        capsules.append(cap)
    return capsules


#: A trend of L_z over a passage is real beyond this many standard errors of its slope ...
STEADY_SLOPE_SIGMAS = 4.0
#: ... and when the change it makes over the passage exceeds this many times the frames' scatter
#: about it (with many frames a tiny slope is significant, yet within the tracing's noise).
STEADY_CHANGE_SCATTER = 2.0
#: Fewest good frames for a trend.
STEADY_MIN_FRAMES = 5


def steadiness(times: np.ndarray, lengths: np.ndarray) -> str:
    """Why a passage's shape is not steady ('' when it is, or too few frames tell).

    The inversion reads a steady shape. A capsule still deforming along its passage (just
    released from an inlet, or a flow that changes) shows a trend of L_z over its frames: the
    least-squares slope, beyond :data:`STEADY_SLOPE_SIGMAS` standard errors, making a change
    over the passage beyond :data:`STEADY_CHANGE_SCATTER` times the frames' scatter about it.
    """
    if lengths.size < STEADY_MIN_FRAMES or np.ptp(times) <= 0:
        return ""
    slope, error = fit_velocity(times, lengths)
    residual = lengths - lengths.mean() - slope * (times - times.mean())
    scatter = float(np.std(residual, ddof=2))
    change = slope * float(np.ptp(times))
    if abs(slope) > STEADY_SLOPE_SIGMAS * error and abs(change) > STEADY_CHANGE_SCATTER * scatter:
        return (f"not steady: L_z changes by {change:+.2f} px over the {lengths.size} frames measured "
                f"({abs(slope) / error:.0f} standard errors of the slope; scatter {scatter:.2f} px)")
    return ""


#: What an independent event's row lacks.
EVENT_NOTE = "independent event: one snapshot, no velocity"


def _measure_event(track: int, observed: list[tuple[FrameResult, TracedObject]]) -> CapsuleMeasurement:
    """An independent event's object: its own lengths, no spread and no velocity."""
    r, t = observed[0]
    cap = CapsuleMeasurement(track, [r.index], [] if t.flag else [r.index], note=EVENT_NOTE)
    if t.flag:
        cap.problem = f"0 good frame(s) of 1 (an independent event): {t.flag}"
        return cap
    cap.L_z_px, cap.L_p_px = t.L_z_px, t.L_p_px
    cap.representative, cap.trace = r.index, t
    return cap


#: In a film, one object's consecutive steps agree within this many px, or this fraction of the step.
STEP_AGREEMENT_PX = 1.0
STEP_AGREEMENT_FRACTION = 0.1
#: ... and its extents along and across the flow within this fraction (plus 1 px) from frame to frame.
SIZE_AGREEMENT = 0.05
#: Links between consecutive frames needed to tell events from a film.
MIN_LINKS_FOR_EVENTS = 3


def _whole(trace: TracedObject) -> bool:
    """Whether an object is whole: not cut by the frame's edge or the straight channel's end."""
    return not trace.flag.startswith("touches")


def _consecutive_links(results: Sequence[FrameResult], max_cross_px: float, interval_s: float,
                       memory: int) -> list[tuple[TracedObject, TracedObject, int]]:
    """Whole objects of frames at most ``memory + 1`` camera frames apart, matched by an optimal
    assignment on their distance (no direction assumed, at most ``max_cross_px`` across):
    (before, after, frames apart)."""
    from scipy.optimize import linear_sum_assignment

    links = []
    for before, after in zip(results[:-1], results[1:]):
        n = frames_apart(before, after, interval_s)
        old, new = [t for t in before.traces if _whole(t)], [t for t in after.traces if _whole(t)]
        if not old or not new or not 1 <= n <= memory + 1:
            continue
        dx = np.array([[c.centre[0] - p.centre[0] for c in new] for p in old])
        dy = np.array([[c.centre[1] - p.centre[1] for c in new] for p in old])
        cost = np.where(np.abs(dy) <= max_cross_px, np.hypot(dx, dy), 1e9)
        links += [(old[i], new[j], n) for i, j in zip(*linear_sum_assignment(cost)) if cost[i, j] < 1e9]
    return links


def _sizes_agree(one: TracedObject, other: TracedObject) -> bool:
    """Whether two objects' extents along and across the flow agree within :data:`SIZE_AGREEMENT`."""
    pairs = ((one.extent_px, other.extent_px), (float(np.ptp(one.contour[:, 1])), float(np.ptp(other.contour[:, 1]))))
    return all(abs(a - b) <= 1.0 + SIZE_AGREEMENT * max(a, b) for a, b in pairs)


def independent_events(results: Sequence[FrameResult], max_cross_px: float, interval_s: float = math.nan,
                       memory: int = TRACK_MEMORY_FRAMES) -> str:
    """Why the stack is a set of independent events, not a film ('' when it is a film, or too
    few frames follow one another to tell).

    Consecutive frames' whole objects are matched (:func:`_consecutive_links`). In a film the
    matched objects keep their size (:data:`SIZE_AGREEMENT`) and each makes the same step as
    one frame before (:data:`STEP_AGREEMENT_PX`); unrelated cells, each at a place of its own,
    do neither. Events: at least :data:`MIN_LINKS_FOR_EVENTS` links, and fewer than half of
    them keeping their size, or fewer than half of the steps that follow one another agreeing.
    """
    links = _consecutive_links(results, max_cross_px, interval_s, memory)
    if len(links) < MIN_LINKS_FOR_EVENTS:
        return ""
    sizes = sum(_sizes_agree(a, b) for a, b, _ in links)
    step_into = {id(b): (b.centre[0] - a.centre[0]) / n for a, b, n in links}
    pairs = agreeing = 0
    for a, b, n in links:
        if id(a) in step_into:
            earlier, later = step_into[id(a)], (b.centre[0] - a.centre[0]) / n
            pairs += 1
            agreeing += abs(later - earlier) <= max(STEP_AGREEMENT_PX,
                                                    STEP_AGREEMENT_FRACTION * max(abs(later), abs(earlier)))
    if sizes >= len(links) / 2 and (pairs < 2 or agreeing >= pairs / 2):
        return ""
    return (f"independent events: the objects of consecutive frames do not move as one capsule ({sizes} of "
            f"{len(links)} keep their size, {agreeing} of {pairs} steps agree with the step before); each object "
            f"is measured as one shape: no tracks across frames, no velocity, no flow direction")


def track_events(results: Sequence[FrameResult]) -> int:
    """Independent events: every object its own track, every frame with objects its own passage;
    return the number of tracks."""
    tracks = passage = 0
    for r in results:
        r.passage = -1
        if r.objects:
            r.passage, passage = passage, passage + 1
        for t in r.traces:
            t.track, tracks = tracks, tracks + 1
    return tracks


#: Why a piece that joins no capsule's track is dropped.
PIECE_DROPPED = ("a piece cut by the frame's edge or lying in a wall's band, beside no whole capsule: "
                 "not a capsule of its own")
#: The band along each wall, as a fraction of the tube radius, in which an object lying wholly
#: is a piece (of a wall's texture, or of a capsule split by the wall's margin), not a capsule.
WALL_BAND_FRACTION = 0.25


def settle_pieces(results: Sequence[FrameResult], interval_s: float = math.nan,
                  memory: int = TRACK_MEMORY_FRAMES, wall_rows: tuple[float, float] | None = None) -> None:
    """Pieces join a capsule's track, or are dropped with the reason (``TracedObject.dropped``).

    A piece: an object cut by the frame's edge or the straight channel's end, or one lying
    wholly in a wall's band (``wall_rows``: the walls' rows; the band
    :data:`WALL_BAND_FRACTION` of the tube radius wide). A capsule entering or leaving the view
    is cut, and a cut ring may fall apart into arcs whose centres jump about: tracked on their
    own, they would make capsules of their own and renumber the real one. A track made of pieces only joins the nearest track (in frames,
    then along the flow) that holds a whole object at most ``memory + 1`` camera frames away,
    the piece within one length of that object moved on by the track's step per frame and
    across the channel where it lies (a piece of it, not of the next capsule entering far
    behind it, nor a speck along the wall beside it); with none, its objects leave the tracks
    (track -1) and say why.
    """
    observed = _observations(results)
    band = WALL_BAND_FRACTION * abs(wall_rows[1] - wall_rows[0]) / 2 if wall_rows else 0.0

    def piece(trace: TracedObject) -> bool:
        rows = trace.contour[:, 1]
        in_band = wall_rows is not None and any(
            float(np.max(np.abs(rows - wall))) <= band for wall in wall_rows)
        return in_band or not _whole(trace)

    whole = {track: [(r, t) for r, t in obs if not piece(t)] for track, obs in observed.items()}
    whole = {track: obs for track, obs in whole.items() if obs}
    step = {track: _step_per_frame(seen, interval_s) for track, seen in whole.items()}
    for track, obs in observed.items():
        if track in whole:
            continue
        best: tuple[int, float, int] | None = None
        for other, seen in whole.items():
            for r, t in obs:
                for q, u in seen:
                    ahead = 0 if q.index == r.index else (
                        frames_apart(q, r, interval_s) if q.index < r.index else -frames_apart(r, q, interval_s))
                    miss = abs(t.centre[0] - u.centre[0] - ahead * step[other])
                    key = (abs(ahead), miss, other)
                    if (abs(ahead) <= memory + 1 and miss <= u.outer_extent_px and _rows_overlap(t, u)
                            and (best is None or key < best)):
                        best = key
        for _, t in obs:
            if best is not None:
                t.track = best[2]
            else:
                t.track, t.dropped = -1, PIECE_DROPPED


def _rows_overlap(one: TracedObject, other: TracedObject, margin_px: float = 2.0) -> bool:
    """Whether two objects share rows (within ``margin_px``): a piece of a capsule lies across
    the channel where the capsule does."""
    return bool(one.contour[:, 1].min() <= other.contour[:, 1].max() + margin_px
                and one.contour[:, 1].max() >= other.contour[:, 1].min() - margin_px)


def _step_per_frame(seen: list[tuple[FrameResult, TracedObject]], interval_s: float) -> float:
    """A track's median step per camera frame along x (0 with a single object)."""
    steps = [(b.centre[0] - a.centre[0]) / max(1, frames_apart(p, q, interval_s))
             for (p, a), (q, b) in zip(seen[:-1], seen[1:]) if q.index > p.index]
    return float(np.median(steps)) if steps else 0.0


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
