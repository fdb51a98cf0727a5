"""Bright-field frames of a channel drawn for the tests, apart from the package's renderer.

Its own optics, simple on purpose: a lamp with a linear illumination gradient; each wall a
dark band (a Gaussian profile of the glass edge) with a bright refraction line on its liquid
side; static dirt as dark Gaussian specks; capsules as dark elliptic rings (the membrane's
absorption, a Gaussian across the outline) around a slightly brighter interior; Gaussian
camera noise, 8-bit. It draws three kinds of stack:

- :func:`noise_stack`: the empty channel only (with its dirt), noise changing frame to frame;
- :func:`film`: one capsule crossing the field at a constant step per frame, its length
  optionally growing along the passage;
- :func:`event_stack`: independent snapshots (as a cytometer exports them), each frame a
  different capsule at a random place with a random size.

A real background (a 2-D array) can replace the drawn channel in the noise-only stacks.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

SHAPE = (160, 480)


@dataclass(frozen=True)
class Optics:
    """The drawn channel and camera."""

    shape: tuple[int, int] = SHAPE
    level: float = 170.0               # grey level of the lamp in the channel's middle
    gradient: float = 0.12             # relative change of the lamp's level across the width
    walls: tuple[float, float] = (30.0, 130.0)   # liquid-side edges of the two walls [row]
    wall_band_px: float = 8.0
    wall_depth: float = 0.55           # fraction of the light the wall band absorbs at its centre
    refraction: float = 0.12           # the bright line beside each wall, relative
    dirt_specks: int = 12
    noise: float = 2.0                 # grey levels (standard deviation)
    ring_width_px: float = 1.3         # Gaussian sigma of the membrane's line
    ring_absorption: float = 0.35
    interior_gain: float = 0.03        # the interior is this much brighter than the liquid


def empty_channel(optics: Optics, rng: np.random.Generator) -> np.ndarray:
    """The empty channel's light, without noise: lamp, gradient, wall bands, refraction lines, dirt."""
    rows, cols = optics.shape
    y, x = np.mgrid[0:rows, 0:cols].astype(float)
    lamp = optics.level * (1 + optics.gradient * (x / cols - 0.5) + 0.3 * optics.gradient * (y / rows - 0.5))
    transmission = np.ones(optics.shape)
    top, bottom = optics.walls
    half = optics.wall_band_px / 2
    for edge, outward in ((top, -1.0), (bottom, 1.0)):
        centre = edge + outward * half
        transmission -= optics.wall_depth * np.exp(-0.5 * ((y - centre) / (half / 1.5)) ** 2)
        transmission += optics.refraction * np.exp(-0.5 * ((y - (edge - outward * 1.5)) / 0.8) ** 2)
    for _ in range(optics.dirt_specks):
        cy, cx = rng.uniform(0, rows), rng.uniform(0, cols)
        size, depth = rng.uniform(0.7, 2.0), rng.uniform(0.03, 0.12)
        transmission -= depth * np.exp(-0.5 * ((y - cy) ** 2 + (x - cx) ** 2) / size ** 2)
    return lamp * transmission


def capsule_transmission(shape: tuple[int, int], centre: tuple[float, float], half_axes: tuple[float, float],
                         optics: Optics, faint_arc: tuple[float, float] | None = None) -> np.ndarray:
    """The transmission of one capsule: a dark elliptic ring around a slightly brighter interior.

    ``faint_arc``: (width, direction) [deg] of an arc of the ring that fades to a tenth of its
    absorption (a cell's rim open on one side; 10 deg of fade on each side of it), the direction
    measured from +x towards +y (image rows) about the centre, in the ellipse's own angle.
    """
    rows, cols = shape
    y, x = np.mgrid[0:rows, 0:cols].astype(float)
    a, b = half_axes
    u, v = (x - centre[0]) / a, (y - centre[1]) / b
    radius = np.hypot(u, v)
    # Distance to the outline along the ray from the centre, in px (exact on the axes).
    scale = np.hypot(a * u, b * v) / np.maximum(radius, 1e-9)
    distance = (radius - 1) * scale
    ring = optics.ring_absorption * np.exp(-0.5 * (distance / optics.ring_width_px) ** 2)
    if faint_arc is not None:
        width, direction = faint_arc
        off = np.abs((np.degrees(np.arctan2(v, u)) - direction + 180) % 360 - 180)
        ring = ring * (0.1 + 0.9 * np.clip((off - width / 2) / 10.0, 0, 1))
    interior = optics.interior_gain * ndimage.gaussian_filter((radius < 1).astype(float), 1.0)
    return 1 - ring + interior


def _camera(light: np.ndarray, optics: Optics, rng: np.random.Generator) -> np.ndarray:
    return np.clip(np.round(light + rng.normal(0, optics.noise, light.shape)), 0, 255).astype(np.uint8)


def noise_stack(frames: int, optics: Optics = Optics(), seed: int = 0,
                background: np.ndarray | None = None, jitter_px: float = 0.0) -> np.ndarray:
    """``frames`` frames of the empty channel (or of ``background``), only the noise changing.

    ``jitter_px``: the chip shakes by this much (standard deviation across the flow, a Gaussian
    sub-pixel shift of the whole view from frame to frame): the walls' edges flicker.
    """
    rng = np.random.default_rng(seed)
    light = empty_channel(optics, rng) if background is None else np.asarray(background, dtype=float)
    shifts = rng.normal(0, jitter_px, frames) if jitter_px else np.zeros(frames)
    return np.stack([_camera(ndimage.shift(light, (dy, 0), order=3, mode="nearest") if dy else light, optics, rng)
                     for dy in shifts])


def film(frames: int, x_start: float, step_px: float, half_axes: tuple[float, float], optics: Optics = Optics(),
         seed: int = 0, growth_px: float = 0.0, others: Sequence[tuple[int, float, tuple[float, float], float]] = (),
         jitter_px: float = 0.0) -> np.ndarray:
    """A capsule crossing the field on the channel's axis, ``step_px`` a frame from ``x_start``.

    ``growth_px``: how much its axial half-length grows from the first frame to the last (0: steady).
    ``others``: more objects, each (frame, centre x, half axes, centre row; NaN: on the axis),
    drawn in that frame only.
    ``jitter_px``: the chip shakes across the flow (see :func:`noise_stack`).
    """
    rng = np.random.default_rng(seed)
    light = empty_channel(optics, rng)
    axis = (optics.walls[0] + optics.walls[1]) / 2
    out = []
    for k in range(frames):
        a = half_axes[0] + growth_px * k / max(1, frames - 1)
        seen = light * capsule_transmission(light.shape, (x_start + step_px * k, axis), (a, half_axes[1]), optics)
        for frame, x, axes, row in others:
            if frame == k:
                seen = seen * capsule_transmission(light.shape, (x, axis if np.isnan(row) else row), axes, optics)
        if jitter_px:
            seen = ndimage.shift(seen, (rng.normal(0, jitter_px), 0), order=3, mode="nearest")
        out.append(_camera(seen, optics, rng))
    return np.stack(out)


def event_stack(frames: int, optics: Optics = Optics(), seed: int = 0, x_range: tuple[float, float] = (90, 390),
                half_axis_range: tuple[float, float] = (16, 28)) -> tuple[np.ndarray, np.ndarray]:
    """Independent snapshots: each frame another capsule at a random x, of a random size.

    Returns the frames and each one's true (centre x, axial half-length) [px].
    """
    rng = np.random.default_rng(seed)
    light = empty_channel(optics, rng)
    axis = (optics.walls[0] + optics.walls[1]) / 2
    out, truth = [], []
    for _ in range(frames):
        x = rng.uniform(*x_range)
        a = rng.uniform(*half_axis_range)
        b = a * rng.uniform(0.8, 0.95)
        out.append(_camera(light * capsule_transmission(light.shape, (x, axis), (a, b), optics), optics, rng))
        truth.append((x, a))
    return np.stack(out), np.array(truth)
