"""A diagnosis remembers each capsule's contour fit and each folded contour
(``capsmech.diagnosis.scoring.score_batch``, ``prepared_contour``): a remembered fit must be the
fit made afresh, bit for bit, and a changed contour (a measurement effect's moved one) must be
fitted again. Capsules of the independent generator (tests/python/independent_batches.py)."""
from __future__ import annotations

import warnings

import independent_batches as ib
import numpy as np

from capsmech.diagnosis import scoring
from capsmech.diagnosis.candidates import contour_offset_candidate
from capsmech.io.catalog import database_path
from capsmech.io.database import load_database
from capsmech.io.measurements import read_measurements


def _same(a: scoring.BatchScore, b: scoring.BatchScore) -> bool:
    return all(np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True)
               for name in ("chi2", "g_s", "delta", "a_over_l", "Ca_s", "residual", "floor"))


def test_remembered_fits_are_the_fresh_ones(tmp_path, monkeypatch) -> None:
    drawn = ib.draw_batch(ib.load_pool(), "NH", tmp_path, "remembered", seed=5, n=4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        capsules = [c for c in read_measurements(drawn.csv, "tube") if c.contour is not None]
    database = load_database(database_path("tube-paper"))
    sigma = scoring.noise_levels(capsules, database, "NH")
    fits = []
    fresh_fit = scoring.contour_fit
    monkeypatch.setattr(scoring, "contour_fit", lambda *a, **k: fits.append(1) or fresh_fit(*a, **k))

    first = scoring.score_batch(capsules, database, "NH", sigma)
    made = len(fits)
    again = scoring.score_batch(capsules, database, "NH", sigma)
    assert made == len(capsules) and len(fits) == made          # the second time: nothing refitted
    assert _same(first, again)

    scoring._SCORES.clear()
    scoring._PREPARED.clear()
    assert _same(first, scoring.score_batch(capsules, database, "NH", sigma))

    moved, _ = contour_offset_candidate("NH").apply(capsules, 0.75)
    before = len(fits)
    shifted = scoring.score_batch(moved, database, "NH", sigma)
    assert len(fits) == before + len(capsules)                  # moved contours: fitted again
    assert not np.array_equal(shifted.chi2, first.chi2)
