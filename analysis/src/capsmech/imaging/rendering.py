"""Synthetic microscopy: frames of a capsule flowing in a capillary, rendered from its profile.

A bright-field microscope focused on the tube's mid-plane shows the capsule's membrane as a
dark line (the meridian mirrored about the axis) and the capillary's two walls as dark
horizontal lines just outside the axis +- l (the glass lies outside the liquid: each line's
liquid-side edge is the wall). ``render_frame`` draws that picture from a simulated
meridian (``capsmech.diagnosis.synthetic.simulate_tube`` or a database profile): the membrane is
a band of a given width centred on the true curve, each wall a band ending at the wall on its
liquid side, convolved with a Gaussian blur (focus), multiplied into a uniform bright background
(transmission: darkenings multiply), plus Gaussian noise, quantised to 8 or 16 bits. Image convention (the one ``capsmech.imaging.extraction`` reads): the tube
axis along x (columns), the flow in +x, so the capsule's front is at the largest x.

The blurred band is computed in closed form from the distance to the curve (the convolution
of a box of width w with a Gaussian, exact for a locally straight line), so sub-pixel
positions and any blur are rendered without supersampling.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import erf

from capsmech.io.atomic import atomic_path

#: Curve points are placed at most this far apart (px) before distances are taken.
_SAMPLE_SPACING_PX = 0.05


@dataclass(frozen=True)
class FrameStyle:
    """How a frame looks: geometry of the image and of the tube, optics, camera.

    Attributes
    ----------
    shape : (rows, columns)
        Image size in pixels.
    tube_radius_px : float
        Inner radius l of the capillary in pixels (the wall lines' liquid-side edges lie at
        axis +- l, the lines outside them).
    axis_row : float or None
        Row (y, may be fractional) of the tube axis; None puts it at the image's middle.
    membrane_width_px, wall_width_px : float
        Width of the dark membrane line and of the wall lines before blurring.
    membrane_darkness, wall_darkness : float
        Fraction of the light a line absorbs at its centre, in (0, 1).
    blur_px : float
        Standard deviation of the Gaussian blur (focus), px.
    background : float
        Background brightness as a fraction of the camera's full scale.
    noise : float
        Standard deviation of the additive Gaussian noise, fraction of full scale.
    bit_depth : {8, 16}
        Camera bit depth (the output dtype is uint8 or uint16).
    """

    shape: tuple[int, int] = (200, 400)
    tube_radius_px: float = 60.0
    axis_row: float | None = None
    membrane_width_px: float = 2.5
    wall_width_px: float = 3.0
    membrane_darkness: float = 0.6
    wall_darkness: float = 0.7
    blur_px: float = 1.0
    background: float = 0.8
    noise: float = 0.02
    bit_depth: int = 8

    @property
    def axis(self) -> float:
        """Row of the tube axis."""
        return (self.shape[0] - 1) / 2 if self.axis_row is None else float(self.axis_row)


def outline_from_meridian(r: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Closed outline seen in the microscope: the meridian and its mirror image about the axis.

    Parameters
    ----------
    r, z : array
        Meridian pole to pole (front pole first), in tube radii l.

    Returns
    -------
    ndarray, shape (n, 2)
        Points (axial z, transverse y) in l: the upper half front to rear, then the lower
        half rear to front; the first point is not repeated at the end.
    """
    r = np.asarray(r, dtype=float)
    z = np.asarray(z, dtype=float)
    if r.shape != z.shape or r.ndim != 1 or r.size < 3:
        raise ValueError("outline_from_meridian: r and z must be 1-D arrays of the same length (>= 3)")
    upper = np.column_stack([z, -r])          # image rows grow downward: the upper half has y < axis
    lower = np.column_stack([z[::-1], r[::-1]])[1:-1]
    return np.vstack([upper, lower])


def drawn_lengths(outline: np.ndarray) -> tuple[float, float]:
    """L_z and L_p (in the outline's units) of an outline made by :func:`outline_from_meridian`.

    L_z is the axial extent; L_p the axial distance from the rear point on the axis to the
    rear-most point (0 for a convex rear).
    """
    z, y = outline[:, 0], outline[:, 1]
    on_axis = np.abs(y) < 1e-12
    rear_on_axis = z[on_axis].min()
    return float(z.max() - z.min()), float(rear_on_axis - z.min())


def _densify(points: np.ndarray, spacing: float) -> np.ndarray:
    """Closed polyline resampled so that consecutive points are at most ``spacing`` apart."""
    closed = np.vstack([points, points[:1]])
    seg = np.diff(closed, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    counts = np.maximum(1, np.ceil(lengths / spacing).astype(int))
    t = np.concatenate([np.arange(c) / c for c in counts])
    start = np.repeat(closed[:-1], counts, axis=0)
    step = np.repeat(seg, counts, axis=0)
    return start + t[:, None] * step


def _band_absorption(distance: np.ndarray, width: float, blur: float, darkness: float) -> np.ndarray:
    """Absorbed fraction at ``distance`` from a line of ``width``, blurred by a Gaussian ``blur``."""
    half = width / 2
    if blur <= 0:
        return darkness * (np.abs(distance) <= half)
    s = blur * np.sqrt(2.0)
    return darkness * 0.5 * (erf((half - distance) / s) + erf((half + distance) / s))


def render_frame(capsules: Sequence[tuple[np.ndarray, float]], style: FrameStyle = FrameStyle(),
                 rng: np.random.Generator | None = None) -> np.ndarray:
    """Render one frame.

    Parameters
    ----------
    capsules : sequence of (outline, x)
        Each capsule's outline (from :func:`outline_from_meridian`, in l) and the image column
        where its z = 0 lies. An empty sequence renders the empty tube.
    style : FrameStyle
        Image, tube, optics and camera.
    rng : numpy Generator, optional
        Noise source (default: a fresh unseeded one).

    Returns
    -------
    ndarray of uint8 or uint16, shape ``style.shape``
    """
    rng = np.random.default_rng() if rng is None else rng
    rows, cols = style.shape
    axis = style.axis
    y = np.arange(rows, dtype=float)
    transmission = np.ones(style.shape)
    # Each wall line lies in the glass, outside the liquid: its liquid-side edge is the wall.
    outside = style.tube_radius_px + style.wall_width_px / 2
    for wall_row in (axis - outside, axis + outside):
        wall = _band_absorption(y - wall_row, style.wall_width_px, style.blur_px, style.wall_darkness)
        transmission *= (1 - wall)[:, None]
    reach = style.membrane_width_px / 2 + 5 * style.blur_px + 1
    for outline, x_centre in capsules:
        pts = np.column_stack([x_centre + outline[:, 0] * style.tube_radius_px,
                               axis + outline[:, 1] * style.tube_radius_px])
        dense = _densify(pts, _SAMPLE_SPACING_PX)
        # Only pixels near the capsule can be darkened by it: take distances in its box.
        c0 = max(0, int(np.floor(dense[:, 0].min() - reach)))
        c1 = min(cols, int(np.ceil(dense[:, 0].max() + reach)) + 1)
        r0 = max(0, int(np.floor(dense[:, 1].min() - reach)))
        r1 = min(rows, int(np.ceil(dense[:, 1].max() + reach)) + 1)
        if c0 >= c1 or r0 >= r1:
            continue
        yy, xx = np.mgrid[r0:r1, c0:c1]
        distance, _ = cKDTree(dense).query(np.column_stack([xx.ravel(), yy.ravel()]),
                                           distance_upper_bound=reach)
        distance = np.where(np.isfinite(distance), distance, reach).reshape(yy.shape)
        membrane = _band_absorption(distance, style.membrane_width_px, style.blur_px, style.membrane_darkness)
        transmission[r0:r1, c0:c1] *= 1 - membrane
    image = style.background * transmission + style.noise * rng.standard_normal(style.shape)
    full_scale = 255 if style.bit_depth == 8 else 65535
    dtype = np.uint8 if style.bit_depth == 8 else np.uint16
    return np.clip(np.rint(image * full_scale), 0, full_scale).astype(dtype)


def render_stack(outline: np.ndarray, n_frames: int, x_start: float, px_per_frame: float,
                 style: FrameStyle = FrameStyle(), seed: int = 0) -> np.ndarray:
    """Frames of one capsule moving along the tube by ``px_per_frame`` each frame.

    Parameters
    ----------
    outline : ndarray
        The capsule's outline in l (:func:`outline_from_meridian`).
    n_frames : int
        Number of frames.
    x_start : float
        Column of the capsule's z = 0 in the first frame.
    px_per_frame : float
        Displacement per frame, v_c / (pixel size * frame rate).
    style : FrameStyle
    seed : int
        Seed of the noise.

    Returns
    -------
    ndarray, shape (n_frames, rows, columns)
    """
    rng = np.random.default_rng(seed)
    return np.stack([render_frame([(outline, x_start + k * px_per_frame)], style, rng) for k in range(n_frames)])


def render_on_background(background: np.ndarray, capsules: Sequence[tuple[np.ndarray, float]], style: FrameStyle,
                         rng: np.random.Generator | None = None, noise: float = 0.0) -> np.ndarray:
    """Capsules drawn over a recorded background (an empty channel's image): its walls, dirt
    and illumination are the real ones, the capsules' transmission multiplies into it.

    Parameters
    ----------
    background : 2-D array
        The recorded empty channel, grey levels of an 8-bit camera.
    capsules : sequence of (outline, x)
        As in :func:`render_frame`; ``style.axis_row`` and ``style.tube_radius_px`` should be
        the recorded channel's.
    style : FrameStyle
        The membrane's look (its walls, background level, noise and size are not used).
    rng : numpy Generator, optional
        Source of the camera noise of ``noise`` grey levels (standard deviation).

    Returns
    -------
    ndarray of uint8, the background's shape
    """
    plain = replace(style, shape=background.shape, wall_darkness=0.0, noise=0.0, background=1.0, bit_depth=16)
    transmission = render_frame(capsules, plain) / 65535.0
    image = np.asarray(background, dtype=float) * transmission
    if noise:
        image = image + noise * (np.random.default_rng() if rng is None else rng).standard_normal(image.shape)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def blurred(style: FrameStyle, blur_px: float) -> FrameStyle:
    """The same style out of focus (``blur_px`` Gaussian blur)."""
    return replace(style, blur_px=blur_px)


def write_tiff_stack(path: str | Path, frames: np.ndarray, pixel_size_um: float | None = None,
                     frame_rate: float | None = None) -> Path:
    """Write frames as one multi-page ImageJ TIFF, with pixel size and frame interval metadata.

    The file is written to a temporary name and renamed, so it is whole or absent.
    """
    import tifffile

    path = Path(path)
    metadata: dict[str, object] = {"axes": "TYX" if frames.ndim == 3 else "YX"}
    resolution = None  # (imwrite's default)
    if pixel_size_um is not None:
        metadata["unit"] = "um"
        resolution = (1 / pixel_size_um, 1 / pixel_size_um)
    if frame_rate is not None:
        metadata["finterval"] = 1 / frame_rate
    with atomic_path(path) as tmp:
        tifffile.imwrite(tmp, frames, imagej=True, metadata=metadata, resolution=resolution)
    return path
