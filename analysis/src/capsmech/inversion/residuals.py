"""What a fit leaves unexplained (issue 7, part 1): residuals of fitted tube capsules, each
with its uncertainty, for one capsule and averaged over a batch.

- **Contour profile**: the signed normal distance from the fitted (simulated) meridian to the
  measured contour, along the meridian's arclength s (0 at the front pole, 1 at the rear
  pole), positive when the measured membrane lies outside. Each half of the contour (above
  and below the axis) gives one estimate; their mean is the residual and half their
  difference its standard error (the two halves see independent tracing errors).
- **Size**: the radius of the sphere of the contour's volume against the fitted a = (a/l) l,
  as a relative residual; its uncertainty from the two halves' volumes.
- **Velocity** (when the mean flow velocity V is known): measured v_c/V against the fitted
  v_c/V, relative; uncertainty: the spread of the five fits.

A batch's profile residual is the mean over its capsules at each s, with the standard error
of that mean: a systematic pattern (an offset everywhere, a bulge at the rim) is what points
to a missing effect, while tracing noise averages out.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from capsmech.io.contours import resample_curve, symmetry_axis, volume_radius

#: Points of the residual profile along the meridian.
PROFILE_POINTS = 64
#: Regions of the profile by normalised arclength s (front pole 0, rear pole 1), for reports.
REGIONS = (("front", 0.0, 0.3), ("side", 0.3, 0.6), ("rear", 0.6, 1.0))


@dataclass(frozen=True)
class ProfileResidual:
    """Signed normal distance, measured minus fitted, along the fitted meridian.

    Attributes
    ----------
    s : np.ndarray
        Normalised arclength from the front pole (0) to the rear pole (1).
    distance : np.ndarray
        Mean over the contour's two halves [units of the inputs]; positive outward.
    error : np.ndarray
        Standard error of ``distance`` (half the two halves' difference).
    """

    s: np.ndarray
    distance: np.ndarray
    error: np.ndarray


def _meridian_normals(meridian_zr: np.ndarray) -> np.ndarray:
    """Outward unit normals of a meridian given as (z, r) from the front pole (largest z) to the
    rear pole: the curve runs counter-clockwise in the (z, r) half-plane, so the outward normal
    is the tangent turned clockwise."""
    # (np.gradient along the points, unit spacing, and np.linalg.norm, written out: the same
    # numbers without their wrappers, on a contour fit's hot path)
    tangent = np.empty_like(meridian_zr, dtype=float)
    tangent[1:-1] = (meridian_zr[2:] - meridian_zr[:-2]) / 2.0
    tangent[0] = (meridian_zr[1] - meridian_zr[0]) / 1.0
    tangent[-1] = (meridian_zr[-1] - meridian_zr[-2]) / 1.0
    tangent /= np.sqrt(tangent[:, 0] * tangent[:, 0] + tangent[:, 1] * tangent[:, 1])[:, None]
    return np.column_stack([tangent[:, 1], -tangent[:, 0]])


def _resample_meridian(meridian: np.ndarray, points: int) -> np.ndarray:
    """``resample_curve`` of the meridian (r, z) as (z, r) at ``points`` points, written out for
    an open curve: the same numbers (``np.linspace``'s included) without the wrappers, on a
    contour fit's hot path."""
    curve = np.empty((len(meridian), 2))
    curve[:, 0], curve[:, 1] = meridian[:, 1], meridian[:, 0]
    difference = curve[1:] - curve[:-1]
    step = np.hypot(difference[:, 0], difference[:, 1])
    moving = step > 0
    if not moving.all():
        curve = curve[np.concatenate([[True], moving])]
        step = step[moving]
    s = np.empty(len(step) + 1)
    s[0] = 0.0
    np.cumsum(step, out=s[1:])
    if s[-1] == 0:
        raise ValueError("curve has zero length")
    target = np.arange(points, dtype=float)
    if points > 1:
        target *= s[-1] / (points - 1)
        target += 0.0
        target[-1] = s[-1]
    else:
        target *= s[-1]
    resampled = np.empty((points, 2))
    resampled[:, 0] = np.interp(target, s, curve[:, 0])
    resampled[:, 1] = np.interp(target, s, curve[:, 1])
    return resampled


class PreparedContour:
    """A measured contour folded about its axis into its two halves (z, r), with a k-d tree per
    half, so that residuals against many trial meridians cost two tree queries each."""

    def __init__(self, contour: np.ndarray, axis_y: float | None = None) -> None:
        # The axis of best mirror symmetry unless the caller knows the capsule's own axis.
        self.axis_y = symmetry_axis(contour)[0] if axis_y is None else float(axis_y)
        measured = resample_curve(contour, closed=True)
        rho = measured[:, 1] - self.axis_y
        self.halves_points = [np.column_stack([measured[side, 0], np.abs(rho[side])]) for side in (rho >= 0, rho < 0)]
        if min(len(h) for h in self.halves_points) < 2:
            raise ValueError("contour has no points on one side of its axis")
        self.trees = [cKDTree(h) for h in self.halves_points]
        self.front = float(measured[:, 0].max())

    def residual(self, meridian: np.ndarray, points: int = PROFILE_POINTS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s, distance, error) along the meridian (r, z) [contour units]: measured minus
        simulated along the outward normal, mean and half difference of the halves
        (``halves``)."""
        s, upper, lower = self.halves(meridian, points)
        return s, 0.5 * (upper + lower), 0.5 * np.abs(upper - lower)

    def halves(self, meridian: np.ndarray, points: int = PROFILE_POINTS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s, upper, lower): each half's signed distance from the meridian (r, z) along its
        outward normal [contour units], the upper half being the one at larger image y.

        The contour's axial position, which the image does not fix, is the one that leaves no
        residual along the axial-shift mode: the least-squares shift, i.e. the weighted mean of
        the halves' mean residual along n_z vanishes. (The Hausdorff distance cannot fix it: a
        uniform outward offset has the same mean distance for every small shift.)"""
        simulated = _resample_meridian(meridian, points)
        normals = _meridian_normals(simulated)
        z, r = simulated[:, 0], simulated[:, 1]
        normal_z, normal_r = normals[:, 0], normals[:, 1]
        difference = np.diff(simulated, axis=0)
        step = np.sqrt(difference[:, 0] * difference[:, 0] + difference[:, 1] * difference[:, 1])
        weight = np.concatenate([[0.5 * step[0]], 0.5 * (step[1:] + step[:-1]), [0.5 * step[-1]]])
        mode = np.sum(weight * normals[:, 0] ** 2)
        extent = float(np.ptp(z))

        def distances(shift: float) -> list[np.ndarray]:
            # (half[k] - placed) . normal with placed = simulated + [shift, 0], its two terms added
            # as np.sum over the columns adds them, "+ 0.0" included: the same numbers, bit for bit)
            placed_z = z + shift
            placed_r = r + 0.0
            out = []
            placed = np.empty((len(z), 2))
            placed[:, 0], placed[:, 1] = placed_z, placed_r
            for half, tree in zip(self.halves_points, self.trees):
                k = tree.query(placed)[1]
                out.append((half[k, 0] - placed_z) * normal_z + (half[k, 1] - placed_r) * normal_r)
            return out

        shift = self.front - z.max()
        for _ in range(6):
            estimates = distances(shift)
            mean = 0.5 * (estimates[0] + estimates[1])
            correction = np.sum(weight * mean * normals[:, 0]) / mode
            # Moving the simulated meridian by +dz changes the residual by -n_z dz to first order.
            shift += correction
            if abs(correction) < 1e-4 * extent:
                break
        # (queried again, not corrected to first order with the same nearest points: a correction
        # under the tolerance still changes a few points' nearest contour points, by up to a third
        # of a pixel on a noisy tracing, and the kept ones are farther: chi2 half a percent high)
        upper, lower = distances(shift)
        arclength = np.concatenate([[0.0], np.cumsum(step)])
        return arclength / arclength[-1], upper, lower


def profile_residual(contour: np.ndarray, meridian: np.ndarray, points: int = PROFILE_POINTS) -> ProfileResidual:
    """Residual profile of one capsule (``PreparedContour.residual``).

    Parameters
    ----------
    contour : np.ndarray
        Measured contour (n, 2) of image coordinates (x along the axis, flow in +x).
    meridian : np.ndarray
        Fitted meridian (m, 2) of (r, z) in the contour's units, front pole first.
    points : int
        Points of the profile along the meridian.
    """
    s, distance, error = PreparedContour(contour).residual(meridian, points)
    return ProfileResidual(s=s, distance=distance, error=error)


def size_residual(contour: np.ndarray, a_fit: float) -> tuple[float, float]:
    """(a_contour / a_fit - 1, its standard error from the two halves' volumes)."""
    axis_y, _ = symmetry_axis(contour)
    whole = volume_radius(contour, axis_y)
    upper, lower = volume_radius(contour, axis_y, "upper"), volume_radius(contour, axis_y, "lower")
    return whole / a_fit - 1.0, 0.5 * abs(upper - lower) / a_fit


def velocity_residual(measured_vc_over_V: float, fitted_vc_over_V: float, fitted_spread: float) -> tuple[float, float]:
    """(measured / fitted v_c/V - 1, its uncertainty from the five fits' spread)."""
    return measured_vc_over_V / fitted_vc_over_V - 1.0, fitted_spread / fitted_vc_over_V


@dataclass(frozen=True)
class BatchProfile:
    """Mean residual profile of a batch at common s, with the standard error of the mean."""

    s: np.ndarray
    distance: np.ndarray
    error: np.ndarray
    count: int

    def region_means(self) -> dict[str, tuple[float, float]]:
        """Mean distance and its standard error over each of ``REGIONS``."""
        out = {}
        for name, low, high in REGIONS:
            keep = (self.s >= low) & (self.s <= high)
            out[name] = (float(self.distance[keep].mean()), float(np.sqrt(np.mean(self.error[keep] ** 2))))
        return out


def batch_profile(residuals: list[ProfileResidual], scales: list[float] | None = None) -> BatchProfile:
    """Average capsules' residual profiles (each divided by its scale, e.g. its radius a).

    The standard error at each s combines the scatter between capsules (standard deviation
    over sqrt(n)), which holds every source of noise, with the halves' own errors when the
    batch is too small for a scatter (one capsule).
    """
    if not residuals:
        raise ValueError("no residual profiles to average")
    s = residuals[0].s
    scales = scales or [1.0] * len(residuals)
    stack = np.array([np.interp(s, r.s, r.distance) / k for r, k in zip(residuals, scales)])
    halves = np.array([np.interp(s, r.s, r.error) / k for r, k in zip(residuals, scales)])
    n = len(residuals)
    if n > 1:
        error = stack.std(axis=0, ddof=1) / np.sqrt(n)
    else:
        error = halves[0]
    return BatchProfile(s=s, distance=stack.mean(axis=0), error=error, count=n)
