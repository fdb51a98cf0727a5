"""Couette-rheometer images drawn for the tests, apart from the package's renderer.

A capsule in the shear plane is drawn from a closed outline (the kernel's shear-plane contour
from the shipped shear database, or an exact ellipse) as a bright-field microscope shows it: a
dark membrane ring a few pixels wide centred on the outline (its depth falls off as a Gaussian
of the distance to the outline), an interior a few percent brighter than the liquid, an
illumination gradient across the field, the optics' blur and the camera's noise. Nothing here
comes from ``capsmech.imaging``.
"""
from __future__ import annotations

from dataclasses import dataclass

import h5py
import numpy as np
from matplotlib.path import Path as PolygonPath
from scipy import ndimage
from scipy.spatial import cKDTree

from capsmech.io.catalog import database_path


@dataclass(frozen=True)
class Optics:
    """How the camera shows a capsule: grey levels of the liquid, the ring's depth and width
    (Gaussian sigma) [px], the interior's excess brightness, the blur [px], the noise's standard
    deviation [grey levels] and the illumination gradient across the field (fraction)."""

    level: float = 160.0
    ring_depth: float = 60.0
    ring_sigma_px: float = 1.2
    interior: float = 0.04
    blur_px: float = 1.0
    noise: float = 3.0
    gradient: float = 0.12


def shear_outline(law: str, row: int) -> tuple[np.ndarray, dict[str, float]]:
    """The kernel's steady shear-plane contour of ``law``'s database row (flow along +x, velocity
    gradient along +y; lengths in a) and the row's Ca_s, D12 and theta [deg]."""
    with h5py.File(database_path("shear-paper"), "r") as f:
        group = f[law]
        outline = np.column_stack([group["profile_z"][row], group["profile_y"][row]])
        truth = {"Ca_s": float(group["Ca_s"][row]), "D12": float(group["D12"][row]),
                 "theta_deg": float(np.degrees(group["theta"][row]))}
    return outline, truth


def ellipse_outline(a: float, b: float, angle_deg: float, count: int = 720) -> np.ndarray:
    """An exact ellipse's outline: semi-axes a, b, major axis at angle_deg from +x (y up)."""
    t = np.linspace(0, 2 * np.pi, count, endpoint=False)
    c, s = np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))
    x, y = a * np.cos(t), b * np.sin(t)
    return np.column_stack([c * x - s * y, s * x + c * y])


def inertia_ellipse(outline: np.ndarray) -> tuple[float, float, float]:
    """Semi-axes L1 >= L2 and the major axis's angle [deg, (-90, 90], y up] of the ellipse with
    the same area moments as the region the closed outline encloses (Green's theorem)."""
    x, y = outline[:, 0], outline[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = cross.sum() / 2
    cx, cy = ((x + xn) * cross).sum() / (6 * area), ((y + yn) * cross).sum() / (6 * area)
    ixx = ((x * x + x * xn + xn * xn) * cross).sum() / 12 / area - cx * cx
    iyy = ((y * y + y * yn + yn * yn) * cross).sum() / 12 / area - cy * cy
    ixy = ((x * yn + 2 * x * y + 2 * xn * yn + xn * y) * cross).sum() / 24 / area - cx * cy
    values, vectors = np.linalg.eigh(np.array([[ixx, ixy], [ixy, iyy]]))
    # An ellipse of semi-axes A, B has moments A^2/4 and B^2/4 per unit area.
    l1, l2 = 2 * np.sqrt(values[1]), 2 * np.sqrt(values[0])
    angle = np.degrees(np.arctan2(vectors[1, 1], vectors[0, 1]))
    angle = (angle + 90) % 180 - 90
    return float(l1), float(l2), float(angle)


def draw_frame(outlines: list[tuple[np.ndarray, tuple[float, float]]], shape: tuple[int, int],
               optics: Optics = Optics(), seed: int = 0) -> np.ndarray:
    """An 8-bit frame of ``shape`` (rows, columns) showing each outline [px, y up] centred at its
    (column, row) position."""
    rng = np.random.default_rng(seed)
    rows, cols = shape
    yy, xx = np.mgrid[0:rows, 0:cols].astype(float)
    image = np.full(shape, optics.level)
    for outline, (col, row) in outlines:
        # Screen coordinates: y up on the outline is -row in the image.
        points = np.column_stack([col + outline[:, 0], row - outline[:, 1]])
        dense = _resample(points, spacing=0.05)
        distance, _ = cKDTree(dense).query(np.column_stack([xx.ravel(), yy.ravel()]))
        distance = distance.reshape(shape)
        inside = PolygonPath(points).contains_points(np.column_stack([xx.ravel(), yy.ravel()])).reshape(shape)
        image += np.where(inside, optics.interior * optics.level, 0.0)
        image -= optics.ring_depth * np.exp(-0.5 * (distance / optics.ring_sigma_px) ** 2)
    image = ndimage.gaussian_filter(image, optics.blur_px)
    illumination = 1 + optics.gradient * ((xx / cols - 0.5) * 0.8 + (yy / rows - 0.5) * 0.6)
    image = image * illumination + rng.normal(0.0, optics.noise, shape)
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def _resample(points: np.ndarray, spacing: float) -> np.ndarray:
    """The closed polygon through ``points`` resampled every ``spacing`` px of arclength."""
    closed = np.vstack([points, points[:1]])
    steps = np.hypot(*np.diff(closed, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(steps)])
    t = np.arange(0.0, s[-1], spacing)
    return np.column_stack([np.interp(t, s, closed[:, 0]), np.interp(t, s, closed[:, 1])])
