"""The tracing noise measured across video frames (issue 19, item 2: "the spread across frames
where images were used"): ``capsmech.imaging.tracking.contour_noise`` on contours made here with
a known noise, the noise the halves' difference cannot see, and its use in the contour's chi2."""
from __future__ import annotations

import math

import numpy as np
import pytest

from capsmech.imaging.tracking import contour_noise
from capsmech.inversion.noise import contour_chi2
from capsmech.inversion.residuals import PreparedContour

A, B = 60.0, 40.0           # semi-axes [px] of the noiseless outline
POINTS = 400


def _outline(rng: np.random.Generator, sigma: float, symmetric: bool) -> np.ndarray:
    """An ellipse moved by a random sub-pixel shift, its radius perturbed by a smooth random
    ripple (modes 6-24, rms sigma px): symmetric about the x axis (cos terms only) or not."""
    theta = np.linspace(0.0, 2 * np.pi, POINTS, endpoint=False)
    ripple = np.zeros_like(theta)
    for k in range(6, 25):
        ripple += rng.normal() * np.cos(k * theta)
        if not symmetric:
            ripple += rng.normal() * np.sin(k * theta)
    ripple *= sigma / np.sqrt(np.mean(ripple ** 2))
    x = (A + ripple) * np.cos(theta)
    y = (B + ripple) * np.sin(theta)
    return np.column_stack([x, y]) + rng.uniform(-0.5, 0.5, 2) + [200.0, 100.0]


@pytest.mark.parametrize("sigma", [0.3, 1.0])
def test_frames_noise_recovers_a_known_noise(sigma):
    rng = np.random.default_rng(7)
    estimates = [contour_noise([_outline(rng, sigma, symmetric=False) for _ in range(12)]) for _ in range(5)]
    # The ripple is radial; the estimator measures normal distances, which on this ellipse are
    # the radial ones times cos of the angle between normal and radius (<= 12 % smaller).
    assert np.median(estimates) == pytest.approx(sigma, rel=0.15)


def test_fewer_than_three_frames_give_no_estimate():
    rng = np.random.default_rng(1)
    assert math.isnan(contour_noise([_outline(rng, 0.5, False) for _ in range(2)]))


def test_noise_shared_by_both_halves_is_seen_across_frames_not_by_the_halves():
    """A ripple symmetric about the axis leaves the two halves equal: their difference reports
    almost no noise, the frames report it; the chi2 then takes the frames' noise."""
    rng = np.random.default_rng(3)
    frames = [_outline(rng, 0.8, symmetric=True) for _ in range(10)]
    across = contour_noise(frames)
    assert across == pytest.approx(0.8, rel=0.15)
    contour = frames[0]
    # The noiseless ellipse's meridian (r, z) as the model, in the contour's units.
    t = np.linspace(0.0, np.pi, 200)
    meridian = np.column_stack([B * np.sin(t), -A * np.cos(t)])
    chi2_halves, sigma_halves = contour_chi2(PreparedContour(contour), meridian, 2 * A)
    chi2_frames, sigma_used = contour_chi2(PreparedContour(contour), meridian, 2 * A, frames_noise=across)
    assert sigma_halves < 0.5 * across
    assert sigma_used == across
    floor = 1e-3 * 2 * A
    assert chi2_frames == pytest.approx(chi2_halves * (sigma_halves ** 2 + floor ** 2) / (across ** 2 + floor ** 2))


def test_a_smaller_frames_noise_leaves_the_halves_noise():
    rng = np.random.default_rng(5)
    contour = _outline(rng, 0.8, symmetric=False)
    t = np.linspace(0.0, np.pi, 200)
    meridian = np.column_stack([B * np.sin(t), -A * np.cos(t)])
    plain = contour_chi2(PreparedContour(contour), meridian, 2 * A)
    assert contour_chi2(PreparedContour(contour), meridian, 2 * A, frames_noise=0.01) == plain
