"""Population analysis (issue 19, item 1): the law a batch supports, weighed over every measured
capsule. Statistical facts on synthetic batches with known truth (the drift test's interval
covers the true drift; laws that cannot be told apart give "cannot tell"; a law that fits
fewer than half of the capsules is never the verdict; too few usable capsules give no
verdict), and the verdicts on the two shipped example batches fitted with every law."""
from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

import capsmech
from capsmech.cli.main import main
from capsmech.inversion.population import law_drift, population_verdict
from capsmech.inversion.population_report import plot_population, verdict_dict

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO / "data" / "examples"
G_S = 0.04   # the example batches' modulus [N/m]


def batch(rng, slope, n=30, g0=0.043, noise=0.05):
    delta = rng.uniform(1.02, 1.25, n)
    g = g0 * (1 + slope * (delta - delta.mean())) * (1 + noise * rng.standard_normal(n))
    return delta, g


def rows_from(law, delta, g):
    return [{"id": f"c{i}", "law": law, "Delta": d, "G_s": x, "G_s_spread": 0.05 * x, "flag": ""}
            for i, (d, x) in enumerate(zip(delta, g))]


def test_constant_law_is_reported_and_drifting_law_is_not(tmp_path):
    rng = np.random.default_rng(1)
    rows = rows_from("NH", *batch(rng, 0.0)) + rows_from("GH_nu0.5", *batch(rng, -2.0))
    # A capsule NH cannot reproduce (and GH_nu0.5 has no row for): no G_s, evidence against both.
    rows.append({"id": "c30", "law": "NH", "Delta": 1.1, "G_s": 9.9, "flag": "outside_database"})
    verdict = population_verdict(rows)
    drifts, best = verdict.drifts, verdict.best
    assert best == "NH" and verdict.kind == "law"
    assert drifts["GH_nu0.5"].drifts and drifts["GH_nu0.5"].ci_high < 0
    assert drifts["NH"].n == 30
    assert verdict.evidence["NH"].fitted == 30 and verdict.used == 31
    assert verdict.evidence["GH_nu0.5"].status == "drifts"
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
    assert verdict.best is None and verdict.kind == "none"
    assert verdict.reason.startswith("no law of the database fits") and "drifts" in verdict.reason
    assert np.isnan(verdict.g_s) and verdict.g_s_interval is None


def test_too_few_capsules_is_an_error():
    with pytest.raises(ValueError, match="needs 3"):
        law_drift("NH", [1.1, 1.2], [0.04, 0.05])


def test_population_table_round_trips_through_hdf5_and_csv(tmp_path):
    import h5py

    from capsmech.inversion.fitting import write_results
    from capsmech.inversion.population_report import POPULATION_UNITS, population_rows, read_results

    rng = np.random.default_rng(7)
    rows = rows_from("NH", *batch(rng, 0.0)) + rows_from("GH_nu0.5", *batch(rng, -2.0))
    verdict = population_verdict(rows)
    drifts = verdict.drifts
    table = population_rows(verdict)
    assert [r["status"] for r in table] == ["verdict", "drifts"]
    write_results(table, POPULATION_UNITS, tmp_path / "pop.h5")
    write_results(table, POPULATION_UNITS, tmp_path / "pop.csv")
    with h5py.File(tmp_path / "pop.h5") as f:
        assert f["G_s_mean"].attrs["units"] == "N/m"
        assert f["drift_p"][1] == pytest.approx(drifts["GH_nu0.5"].p_value)
    assert float(read_results(tmp_path / "pop.csv")[0]["drift"]) == pytest.approx(drifts["NH"].slope, rel=1e-5)


def flat_batch(rng, n=12, g0=0.043, noise=0.05):
    """A batch with no drift at all: the noise's regression on Delta removed (slope exactly 0),
    so that the verdict tests below do not hinge on a chance drift."""
    delta = rng.uniform(1.02, 1.25, n)
    e = rng.standard_normal(n)
    e -= np.polyval(np.polyfit(delta, e, 1), delta)
    return delta, g0 * (1 + noise * e)


def rows_with_contours(law, delta, g, misfit, flags=None):
    flags = flags or [""] * len(delta)
    return [{"id": f"c{i}", "law": law, "Delta": d, "G_s": x, "flag": f, "H_over_a": h, "reason": f}
            for i, (d, x, h, f) in enumerate(zip(delta, g, misfit, flags))]


def test_contours_decide_where_the_drift_test_cannot():
    # Two laws that both give a constant G_s (one rescaled): the drift test cannot choose; the
    # paired contour comparison picks the law whose profiles fit every capsule better.
    rng = np.random.default_rng(11)
    delta, g = flat_batch(rng)
    good = 0.010 + 0.002 * rng.random(12)
    rows = (rows_with_contours("A", delta, g, good + 0.004 + 0.002 * rng.random(12))
            + rows_with_contours("B", delta, 2 * g, good))
    verdict = population_verdict(rows)
    assert verdict.p_better[("B", "A")] < 0.001        # 12 of 12 pairs on one side: 1/2^12
    assert verdict.best == "B" and not verdict.drifts["B"].drifts
    assert verdict.evidence["A"].status == "worse contours"
    assert verdict.g_s_interval[0] < verdict.g_s < verdict.g_s_interval[1]


def test_contours_and_drift_disagreeing_report_no_law():
    rng = np.random.default_rng(12)
    delta, g = batch(rng, -3.0, n=12)
    good = 0.010 + 0.002 * rng.random(12)
    rows = rows_with_contours("A", delta, g, good) + rows_with_contours("B", *flat_batch(rng), good + 0.01)
    verdict = population_verdict(rows)
    assert verdict.p_better[("A", "B")] < 0.001 and verdict.drifts["A"].drifts
    assert verdict.best is None and verdict.kind == "none" and "disagree" in verdict.reason


def test_indistinguishable_contours_leave_the_drift_test_to_decide():
    rng = np.random.default_rng(13)
    misfit = 0.01 + 0.003 * rng.random(12)
    rows = (rows_with_contours("NH", *flat_batch(rng), misfit + 1e-4 * rng.standard_normal(12))
            + rows_with_contours("GH", *batch(rng, -3.0, n=12), misfit + 1e-4 * rng.standard_normal(12)))
    verdict = population_verdict(rows)
    assert min(verdict.p_better.values()) > 0.025
    assert verdict.best == "NH" and verdict.evidence["GH"].status == "drifts"


def test_two_laws_that_cannot_be_told_apart_give_cannot_tell():
    # Same contour misfit up to noise, neither G_s drifts (one a rescaling of the other, as GH
    # nu_s 0.5 and SK C = 1, which share the area modulus 3 G_s, at small deformation): no single
    # law. The G_s interval holds either law's interval where they overlap.
    rng = np.random.default_rng(21)
    delta, g = flat_batch(rng, n=14)
    misfit = 0.01 + 0.004 * rng.random(14)
    rows = (rows_with_contours("X", delta, g, misfit + 5e-4 * rng.standard_normal(14))
            + rows_with_contours("Y", delta, 1.03 * g, misfit + 5e-4 * rng.standard_normal(14)))
    verdict = population_verdict(rows)
    assert verdict.kind == "cannot_tell" and verdict.best is None
    assert set(verdict.candidates) == {"X", "Y"}
    assert "cannot tell" in verdict.line()
    assert np.isnan(verdict.g_s)
    low, high = verdict.g_s_interval
    for law in ("X", "Y"):
        e = verdict.evidence[law]
        assert low <= e.g_s_interval[0] and e.g_s_interval[1] <= high
    # Their G_s far apart (one twice the other): still no law; G_s lies in the hull of their
    # intervals whichever is right, and the reason says that knowing the law would narrow it.
    rows = (rows_with_contours("X", delta, g, misfit + 5e-4 * rng.standard_normal(14))
            + rows_with_contours("Y", delta, 2 * g, misfit + 5e-4 * rng.standard_normal(14)))
    verdict = population_verdict(rows)
    assert verdict.kind == "cannot_tell" and np.isnan(verdict.g_s)
    low, high = verdict.g_s_interval
    x, y = verdict.evidence["X"].g_s_interval, verdict.evidence["Y"].g_s_interval
    assert x[1] < y[0] and (low, high) == (x[0], y[1])
    assert "do not overlap" in verdict.reason and "whichever it is" in verdict.line()


def test_a_law_fitting_fewer_than_half_is_never_the_verdict():
    # A reproduces 5 of 12 capsules, each better than B does, with a G_s that does not drift;
    # the 7 it cannot reproduce are evidence against it, not capsules to drop.
    rng = np.random.default_rng(31)
    delta, g = flat_batch(rng)
    good = 0.005 + 0.001 * rng.random(12)
    fails = ["outside_database"] * 7 + [""] * 5
    a = rows_with_contours("A", delta, g, np.where(np.array(fails) == "", good, np.nan), fails)
    b = rows_with_contours("B", delta, 2 * g, good + 0.01)
    verdict = population_verdict(a + b)
    assert verdict.best == "B"
    assert verdict.evidence["A"].status == "fits < half" and verdict.evidence["A"].fitted == 5
    assert verdict.evidence["A"].score_median == 1.0
    # B drifting: A is still not named; no law of the database fits.
    b = rows_with_contours("B", *batch(rng, -3.0, n=12), good + 0.01)
    verdict = population_verdict(a + b)
    assert verdict.kind == "none" and verdict.best is None
    assert verdict.reason.startswith("no law of the database fits")
    # A alone: every law fits fewer than half of the capsules.
    verdict = population_verdict(a)
    assert verdict.kind == "none" and "fewer than half" in verdict.reason


def test_failures_count_against_the_law_not_the_capsule():
    # Today's GH-batch situation: A fits every capsule; B fits them slightly better but cannot
    # reproduce 5 of 12. Over the 7 capsules both fit B looks best; over all 12 it is not.
    rng = np.random.default_rng(41)
    delta, g = flat_batch(rng)
    misfit = 0.012 + 0.004 * rng.random(12)
    fails = [""] * 7 + ["central_fit_outside"] * 5
    a = rows_with_contours("A", delta, g, misfit)
    b = rows_with_contours("B", delta, 2 * g, np.where(np.array(fails) == "", misfit - 0.001, np.nan), fails)
    verdict = population_verdict(a + b)
    assert verdict.evidence["B"].fitted == 7 and verdict.used == 12
    assert verdict.best != "B"


def test_law_independent_flags_leave_the_capsule_out_for_every_law():
    rng = np.random.default_rng(51)
    delta, g = flat_batch(rng)
    misfit = 0.01 + 0.002 * rng.random(12)
    flags = ["asymmetric"] * 2 + ["invalid_input"] + [""] * 9
    rows = (rows_with_contours("A", delta, g, misfit, flags)
            + rows_with_contours("B", delta, 2 * g, misfit + 0.01, flags))
    verdict = population_verdict(rows)
    assert verdict.measured == 12 and verdict.used == 9
    assert [cid for cid, _ in verdict.left_out] == ["c0", "c1", "c2"]
    assert verdict.evidence["A"].fitted == 9 and verdict.best == "A"


def test_fewer_than_five_usable_capsules_give_no_verdict():
    rng = np.random.default_rng(61)
    delta, g = flat_batch(rng, n=7)
    flags = ["asymmetric"] * 3 + [""] * 4
    rows = rows_with_contours("A", delta, g, np.full(7, 0.01), flags)
    verdict = population_verdict(rows)
    assert verdict.kind == "none" and verdict.best is None and verdict.candidates == ()
    assert "4 usable capsules of 7 measured, a verdict needs 5" in verdict.reason
    assert "asymmetric" in verdict.reason
    assert np.isnan(verdict.g_s) and verdict.g_s_interval is None
    assert verdict_dict(verdict)["G_s"] is None


def test_a_batch_of_asymmetric_contours_gets_no_verdict():
    rng = np.random.default_rng(71)
    delta, g = flat_batch(rng)
    flags = ["asymmetric"] * 12
    rows = (rows_with_contours("A", delta, g, np.full(12, 0.01), flags)
            + rows_with_contours("B", delta, 2 * g, np.full(12, 0.02), flags))
    verdict = population_verdict(rows)
    assert verdict.kind == "none" and verdict.used == 0 and len(verdict.left_out) == 12
    assert "0 usable capsules of 12 measured" in verdict.reason
    data = verdict_dict(verdict)
    assert data["verdict"] == "none" and data["law"] is None and data["G_s"] is None
    assert {c["reason"] for c in data["capsules"]["left_out"]} == {"asymmetric"}


def test_a_capsule_twice_for_one_law_is_an_error():
    rows = rows_from("A", [1.1, 1.2], [0.04, 0.05])
    with pytest.raises(capsmech.CapsmechError, match="appears twice"):
        population_verdict(rows + rows)


# The shipped example batches, fitted with every law of the paper-grid database (the default).
@pytest.fixture(scope="module")
def example_fits(tmp_path_factory):
    out = tmp_path_factory.mktemp("population")
    paths = {}
    for law in ("NH", "GH_nu0.5"):
        paths[law] = out / f"fit_{law}.csv"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", capsmech.CapsmechWarning)
            assert main(["fit-tube", str(EXAMPLES / f"tube_batch_{law}.csv"), "--database", "tube-paper",
                         "--out", str(paths[law])]) == 0
    return paths


def test_the_nh_example_batch_names_nh(example_fits):
    verdict = capsmech.population(example_fits["NH"])
    assert verdict.kind == "law" and verdict.best == "NH", verdict.reason
    low, high = verdict.g_s_interval
    assert low < G_S < high and low < verdict.g_s < high
    assert all(e.status == "drifts" for law, e in verdict.evidence.items() if law != "NH")


def test_the_gh_example_batch_names_gh_nu05(example_fits):
    # Measured (2026-11-26): scored by each law's best shape on the contour (contour fit), GH
    # nu_s 0.5 reaches the tracing noise (median H/a 0.0046) and SK C = 1, the law of the same
    # area modulus 3 G_s, stays above it on all 12 capsules (0.0051; p = 1/4096). Scored by the
    # misfit at the length fit (0.011 against 0.018), the lengths' 2 % error hid that (p = 0.18,
    # "cannot tell"). NH (the first verdict, 0.089 N/m) fits the contours worse on all 12.
    # Against the noise (chi2 per degree of freedom, limit 1.54): GH nu_s 0.5 0.95, SK C = 1 1.68.
    # With the tube-paper database of kernel 0.3.5 (2026-11-27): p = 7/4096 (GH nu_s 0.5 better
    # on 11 of 12, s002 by chi2_shape 9.16 against 9.63 the other way), chi2/dof 0.93 and 1.69.
    verdict = capsmech.population(example_fits["GH_nu0.5"])
    assert verdict.kind == "law" and verdict.best == "GH_nu0.5", verdict.reason
    assert verdict.candidates == ("GH_nu0.5",)
    assert verdict.evidence["GH_nu0.5"].noise.consistent
    assert verdict.evidence["SK_C1"].status in ("worse contours", "misfits noise")
    assert not verdict.evidence["SK_C1"].noise.consistent
    assert verdict.p_better[("GH_nu0.5", "SK_C1")] < 0.005
    assert verdict.p_better[("GH_nu0.5", "NH")] < 0.001
    assert verdict.evidence["NH"].status in ("worse contours", "misfits noise", "drifts")
    # GH nu_s 0 is rejected by its contours (chi2/dof 41 against 1.68) since the drift test
    # allows for the database's own error (its drift, -3.0 per unit Delta, within 2.3 of what
    # that error can make: p = 0.5).
    assert verdict.evidence["GH_nu0"].status in ("fits < half", "drifts", "misfits noise")
    # G_s at the best shapes (their noise tested): within 2.5 % of the truth, the interval
    # (with the database's accuracy) holding it and narrower than 11 % of it (10.3 %, 2026-11-27;
    # below 10 % until the databases' accuracy counted the rows next to the rear's buckling,
    # Ca_s 0.02-0.03, at 0.2 % of L_z and 0.003 l: capsule s002, at Ca_s 0.023, where L_z hardly
    # moves with Ca_s, now carries a database error of 22 % of its G_s, 8 % before).
    assert verdict.estimator == "contour fits"
    assert verdict.g_s == pytest.approx(G_S, rel=0.025)
    low, high = verdict.g_s_interval
    assert low < G_S < high and high - low < 0.11 * G_S
    for law in verdict.candidates:
        e = verdict.evidence[law]
        assert e.g_s_interval[0] < G_S < e.g_s_interval[1]
    # With the two laws of the paper (NH, GH nu_s 0.5), the contours name GH nu_s 0.5.
    rows = [r for r in capsmech.read_results(example_fits["GH_nu0.5"]).to_dict("records")
            if r["law"] in ("NH", "GH_nu0.5")]
    verdict = capsmech.population(rows)
    assert verdict.best == "GH_nu0.5" and verdict.g_s_interval[0] < G_S < verdict.g_s_interval[1]


@pytest.mark.parametrize("law", ["NH", "GH_nu0.5"])
def test_the_json_file_says_what_the_cli_prints(example_fits, law, tmp_path, capsys):
    out = tmp_path / "verdict.json"
    assert main(["population", str(example_fits[law]), "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    line = next(text for text in printed.splitlines() if text.startswith("verdict: "))
    data = json.loads(out.read_text(encoding="utf-8"))
    assert not list(tmp_path.glob("*.tmp"))
    assert set(data) >= {"verdict", "law", "G_s", "G_s_interval", "laws", "capsules"}
    assert data["capsules"]["measured"] == data["capsules"]["used"] + len(data["capsules"]["left_out"])
    assert set(data["laws"]) == {"NH", "SK_C1", "GH_nu0.5", "GH_nu0.2", "GH_nu0"}
    for name, evidence in data["laws"].items():
        row = re.search(rf"^\s*{re.escape(name)}\s+(\d+)/(\d+)\s", printed, re.M)
        assert row and (int(row.group(1)), int(row.group(2))) == (evidence["fitted"], evidence["used"])
    if data["verdict"] == "law":
        match = re.match(r"verdict: (\S+), G_s = ([0-9.e-]+) \+- ([0-9.e-]+) N/m by (contour fits|lengths)", line)
        assert match and match.group(1) == data["law"]
        assert float(match.group(2)) == pytest.approx(data["G_s"], rel=1e-3)
        assert float(match.group(3)) == pytest.approx(data["G_s_std"], rel=0.05)
        assert data["candidates"] == [data["law"]]
        assert match.group(4) == data["G_s_estimator"]
    else:
        assert data["verdict"] == "cannot_tell" and data["law"] is None and data["G_s"] is None
        assert line.startswith("verdict: cannot tell " + " from ".join(data["candidates"]))
        low, high = data["G_s_interval"]
        assert f"G_s {low:.4g}-{high:.4g} N/m" in line


def test_a_drift_the_databases_error_can_make_is_not_a_drift():
    """A G_s biased by +0 % at the smallest Delta to +10 % at the largest (what a 64-element
    database does on deep parachutes with a corner), 1 % scatter: a drift for the plain
    regression, none when each capsule's database error (5 % of G_s) is given; a bias three
    times steeper than those errors allow still drifts."""
    rng = np.random.default_rng(5)
    delta = np.linspace(1.05, 1.30, 14)
    bias = 0.10 * (delta - delta[0]) / np.ptp(delta)
    g = 0.025 * (1 + bias) * (1 + 0.01 * rng.standard_normal(delta.size))
    errors = np.full(delta.size, 0.05 * 0.025)
    assert law_drift("SK_C1", delta, g).drifts
    allowed = law_drift("SK_C1", delta, g, errors)
    assert not allowed.drifts
    # The steepest linear bias within +-5 % over the range: 10 % / ptp(Delta) (over the mean).
    assert allowed.database_slope == pytest.approx(0.10 / np.ptp(delta) / (g.mean() / 0.025), rel=1e-9)
    steep = 0.025 * (1 + 3 * bias) * (1 + 0.01 * rng.standard_normal(delta.size))
    assert law_drift("SK_C1", delta, steep, errors).drifts
    # Unknown errors (NaN) allow nothing: the plain test.
    assert law_drift("SK_C1", delta, g, np.full(delta.size, np.nan)).p_value == law_drift("SK_C1", delta, g).p_value
