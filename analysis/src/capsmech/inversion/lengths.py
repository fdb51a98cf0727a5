"""A capsule's lengths (L_z, L_p) measured on its traced contour by a smooth fit, not read off
the extremes of its noisy points.

L_z (the extent along the axis) and L_p (the parachute depth: from the rear crossing of the
axis to the rear-most point) read off a noisy contour's extreme points are biased long: the
extreme of a set of noisy points lies, on average, outside the curve they trace. On batches of
the independent generator (``tests/python/independent_batches.py``: 0.45 px of correlated
tracing noise on capsules ~200 px long) the extremes gave L_z +0.78 ± 0.53 px and L_p
+0.40 ± 0.57 px, and G_s by lengths 5.6 % low (10 % at 0.9 px); the tube's G_s is that
sensitive to the lengths. Here the contour is folded about its symmetry axis (the capsule is
axisymmetric, so both halves trace one meridian) and its radius about the centre is fitted by
a cosine series in the polar angle (least squares, ``HARMONICS`` terms: enough for the sharp
rims of a parachute, measured on noise-free contours: L_z within 0.05 px, L_p within 0.05 px);
the lengths are read off that fitted curve. With the same noise: L_z -0.08 ± 0.42 px,
L_p -0.04 ± 0.40 px.
"""
from __future__ import annotations

import math

import numpy as np

from capsmech.io.contours import symmetry_axis

#: Cosine terms of the fitted radius (at most; fewer for a contour of few points).
HARMONICS = 32
#: Points per fitted term below which the fit would follow the noise.
POINTS_PER_TERM = 8
#: Polar angles at which the fitted curve is evaluated.
EVALUATION_POINTS = 2001


def contour_lengths(contour: np.ndarray) -> tuple[float, float]:
    """(L_z, L_p) of a closed tube-flow contour (x along the flow, in +x), in its own unit.

    Parameters
    ----------
    contour : np.ndarray
        Traced contour (n, 2) [any length unit], both halves of the section through the axis.

    Returns
    -------
    (L_z, L_p) : tuple of float
        The extent along the axis and the parachute depth (0 for a convex rear) of the fitted
        curve; NaN when the contour has too few points for the fit (fewer than
        ``POINTS_PER_TERM`` per term of a 4-term series).
    """
    points = np.asarray(contour, dtype=float)
    harmonics = min(HARMONICS, len(points) // POINTS_PER_TERM - 1)
    if harmonics < 3:
        return math.nan, math.nan
    axis_y, _ = symmetry_axis(points)
    x, y = points[:, 0], np.abs(points[:, 1] - axis_y)
    centre = 0.5 * (x.min() + x.max())
    angle, radius = np.arctan2(y, x - centre), np.hypot(y, x - centre)
    orders = np.arange(harmonics + 1)
    coefficients = np.linalg.lstsq(np.cos(np.outer(angle, orders)), radius, rcond=None)[0]
    grid = np.linspace(0.0, math.pi, EVALUATION_POINTS)
    fitted_x = centre + (np.cos(np.outer(grid, orders)) @ coefficients) * np.cos(grid)
    rear_most = float(fitted_x.min())
    # grid[0] is the front pole on the axis, grid[-1] the rear crossing of the axis.
    return float(fitted_x[0]) - rear_most, max(float(fitted_x[-1]) - rear_most, 0.0)
