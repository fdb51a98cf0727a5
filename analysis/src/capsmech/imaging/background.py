"""The static background of a stack, and the flat-field contrast of a frame against it.

Light is absorbed multiplicatively, so a frame divided by the empty-channel image (flat-field
division) leaves the object's absorption alone: walls, dirt on the chip and illumination
gradients divide out, whatever their shape. The empty-channel image is, in order of
preference, the user's background image (or the recording's own), the temporal median of the
stack with the passing objects masked out, or - for stacks too short for a temporal median -
each levelled frame's per-row median (walls are horizontal once the channel is levelled).
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import ndimage

#: Fewest frames for a temporal median: with fewer, an object passes through half of them.
MIN_FRAMES_TEMPORAL = 5
#: At most this many frames (evenly spread) enter the temporal median: enough for a robust
#: median, bounded cost on long films.
MAX_FRAMES_TEMPORAL = 101
#: Pixels this many noise deviations (after a 1 px smoothing) off the reference are an object's.
OBJECT_SIGMAS = 4.0
#: Object masks grow by this many pixels: the blurred edges of a line lie below the threshold.
OBJECT_MARGIN_PX = 3


def row_background(image: np.ndarray) -> np.ndarray:
    """Each row's median over the columns, spread over the row (levelled frames: walls horizontal).

    The fallback for single frames: an object filling less than half of every row does not
    move the median.
    """
    image = np.asarray(image, dtype=np.float32)
    return np.repeat(np.median(image, axis=1)[:, None], image.shape[1], axis=1)


def noise_level(values: np.ndarray) -> float:
    """Robust standard deviation (1.4826 median absolute deviation) of ``values``."""
    values = np.asarray(values, dtype=np.float32).ravel()
    return float(1.4826 * np.median(np.abs(values - np.median(values))))


def stack_background(frames: Sequence[np.ndarray]) -> np.ndarray | None:
    """Static background of a levelled stack: temporal median with the moving objects left out.

    A plain temporal median keeps whatever lies in a pixel in at least half the frames - a
    slow capsule that covers the same pixels all along its passage. So each frame's objects
    are found first against its own per-row median (object-free where the capsule fills less
    than half of a row), masked, and the median is taken over the frames left. A pixel masked
    in every frame is a static object (dirt: the plain temporal median is right there) or a
    part of a slow capsule (the per-row median is the background there): see
    :func:`_covered_background`.

    Parameters
    ----------
    frames : sequence of 2-D arrays
        The levelled frames (walls horizontal).

    Returns
    -------
    2-D float32 array, or None
        None when the stack has fewer than :data:`MIN_FRAMES_TEMPORAL` frames.
    """
    if len(frames) < MIN_FRAMES_TEMPORAL:
        return None
    picks = np.unique(np.linspace(0, len(frames) - 1, min(len(frames), MAX_FRAMES_TEMPORAL)).round().astype(int))
    stack = np.stack([np.asarray(frames[k], dtype=np.float32) for k in picks])
    plain = np.median(stack, axis=0)
    rows = np.median(stack, axis=2, keepdims=True)
    safe_rows = np.maximum(rows, max(float(rows.max()) * 1e-3, 1e-6))
    residual = ndimage.gaussian_filter(stack / safe_rows - 1, (0, 1, 1))
    sigma = max(noise_level(residual[:, ::2, ::2]), 1e-4)
    masks = ndimage.binary_dilation(np.abs(residual) > OBJECT_SIGMAS * sigma,
                                    structure=np.ones((1, 3, 3), bool), iterations=OBJECT_MARGIN_PX)
    masked = np.where(masks, np.nan, stack)
    covered = masks.all(axis=0)
    background = _nanmedian_first_axis(np.where(covered[None], 0.0, masked))
    if covered.any():
        background = np.where(covered, _covered_background(stack, masks, covered, plain, rows), background)
    return background.astype(np.float32)


def _nanmedian_first_axis(stack: np.ndarray) -> np.ndarray:
    """``np.nanmedian(stack, axis=0)`` for a stack with at least one number per pixel, by one
    sort (NaNs sort last) and the middle of each pixel's numbers: numpy's nanmedian goes through
    masked arrays and is 5-10 times slower."""
    ordered = np.sort(stack, axis=0)
    count = np.sum(~np.isnan(stack), axis=0)
    low = np.take_along_axis(ordered, ((count - 1) // 2)[None], axis=0)[0]
    high = np.take_along_axis(ordered, (count // 2)[None], axis=0)[0]
    return 0.5 * (low + high)


def flat_field(image: np.ndarray, background: np.ndarray) -> np.ndarray:
    """Contrast ``1 - image / background``: the object's absorption (dark > 0, bright < 0).

    Pixels where the background is black (padding rows, masked corners) get zero contrast.
    """
    image = np.asarray(image, dtype=np.float32)
    background = np.asarray(background, dtype=np.float32)
    floor = max(float(np.percentile(background, 90)) * 0.05, 1e-6)
    out = 1 - image / np.maximum(background, floor)
    out[background < floor] = 0.0
    return out


def _covered_background(stack: np.ndarray, masks: np.ndarray, covered: np.ndarray, plain: np.ndarray,
                        rows: np.ndarray) -> np.ndarray:
    """The background where every frame's mask covers a pixel: the plain median or the row median.

    Such a pixel is a static object (dirt, a patch of the chip: the plain temporal median is
    right) or part of a slow object that stays put - a capsule's top and bottom membrane run
    along the flow and cover the same pixels in every frame of its passage (the row's median
    is right). Frames in which nothing moves tell them apart: when at least a fifth of the
    frames show no moving object, whatever every frame shows is static. Otherwise a covered
    region that borders pixels masked in many (a third or more) but not all frames belongs to a
    moving object; one surrounded by pixels masked in none or a few (noise) is static. The edges
    of a wall line flicker in many frames: rows beside a wall line do not count.
    """
    from skimage.measure import label as label_components

    from capsmech.imaging.channel import wall_lines

    # Frames in which nothing moves: under 40 % of the busiest frame's moving pixels (noise and
    # the flicker of the wall lines mask a few hundred pixels in every frame).
    moving = (masks & ~covered[None]).reshape(len(stack), -1).sum(axis=1)
    quiet = int(np.sum(moving < 0.4 * moving.max()))
    if quiet >= max(1, len(stack) // 5):
        return plain
    partial = (masks.sum(axis=0) >= max(2, len(stack) // 3)) & ~covered
    for row in wall_lines(plain):
        partial[max(0, int(row) - 4):int(row) + 6] = False
    parts, count = label_components(covered, return_num=True, connectivity=2)
    row_level = np.broadcast_to(np.median(rows, axis=0)[:, :1], plain.shape)
    out = plain.copy()
    for k in range(1, count + 1):
        part = parts == k
        shell = ndimage.binary_dilation(part, iterations=2) & ~part
        if shell.any() and partial[shell].mean() > 0.3:
            out[part] = row_level[part]
    return out
