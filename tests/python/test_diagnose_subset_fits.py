"""Fitting part of a batch (``capsmech.diagnosis.scoring.score_batch`` with ``only`` and
``stop_on_failure``) and reading a model strength off between measurement values
(``capsmech.diagnosis.sequential.ModelProfile.interpolated``): what the combined round
(a measurement effect fitted with a model effect) uses to refit fewer capsules.

A capsule's fit must not depend on which other capsules are fitted with it: the fits of a
subset are those of the whole batch, bit for bit. Capsules of the independent generator
(tests/python/independent_batches.py)."""
from __future__ import annotations

import math
import warnings

import independent_batches as ib
import numpy as np

from capsmech.diagnosis import scoring
from capsmech.diagnosis.candidates import prestress_candidate
from capsmech.diagnosis.sequential import ModelProfile
from capsmech.io.catalog import database_path
from capsmech.io.database import load_database
from capsmech.io.measurements import read_measurements


def test_a_subsets_fits_are_the_whole_batchs_and_a_failure_stops_it(tmp_path) -> None:
    drawn = ib.draw_batch(ib.load_pool(), "NH", tmp_path, "subset", seed=5, n=4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        capsules = [c for c in read_measurements(drawn.csv, "tube") if c.contour is not None]
    database = load_database(database_path("tube-paper"))
    sigma = scoring.noise_levels(capsules, database, "NH")
    whole = scoring.score_batch(capsules, database, "NH", sigma)
    assert np.all(np.isfinite(whole.chi2))

    scoring._SCORES.clear()
    scoring._PREPARED.clear()
    part = scoring.score_batch(capsules, database, "NH", sigma, only=[2, 0])
    for name in ("chi2", "g_s", "delta", "a_over_l", "Ca_s"):
        assert np.array_equal(getattr(part, name)[[0, 2]], getattr(whole, name)[[0, 2]]), name
        assert np.all(np.isnan(getattr(part, name)[[1, 3]])), name
    assert np.array_equal(part.residual[[0, 2]], whole.residual[[0, 2]])

    # A capsule without a noise level is not fitted: the fits stop there, in the order given.
    no_noise = sigma.copy()
    no_noise[1] = math.nan
    stopped = scoring.score_batch(capsules, database, "NH", no_noise, only=[3, 1, 0, 2], stop_on_failure=True)
    assert stopped.chi2[3] == whole.chi2[3]
    assert np.all(np.isnan(stopped.chi2[[0, 1, 2]]))
    going_on = scoring.score_batch(capsules, database, "NH", no_noise)
    assert np.isnan(going_on.chi2[1]) and np.array_equal(going_on.chi2[[0, 2, 3]], whole.chi2[[0, 2, 3]])


def test_a_strength_between_the_values_searched_is_read_off_straight_between_them() -> None:
    profile = ModelProfile(prestress_candidate("NH"))
    assert math.isnan(profile.interpolated(0.5))
    profile.strengths.update({0.0: 0.045, 1.0: 0.055, 2.0: 0.09, -1.0: 0.030})
    # (a value where some capsule was not fitted has no strength to read: left out)
    profile.chi2.update({0.0: 200.0, 1.0: 210.0, 2.0: math.inf, -1.0: 260.0})
    assert math.isclose(profile.interpolated(0.5), 0.050, rel_tol=1e-12)
    assert math.isclose(profile.interpolated(-0.25), 0.04125, rel_tol=1e-12)
    assert math.isclose(profile.interpolated(1.5), 0.055, rel_tol=1e-12)   # the last value fitted
