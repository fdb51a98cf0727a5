"""From microscope frames to tube measurements: level, background, walls, objects, L_z, L_p, v_c.

Frame convention: the tube axis runs along the image's x (columns) and the flow goes in +x,
so the capsule's front is at the largest x (mirror the frames first when it goes in -x).

The steps, each in its module:

Per stack (:func:`prepare`)
    1. Tilt (``channel.estimate_tilt``): the walls' angle, found on a background image (the
       user's, else the stack's temporal median), and every frame rotated level
       (``channel.level``) before anything else.
    2. Background (``background.stack_background``): the temporal median of the levelled
       stack with the passing objects masked out; a user's background image (levelled alike)
       replaces it; stacks of fewer than 5 frames fall back on each frame's per-row median.
    3. Walls (``channel.find_walls``): the widest bright interval between the glass's dark
       lines and bands in the levelled background (a band's liquid-side edge, a line's centre),
       each wall with its uncertainty, or the user's rows; the channel width given by the user
       (with its tolerance) is checked against the one found (``channel.check_width``), and
       where it placed a wall outside the view, the axis against the objects' symmetry line.
    4. Straight channel (``channel.straight_columns``): where the view shows an inlet or an
       outlet, the columns beyond which the walls leave their rows are cut off; objects are
       looked for between them only.
Per frame (:func:`analyse_contrast`)
    1. Contrast c = 1 - I / background (flat field: walls, dirt and gradients divide out).
    2. Objects (``objects.find_objects``): c smoothed (1 px) above 6 noise deviations
       inside the channel - the frame's, or where larger the stack's own at that pixel
       (``background.temporal_noise``: its spread over up to 31 pairs of consecutive
       frames, so that the dim rows beside a wall, a wall's flickering edge and shaking dirt
       are no objects) - fragments joined, specks dropped. None: ``no capsule``; one
       whose pixels reach the image's left or right edge: ``touches the image border`` (the
       straight channel's end: ``touches the end of the straight channel``); more than one:
       ``N capsules`` (each is still traced and drawn).
    3. Tracing (``objects.trace_object``): a dark ring around a transparent interior gives
       its mid-line; a filled silhouette its outer edge (the report says which). An object
       that holds two light interiors or more (touching cells) is flagged ``touching objects``,
       not measured.
    4. Focus: a ring whose line is wider than ``max_line_width_px``, or than ``focus_ratio``
       times the stack's median width, is ``out of focus``; so is a frame whose object shows
       no interior in a stack of rings.
    5. Lengths: L_z = x_front - x_rear; L_p = x(rear point on the axis) - x_rear, the rear
       axis point being the contour's rear crossing of the axis (linear interpolation).
       Symmetry: the mean distance between the upper half and the mirrored lower half (both
       ways, the larger), over L_z / 2; above ``max_asymmetry`` the frame is ``asymmetric``.
Per stack, after the frames (``tracking``)
    Every traced object is measured on its own (``measurement.measure_trace``). A stack whose
    objects do not keep their size and step from frame to frame is a set of independent
    events (``independent_events``; only for stacks without their own frame times): each
    object is then one capsule of one snapshot, with no track across frames, no velocity and
    no flow direction from the motion. In a film each object gets a
    track (``track_objects``: optimal assignment between frames, bridging up to
    ``TRACK_MEMORY_FRAMES`` missing frames; two frames of one passage with one object each are
    always linked); a track made only of pieces cut by the frame's edge joins the capsule
    beside it or is dropped with the reason (``settle_pieces``). The flow's direction is the sign of
    the objects' median step between consecutive frames (``flow_steps``, no direction
    assumed); with ``flow_direction='auto'`` frames moving in -x are mirrored and analysed again.
Per capsule (:func:`measure_capsules`)
    Each track is a capsule, also when several are in view at once. Its lengths are the
    medians over its good objects, with their standard deviation as spread; v_c is the slope
    of the least-squares line through the contour's area centroid against the frames' times,
    with its standard error; a capsule whose L_z still changes along its passage is not measured
    (``steadiness``: "not steady"). A track ends when the capsule is missing from more than
    ``TRACK_MEMORY_FRAMES`` camera frames in a row (counted from the frames' times), or when
    the object jumps back against the flow.
"""
from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from capsmech.imaging.background import (
    FLOOR_FRACTION,
    MAX_FRAMES_TEMPORAL,
    MAX_NOISE_PAIRS,
    MIN_FRAMES_TEMPORAL,
    MIN_FREE_FRAMES,
    flat_field,
    row_background,
    stack_background,
    temporal_noise,
)
from capsmech.imaging.channel import (
    DEFAULT_WIDTH_TOLERANCE,
    Walls,
    axis_from_objects,
    check_axis,
    check_width,
    estimate_tilt,
    find_walls,
    level,
    straight_columns,
)
from capsmech.imaging.frames import (
    ExtractionError,
    FrameStack,
    expand_frame_paths,
    mirror_frames,
    read_frame_times,
    read_frames,
)
from capsmech.imaging.measurement import (
    DEFAULT_SETTINGS,
    ExtractionSettings,
    FrameResult,
    cut_flag,
    flag_out_of_focus,
    measure_trace,
)
from capsmech.imaging.objects import (
    DETECTION_SMOOTHING_PX,
    TracedObject,
    find_objects,
    polygon_centroid,
    trace_object,
)
from capsmech.imaging.tracking import (
    CapsuleMeasurement,
    assign_passages,
    fit_velocity,
    flow_steps,
    frame_interval,
    gap_limit,
    independent_events,
    measure_capsules,
    settle_pieces,
    track_events,
    track_objects,
)

__all__ = ["ExtractionError", "FrameStack", "Walls", "expand_frame_paths", "read_frame_times", "read_frames",
           "ExtractionSettings", "FrameResult", "Channel", "prepare", "analyse_contrast", "analyse_frame",
           "flag_out_of_focus", "CapsuleMeasurement", "assign_passages", "fit_velocity", "measure_capsules",
           "extract", "extract_stack", "track_objects", "progress_printer", "iter_good"]


#: An object is measured only when at most this fraction of its contour lies on pixels whose
#: stack background cannot be trusted (a few noisy pixels at the edge of a mask are harmless).
MAX_UNTRUSTED_CONTOUR = 0.05


@dataclass
class Channel:
    """The stack's geometry and background, found once (:func:`prepare`).

    Attributes
    ----------
    walls : Walls
        In the levelled frames.
    tilt_deg : float
        The walls' tilt in the frames as read (``atan(d row / d column)``); the frames are
        rotated by it.
    background : 2-D array or None
        The levelled static background; None: each frame's per-row median.
    background_source : str
        ``given``, ``temporal median`` or ``per-row median of each frame``.
    width_check : str
        The detected width against the user's ``channel_width``, in words: which is used and
        why ('' if none given; ``channel.check_width``); where a wall was placed at that width,
        the axis against the objects' symmetry line too.
    width_disagrees : bool
        The two widths (or the placed axis and the objects) disagree beyond both uncertainties.
    width_verdict : str
        The check in a few words, for the measurement CSV ('' if no width was given).
    flow_direction : {'right', 'left'}
        The flow's direction in the frames as read ('left': they were mirrored to +x).
    flow_check : str
        How the direction was found: from the objects' motion, given and confirmed, given and
        contradicted by the motion, or assumed (no object followed from frame to frame).
    untrusted : 2-D bool array or None
        Levelled pixels whose stack background cannot be trusted
        (``background.StackBackground.untrusted``); None: a given background, trusted.
    background_check : str
        Where the stack background cannot be trusted, in words ('' where it can everywhere).
    geometry_check : str
        Where the channel is straight, in words, when not over the whole width ('' when it is):
        objects are looked for there only (``walls.columns``).
    independent_events : str
        Why the stack is a set of independent events, not a film ('' for a film):
        ``tracking.independent_events``.
    """

    walls: Walls
    tilt_deg: float
    background: np.ndarray | None
    background_source: str
    width_check: str = ""
    flow_direction: str = "right"
    width_disagrees: bool = False
    width_verdict: str = ""
    flow_check: str = ""
    untrusted: np.ndarray | None = None
    background_check: str = ""
    geometry_check: str = ""
    independent_events: str = ""
    _reference: tuple[np.ndarray, np.ndarray, float] | None = field(default=None, init=False, repr=False, compare=False)
    _reference_key: tuple[np.ndarray, Walls] | None = field(default=None, init=False, repr=False, compare=False)

    def background_trusted_under(self, trace: TracedObject) -> bool:
        """Whether the background under a traced object's contour can be trusted: at most
        :data:`MAX_UNTRUSTED_CONTOUR` of its contour points on untrusted pixels."""
        if self.untrusted is None or not self.untrusted.any():
            return True
        rows, cols = self.untrusted.shape
        x = np.clip(np.round(trace.contour[:, 0]).astype(int), 0, cols - 1)
        y = np.clip(np.round(trace.contour[:, 1]).astype(int), 0, rows - 1)
        return float(self.untrusted[y, x].mean()) <= MAX_UNTRUSTED_CONTOUR

    def levelled(self, image: np.ndarray) -> np.ndarray:
        """A frame rotated level."""
        return level(image, self.tilt_deg)

    def contrast(self, image: np.ndarray) -> np.ndarray:
        """The levelled frame's flat-field contrast (``1 - I / background``).

        Against a stack background the frame's brightness is matched first (the median ratio
        over the channel): a flash or lamp that varies from frame to frame would otherwise
        leave an offset over the whole frame and a ghost of every wall line.
        """
        levelled = self.levelled(image)
        if self.background is None:
            return flat_field(levelled, row_background(levelled, self.walls.columns))
        inside, reference, bright = self._gain_reference()
        ratio = levelled[::2, ::2][inside] / reference if reference.size else np.ones(1)
        median = float(np.median(ratio))
        gain = median if math.isfinite(median) and median > 0 else 1.0
        # The floor of the scaled background is the gain times the background's own (its 90th
        # percentile scales with it): no percentile of every frame's background.
        return flat_field(levelled, gain * self.background, floor=FLOOR_FRACTION * gain * bright)

    def _gain_reference(self) -> tuple[np.ndarray, np.ndarray, float]:
        """What every frame's brightness match reads of the stack background, found once: the
        channel's pixels on every other row and column, the background there (at least 1e-6),
        and the background's 90th percentile (the flat field's floor, before the gain)."""
        assert self.background is not None
        key = self._reference_key
        if key is None or key[0] is not self.background or key[1] is not self.walls:
            inside = _inside(self.background.shape, self.walls)[::2, ::2]
            reference = np.maximum(self.background[::2, ::2][inside], 1e-6)
            self._reference = (inside, reference, float(np.percentile(self.background, 90)))
            self._reference_key = (self.background, self.walls)
        assert self._reference is not None
        return self._reference


def prepare(stack: FrameStack, background: np.ndarray | None = None, walls: tuple[float, float] | Walls | None = None,
            channel_width_px: float | None = None, tilt_deg: float | None = None,
            channel_width_tolerance: float = DEFAULT_WIDTH_TOLERANCE) -> Channel:
    """Level the stack, find its background and walls (see the module docstring).

    Parameters
    ----------
    stack : FrameStack
    background : 2-D array, optional
        The empty channel, as recorded (same size as the frames, same mirroring).
    walls : (top, bottom) rows or Walls, optional
        The walls' rows in the levelled frame (at the centre column, where levelling keeps
        rows in place): no detection.
    channel_width_px : float, optional
        The channel's width: checked against the walls found, and used to place a wall that
        lies outside the view.
    tilt_deg : float, optional
        The tilt, when known: no estimation (0 for frames known to be level).
    channel_width_tolerance : float
        The given width's tolerance, a fraction of it (default 2 %).

    Raises
    ------
    ExtractionError
        When the walls are neither found nor given, or the background's size is not the frames'.
    """
    frames = stack.frames
    label = stack.labels[0] if stack.labels else "frames"
    if background is not None:
        background = np.asarray(background, dtype=np.float32)
        if background.shape != frames[0].shape:
            raise ExtractionError(f"background: {background.shape[1]}x{background.shape[0]} px, the frames are "
                                  f"{frames[0].shape[1]}x{frames[0].shape[0]} px")
    picks = np.unique(np.linspace(0, len(frames) - 1, min(len(frames), MAX_FRAMES_TEMPORAL)).round().astype(int))
    raw = background if background is not None else _temporal_median([frames[k] for k in picks])
    tilt = estimate_tilt(raw) if tilt_deg is None else float(tilt_deg)
    untrusted, trust_check = None, ""
    if background is not None:
        levelled_bg: np.ndarray | None = level(background, tilt)
        source = "given"
    else:
        estimate = stack_background([level(frames[k], tilt) for k in picks])
        levelled_bg = estimate.image if estimate is not None else None
        source = "temporal median" if estimate is not None else "per-row median of each frame"
        if estimate is not None and estimate.untrusted.any():
            untrusted = estimate.untrusted
            free = "no frame" if MIN_FREE_FRAMES == 1 else f"fewer than {MIN_FREE_FRAMES} frames"
            trust_check = (f"background not trusted on {int(untrusted.sum())} px ({free} of {estimate.frames} shows "
                           f"them free of objects);\nobjects there are flagged: give --background to measure them")
    # The levelled image the walls and the straight channel are found on (the stack's median
    # frame, levelled, where there is no background).
    reference = levelled_bg if levelled_bg is not None else level(raw, tilt)
    if isinstance(walls, Walls):
        found = walls
    elif walls is not None:
        found = Walls(float(walls[0]), float(walls[1]), "given")
    else:
        found = find_walls(reference, label, channel_width_px,
                           channel_width_sigma_px=channel_width_tolerance * (channel_width_px or 0.0))
    geometry = ""
    if found.columns is None:
        found = dataclasses.replace(found, columns=straight_columns(reference, found))
    if found.columns is not None:
        width = np.asarray(frames[0]).shape[1]
        geometry = (f"straight channel: columns {found.columns[0]}-{found.columns[1]} of 0-{width - 1} (the walls "
                    f"leave their rows beyond: an inlet, an outlet or a widening); objects are looked for there only")
    if source.startswith("per-row"):
        trust_check = (f"background: each frame's own per-row median ({len(frames)} frame"
                       f"{'s' if len(frames) != 1 else ''}, fewer than {MIN_FRAMES_TEMPORAL} for a temporal median):"
                       f"\nan object fainter than the chip's texture is not seen; give the empty channel's image "
                       f"(--background) to find it")
    given = check_width(found, channel_width_px, channel_width_tolerance) if channel_width_px else None
    return Channel(found, tilt, levelled_bg, source, given.text if given else "", untrusted=untrusted,
                   background_check=trust_check, geometry_check=geometry,
                   width_disagrees=given.disagrees if given else False, width_verdict=given.verdict if given else "")


def _temporal_median(frames: list[np.ndarray]) -> np.ndarray:
    """The frames' median, pixel by pixel, as float32. Integer frames of up to 16 bits are
    sorted as they are (their median, a whole or a half grey level, is exact in float32; a
    partition of 8-bit values is twice as fast as of their float copies)."""
    stack = np.stack([np.asarray(frame) for frame in frames])
    if stack.dtype.kind not in "ui" or stack.dtype.itemsize > 2:
        stack = stack.astype(np.float32)
    return np.median(stack, axis=0).astype(np.float32)


def _inside(shape: tuple[int, int], walls: Walls, margin: int = 3) -> np.ndarray:
    """The rows between the walls, ``margin`` px clear of each wall line in view, in the straight
    channel's columns (``walls.columns``).

    Clear of them: a frame whose walls differ from the background's (blurred, or moved by a
    fraction of a pixel) leaves streaks along them that are no object.
    """
    inside = np.zeros(shape, dtype=bool)
    top = int(math.floor(walls.top_row)) + 1 + (margin if walls.top_row >= 0 else 0)
    bottom = int(math.ceil(walls.bottom_row)) - (margin if walls.bottom_row <= shape[0] - 1 else 0)
    inside[max(0, top):max(0, min(shape[0], bottom))] = True
    if walls.columns is not None:
        inside[:, :walls.columns[0]] = False
        inside[:, walls.columns[1] + 1:] = False
    return inside


def analyse_contrast(contrast: np.ndarray, walls: Walls, index: int = 0, label: str = "",
                     settings: ExtractionSettings = DEFAULT_SETTINGS, noise: np.ndarray | None = None) -> FrameResult:
    """Find the capsule in one frame's flat-field contrast and measure its contour.

    Parameters
    ----------
    contrast : 2-D array
        ``1 - I / background`` of the levelled frame, flow in +x.
    walls : Walls
        The stack's walls (levelled frame).
    index, label : int, str
        Frame number and name, copied into the result.
    settings : ExtractionSettings
    noise : 2-D array, optional
        The stack's own noise of the smoothed contrast at each pixel
        (``background.temporal_noise``): objects are detected against it where it is larger
        than the frame's.

    Returns
    -------
    FrameResult
        With ``flag`` set when the frame cannot be measured (the lengths of a traced object
        are kept when the flag comes after the tracing: asymmetry, off-axis, several objects);
        the out-of-focus test against the other frames is :func:`flag_out_of_focus`'s.
    """
    result = FrameResult(index=index, label=label)
    rows, cols = contrast.shape
    smooth = ndimage.gaussian_filter(contrast, DETECTION_SMOOTHING_PX)
    inside = _inside(contrast.shape, walls)
    labels, mask, keep, threshold = find_objects(smooth, inside, settings.detection_sigmas, settings.min_area_px,
                                                 (walls.top_row, walls.bottom_row), noise_map=noise)
    result.objects = len(keep)
    if not keep:
        result.flag = "no capsule"
        return result
    traces: list[TracedObject] = []
    reasons = []
    # Each object is looked at in its bounding box only (the rest of the frame is not its).
    boxes = ndimage.find_objects(labels, max_label=max(keep))
    column_sum, pixels, first, last = 0, 0, cols, -1
    for k in keep:
        box = boxes[k - 1]
        region = np.zeros(labels.shape, dtype=bool)
        region[box] = labels[box] == k
        traced = trace_object(contrast, region, mask, threshold, smooth, box)
        if isinstance(traced, str):
            reasons.append(traced)
        else:
            traces.append(traced)
        columns = np.nonzero(region[box] & mask[box])[1]
        if columns.size:
            column_sum += int(columns.sum()) + box[1].start * columns.size
            pixels += columns.size
            first, last = min(first, box[1].start + int(columns.min())), max(last, box[1].start + int(columns.max()))
    result.traces = traces
    for t in traces:
        measure_trace(t, walls.axis_row, cols, settings, walls.columns)
    result.object_x = column_sum / pixels
    rings = [t for t in traces if t.kind == "ring"]
    if rings:
        result.line_width_px = float(np.median([t.line_width_px for t in rings]))
        result.line_contrast = float(np.median([t.line_contrast for t in rings]))
        if result.line_width_px > settings.max_line_width_px:
            result.flag = f"out of focus (line {result.line_width_px:.1f} px wide > {settings.max_line_width_px:g})"
            return result
    elif traces:
        result.line_contrast = float(np.median([t.line_contrast for t in traces]))
    # The border first (or the straight channel's end): a capsule cut by it may fall apart into
    # several arcs. measure_trace flagged each object it cuts.
    cut = [t for t in traces if t.flag.startswith("touches")]
    whole_cut = cut_flag((first, last), cols, walls.columns)
    if len(cut) == len(traces) and whole_cut:
        result.flag = whole_cut
        return result
    if len(keep) > 1:
        result.flag = f"{len(keep)} capsules" + (f" ({len(cut)} cut by the image border or the channel's end)"
                                                 if cut else "")
        return result
    if not traces:
        result.flag = reasons[0]
        return result
    (trace,) = traces
    result.kind, result.contour_at = trace.kind, trace.contour_at
    if trace.flag.startswith("touching"):
        # Touching cells: no lengths of one capsule from them.
        result.flag = trace.flag
        return result
    result.contour = trace.contour
    result.x_front, result.x_rear = trace.x_front, trace.x_rear
    result.extent_px, result.outer_extent_px = trace.extent_px, trace.outer_extent_px
    result.x_rear_axis = trace.x_rear_axis
    result.L_z_px = trace.L_z_px
    result.L_p_px = max(0.0, result.x_rear_axis - result.x_rear)
    result.centroid_x, result.centroid_y = polygon_centroid(trace.contour)
    result.asymmetry = trace.asymmetry
    if not math.isfinite(result.x_rear_axis):
        result.flag = "contour does not cross the tube axis (capsule off the axis)"
    elif result.asymmetry > settings.max_asymmetry:
        result.flag = f"asymmetric ({result.asymmetry:.3f} > {settings.max_asymmetry} of L_z/2)"
    return result


def analyse_frame(image: np.ndarray, walls: Walls, index: int = 0, label: str = "",
                  settings: ExtractionSettings = DEFAULT_SETTINGS,
                  background: np.ndarray | None = None) -> FrameResult:
    """:func:`analyse_contrast` of a level frame against ``background`` (default: its per-row median)."""
    image = np.asarray(image, dtype=np.float32)
    return analyse_contrast(flat_field(image, background if background is not None else row_background(image)),
                            walls, index, label, settings)


def extract(stack: FrameStack, settings: ExtractionSettings = DEFAULT_SETTINGS,
            progress: Callable[[int, int], None] | None = None,
            walls: Walls | tuple[float, float] | None = None, background: np.ndarray | None = None,
            channel_width_px: float | None = None, tilt_deg: float | None = None,
            frame_rate: float | None = None) -> tuple[Walls, list[FrameResult]]:
    """Walls of the stack and every frame's analysis (out-of-focus and passages included).

    See :func:`prepare` for ``walls``, ``background``, ``channel_width_px`` and ``tilt_deg``;
    :func:`extract_stack` also returns the :class:`Channel`.
    """
    channel, results = extract_stack(stack, settings, progress, walls, background, channel_width_px, tilt_deg,
                                     frame_rate)
    return channel.walls, results


def _analyse(stack: FrameStack, settings: ExtractionSettings, progress: Callable[[int, int], None] | None,
             walls: Walls | tuple[float, float] | None, background: np.ndarray | None,
             channel_width_px: float | None, tilt_deg: float | None,
             rate: float | None, channel_width_tolerance: float = DEFAULT_WIDTH_TOLERANCE) -> tuple[Channel, list[FrameResult]]:
    """Every frame's analysis against the stack's channel, with times, focus and tracks."""
    channel = prepare(stack, background, walls, channel_width_px, tilt_deg, channel_width_tolerance)
    times = stack.frame_times(rate) if (stack.times_s is not None or rate) else None
    noise = _stack_noise(stack, channel)
    results = []
    for k, image in enumerate(stack.frames):
        result = analyse_contrast(channel.contrast(image), channel.walls, k, stack.labels[k], settings, noise)
        if times is not None:
            result.time_s = float(times[k])
        results.append(result)
        if progress is not None:
            progress(k + 1, len(stack))
    flag_out_of_focus(results, settings)
    _flag_untrusted_background(results, channel)
    for r in results:
        # A frame's flag is its only object's (focus is judged per frame, against the stack).
        if r.objects == 1 and len(r.traces) == 1 and r.flag and not r.traces[0].flag:
            r.traces[0].flag = r.flag
    interval = frame_interval(results, rate)
    # Frames with their own times (a recording's, a frame-times file) say which follow one another:
    # a cytometer's events a few camera frames apart may show one cell, and are tracked as a film.
    # Regular times given to a stack (a TIFF's frame interval) may hide independent events.
    if stack.times_s is None and stack.frame_numbers is None:
        channel.independent_events = independent_events(results, 0.25 * channel.walls.radius_px, interval)
    if channel.independent_events:
        track_events(results)
        return channel, results
    assign_passages(results, jump_px=0.25 * channel.walls.radius_px, interval_s=interval)
    track_objects(results, max_step_px=channel.walls.width_px, max_cross_px=0.25 * channel.walls.radius_px,
                  interval_s=interval)
    settle_pieces(results, interval, wall_rows=(channel.walls.top_row, channel.walls.bottom_row))
    return channel, results


def _stack_noise(stack: FrameStack, channel: Channel) -> np.ndarray | None:
    """The stack's own noise of the detection's contrast at each pixel (``background.temporal_noise``),
    from up to :data:`background.MAX_NOISE_PAIRS` pairs of consecutive frames spread over the
    stack. Only the pairs' differences are kept (bounded memory on large frames); the frames'
    analysis computes their contrasts again (a few per cent of its time)."""
    if len(stack) < 2:
        return None
    firsts = np.unique(np.linspace(0, len(stack) - 2, min(len(stack) - 1, MAX_NOISE_PAIRS)).round().astype(int))

    def smooth(k: int) -> np.ndarray:
        return ndimage.gaussian_filter(channel.contrast(stack.frames[k]), DETECTION_SMOOTHING_PX)

    differences = np.stack([smooth(int(k) + 1) - smooth(int(k)) for k in firsts])
    shape = (differences.shape[1], differences.shape[2])
    return temporal_noise(differences, _inside(shape, channel.walls))


#: The flag of an object over pixels whose stack background cannot be trusted.
UNTRUSTED_FLAG = "background not trusted under the object (too few frames free of objects there)"


def _flag_untrusted_background(results: list[FrameResult], channel: Channel) -> None:
    """Flag the objects (and single-object frames) lying on untrusted background, rather than
    measuring them against a background that may hold a part of them. The flag replaces a shape
    flag (asymmetric, off the axis: the shape itself is in doubt), not a cut by the border."""
    for r in results:
        for t in r.traces:
            if not t.flag.startswith("touches") and not channel.background_trusted_under(t):
                t.flag = UNTRUSTED_FLAG
        if (len(r.traces) == 1 and r.objects == 1 and r.traces[0].flag == UNTRUSTED_FLAG
                and not r.flag.startswith(("touches", "out of focus"))):
            r.flag = UNTRUSTED_FLAG


#: The median step [px] between frames that tells the flow's direction; at least this many steps.
MIN_FLOW_STEP_PX = 0.5
MIN_FLOW_STEPS = 2


def _motion(results: list[FrameResult], channel: Channel, rate: float | None) -> float:
    """The objects' median step along x between consecutive frames (NaN when too few are seen)."""
    steps = flow_steps(results, channel.walls.width_px, 0.25 * channel.walls.radius_px,
                       gap_limit(results, frame_rate=rate))
    return float(np.median(steps)) if steps.size >= MIN_FLOW_STEPS else math.nan


def extract_stack(stack: FrameStack, settings: ExtractionSettings = DEFAULT_SETTINGS,
                  progress: Callable[[int, int], None] | None = None,
                  walls: Walls | tuple[float, float] | None = None, background: np.ndarray | None = None,
                  channel_width_px: float | None = None, tilt_deg: float | None = None,
                  frame_rate: float | None = None, flow_direction: str | None = None,
                  channel_width_tolerance: float = DEFAULT_WIDTH_TOLERANCE) -> tuple[Channel, list[FrameResult]]:
    """The stack's :class:`Channel` and every frame's analysis, with times, passages and tracks.

    The file's own background (``stack.background``) and nominal channel width
    (``stack.channel_width_um``) are used when none is given. The flow's direction comes from
    the motion: the objects' median step between consecutive frames (:func:`tracking.flow_steps`).
    With ``flow_direction`` (default ``stack.flow_direction``) 'auto', frames whose objects move
    in -x are mirrored (``stack.frames`` too) and analysed again; 'right' or 'left' (the frames
    already mirrored by :func:`read_frames`) is checked against the motion, and a disagreement
    said in ``Channel.flow_check``. ``channel_width_tolerance``: see :func:`prepare`; where a
    wall was placed at the channel width, the axis is checked against the objects' symmetry line
    (``channel.check_axis``, said in ``Channel.width_check``).
    """
    direction = flow_direction or stack.flow_direction
    rate = frame_rate or stack.frame_rate
    if background is None and stack.background is not None:
        background = stack.background
    if channel_width_px is None and stack.channel_width_um and stack.pixel_size_um:
        channel_width_px = stack.channel_width_um / stack.pixel_size_um
    channel, results = _analyse(stack, settings, progress, walls, background, channel_width_px, tilt_deg, rate,
                                channel_width_tolerance)
    if background is not None and background is stack.background and stack.background_source:
        channel.background_source = stack.background_source
    step = math.nan if channel.independent_events else _motion(results, channel, rate)
    given = "left" if direction == "left" else "right"
    if channel.independent_events:
        channel.flow_direction = given
        channel.flow_check = (f"flow direction {given}: " + ("given" if direction != "auto" else "assumed")
                              + " (independent events: no motion between frames to tell it)")
    elif not math.isfinite(step) or abs(step) < MIN_FLOW_STEP_PX:
        channel.flow_direction = given
        channel.flow_check = (f"flow direction {given}: " + ("given" if direction != "auto" else "assumed")
                              + " (no object followed over consecutive frames)")
    elif direction == "auto" and step < 0:
        stack.frames = mirror_frames(stack.frames)
        if background is not None:
            background = np.ascontiguousarray(np.asarray(background)[:, ::-1])
        if isinstance(walls, Walls):
            walls = (walls.top_row, walls.bottom_row)
        tilt = -tilt_deg if tilt_deg is not None else None
        channel, results = _analyse(stack, settings, progress, walls, background, channel_width_px, tilt, rate,
                                    channel_width_tolerance)
        stack.flow_direction = channel.flow_direction = "left"
        channel.flow_check = (f"flow direction left: from the motion (objects move {-step:.2f} px a frame in -x; "
                              f"the frames were mirrored)")
    elif direction == "auto":
        channel.flow_direction = "right"
        channel.flow_check = f"flow direction right: from the motion (objects move {step:.2f} px a frame in +x)"
    else:
        channel.flow_direction = given
        channel.flow_check = (f"flow direction {given}: given, " + (
            "confirmed by the motion" if step > 0 else
            f"but the objects move the other way ({abs(step):.2f} px a frame): check --flow-direction"))
    if "placed" in channel.walls.source:
        rows = [r.centroid_y for r in results if r.objects == 1 and r.traces]
        sentence, off = check_axis(channel.walls, rows)
        if off:
            # The capsules are centred on the tube's axis: the wall placed at the width given is
            # moved to make their symmetry line the axis, and the frames are measured again.
            before = channel
            moved = axis_from_objects(channel.walls, rows)
            channel, results = _analyse(stack, settings, progress, moved, background, channel_width_px,
                                        before.tilt_deg, rate, channel_width_tolerance)
            channel.flow_direction, channel.flow_check = before.flow_direction, before.flow_check
            channel.background_source = before.background_source
            given = f"{channel_width_px:.1f} px given" if channel_width_px else "the width given"
            sentence += (f"; the {moved.placed_side} wall is moved to row "
                         f"{moved.top_row if moved.placed_side == 'top' else moved.bottom_row:.1f}, the axis to that "
                         f"line: the width is {moved.width_px:.1f} +- {moved.width_sigma_px:.1f} px ({given}) and "
                         f"the frames are measured against it")
            channel.width_check = before.width_check
            channel.width_disagrees = True
            channel.width_verdict = (f"axis from the objects' symmetry line ({moved.axis_row - before.walls.axis_row:+.1f} px "
                                     f"from the one placed at the width given)")
        channel.width_check = f"{channel.width_check}; {sentence}" if channel.width_check else sentence
    return channel, results


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
