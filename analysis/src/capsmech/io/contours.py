"""Measured capsule contours: reading ImageJ XY files, the axis of symmetry, and the
comparison with a simulated meridian by the modified Hausdorff distance (paper section 4.2).

Conventions
-----------
A contour is the capsule's mid-line (the middle of the dark membrane line) in a plane
through the tube axis, as an (n, 2) array of image coordinates (x, y): x along the tube
axis with the flow in +x (the capsule's front at the largest x), y across it. It is the
whole closed curve (both halves), from any start point, in any orientation. A simulated
meridian is (m, 2) of (r, z), pole to pole, with the front pole at the largest z.

Why these measures
------------------
*Asymmetry*: a centred, steadily flowing capsule is axisymmetric; a contour whose two halves
differ (an off-centre or tumbling capsule, a bad segmentation) cannot be fitted by the
axisymmetric databases. It is the modified Hausdorff distance between the contour and its
mirror image about the best axis, over the capsule radius.

*H/a*: the modified Hausdorff distance between the measured contour and the simulated
profile at the fitted parameters, over the capsule radius a, after the best axial shift (the
image's origin is arbitrary). The paper excludes capsules with H/a > 0.06.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.spatial import cKDTree

from capsmech.errors import CapsmechError
from capsmech.io.text import read_text, split_lines

#: The paper's limit on the profile misfit H/a (section 4.2).
MAX_H_OVER_A = 0.06
#: Contours whose mirrored halves differ (mean distance) by more than this fraction of a, and
#: by more than ASYMMETRY_PIXELS, are flagged as asymmetric. Tracing errors of +-1 px alone
#: give ~0.55 px (measured on the synthetic batches); one half 10 % wider than the other
#: gives ~0.01 a (the best axis takes up half of the difference).
MAX_ASYMMETRY = 0.01
ASYMMETRY_PIXELS = 1.0
#: ... or by more than this many times the contour's own tracing noise (``contour_tracing_noise``):
#: a symmetric capsule traced with noise of 1.35-2 px has halves that differ by 1.2-1.3 times
#: that estimate on average, at most 1.6 (the independent generator's NH, GH, SK, pre-stressed,
#: bending and deep-parachute contours, 144 at each noise), so noisy tracing widens the capsule's
#: uncertainty instead of discarding it; one half 15 % wider than the other under +-1 px of
#: noise (2.2 times) and an off-centre capsule (0.04-0.07 a) stay flagged. Below about 0.6 px
#: of noise the one-pixel limit is the larger.
ASYMMETRY_NOISE_FACTOR = 2.0
#: Fourier harmonics of the smooth closed curve the tracing noise is measured about: one per
#: ``POINTS_PER_HARMONIC`` contour points, within ``NOISE_HARMONICS`` (fewer would leave a
#: parachute's rim in the residual, more would absorb the noise).
POINTS_PER_HARMONIC = 8
NOISE_HARMONICS = (6, 40)
#: Points each curve is resampled to before distances are measured, so that the distance
#: measures the curves and not their sampling.
RESAMPLE_POINTS = 1000
#: Fewest (distinct) points a contour file must hold.
MIN_CONTOUR_POINTS = 8
#: Largest contour file read [bytes] (some 400,000 points; ImageJ writes a few thousand).
MAX_CONTOUR_BYTES = 8 * 2**20
#: Range of a contour's coordinates and extents, in its units: beyond it the area and volume
#: measures under- or overflow.
CONTOUR_SCALE = (1e-60, 1e60)
#: Smallest area a contour encloses, as a fraction of its bounding box (an ellipse: pi/4).
MIN_FILL = 0.05

_SEPARATOR = re.compile(r"[\s,;]+")


class ContourError(CapsmechError, ValueError):
    """A contour file that cannot be read; the message names file and line."""


def read_contour(path: str | Path) -> np.ndarray:
    """Read an ImageJ "Save XY Coordinates" file: two numeric columns x y per line.

    Columns may be separated by tabs, spaces, commas or semicolons; one header line (such as
    ``X\\tY``) and ``#`` comment lines are skipped; a third column (ImageJ's value) is ignored.
    The text may be UTF-8, Windows-1252 or Latin-1 (``capsmech.io.text``).

    Returns
    -------
    np.ndarray
        (n, 2) array of (x, y), in the file's units.

    Raises
    ------
    ContourError
        Unreadable, binary or over ``MAX_CONTOUR_BYTES``; non-numeric or non-finite values;
        fewer than 8 distinct points, or a degenerate curve (``contour_problem``). The message
        names the file, and the line where there is one.
    """
    path = Path(path)
    text = read_text(path, MAX_CONTOUR_BYTES, "contour file", ContourError)
    points: list[tuple[float, float]] = []
    header_seen = False
    for number, line in enumerate(split_lines(text), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        cells = [c for c in _SEPARATOR.split(stripped) if c]
        try:
            values = [float(c) for c in cells[:2]]
        except ValueError:
            if not points and not header_seen:
                header_seen = True
                continue
            raise ContourError(f"{path}:{number}: {stripped[:80]!r} is not two numbers x y") from None
        if len(values) < 2:
            raise ContourError(f"{path}:{number}: {stripped[:80]!r} has one column, expected x y")
        if not all(math.isfinite(v) for v in values):
            raise ContourError(f"{path}:{number}: {stripped[:80]!r} is not finite")
        points.append((values[0], values[1]))
    contour = np.array(points, dtype=float).reshape(-1, 2)
    problem = contour_problem(contour)
    if problem is not None:
        raise ContourError(f"{path}: {problem}")
    return contour


def contour_problem(contour: np.ndarray) -> str | None:
    """Why a contour cannot be measured, or None when it can.

    A contour must have at least ``MIN_CONTOUR_POINTS`` distinct finite points, coordinates
    and an extent within ``CONTOUR_SCALE`` (so that its area and volume are representable
    numbers), and enclose an area of at least ``MIN_FILL`` of its bounding box (not a point,
    a line or a curve folded onto itself). What passes gives finite measures in
    ``contour_asymmetry`` and ``profile_misfit``.

    Parameters
    ----------
    contour : np.ndarray
        (n, 2) points, in any length unit.

    Returns
    -------
    str or None
        The problem in words (no file name: the caller adds it), or None.
    """
    points = np.asarray(contour, dtype=float)
    if points.ndim != 2 or points.shape[1] != 2:
        return f"contour of shape {points.shape}, expected (n, 2) points x y"
    if not np.all(np.isfinite(points)):
        return "a contour point is not finite"
    if len(points) < MIN_CONTOUR_POINTS:
        return f"{len(points)} contour points, at least {MIN_CONTOUR_POINTS} needed"
    distinct = len(np.unique(points, axis=0))
    if distinct < MIN_CONTOUR_POINTS:
        return f"{distinct} distinct contour points, at least {MIN_CONTOUR_POINTS} needed"
    low, high = CONTOUR_SCALE
    extent = np.ptp(points, axis=0)
    largest = float(np.abs(points).max())
    if largest > high or float(extent.min()) < low:
        return (f"coordinates up to {largest:.3g} with extents {extent[0]:.3g} x {extent[1]:.3g}: outside "
                f"{low:g} to {high:g}, the range a contour may span in its units")
    centred = (points - points.mean(axis=0)) / extent
    x, y = centred[:, 0], centred[:, 1]
    fill = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y)))
    if fill < MIN_FILL:
        return (f"the contour encloses {fill:.2g} of its bounding box (at least {MIN_FILL:g}): its points lie "
                "on a line or the curve folds onto itself")
    return None


def resample_curve(points: np.ndarray, n: int = RESAMPLE_POINTS, closed: bool = False) -> np.ndarray:
    """Points at equal arclength along a polyline (closed: back to the first point)."""
    points = np.asarray(points, dtype=float)
    if closed:
        points = np.vstack([points, points[:1]])
    step = np.hypot(*np.diff(points, axis=0).T)
    keep = np.concatenate([[True], step > 0])
    points = points[keep]
    s = np.concatenate([[0.0], np.cumsum(step[step > 0])])
    if s[-1] == 0:
        raise ValueError("curve has zero length")
    target = np.linspace(0, s[-1], n, endpoint=not closed)
    return np.column_stack([np.interp(target, s, points[:, 0]), np.interp(target, s, points[:, 1])])


def modified_hausdorff(a: np.ndarray, b: np.ndarray) -> float:
    """Modified (mean) Hausdorff distance (Dubuisson & Jain 1994) between point sets (n, 2), (m, 2):
    max(mean_i min_j |a_i - b_j|, mean_j min_i |a_i - b_j|)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    d_ab = cKDTree(b).query(a)[0].mean()
    d_ba = cKDTree(a).query(b)[0].mean()
    return float(max(d_ab, d_ba))


def _mirror(points: np.ndarray, axis_y: float) -> np.ndarray:
    return np.column_stack([points[:, 0], 2 * axis_y - points[:, 1]])


def symmetry_axis(contour: np.ndarray) -> tuple[float, float]:
    """The line y = y0 the contour is most nearly symmetric about, and the remaining misfit.

    Returns
    -------
    (y0, distance) : tuple of float
        The axis and the modified Hausdorff distance between the contour and its mirror
        image about it (in the contour's units).
    """
    curve = resample_curve(contour, closed=True)
    low, high = curve[:, 1].min(), curve[:, 1].max()
    half_height = 0.5 * (high - low)
    centre = 0.5 * (low + high)
    best = minimize_scalar(lambda y0: modified_hausdorff(curve, _mirror(curve, y0)),
                           bounds=(centre - 0.2 * half_height, centre + 0.2 * half_height), method="bounded",
                           options={"xatol": 1e-4 * half_height})
    return float(best.x), float(best.fun)


def contour_tracing_noise(contour: np.ndarray) -> float:
    """The contour's tracing noise [its units]: the rms normal residual of its points about a
    smooth closed curve, a Fourier series in arclength (``POINTS_PER_HARMONIC``), over the
    residual's degrees of freedom. It needs neither the capsule's symmetry nor a model, so an
    asymmetric shape does not count as noise (the halves' difference of
    ``capsmech.inversion.noise`` does). Noise correlated along the contour is partly taken up by
    the smooth curve: on the independent generator's contours (normal noise, AR(1) rho 0.5 at
    2.5 px steps) it reads 0.74-0.84 of the noise's sigma. NaN for fewer than 4 points a
    harmonic."""
    points = np.asarray(contour, dtype=float)
    step = np.hypot(*np.diff(np.vstack([points, points[:1]]), axis=0).T)
    points = points[step > 0]
    step = step[step > 0]
    harmonics = int(np.clip(len(points) // POINTS_PER_HARMONIC, *NOISE_HARMONICS))
    unknowns = 2 * harmonics + 1
    if len(points) < 2 * unknowns:
        return math.nan
    t = 2 * np.pi * np.concatenate([[0.0], np.cumsum(step[:-1])]) / step.sum()
    k = np.arange(1, harmonics + 1)
    basis = np.column_stack([np.ones_like(t), np.cos(np.outer(t, k)), np.sin(np.outer(t, k))])
    slope = np.column_stack([np.zeros_like(t), -k * np.sin(np.outer(t, k)), k * np.cos(np.outer(t, k))])
    # The normal equations (the basis is near-orthogonal at near-uniform arclength steps), summed
    # by einsum: an SVD least-squares solve of this size stalls for tenths of a second when the
    # BLAS threads compete with other processes.
    coefficients = np.linalg.solve(np.einsum("ni,nj->ij", basis, basis), np.einsum("ni,nk->ik", basis, points))
    tangent = slope @ coefficients
    tangent /= np.hypot(*tangent.T)[:, None]
    normal_residual = np.sum((points - basis @ coefficients) * tangent[:, ::-1] * [1.0, -1.0], axis=1)
    return float(np.sqrt(np.sum(normal_residual ** 2) / (len(points) - unknowns)))


def contour_asymmetry(contour: np.ndarray, pixel_size: float = math.nan) -> tuple[float, float, float]:
    """How far a contour is from mirror symmetry about its best axis, and the flag's limit.

    Returns
    -------
    (asymmetry, limit, axis_y) : tuple of float
        The mirror distance (``symmetry_axis``) over the radius of the capsule's
        volume-equivalent size estimated from the contour itself; the limit above which the
        contour is flagged asymmetric (``MAX_ASYMMETRY``, or ``ASYMMETRY_PIXELS`` pixels when
        ``pixel_size`` is known, or ``ASYMMETRY_NOISE_FACTOR`` times the contour's own tracing
        noise, ``contour_tracing_noise``, whichever is largest); the axis y0.
    """
    axis_y, mirror_distance = symmetry_axis(contour)
    radius = volume_radius(contour, axis_y)
    limit = MAX_ASYMMETRY
    if not (math.isfinite(radius) and radius > 0):
        # No volume about the best axis (the halves cancel): nothing like an axisymmetric capsule.
        return math.inf, limit, axis_y
    if math.isfinite(pixel_size):
        limit = max(MAX_ASYMMETRY, ASYMMETRY_PIXELS * pixel_size / radius)
    noise = contour_tracing_noise(contour)
    if math.isfinite(noise):
        limit = max(limit, ASYMMETRY_NOISE_FACTOR * noise / radius)
    return mirror_distance / radius, limit, axis_y


def full_profile(meridian: np.ndarray) -> np.ndarray:
    """The closed profile (x = z, y = r) of a meridian (r, z) mirrored about the axis."""
    meridian = np.asarray(meridian, dtype=float)
    upper = np.column_stack([meridian[:, 1], meridian[:, 0]])
    lower = np.column_stack([meridian[::-1, 1], -meridian[::-1, 0]])
    return np.vstack([upper, lower[1:-1]])


def profile_misfit(contour: np.ndarray, meridian: np.ndarray, axis_y: float | None = None) -> tuple[float, float]:
    """Modified Hausdorff distance between a measured contour and a simulated meridian.

    Parameters
    ----------
    contour : np.ndarray
        Measured contour (n, 2) of image coordinates, in the meridian's units (see module).
    meridian : np.ndarray
        Simulated meridian (m, 2) of (r, z), pole to pole, front pole at the largest z.
    axis_y : float, optional
        The contour's axis; by default the axis of best symmetry.

    Returns
    -------
    (distance, shift) : tuple of float
        The smallest distance over axial shifts of the simulated profile, and that shift.
    """
    if axis_y is None:
        axis_y, _ = symmetry_axis(contour)
    measured = resample_curve(contour, closed=True)
    measured[:, 1] -= axis_y
    simulated = resample_curve(full_profile(meridian), closed=True)
    # Start from the front poles coinciding; the best shift lies within a few percent of the
    # capsule length of it, so a bounded scalar search is enough.
    length = np.ptp(simulated[:, 0])
    start = measured[:, 0].max() - simulated[:, 0].max()

    def distance(shift: float) -> float:
        return modified_hausdorff(measured, simulated + [shift, 0.0])

    best = minimize_scalar(distance, bounds=(start - 0.1 * length, start + 0.1 * length), method="bounded",
                           options={"xatol": 1e-5 * length})
    return float(best.fun), float(best.x)


def volume_radius(contour: np.ndarray, axis_y: float, half: str | None = None) -> float:
    """Radius of the sphere with the volume of the contour revolved about y = axis_y.

    V = pi |closed integral of rho |rho| / 2 dx| over the closed contour (Green's theorem;
    holds for any start point and for a rear that folds back). With ``half`` = 'upper' or
    'lower', the volume of that half mirrored (rho replaced by the half's own distances).
    """
    closed = np.vstack([contour, contour[:1]])
    rho = closed[:, 1] - axis_y
    if half == "upper":
        rho = np.maximum(rho, 0.0)
    elif half == "lower":
        rho = np.minimum(rho, 0.0)
    mid = 0.5 * (rho[1:] + rho[:-1])
    factor = 1.0 if half is None else 2.0
    volume = factor * np.pi * abs(np.sum(0.5 * mid * np.abs(mid) * np.diff(closed[:, 0])))
    return float((3 * volume / (4 * np.pi)) ** (1 / 3))
