"""A contour's misfit against its own tracing noise: the chi2 that tells "this model's shape is the
capsule's, up to noise" from "no shape of this model is" (issue 19, item 2).

Shared by the law verdict (``fit-tube``'s ``chi2_shape``, tested by
``capsmech.inversion.population``) and the goodness of fit after a diagnosis
(``capsmech.diagnosis.goodness``), so that both refer a misfit to the same noise model:

- the residual profile: ``CHI2_POINTS`` signed normal distances along the meridian between the
  contour's halves (folded about its axis, their mean) and the model's profile;
- each point's variance: sigma^2, the tracing noise measured on the contour itself (the rms over
  the meridian of its two halves' half difference, at ``NOISE_POINTS`` points; or, where larger,
  the noise measured across the video frames, ``capsmech extract``'s ``contour_noise``), plus the square
  of the databases' own accuracy, ``MODEL_FLOOR_REL`` of the capsule's length (64 against 128
  meridian elements), more from a sharp parachute edge to the rear pole
  (``capsmech.inversion.sharp_edge.profile_floor``): a capsule is not called misfitted for what
  the databases cannot resolve;
- the noise is each capsule's own, measured on its contour (or across its frames): a noisily
  traced capsule gets a larger sigma, so its chi2 stays that of noise and its contour fit's
  uncertainty (``capsmech.inversion.shape_fit``) grows. The asymmetry screen scales with the
  noise measured about a smooth curve instead (``capsmech.io.contours.contour_tracing_noise``),
  since the halves' difference holds the very asymmetry it screens for;
- with the fit's two parameters removed, ``DOF`` degrees of freedom; and since sigma is itself
  estimated (from ``NOISE_DOF`` effectively independent points), chi2 / DOF follows an
  F(DOF, NOISE_DOF) distribution when the model is right, not a chi2. A batch's total is
  referred to the sum of such variates (``chi2_reference``: Monte Carlo with a fixed seed, so
  the p-value is reproducible).
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from capsmech.inversion.residuals import PreparedContour
from capsmech.inversion.sharp_edge import SMOOTH_FLOOR_REL, profile_floor

#: Points of a capsule's residual profile in its chi2.
CHI2_POINTS = 16
#: Degrees of freedom of that chi2: the points less the contour fit's two parameters (a/l, Ca_s).
DOF = CHI2_POINTS - 2
#: Points at which the halves' difference is sampled for the noise level.
NOISE_POINTS = 64
#: Effectively independent points behind a capsule's noise level: the half difference of the
#: contour's halves at 64 points along the meridian, correlated over a few pixels by the
#: tracing; 24 is the conservative end (a smaller value widens the reference distribution).
NOISE_DOF = 24
#: The databases' profiles hold their lengths to 0.1 % (64 against 128 meridian elements) where
#: they are smooth: a residual smaller than this fraction of a capsule's length is model error.
#: Next to a sharp parachute edge they hold less (``capsmech.inversion.sharp_edge.profile_floor``).
MODEL_FLOOR_REL = SMOOTH_FLOOR_REL
#: Significance of a test against the noise (a batch whose chi2 noise alone reaches with a
#: smaller probability is not explained by the model).
GOODNESS_ALPHA = 0.01
#: Monte Carlo draws of the reference distributions, and their seed.
DRAWS = 4000
SEED = 20261126


def tracing_noise(prepared: PreparedContour, meridian: np.ndarray, frames_noise: float = math.nan) -> float:
    """The contour's tracing-noise level sigma [contour units] against a profile (r, z) in its
    units: the rms over the meridian of the half difference of its two halves (the standard
    error of their mean at a point), or, where larger, ``frames_noise``: the tracing noise
    measured across the video frames (``capsmech extract``'s ``contour_noise``), which also sees
    what both halves share."""
    _, _, error = prepared.residual(meridian, points=NOISE_POINTS)
    sigma = float(np.sqrt(np.mean(error ** 2)))
    return frames_noise if math.isfinite(frames_noise) and frames_noise > sigma else sigma


def contour_chi2(prepared: PreparedContour, meridian: np.ndarray, length: float,
                 frames_noise: float = math.nan, tube_radius: float = math.nan,
                 stated_error_rel: tuple[float, float] = (math.nan, math.nan)) -> tuple[float, float]:
    """(chi2, sigma) of a contour against a profile (r, z), both in the contour's units: the sum
    over ``CHI2_POINTS`` of the squared residual over sigma^2 plus the square of the database's
    accuracy at the point (``profile_floor``: ``MODEL_FLOOR_REL`` of ``length``, more behind a
    sharp parachute edge; ``tube_radius`` in the contour's units), sigma measured on the contour,
    or across the video frames where larger (``tracing_noise``); ``stated_error_rel``: the
    database rows' own stated errors there (``profile_floor``). NaN where sigma is not positive."""
    sigma = tracing_noise(prepared, meridian, frames_noise)
    floor = profile_floor(meridian, length, CHI2_POINTS, tube_radius, stated_error_rel)
    return weighted_chi2(prepared, meridian, sigma ** 2 + floor ** 2), sigma


def weighted_chi2(prepared: PreparedContour, meridian: np.ndarray, variance: np.ndarray) -> float:
    """The contour's chi2 against a profile (r, z) in its units: the ``CHI2_POINTS`` residuals
    squared over their ``variance``; NaN where a variance is not positive."""
    if not (np.all(np.isfinite(variance)) and np.all(variance > 0)):
        return math.nan
    _, distance, _ = prepared.residual(meridian, points=CHI2_POINTS)
    return float(np.sum(distance ** 2 / variance))


@lru_cache(maxsize=64)
def chi2_reference(capsules: int, draws: int = DRAWS, seed: int = SEED) -> np.ndarray:
    """Draws of a batch's total chi2 under noise alone: the sum over the capsules of
    DOF F(DOF, NOISE_DOF) variates (each capsule's chi2 with its noise level estimated).
    Cached (read-only): the draws depend on the batch's size alone."""
    rng = np.random.default_rng(seed)
    draws_ = DOF * rng.f(DOF, NOISE_DOF, size=(draws, capsules)).sum(axis=1)
    draws_.setflags(write=False)
    return draws_


def chi2_test(total: float, capsules: int, alpha: float) -> tuple[float, float]:
    """(p-value, limit) of a batch's total chi2 over ``capsules`` capsules: the probability that
    noise alone reaches it, and the chi2 per degree of freedom that noise exceeds with
    probability ``alpha``."""
    reference = chi2_reference(capsules)
    p = float((1 + np.sum(reference >= total)) / (1 + len(reference)))
    return p, float(np.quantile(reference, 1 - alpha)) / (capsules * DOF)
