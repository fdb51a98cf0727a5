"""Residuals of fitted capsules (capsmech.inversion.residuals, issue 7 part 1): numerical facts.

- The volume radius of a contour is exact for a spheroid, and equal from either half.
- A contour offset outward by delta along its normals has the residual profile +delta at
  every s; a contour 3 % larger than the fitted capsule has the size residual +0.03.
- Tracing noise alone (+-1 px) leaves a batch mean profile within its standard errors of 0,
  and the standard error falls as 1/sqrt(n).
"""
from __future__ import annotations

import numpy as np
import pytest

from capsmech.diagnosis.synthetic import noisy_contour
from capsmech.inversion.residuals import batch_profile, profile_residual, size_residual
from capsmech.io.catalog import database_path
from capsmech.io.contours import full_profile, resample_curve, volume_radius

PX_PER_L = 100.0


def parachute_meridian(n: int = 400) -> np.ndarray:
    """A smooth meridian (r, z) [l] with a concave rear, front pole first."""
    s = np.linspace(0, np.pi, n)
    r = 0.8 * np.sin(s)
    z = 1.1 * np.cos(s) + 1.4 * np.sin(s) ** 2 * (s > np.pi / 2) * np.cos(s) ** 2
    return np.column_stack([r, z])


def offset_contour(meridian: np.ndarray, delta: float) -> np.ndarray:
    """The full profile of a meridian moved by delta along its outward normals."""
    profile = resample_curve(full_profile(meridian), n=4000, closed=True)
    tangent = np.gradient(np.vstack([profile[-1:], profile, profile[:1]]), axis=0)[1:-1]
    tangent /= np.linalg.norm(tangent, axis=1)[:, None]
    normal = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    # Orient outward: away from the centroid on average.
    if np.mean(np.sum((profile - profile.mean(axis=0)) * normal, axis=1)) < 0:
        normal = -normal
    return profile + delta * normal


def test_volume_radius_of_a_spheroid_and_its_halves():
    t = np.linspace(0, 2 * np.pi, 4000, endpoint=False)
    spheroid = np.column_stack([50 + 1.3 * np.cos(t), 7 + 0.8 * np.sin(t)])
    exact = (1.3 * 0.8 ** 2) ** (1 / 3)
    assert volume_radius(spheroid, 7.0) == pytest.approx(exact, rel=1e-5)
    assert volume_radius(spheroid, 7.0, "upper") == pytest.approx(exact, rel=1e-5)
    assert volume_radius(spheroid, 7.0, "lower") == pytest.approx(exact, rel=1e-5)


@pytest.mark.parametrize("delta", [1.5, -1.0])
def test_uniform_normal_offset_is_measured_everywhere(delta):
    meridian = parachute_meridian() * PX_PER_L
    residual = profile_residual(offset_contour(meridian, delta) + [300.0, 200.0], meridian)
    # Nearest-point projection on a 4000-point contour: within 0.05 px of the offset, except
    # within a few points of the poles where the normal turns fastest.
    inner = (residual.s > 0.03) & (residual.s < 0.97)
    assert np.allclose(residual.distance[inner], delta, atol=0.05)
    assert np.all(residual.error[inner] < 0.02)


def test_size_residual_of_a_larger_capsule():
    meridian = parachute_meridian()
    contour = full_profile(meridian) * PX_PER_L * 1.03 + [250.0, 180.0]
    a_fit = volume_radius(full_profile(meridian) * PX_PER_L, 0.0)
    residual, error = size_residual(contour, a_fit)
    assert residual == pytest.approx(0.03, abs=1e-3)
    assert error < 1e-3


def test_tracing_noise_averages_out_over_a_batch():
    meridian = parachute_meridian()
    rng = np.random.default_rng(11)
    batches = {}
    for n in (5, 20):
        residuals = [profile_residual(noisy_contour(meridian, PX_PER_L, rng), meridian * PX_PER_L) for _ in range(n)]
        batches[n] = batch_profile(residuals)
    big = batches[20]
    inner = (big.s > 0.05) & (big.s < 0.95)
    z = big.distance[inner] / big.error[inner]
    # Mean within its standard errors of zero: |z| < 3 nearly everywhere.
    assert np.mean(np.abs(z) < 3) > 0.9
    # Uniform +-1 px on both coordinates: 0.4-0.6 px per point and half, so the batch
    # standard error of 20 capsules is ~0.1 px; 4 times fewer capsules, twice the error.
    assert 0.05 < np.median(big.error[inner]) < 0.2
    ratio = np.median(batches[5].error[inner]) / np.median(big.error[inner])
    assert 1.4 < ratio < 3.0


def test_fitted_batch_size_residuals_are_noise_and_catch_a_scaled_image():
    """The shipped NH batch fitted with NH: contour sizes agree with the fitted a within their
    uncertainties; the same contours scaled by 3 % (a wrong pixel size) show +0.03."""
    from pathlib import Path

    from capsmech.inversion.fitting import fit_tube_rows
    from capsmech.io.database import load_database
    from capsmech.io.measurements import Capsule, read_measurements

    root = Path(__file__).resolve().parents[2]
    capsules = read_measurements(root / "data" / "examples" / "tube_batch_NH.csv", "tube")
    database = load_database(database_path("tube-paper"))
    rows = fit_tube_rows(capsules, database, ["NH"])
    residual = np.array([r["size_residual"] for r in rows])
    error = np.array([r["size_residual_error"] for r in rows])
    assert np.mean((residual / error) ** 2) < 3.0           # chi^2 per capsule ~ 1
    assert abs(residual.mean()) < 3 * residual.std(ddof=1) / np.sqrt(len(rows))
    scaled = [Capsule(c.id, c.values, c.line, c.contour * 1.03) for c in capsules]
    shifted = np.array([r["size_residual"] for r in fit_tube_rows(scaled, database, ["NH"])])
    assert shifted.mean() == pytest.approx(residual.mean() + 0.03, abs=0.002)
