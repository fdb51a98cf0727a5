"""Population analysis: the drift test finds the law with a constant G_s, and its confidence
interval covers the true drift (statistical facts on synthetic batches with known truth)."""
from __future__ import annotations

import numpy as np
import pytest

from capsmech.inversion.population import law_drift, plot_population, population_verdict


def batch(rng, slope, n=30, g0=0.043, noise=0.05):
    delta = rng.uniform(1.02, 1.25, n)
    g = g0 * (1 + slope * (delta - delta.mean())) * (1 + noise * rng.standard_normal(n))
    return delta, g


def rows_from(law, delta, g):
    return [{"law": law, "Delta": d, "G_s": x, "G_s_spread": 0.05 * x, "flag": ""} for d, x in zip(delta, g)]


def test_constant_law_is_reported_and_drifting_law_is_not(tmp_path):
    rng = np.random.default_rng(1)
    rows = rows_from("NH", *batch(rng, 0.0)) + rows_from("GH_nu0.5", *batch(rng, -2.0))
    rows.append({"law": "NH", "Delta": 1.1, "G_s": 9.9, "flag": "outside the database"})   # excluded
    verdict = population_verdict(rows)
    drifts, best = verdict.drifts, verdict.best
    assert best == "NH"
    assert drifts["GH_nu0.5"].drifts and drifts["GH_nu0.5"].ci_high < 0
    assert drifts["NH"].n == 30
    figure = plot_population(rows, drifts)
    assert [ax.get_ylabel() for ax in figure.axes] == ["G_s [N/m]"]
    assert len(figure.axes[0].lines) >= len(drifts)  # one regression line per law


def test_confidence_interval_covers_the_true_drift_at_its_level():
    # Over 400 synthetic batches the 95 % interval must cover the true slope ~95 % of the time.
    rng = np.random.default_rng(7)
    covered = 0
    trials = 400
    for _ in range(trials):
        d = law_drift("x", *batch(rng, -1.0))
        covered += d.ci_low <= -1.0 <= d.ci_high
    assert 0.92 <= covered / trials <= 0.98


def test_every_law_drifting_reports_none():
    rng = np.random.default_rng(3)
    rows = rows_from("A", *batch(rng, 2.0)) + rows_from("B", *batch(rng, -2.0))
    verdict = population_verdict(rows)
    _, best = verdict.drifts, verdict.best
    assert best is None


def test_too_few_capsules_is_an_error():
    with pytest.raises(ValueError, match="needs 3"):
        law_drift("NH", [1.1, 1.2], [0.04, 0.05])


def test_population_table_round_trips_through_hdf5_and_csv(tmp_path):
    import h5py

    from capsmech.inversion.fitting import write_results
    from capsmech.inversion.population import POPULATION_UNITS, population_rows, read_results

    rng = np.random.default_rng(7)
    rows = rows_from("NH", *batch(rng, 0.0)) + rows_from("GH_nu0.5", *batch(rng, -2.0))
    verdict = population_verdict(rows)
    drifts, best = verdict.drifts, verdict.best
    table = population_rows(drifts, best)
    assert [r["verdict"] for r in table] == ["supported", "drifts"]
    write_results(table, POPULATION_UNITS, tmp_path / "pop.h5")
    write_results(table, POPULATION_UNITS, tmp_path / "pop.csv")
    with h5py.File(tmp_path / "pop.h5") as f:
        assert f["G_s_mean"].attrs["units"] == "N/m"
        assert f["p_value"][1] == pytest.approx(drifts["GH_nu0.5"].p_value)
    assert float(read_results(tmp_path / "pop.csv")[0]["drift"]) == pytest.approx(drifts["NH"].slope, rel=1e-5)


def flat_batch(rng, n=12, g0=0.043, noise=0.05):
    """A batch with no drift at all: the noise's regression on Delta removed (slope exactly 0),
    so that the verdict tests below do not hinge on a chance drift."""
    delta = rng.uniform(1.02, 1.25, n)
    e = rng.standard_normal(n)
    e -= np.polyval(np.polyfit(delta, e, 1), delta)
    return delta, g0 * (1 + noise * e)


def rows_with_contours(law, delta, g, misfit):
    return [{"id": f"c{i}", "law": law, "Delta": d, "G_s": x, "flag": "", "H_over_a": h}
            for i, (d, x, h) in enumerate(zip(delta, g, misfit))]


def test_contours_decide_where_the_drift_test_cannot():
    # Two laws that both give a constant G_s (one rescaled): the drift test alone reports the
    # one with the larger p-value; the paired contour comparison picks the law whose profiles
    # fit every capsule better, and the verdict follows it.
    rng = np.random.default_rng(11)
    delta, g = flat_batch(rng)
    good = 0.010 + 0.002 * rng.random(12)
    rows = (rows_with_contours("A", delta, g, good + 0.004 + 0.002 * rng.random(12))
            + rows_with_contours("B", delta, 2 * g, good))
    verdict = population_verdict(rows)
    assert verdict.shape.n == 12 and verdict.shape.best == "B"
    assert verdict.shape.p_values[("A", "B")] < 0.001        # 12 of 12 pairs on one side: 2/2^12
    assert verdict.best == "B" and not verdict.drifts["B"].drifts


def test_contours_and_drift_disagreeing_report_no_law():
    rng = np.random.default_rng(12)
    delta, g = batch(rng, -3.0, n=12)
    good = 0.010 + 0.002 * rng.random(12)
    rows = rows_with_contours("A", delta, g, good) + rows_with_contours("B", *flat_batch(rng), good + 0.01)
    verdict = population_verdict(rows)
    assert verdict.shape.best == "A" and verdict.drifts["A"].drifts
    assert verdict.best is None and "disagree" in verdict.reason


def test_indistinguishable_contours_fall_back_on_the_drift_test():
    rng = np.random.default_rng(13)
    misfit = 0.01 + 0.003 * rng.random(12)
    rows = (rows_with_contours("NH", *flat_batch(rng), misfit + 1e-4 * rng.standard_normal(12))
            + rows_with_contours("GH", *batch(rng, -3.0, n=12), misfit + 1e-4 * rng.standard_normal(12)))
    verdict = population_verdict(rows)
    assert verdict.shape is not None and verdict.shape.best is None
    assert verdict.best == "NH"
