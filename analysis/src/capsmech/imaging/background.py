"""The static background of a stack, and the flat-field contrast of a frame against it.

Light is absorbed multiplicatively, so a frame divided by the empty-channel image (flat-field
division) leaves the object's absorption alone: walls, dirt on the chip and illumination
gradients divide out, whatever their shape. The empty-channel image is, in order of
preference, the user's background image (or the recording's own), the temporal median of the
stack with the passing objects masked out, or - for stacks too short for a temporal median -
each levelled frame's per-row median (walls are horizontal once the channel is levelled).

A temporal median is only as good as the frames in which a pixel is free: a capsule that sits
for most of a short film leaves too few. :class:`StackBackground` says, pixel by pixel, where
the background cannot be trusted, so that objects there are flagged instead of measured wrong.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

#: Fewest frames for a temporal median: with fewer, an object passes through half of them.
MIN_FRAMES_TEMPORAL = 5
#: At most this many frames (evenly spread) enter the temporal median: enough for a robust
#: median (its noise 0.18 of a frame's), bounded cost on long films (101 frames: 0.13 of a
#: frame's noise, and twice the stack's preparation).
MAX_FRAMES_TEMPORAL = 51
#: Pixels this many noise deviations (after a 1 px smoothing) off the reference are an object's.
OBJECT_SIGMAS = 4.0
#: Object masks grow by this many pixels: the blurred edges of a line lie below the threshold.
OBJECT_MARGIN_PX = 3
#: A pixel's background is trusted when at least this many frames show it free of any object.
#: One is enough: masks are grown by OBJECT_MARGIN_PX, so a free pixel is one no object came
#: near, and one frame's noise adds sqrt(2) to the contrast's, far below the detection's 6
#: deviations. With none the background is a guess (:func:`_covered_background`).
MIN_FREE_FRAMES = 1
#: A pixel covered in every frame is steady (static dirt) when its grey level varies over the
#: frames by at most this many times the frame-to-frame noise.
STEADY_SIGMAS = 3.0
#: A pixel masked in many frames shows an object passing over it (not the noise flickering at
#: the edge of a static region) when its largest deviation from its median exceeds this many
#: frame-to-frame noise deviations (the noise alone: about 3 over 51 frames, one pixel in 10^6 beyond 6).
MOTION_SIGMAS = 6.0


@dataclass
class StackBackground:
    """A stack's static background and how far it can be trusted, pixel by pixel.

    Attributes
    ----------
    image : 2-D float32 array
        The empty channel (levelled).
    free_frames : 2-D int array
        In how many of the ``frames`` each pixel was free of any object.
    untrusted : 2-D bool array
        Pixels free in fewer than :data:`MIN_FREE_FRAMES` frames that :func:`_covered_background`
        cannot vouch for: their background is a guess, and an object over them cannot be
        measured reliably.
    frames : int
        The frames the median was taken over.
    """

    image: np.ndarray
    free_frames: np.ndarray
    untrusted: np.ndarray
    frames: int


def row_background(image: np.ndarray, columns: tuple[int, int] | None = None) -> np.ndarray:
    """Each row's median over the columns, spread over the row (levelled frames: walls horizontal).

    The fallback for single frames: an object filling less than half of every row does not
    move the median. ``columns``: the first and last column of the straight channel, over
    which the median is taken (beyond, the walls leave their rows).
    """
    image = np.asarray(image, dtype=np.float32)
    part = image if columns is None else image[:, columns[0]:columns[1] + 1]
    return np.repeat(np.median(part, axis=1)[:, None], image.shape[1], axis=1)


def noise_level(values: np.ndarray) -> float:
    """Robust standard deviation (1.4826 median absolute deviation) of ``values``."""
    values = np.asarray(values, dtype=np.float32).ravel()
    return float(1.4826 * np.median(np.abs(values - np.median(values))))


def stack_background(frames: Sequence[np.ndarray]) -> StackBackground | None:
    """Static background of a levelled stack: temporal median with the moving objects left out.

    A plain temporal median keeps whatever lies in a pixel in at least half the frames - a
    slow capsule that covers the same pixels all along its passage. So each frame's objects
    are found first against its own per-row median (object-free where the capsule fills less
    than half of a row; times the lamp's trend along the rows where there is one), masked
    with what their outlines enclose (a capsule's interior, often a little brighter than the
    liquid), and the median is taken over the frames left. A pixel masked
    in every frame is a static object (dirt: the plain temporal median is right there), a
    part of a slow capsule (the per-row median is the background there), or neither to tell -
    then the background there is not trusted (``StackBackground.untrusted``): see
    :func:`_covered_background`.

    Parameters
    ----------
    frames : sequence of 2-D arrays
        The levelled frames (walls horizontal).

    Returns
    -------
    StackBackground or None
        The background with the count of free frames per pixel and the pixels it cannot vouch
        for; None when the stack has fewer than :data:`MIN_FRAMES_TEMPORAL` frames.
    """
    if len(frames) < MIN_FRAMES_TEMPORAL:
        return None
    picks = np.unique(np.linspace(0, len(frames) - 1, min(len(frames), MAX_FRAMES_TEMPORAL)).round().astype(int))
    stack = np.stack([np.asarray(frames[k], dtype=np.float32) for k in picks])
    rows = np.median(stack, axis=2, keepdims=True)
    safe_rows = np.maximum(rows, max(float(rows.max()) * 1e-3, 1e-6))
    # Each frame's rows times the lamp's trend along them: against the rows alone an
    # illumination gradient along the flow sets the image's ends off by several per cent, the
    # noise estimate with them - the liquid there is then masked as an object while a capsule's
    # slightly brighter interior passes for the empty channel, and the median keeps it. The
    # trend is used where it explains a good part of the residual's spread (a lamp's gradient),
    # not where it would only follow the objects of a short stack.
    residual = ndimage.gaussian_filter(stack / safe_rows - 1, (0, 1, 1))
    sigma = max(noise_level(residual[:, ::2, ::2]), 1e-4)
    trend = _column_trend(stack / safe_rows)
    levelled = ndimage.gaussian_filter(stack / (safe_rows * trend) - 1, (0, 1, 1))
    if noise_level(levelled[:, ::2, ::2]) < TREND_NOISE_FALL * sigma:
        residual, sigma = levelled, max(noise_level(levelled[:, ::2, ::2]), 1e-4)
    else:
        trend = np.ones_like(trend)
    deviant = np.abs(residual) > OBJECT_SIGMAS * sigma
    interiors = _interiors(deviant)
    masks = ndimage.binary_dilation(deviant | interiors, structure=np.ones((1, 3, 3), bool),
                                    iterations=OBJECT_MARGIN_PX)
    masked = np.where(masks, np.nan, stack)
    covered = masks.all(axis=0)
    background = _nanmedian_first_axis(np.where(covered[None], 0.0, masked))
    free = len(stack) - masks.sum(axis=0)
    vouched = np.zeros_like(covered)
    if covered.any():
        plain = np.median(stack, axis=0)
        row_level = np.median(rows, axis=0)[:, :1] * trend[0]
        fill, vouched = _covered_background(stack, masks, covered, plain, row_level, interiors)
        background = np.where(covered, fill, background)
    return StackBackground(background.astype(np.float32), free, (free < MIN_FREE_FRAMES) & ~vouched, len(stack))


#: Fewest pairs of consecutive frames for a per-pixel temporal noise (:func:`temporal_noise`):
#: with fewer, the spread of a pixel's few values is itself too uncertain to set a threshold by.
MIN_NOISE_PAIRS = 12
#: At most this many pairs (evenly spread over the stack) give the temporal noise: the spread of
#: 31 values is known to about 15 %, and the map is smoothed over 5 x 5 pixels on top.
MAX_NOISE_PAIRS = 31
#: A pixel's own spread counts up to this many times its row's: enough for dirt that shakes,
#: and a bound on what the edges of passing objects leave in it.
MAX_OWN_NOISE = 3.0


def temporal_noise(differences: np.ndarray, inside: np.ndarray) -> np.ndarray | None:
    """The contrast's noise at each pixel, from the differences between consecutive frames.

    Detection thresholds against one number for the whole frame find "objects" wherever the
    noise is larger than elsewhere: in the dim rows beside a wall (the flat field divides the
    camera's noise by a low grey level), on a wall's edge that flickers as the chip shakes by
    a fraction of a pixel, on dirt that shakes. Each pixel's own spread over the stack knows
    all of these. It is read on the difference between consecutive frames (1.4826 median
    absolute deviation, over sqrt(2)): the noise and the flicker of two frames are
    independent, while an object - a slow capsule over a pixel in most frames, its light
    interior, its dark line - moves little from one frame to the next and leaves the
    difference alone but at its edges, in a few frames of each passage. The map is the larger
    of each row's median spread over the channel's columns (the walls are level: a row shares
    its light and its wall's flicker) and the pixel's own, median-filtered over 5 x 5 pixels
    and at most :data:`MAX_OWN_NOISE` times its row's.

    Parameters
    ----------
    differences : (n, rows, cols) array
        Differences of the flat-field contrast between ``n`` pairs of consecutive frames
        spread over the stack, smoothed as the detection smooths it.
    inside : 2-D bool array
        The channel's pixels where objects are looked for.

    Returns
    -------
    2-D float32 array, or None
        The noise (contrast units) of one frame at each pixel; None with fewer than
        :data:`MIN_NOISE_PAIRS` pairs or no pixel inside.
    """
    if len(differences) < MIN_NOISE_PAIRS or not inside.any():
        return None
    differences = np.asarray(differences, dtype=np.float32)
    centre = np.median(differences, axis=0)
    spread = 1.4826 / np.sqrt(2) * np.median(np.abs(differences - centre[None]), axis=0)
    counted = inside.any(axis=1)
    rows = np.full(spread.shape[0], float(np.median(spread[inside])), dtype=np.float32)
    rows[counted] = [np.median(spread[k, inside[k]]) for k in np.nonzero(counted)[0]]
    row_map = np.broadcast_to(rows[:, None], spread.shape)
    own = np.minimum(ndimage.median_filter(spread, size=5), MAX_OWN_NOISE * row_map)
    return np.maximum(row_map, own).astype(np.float32)


def _nanmedian_first_axis(stack: np.ndarray) -> np.ndarray:
    """``np.nanmedian(stack, axis=0)`` for a stack with at least one number per pixel, by one
    sort (NaNs sort last) and the middle of each pixel's numbers: numpy's nanmedian goes through
    masked arrays and is 5-10 times slower."""
    ordered = np.sort(stack, axis=0)
    count = np.sum(~np.isnan(stack), axis=0)
    low = np.take_along_axis(ordered, ((count - 1) // 2)[None], axis=0)[0]
    high = np.take_along_axis(ordered, (count // 2)[None], axis=0)[0]
    return 0.5 * (low + high)


#: Background pixels darker than this fraction of its 90th percentile are black (no contrast).
FLOOR_FRACTION = 0.05


def flat_field(image: np.ndarray, background: np.ndarray, floor: float | None = None) -> np.ndarray:
    """Contrast ``1 - image / background``: the object's absorption (dark > 0, bright < 0).

    Pixels where the background is black (padding rows, masked corners), below ``floor``
    (default :data:`FLOOR_FRACTION` of its 90th percentile, at least 1e-6), get zero contrast.
    """
    image = np.asarray(image, dtype=np.float32)
    background = np.asarray(background, dtype=np.float32)
    floor = max(float(np.percentile(background, 90)) * FLOOR_FRACTION if floor is None else floor, 1e-6)
    if background.min() >= np.float32(floor):
        # No black pixel (the usual case): the floor changes nothing (it is compared in float32).
        return 1 - image / background
    out = 1 - image / np.maximum(background, floor)
    out[background < floor] = 0.0
    return out


def _interiors(masks: np.ndarray) -> np.ndarray:
    """What each frame's object outlines enclose (the holes of its mask, ``masks`` not included).

    A capsule's interior is often slightly brighter than the liquid, a few per cent: too little
    to pass the threshold, enough to set a pixel's median off where the liquid's frames are
    masked for another reason (static dirt, deviant against the rows in every frame it shows)
    and the capsule's are not. An interior is a hole of the frame's mask, the image's left and
    right borders closing the outline of an object cut by them; a hole that reaches both (the
    channel between two wall lines) is no object's.
    """
    columns = masks.shape[2]
    # The free pixels' regions, each frame on its own: one labelling of the whole stack.
    in_plane = np.zeros((3, 3, 3), bool)
    in_plane[1] = ndimage.generate_binary_structure(2, 1)
    labels, count = ndimage.label(~masks, structure=in_plane)
    enclosed = np.ones(count + 1, bool)
    enclosed[0] = False
    enclosed[np.unique(labels[:, [0, -1], :])] = False
    for n, box in enumerate(ndimage.find_objects(labels), start=1):
        if box is not None and box[2].start == 0 and box[2].stop == columns:
            enclosed[n] = False
    return enclosed[labels]


#: The lamp's trend along the rows is divided out when the noise estimate falls below this
#: fraction of the one against the rows alone (a 5-25 % gradient: 0.4-0.5; none: 0.9-1).
TREND_NOISE_FALL = 0.75
#: Columns over which the lamp's trend along the rows is smoothed (a median): wider than an
#: object's pixels in a column's median, narrower than an illumination gradient.
TREND_COLUMNS = 31


def _column_trend(ratio: np.ndarray) -> np.ndarray:
    """The lamp's smooth trend along the rows, (1, 1, columns): each column's median over the
    frames and rows of ``ratio`` (the frames over their rows' medians), median-filtered over
    :data:`TREND_COLUMNS` columns. An object covers a minority of a column's rows and frames."""
    columns = ratio.shape[2]
    per_column = np.median(ratio[:, ::2].reshape(-1, columns), axis=0)
    trend = ndimage.median_filter(per_column, size=TREND_COLUMNS, mode="nearest")
    trend = np.where(np.isfinite(trend) & (trend > 0.2), trend, 1.0)
    return trend.astype(np.float32)[None, None, :]


def _seen_around_passages(stack: np.ndarray, interiors: np.ndarray, covered: np.ndarray,
                          noise: float) -> tuple[np.ndarray, np.ndarray]:
    """Covered pixels that are static features an object passed over, and their level.

    Dirt is deviant against the rows in every frame it shows, so it is covered wherever an
    object's interior passed over it. It shows, steady, in frames both before and after that
    passage: its level is the median over the frames outside any interior. (A capsule's
    membrane that sits over a pixel does not come back to it after its interior has passed.)
    """
    static = np.zeros_like(covered)
    level_map = np.zeros(covered.shape, dtype=np.float32)
    inside = interiors[:, covered]
    passed = inside.any(axis=0)
    if not passed.any():
        return static, level_map
    n = len(stack)
    frame = np.arange(n)[:, None]
    first = np.where(passed, np.argmax(inside, axis=0), n)
    last = np.where(passed, n - 1 - np.argmax(inside[::-1], axis=0), -1)
    around = passed & (~inside & (frame < first)).any(axis=0) & (~inside & (frame > last)).any(axis=0)
    if not around.any():
        return static, level_map
    values = np.where(inside[:, around], np.nan, stack[:, covered][:, around])
    level_now = np.maximum(_nanmedian_first_axis(values), 1e-6)
    spread = 1.4826 * _nanmedian_first_axis(np.abs(values - level_now)) / level_now
    steady = spread <= STEADY_SIGMAS * noise
    candidates = np.flatnonzero(covered.ravel())[np.flatnonzero(around)[steady]]
    static.ravel()[candidates] = True
    level_map.ravel()[candidates] = level_now[steady]
    return static, level_map


def _covered_background(stack: np.ndarray, masks: np.ndarray, covered: np.ndarray, plain: np.ndarray,
                        row_level: np.ndarray, interiors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The background where every frame's mask covers a pixel: the plain median or the row median;
    and which covered pixels it can vouch for.

    Such a pixel is a static object (dirt, a patch of the chip: the plain temporal median is
    right) or lies under moving objects in every frame - a slow capsule's top and bottom
    membrane run along the flow and cover the same pixels all along its passage, or one object
    follows another over the same spot in a short film (the row's median is the best guess
    there). A covered region is static when both hold:

    - it is steady: its pixels keep their grey level from frame to frame (a robust spread over
      the frames within :data:`STEADY_SIGMAS` of the frame-to-frame noise); objects passing
      over it change it;
    - it is no part of a moving object: at least a fifth of the frames show no moving object
      (then whatever every frame shows is static), or it does not border pixels masked in many
      (a third or more) but not all frames. The edges of a wall line flicker in many frames:
      rows beside a wall line do not count.

    Dirt that an object's interior passed over, seen steady before and after the passage, is
    static whatever moves beside it: the median of the frames outside the interior
    (:func:`_seen_around_passages`).

    Vouched for: a static region (the plain median), and a region beside the motion of an
    object (the row's median: the walls are level, and the object moves on, as the pixels
    around show). Not vouched for: a region neither steady nor beside a moving object - objects
    that follow one another over the same spot, in a film too short to show it free.
    """
    from skimage.measure import label as label_components

    from capsmech.imaging.channel import wall_lines

    values = stack[:, covered]
    level_now = np.maximum(np.median(values, axis=0), 1e-6)
    spread = 1.4826 * np.median(np.abs(values - level_now), axis=0) / level_now
    # The frame-to-frame noise (relative), robust to the objects: consecutive frames differ by
    # sqrt(2) times it where nothing moves.
    noise = max(noise_level((stack[1:, ::2, ::2] - stack[:-1, ::2, ::2]) / np.maximum(plain[::2, ::2], 1e-6))
                / np.sqrt(2), 1e-4)
    steady = np.zeros_like(covered)
    steady[covered] = spread <= STEADY_SIGMAS * noise
    # Frames in which nothing moves: under 40 % of the busiest frame's moving pixels (noise and
    # the flicker of the wall lines mask a few hundred pixels in every frame).
    moving = (masks & ~covered[None]).reshape(len(stack), -1).sum(axis=1)
    quiet = int(np.sum(moving < 0.4 * moving.max()))
    partial = (masks.sum(axis=0) >= max(2, len(stack) // 3)) & ~covered
    # Masked often, but only by the noise: the edge of a static region, where the noise flickers
    # across the threshold, is no motion. An object that passed over a pixel moves it far beyond
    # the noise in at least one frame, be it the object's or the free one.
    if partial.any():
        values = stack[:, partial]
        centre = np.median(values, axis=0)
        excursion = np.max(np.abs(values - centre), axis=0) / np.maximum(centre, 1e-6)
        partial[partial] = excursion > MOTION_SIGMAS * noise
    for row in wall_lines(plain):
        partial[max(0, int(row) - 4):int(row) + 6] = False
    parts, count = label_components(covered, return_num=True, connectivity=2)
    row_level = np.broadcast_to(row_level, plain.shape)
    out = plain.copy()
    vouched = covered.copy()
    for k in range(1, count + 1):
        part = parts == k
        shell = ndimage.binary_dilation(part, iterations=2) & ~part
        beside_motion = quiet < max(1, len(stack) // 5) and shell.any() and partial[shell].mean() > 0.3
        if beside_motion or steady[part].mean() < 0.5:
            out[part] = row_level[part]
            vouched[part] = beside_motion
    static, static_level = _seen_around_passages(stack, interiors, covered, noise)
    out = np.where(static, static_level, out)
    return out, vouched | static
