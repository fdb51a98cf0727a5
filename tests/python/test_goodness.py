"""The goodness-of-fit tests after a diagnosis (issue 19, item 2): calibrated on noise alone,
and failing on what noise cannot make (``capsmech.diagnosis.goodness``)."""
from __future__ import annotations

import numpy as np
import pytest

from capsmech.diagnosis.goodness import ALPHA, DOF, NOISE_DOF, goodness_of_fit

CAPSULES, POINTS = 16, 16
LENGTH_PX = np.full(CAPSULES, 200.0)          # a 200 px capsule: model floor 0.2 px
NO_FLOOR = np.full(CAPSULES, 1e-6)             # a length whose floor is negligible
# A fit of two parameters leaves DOF independent directions of noise in the POINTS residuals.
BASIS = np.linalg.qr(np.random.default_rng(0).standard_normal((POINTS, DOF)))[0]


def noise_only(rng: np.random.Generator, sigma_px: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """A batch the model explains: each capsule's residual profile is noise of level sigma in
    DOF directions, and its noise level is itself estimated from NOISE_DOF values."""
    residual = sigma_px * rng.standard_normal((CAPSULES, DOF)) @ BASIS.T
    estimated = sigma_px * np.sqrt(rng.chisquare(NOISE_DOF, CAPSULES) / NOISE_DOF)
    return residual, estimated


def test_noise_alone_fails_at_the_stated_rate():
    """Over 300 batches of noise alone, the size and structure tests together fail in about
    2 ALPHA of them (each at ALPHA), not more."""
    rng = np.random.default_rng(1)
    failures = 0
    for _ in range(300):
        failures += not goodness_of_fit(*noise_only(rng), NO_FLOOR).consistent
    # Binomial(300, 0.02): mean 6, P(> 16) < 1e-3.
    assert failures <= 16, failures


def test_chi2_p_value_is_uniform_under_noise():
    rng = np.random.default_rng(2)
    p = np.array([goodness_of_fit(*noise_only(rng), NO_FLOOR).chi2_p_value for _ in range(200)])
    # Kolmogorov-Smirnov distance to the uniform law, well within its 1 % critical value (0.115).
    p.sort()
    ks = np.max(np.abs(p - (np.arange(1, len(p) + 1) - 0.5) / len(p)))
    assert ks < 0.115, ks


def test_a_misfit_twice_the_noise_is_caught():
    """What the SK C = 5 batch left after pre-stress: about 40 a capsule instead of 14-16."""
    rng = np.random.default_rng(3)
    residual, sigma = noise_only(rng)
    fit = goodness_of_fit(1.65 * residual, sigma, NO_FLOOR)
    assert not fit.consistent and fit.chi2_p_value < ALPHA
    assert fit.reduced_chi2 > fit.reduced_chi2_limit
    assert "chi2 per degree of freedom" in fit.failures[0]


def test_the_model_floor_forgives_what_the_databases_cannot_resolve():
    """A misfit of 0.15 px everywhere on 0.1 px noise: inconsistent with the noise alone, but
    within the databases' accuracy on a 200 px capsule (0.2 px)."""
    rng = np.random.default_rng(7)
    residual, sigma = noise_only(rng, sigma_px=0.1)
    extra = 0.15 * rng.standard_normal((CAPSULES, DOF)) @ BASIS.T
    assert not goodness_of_fit(residual + extra, sigma, NO_FLOOR).consistent
    assert goodness_of_fit(residual + extra, sigma, LENGTH_PX).chi2_p_value > ALPHA


@pytest.mark.parametrize("amplitude_px, caught", [(0.6, True), (0.1, False)])
def test_a_shared_pattern_counts_above_the_model_floor(amplitude_px, caught):
    """A cos(2 pi s) pattern every capsule shares: caught at 0.6 px (3 times the databases' own
    accuracy on a 200 px capsule), not at 0.1 px (below it) even though significant."""
    rng = np.random.default_rng(4)
    residual, sigma = noise_only(rng, sigma_px=0.2)
    s = np.linspace(0, 1, POINTS)
    fit = goodness_of_fit(residual + amplitude_px * np.cos(2 * np.pi * s), sigma, LENGTH_PX)
    assert fit.structure_p_value < ALPHA
    assert (not fit.consistent) is caught
    assert fit.structure_floor_px == pytest.approx(0.2)


def test_a_drift_of_g_s_with_delta_is_caught():
    """A steady G_s (1 % scatter) fails the drift test at its rate ALPHA (here at most 8 of 300
    batches; Binomial(300, 0.01): mean 3, P(> 8) < 0.4 %); G_s growing by half over the range of
    Delta is caught."""
    rng = np.random.default_rng(5)
    residual, sigma = noise_only(rng)
    delta = np.linspace(0.1, 0.5, CAPSULES)
    false_alarms = sum(goodness_of_fit(residual, sigma, LENGTH_PX, 0.04 * (1 + 0.01 * rng.standard_normal(CAPSULES)),
                                       delta).drift_p_value < ALPHA for _ in range(300))
    assert false_alarms <= 8, false_alarms
    drifting = 0.04 * (1 + 0.01 * rng.standard_normal(CAPSULES)) * (1 + 0.5 * delta)
    fit = goodness_of_fit(residual, sigma, LENGTH_PX, drifting, delta)
    assert fit.drift_p_value < ALPHA and not fit.consistent
    assert "drifts" in fit.failures[-1]


def test_capsules_without_a_fit_are_left_out_and_two_are_needed():
    rng = np.random.default_rng(6)
    residual, sigma = noise_only(rng)
    sigma[:3] = np.nan
    assert goodness_of_fit(residual, sigma, LENGTH_PX).capsules == CAPSULES - 3
    sigma[:-1] = np.nan
    with pytest.raises(ValueError, match="at least 2"):
        goodness_of_fit(residual, sigma, LENGTH_PX)


def test_a_point_by_point_floor_forgives_a_misfit_behind_the_rim_only():
    """A -3 px misfit at two points just behind a parachute's rim (what a 64-element database
    leaves on a deep parachute with a corner, docs/validation/databases.md) on 0.3 px noise: a
    misfit with the 0.2 px floor everywhere; consistent with the rim's floor at those points
    (7 px, 6.5 % of L_p there), and still caught when the misfit sits in front of the rim."""
    rng = np.random.default_rng(8)
    residual, sigma = noise_only(rng, sigma_px=0.3)
    rim = np.zeros(POINTS)
    rim[11:13] = -3.0
    floor = np.full((CAPSULES, POINTS), 0.2)
    floor[:, 10:] = 7.0
    assert not goodness_of_fit(residual + rim, sigma, LENGTH_PX).consistent
    assert goodness_of_fit(residual + rim, sigma, LENGTH_PX, floor_px=floor).consistent
    assert not goodness_of_fit(residual + np.roll(rim, -8), sigma, LENGTH_PX, floor_px=floor).consistent
