"""Verdicts on batches the method was not tuned on (issue 19, items 2, 5 and 6).

The batches come from ``independent_batches`` (numpy, h5py and capsim only; the kernel runs
shipped as a pool): a different size range, mesh, noise model, contour sampling and length
measurement from capsmech's own generator. The default suite diagnoses three small batches
with two candidates each; the whole confusion study (every batch, the whole library) and the
interval coverage study are ``validate`` (``confusion_study.py``, ``interval_coverage.py``).
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
from functools import cache
from pathlib import Path

import independent_batches as ib
import numpy as np
import pytest

from capsmech.diagnosis.candidates import DatabaseSet, contour_offset_candidate, law_candidate, tube_radius_candidate
from capsmech.diagnosis.diagnose import diagnose
from capsmech.io.catalog import database_path
from capsmech.io.database import load_database
from capsmech.io.measurements import read_measurements

CAPSULES = 8


@cache
def pool() -> ib.Pool:
    return ib.load_pool()


@cache
def databases() -> DatabaseSet:
    return DatabaseSet([load_database(database_path("tube-paper"))])


def batch(tmp_path: Path, name: str, seed: int = 11):
    key, keywords, _ = ib.CONFUSION_BATCHES[name]
    drawn = ib.draw_batch(pool(), key, tmp_path, name, seed=seed, n=CAPSULES, **keywords)
    return drawn, read_measurements(drawn.csv, "tube")


def test_the_pool_is_the_kernel_steady_shapes_of_every_membrane():
    p = pool()
    assert p.keys == list(ib.POOL_KEYS)
    assert np.all(p.status == "steady")
    # Latin hypercube: one capsule in each of the 24 slices of a/l and of ln Ca_s.
    for values, (low, high), log in ((p.a_over_l, ib.A_OVER_L, False), (p.Ca_s, ib.CA_S, True)):
        u = (np.log(values / low) / np.log(high / low)) if log else (values - low) / (high - low)
        assert sorted(np.floor(u * len(values)).astype(int)) == list(range(len(values)))


def test_lengths_read_off_a_noiseless_trace_are_the_kernels(monkeypatch):
    """The generator's own check: without noise, the lengths it measures on its traced contour
    are the kernel's L_z and L_p to 0.15 px (a contour sampled every 2.5 px)."""
    monkeypatch.setattr(ib, "NOISE_PX", 0.0)
    p, k = pool(), ib.load_pool().keys.index("NH")
    with np.load(ib.POOL) as f:
        true_lz, true_lp = f["L_z"][k], f["L_p"][k]
    scale = ib.TUBE_RADIUS_UM / ib.PIXEL_SIZE_UM
    rng = np.random.default_rng(0)
    for i in range(0, 24, 5):
        section = ib._closed_section(p.r[k, i], p.z[k, i]) * scale
        L_z, L_p = ib.measured_lengths(ib.traced(section, rng))
        assert L_z == pytest.approx(true_lz[i] * scale, abs=0.15)
        assert L_p == pytest.approx(true_lp[i] * scale, abs=0.15)


def test_lengths_fitted_on_a_noisy_trace_are_unbiased_where_its_extremes_are_not():
    """The generator's tracing noise (0.45 px, correlated) makes the extremes of the points
    read L_z about 0.8 px and L_p 0.4 px long; the contour's fit (``contour_lengths``) reads both
    within 0.2 px on average over the pool's 24 NH capsules traced four times, and its scatter is
    not larger than the extremes'."""
    from capsmech.inversion.lengths import contour_lengths

    p, k = pool(), pool().keys.index("NH")
    with np.load(ib.POOL) as f:
        true_lz, true_lp = f["L_z"][k], f["L_p"][k]
    scale = ib.TUBE_RADIUS_UM / ib.PIXEL_SIZE_UM
    rng = np.random.default_rng(5)
    extremes, fitted = [], []
    for _ in range(4):
        for i in range(len(true_lz)):
            contour = ib.traced(ib._closed_section(p.r[k, i], p.z[k, i]) * scale + [300.0, 150.0], rng)
            truth = np.array([true_lz[i], true_lp[i]]) * scale
            extremes.append(np.array(ib.measured_lengths(contour)) - truth)
            fitted.append(np.array(contour_lengths(contour)) - truth)
    extremes, fitted = np.array(extremes), np.array(fitted)
    assert extremes.mean(axis=0)[0] > 0.5 and extremes.mean(axis=0)[1] > 0.25
    assert np.all(np.abs(fitted.mean(axis=0)) < 0.2), fitted.mean(axis=0)
    assert np.all(fitted.std(axis=0) <= extremes.std(axis=0)), (fitted.std(axis=0), extremes.std(axis=0))


def test_lengths_of_an_ellipse_and_of_too_few_points():
    """An ellipse (semi-axes 90 and 70 px, 230 points): L_z 180 px to 0.01 px and no parachute;
    a contour of 20 points is too few for the fit: NaN, not a number it cannot support."""
    from capsmech.inversion.lengths import contour_lengths

    t = np.linspace(0, 2 * np.pi, 230, endpoint=False)
    ellipse = np.column_stack([300 + 90 * np.cos(t), 150 + 70 * np.sin(t)])
    L_z, L_p = contour_lengths(ellipse)
    assert L_z == pytest.approx(180.0, abs=0.01) and L_p == pytest.approx(0.0, abs=0.01)
    assert all(math.isnan(v) for v in contour_lengths(ellipse[::12]))


def test_g_s_by_lengths_holds_the_truth_on_control_batches(tmp_path):
    """G_s by lengths of 12 control batches (16 NH capsules each, fresh noise): the mean error
    under 1.5 % (it was -5.2 % with the lengths of the file, read off the extremes), and the 95 %
    interval (Student t with the databases' accuracy) holds G_s = 0.025 N/m in at least 11."""
    from capsmech.diagnosis.record import g_s_interval
    from capsmech.diagnosis.scoring import length_g_s_with_systematic
    from capsmech.inversion.fitting import tube_inverter

    inverter = tube_inverter(load_database(database_path("tube-paper")), "NH")
    errors, held = [], 0
    for seed in range(12):
        drawn = ib.draw_batch(pool(), "NH", tmp_path, f"control{seed}", seed=4100 + seed, n=16)
        summary, systematic = length_g_s_with_systematic(read_measurements(drawn.csv, "tube"), inverter)
        interval = g_s_interval(*summary, systematic)
        low, high = interval["interval"]
        assert systematic > 0 and low < interval["value"] < high
        errors.append(interval["value"] / ib.G_S - 1)
        held += low <= ib.G_S <= high
    assert abs(np.mean(errors)) < 0.015, errors
    assert held >= 11, (held, errors)


@pytest.mark.parametrize("key", ib.DEEP_KEYS)
def test_deep_parachutes_name_their_law_with_an_interval_that_holds(tmp_path, key):
    """Deep parachutes (Ca_s 0.2-0.93, a/l 0.8-0.95; 96 elements): a corner at the rim, where
    the 64-element database reads G_s up to 10 % high. fit-tube with every law, then
    population, names the batch's law, and its G_s interval holds the truth. Measured
    (2026-11-26, seeds 1 and 2): GH nu_s 0.5 0.0262 and 0.0259 N/m, SK C = 1 0.0265 and 0.0266
    (truth 0.025), intervals about +-11 %. Before the drift test allowed for the database's
    own error (capsmech.inversion.population.law_drift), the SK batches gave "no law of the
    database fits" (SK's G_s drifting, p = 0.031 and 0.0085)."""
    import capsmech

    drawn = ib.draw_batch(ib.load_pool(ib.DEEP_POOL), key, tmp_path, key, seed=1, n=12)
    verdict = capsmech.population(capsmech.fit_tube(drawn.csv, "tube-paper"))
    assert verdict.kind == "law" and verdict.best == key, verdict.reason
    low, high = verdict.g_s_interval
    assert low < ib.G_S < high


def test_a_g_s_interval_adds_its_systematic_part_in_quadrature():
    from scipy import stats

    from capsmech.diagnosis.record import g_s_interval

    statistical = stats.t.ppf(0.975, 15) * 0.004 / 4
    interval = g_s_interval(0.025, 0.004, 16, 0.0007)
    assert interval["interval"][1] - 0.025 == pytest.approx(math.hypot(statistical, 0.0007), rel=1e-12)
    assert g_s_interval(0.025, 0.004, 16)["interval"][1] - 0.025 == pytest.approx(statistical, rel=1e-12)
    assert g_s_interval(0.025, 0.004, 1)["interval"] is None


def test_a_distortion_no_candidate_describes_is_unexplained(tmp_path):
    """A cos(4 phi) ripple of 1.5 px: the offset and radius candidates lower chi2, but what they
    leave is far from noise, so no effect is named and G_s after is not given."""
    drawn, capsules = batch(tmp_path, "outside_ripple_1.5px")
    result = diagnose(capsules, databases(), "NH", [contour_offset_candidate("NH"), tube_radius_candidate("NH")],
                      refine_evaluations=0)
    assert result.kind == "unexplained", result.verdict
    assert result.fit is not None and result.fit.reduced_chi2 > 3 * result.fit.reduced_chi2_limit
    assert result.verdict.startswith("unexplained") and "closest" in result.verdict


def test_a_law_of_the_database_is_named_without_an_interval(tmp_path):
    """The law is chosen (BIC drop 798 against the offset's 723) and named without an interval.
    Whether the offset remains a rival is decided by 8 capsules at Ca_s 0.023-0.046, next to
    the rear's buckling fold, where the database rows move by up to 0.17 % of L_z between two
    fillings (validation: databases): with the tube-paper of kernel 0.3.2, 7 of 8 capsules
    preferred the law (Wilcoxon p = 0.027, "effect"); with 0.3.5's, 6 of 8 (p = 0.074), and the
    verdict says the data cannot tell it from the offset. Either is accepted; the chosen one and
    its missing interval are asserted."""
    drawn, capsules = batch(tmp_path, "law_GH_nu0.5")
    result = diagnose(capsules, databases(), "NH", [law_candidate("NH", "GH_nu0.5"), contour_offset_candidate("NH")],
                      refine_evaluations=0)
    assert result.kind in ("effect", "cannot_tell") and result.chosen is not None, result.verdict
    assert [r.name for r in result.rivals] in ([], ["contour_offset"]), result.verdict
    assert result.chosen.name == "law GH_nu0.5" and result.chosen.discrete
    assert "no interval" in result.verdict


def test_an_offset_is_never_named_a_tube_radius_error(tmp_path):
    """Offset and radius scale a near-spherical contour alike: the verdict is the offset, or
    the two tied (cannot_tell), never the radius alone."""
    drawn, capsules = batch(tmp_path, "offset_2.2px")
    result = diagnose(capsules, databases(), "NH", [contour_offset_candidate("NH"), tube_radius_candidate("NH")],
                      refine_evaluations=0)
    assert result.kind in ("effect", "cannot_tell"), result.verdict
    named = {result.chosen.name, *(r.name for r in result.rivals)} if result.chosen else set()
    assert "contour_offset" in named, result.verdict
    if result.kind == "effect":
        assert result.chosen.name == "contour_offset"
    # Its interval carries the databases' accuracy over the offset's signature, and holds the truth.
    offset = next(r for r in result.results if r.name == "contour_offset")
    assert offset.systematic > 0
    assert offset.interval[0] <= 2.2 <= offset.interval[1], offset.interval
    assert offset.interval[1] - offset.theta >= offset.systematic


def test_cli_json_says_unexplained_and_gives_no_g_s_after(tmp_path):
    """``capsmech diagnose --json``: the verdict's kind, no effect, no G_s after (with the
    reason), the goodness of fit with its p-values, every candidate's evidence."""
    drawn, _ = batch(tmp_path, "outside_ripple_1.5px")
    out = tmp_path / "verdict.json"
    run = subprocess.run([sys.executable, "-m", "capsmech.cli", "diagnose", str(drawn.csv), "--candidate",
                          "contour_offset", "--max-effects", "1", "--json", str(out)],
                         capture_output=True, text=True, timeout=1800)
    assert run.returncode == 0, run.stderr
    record = json.loads(out.read_text())
    assert record["verdict"] == "unexplained" and record["effects"] == []
    assert record["g_s"]["lengths"]["after"] is None and "no G_s after" in record["g_s_after_reason"]
    before = record["g_s"]["lengths"]["before"]
    assert before["interval"][0] < before["value"] < before["interval"][1]
    fit = record["goodness_of_fit"]
    assert not fit["consistent"] and fit["chi2_p_value"] < 0.01 and len(fit["residual_profile_px"]) == 16
    (candidate,) = record["candidates"]
    assert candidate["name"] == "contour_offset" and math.isfinite(candidate["strength"])
    assert candidate["interval"][0] < candidate["strength"] < candidate["interval"][1]
    assert "verdict: unexplained" in run.stdout


@pytest.mark.validate
def test_confusion_study_names_no_wrong_effect(tmp_path):
    """Every batch of the study (the whole library, capsmech's defaults): no wrong effect named,
    every batch outside the library unexplained (about 15 core-minutes)."""
    import confusion_study

    confusion_study.main([str(tmp_path), "--workers", "2"])
    import csv

    rows = list(csv.DictReader((tmp_path / "confusion.csv").open()))
    assert len(rows) == len(ib.CONFUSION_BATCHES)
    assert not [r["batch"] for r in rows if r["wrong_effect_named"] == "True"]
    assert all(r["verdict"] == "unexplained" for r in rows if r["expected"] == "unexplained")


@pytest.mark.validate
def test_strength_intervals_hold_the_truth_at_their_level(tmp_path):
    """With the databases' accuracy carried (measured: 400 of 400, 50 batches per effect and
    strength); here 8 batches of four configurations, ~20 core-minutes."""
    import interval_coverage

    out = interval_coverage.run_study(8, 2, tmp_path / "coverage.csv", configs=[0, 2, 4, 6])
    for entry in interval_coverage.summarise(out):
        k, n, _, high = entry["covered"]
        if n:
            assert high >= 0.95, entry


@pytest.mark.validate
def test_g_s_intervals_hold_the_truth_at_their_level(tmp_path):
    """G_s after the true effect, by lengths (measured on the contour) and by the contour fits,
    with the databases' accuracy and the strength's interval carried (measured before: the
    control 4/25, the effects 8-100 % by lengths and 40-88 % by the contour fits; after, 8
    batches of each effect and 50 of the control: 113/114 and 64/64). Here 8 batches of the
    control, an offset and a pre-stress, ~15 core-minutes; the control's G_s by lengths is no
    longer biased (it was -5.2 %)."""
    import interval_coverage

    out = interval_coverage.run_study(8, 2, tmp_path / "coverage.csv", configs=[8, 0, 4])
    for entry in interval_coverage.summarise(out):
        for column in ("g_s_lengths_covered", "g_s_contours_covered"):
            k, n, _, high = entry[column]
            if n:
                assert high >= 0.95, (column, entry)
        if entry["config"] == "no effect":
            assert abs(entry["g_s_lengths_median_error"]) < 0.02, entry
