"""One material or several (``capsmech.inversion.heterogeneity``): the false alarms on
one-material batches, the power on a batch of two materials, and the verdict end to end on
batches of the independent generator (``independent_batches``: its own optics and noise; G_s
set per capsule).
"""
from __future__ import annotations

import json
import math
from functools import cache

import independent_batches as ib
import numpy as np
import pytest

from capsmech.inversion import heterogeneity as het

#: Per-capsule relative uncertainties of the contour fits at 0.45-1.35 px of tracing noise
#: (measured on the independent generator: 1.3-5 %), and the velocity's error beyond them.
ERRORS = [0.013, 0.017, 0.022, 0.03, 0.04, 0.05]
VELOCITY_SPREAD = 0.015


@cache
def pool() -> ib.Pool:
    return ib.load_pool()


@pytest.mark.parametrize(("capsules", "errors", "spread"), [
    (5, [0.0], 0.1),                     # no uncertainties, a 10 % spread: the worst case found
    (13, ERRORS, VELOCITY_SPREAD),        # the 6 + 7 case's size, realistic uncertainties
    (10, [0.015], 0.03),                 # a spread twice the uncertainties
])
def test_one_material_batches_are_rarely_called_several(capsules, errors, spread):
    """600 simulated one-material batches each (normal ln G_s, each capsule's own uncertainty
    and a spread beyond it): "not one material" in at most 5 % (measured with 2000 draws: 2.3 %,
    the worst case found over 5-40 capsules and spreads of 0-10 %; 0.0 % and 0.1 %)."""
    assert het.false_alarm_rate(capsules, errors, spread, draws=600, seed=capsules) <= 0.05


def test_two_materials_are_found_with_their_groups():
    """6 capsules at 0.03 N/m and 7 at 0.06 N/m, each with its own uncertainty (ERRORS) and the
    velocity's spread: of 1000 batches every one "not one material" (power 100 %); on 30 of
    them the groups' members are exactly the two materials and each group's 95 % interval
    holds its G_s in at least 90 % of the batches."""
    rng = np.random.default_rng(5)
    truth = np.array([0.03] * 6 + [0.06] * 7)
    s = rng.choice(ERRORS, size=(1000, 13))
    x = np.log(truth) + rng.normal(0.0, np.hypot(s, VELOCITY_SPREAD))
    assert np.all((het.bic_gain(x, s ** 2) > het.BIC_THRESHOLD) & (het.scatter_chi2(x, s ** 2)[1] < het.ALPHA))
    ids = [f"c{k:02d}" for k in range(13)]
    held = 0
    for g, error in zip(np.exp(x[:30]), s[:30]):
        found = het.heterogeneity(ids, g, g * error)
        assert not found.one_material, found.line()
        low, high = found.groups
        assert low.members == tuple(ids[:6]) and high.members == tuple(ids[6:])
        held += (low.interval[0] < 0.03 < low.interval[1]) and (high.interval[0] < 0.06 < high.interval[1])
    assert held >= 27, held


def test_scatter_alone_is_not_two_materials():
    """A continuous spread (ln G_s uniform over +-15 %, 14 capsules of 1.5 % uncertainty): the
    scatter test rejects the uncertainties (p < 0.05), but two groups do not fit better by the
    threshold: one material, with its spread."""
    ids = [f"c{k}" for k in range(14)]
    g = 0.04 * np.exp(np.linspace(-0.15, 0.15, 14))
    found = het.heterogeneity(ids, g, 0.015 * g)
    assert found.chi2_p < 0.05 and found.one_material and found.spread > 0.05, found.line()


def test_a_two_material_batch_gets_no_single_g_s(tmp_path):
    """The independent generator's NH capsules, 6 at G_s 0.03 and 7 at 0.06 N/m, fitted and
    judged by population: not one material (before: NH, G_s 0.046 +- 0.015, "consistent"),
    no single G_s, each group's interval holding its G_s and its members the right capsules;
    the JSON says the same."""
    import capsmech
    from capsmech.inversion.population_report import verdict_dict

    drawn = ib.draw_batch(pool(), "NH", tmp_path, "two", seed=7, n=13, g_s=[0.03] * 6 + [0.06] * 7)
    verdict = capsmech.population(capsmech.fit_tube(drawn.csv, "tube-paper", laws=["NH"]))
    assert verdict.kind == "not_one_material" and verdict.best == "NH", verdict.line()
    assert math.isnan(verdict.g_s) and verdict.g_s_interval is None
    assert verdict.line().startswith("verdict: NH, not one material")
    low, high = verdict.heterogeneity.groups
    assert low.members == tuple(f"c{k:02d}" for k in range(1, 7))
    assert high.members == tuple(f"c{k:02d}" for k in range(7, 14))
    assert low.interval[0] < 0.03 < low.interval[1] and high.interval[0] < 0.06 < high.interval[1]
    data = json.loads(json.dumps(verdict_dict(verdict), allow_nan=False))
    assert data["verdict"] == "not_one_material" and data["G_s"] is None
    assert data["heterogeneity"]["verdict"] == "not one material"
    assert [g["members"] for g in data["heterogeneity"]["groups"]] == [list(low.members), list(high.members)]


def test_one_material_batches_keep_their_g_s(tmp_path):
    """A one-material batch of 13 NH capsules: one material, the law and its G_s with an
    interval holding 0.025 N/m (test_noise_from_contour checks four more of 11)."""
    import capsmech

    for seed in (3,):
        drawn = ib.draw_batch(pool(), "NH", tmp_path, f"one{seed}", seed=seed, n=13)
        verdict = capsmech.population(capsmech.fit_tube(drawn.csv, "tube-paper", laws=["NH"]))
        assert verdict.kind == "law" and verdict.heterogeneity.one_material, verdict.line()
        assert verdict.g_s_interval[0] < ib.G_S < verdict.g_s_interval[1]


def test_the_diagnosis_report_says_when_a_batch_is_not_one_material(tmp_path):
    """diagnose's Markdown report and JSON record carry the test on the contour fits' G_s (no
    per-capsule uncertainties there: the mixture alone): two groups at 0.03 and 0.06 N/m with
    their members, where the verdict alone would say "none"."""
    from capsmech.diagnosis.diagnose import Diagnosis
    from capsmech.diagnosis.record import diagnosis_record
    from capsmech.diagnosis.report import write_report
    from capsmech.diagnosis.scoring import BatchScore

    rng = np.random.default_rng(2)
    g = np.array([0.03] * 6 + [0.06] * 7) * np.exp(rng.normal(0.0, 0.02, 13))
    diagnosis = Diagnosis(base_law="NH", results=[], chosen=None,
                          base=BatchScore(chi2=np.full(13, 14.0), g_s=g, delta=np.linspace(0.05, 0.2, 13)))
    text = write_report(diagnosis, tmp_path / "report.md", figures=False).read_text()
    assert "## One material or several" in text and "**not one material: G_s = " in text
    record = json.loads(json.dumps(diagnosis_record(diagnosis), allow_nan=False))["heterogeneity"]
    assert record["verdict"] == "not one material" and record["chi2"] is None
    low, high = record["groups"]
    assert low["members"] == [f"capsule {k}" for k in range(1, 7)] and low["G_s_interval"][0] < 0.03 < low["G_s_interval"][1]
    assert high["G_s_interval"][0] < 0.06 < high["G_s_interval"][1]
