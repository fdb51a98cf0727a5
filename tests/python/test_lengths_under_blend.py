"""G_s by lengths under a blended law (a strength between or beyond two levels) and when it is
left out beside the contour fits' G_s.

The blend's lengths are inverted on its own rows (``blended_table``: the levels' L_z, L_p and
v_c/V summed with the blend's weights at the nodes they share, as the contour fits sum their
profiles), not by averaging each level's own lengths fit. Batches come from the independent
generator (``independent_batches``: its own optics and noise, kernel shapes at 96 elements,
G_s 0.025 N/m).
"""
from __future__ import annotations

from functools import cache
from types import SimpleNamespace

import independent_batches as ib
import numpy as np
import pytest

from capsmech.diagnosis.candidates import MIN_SHARED_NODES, BlendedLaw, DatabaseSet, blended_table, level_inverter
from capsmech.diagnosis.record import g_s_interval, lengths_left_out
from capsmech.diagnosis.scoring import length_g_s_with_systematic, lengths_inverter
from capsmech.io.catalog import database_path
from capsmech.io.database import load_database
from capsmech.io.measurements import read_measurements


@cache
def databases() -> DatabaseSet:
    return DatabaseSet([load_database(database_path("tube-paper"))])


def test_the_blends_rows_are_the_levels_rows_weighted():
    """At weights (1, 0) the blend's rows are the first level's at the nodes both share; at
    (0.5, 0.5) their midpoint; extrapolating weights (1.5, -0.5) extend the difference."""
    low, high = (level_inverter(databases(), key).table for key in ("GH_nu0.2", "GH_nu0.5"))
    shared = {(round(a, 9), round(c, 9)) for a, c in zip(low.a_over_l, low.Ca_s)} & {
        (round(a, 9), round(c, 9)) for a, c in zip(high.a_over_l, high.Ca_s)}
    first = blended_table([low, high], [1.0, 0.0])
    assert first is not None and len(first.a_over_l) == len(shared) >= MIN_SHARED_NODES
    index = {(round(a, 9), round(c, 9)): i for i, (a, c) in enumerate(zip(low.a_over_l, low.Ca_s))}
    rows = [index[(round(a, 9), round(c, 9))] for a, c in zip(first.a_over_l, first.Ca_s)]
    assert np.array_equal(first.L_z, low.L_z[rows]) and np.array_equal(first.vc_over_V, low.vc_over_V[rows])
    middle = blended_table([low, high], [0.5, 0.5])
    beyond = blended_table([low, high], [1.5, -0.5])
    assert middle is not None and beyond is not None
    index_high = {(round(a, 9), round(c, 9)): i for i, (a, c) in enumerate(zip(high.a_over_l, high.Ca_s))}
    rows_high = [index_high[(round(a, 9), round(c, 9))] for a, c in zip(first.a_over_l, first.Ca_s)]
    np.testing.assert_allclose(2 * middle.L_p - first.L_p, high.L_p[rows_high], rtol=0, atol=1e-12)
    np.testing.assert_allclose(middle.L_z - first.L_z, first.L_z - beyond.L_z, rtol=0, atol=1e-12)


def test_a_blend_between_two_law_groups_gives_g_s_by_lengths(tmp_path):
    """GH nu_s = 0.35, between the shipped groups 0.2 and 0.5 (12 capsules, seed 11; truth G_s
    0.025 N/m), at the true nu_s: G_s by lengths on the blend's rows 0.0254 from 11 capsules,
    its interval holding 0.025. (The average of each level's own lengths fit, the estimator
    before: 0.0292 from 9; the levels' own fits 0.044 and 0.014.)"""
    drawn = ib.draw_batch(ib.load_pool(), "GH_nu0.35", tmp_path, "gh035", seed=11, n=12)
    capsules = read_measurements(drawn.csv, "tube")
    law = BlendedLaw(["GH_nu0.2", "GH_nu0.5"], [0.5, 0.5])
    (mean, sd, n), systematic = length_g_s_with_systematic(capsules, lengths_inverter(databases(), law))
    assert n >= 11 and abs(mean / ib.G_S - 1) < 0.05, (mean, sd, n)
    interval = g_s_interval(mean, sd, n, systematic)["interval"]
    assert interval[0] <= ib.G_S <= interval[1], interval


def test_levels_that_share_too_few_nodes_give_no_lengths_estimate():
    """A blend whose levels share fewer than MIN_SHARED_NODES nodes has no lengths inverter
    (G_s by lengths NaN from 0 capsules), not an inversion on a handful of rows."""
    table = level_inverter(databases(), "GH_nu0.2").table
    # (a table this small is refused by TubeTable itself: the rows alone)
    few = SimpleNamespace(**{name: getattr(table, name)[:MIN_SHARED_NODES - 1]
                             for name in ("a_over_l", "Ca_s", "L_z", "L_p", "vc_over_V")},
                          profile_r=None, profile_z=None, root=None)
    assert blended_table([table, few], [0.5, 0.5]) is None
    (mean, _, n), _ = length_g_s_with_systematic([], None)
    assert n == 0 and np.isnan(mean)


@pytest.mark.parametrize(("lengths", "contour", "left_out"), [
    # overlapping intervals, most capsules: kept
    ((0.026, 0.0015, 10), (0.025, 0.0005, 12), ""),
    # disjoint: left out, the reason naming both
    ((0.052, 0.002, 10), (0.025, 0.0005, 12), "disagrees with the contour fits'"),
    # fewer than half the capsules: left out
    ((0.025, 0.001, 4), (0.025, 0.0005, 12), "reproduces the lengths of 4 of the 12"),
    # an interval reaching 0 (the Skalak C = 10 batch at the level C = 8): left out
    ((0.0333, 0.0290, 5), (0.0274, 0.0100, 5), "the interval reaches 0"),
    # a scatter 6 times the contour fits' (one-material batches: 3-8 times): kept
    ((0.025, 0.0030, 15), (0.025, 0.0005, 16), ""),
])
def test_g_s_by_lengths_is_left_out_with_a_reason(lengths, contour, left_out):
    reason = lengths_left_out(g_s_interval(*lengths), g_s_interval(*contour))
    assert (left_out in reason) if left_out else reason == ""
    assert lengths_left_out(None, g_s_interval(*contour)) == ""


def test_the_stiff_pool_is_the_kernels_steady_shapes():
    pool = ib.load_pool(ib.STIFF_POOL)
    assert pool.keys == list(ib.STIFF_KEYS) and len(pool.a_over_l) == ib.STIFF_CAPSULES
    assert np.all(pool.status == "steady")


@pytest.mark.validate
def test_a_stiff_skalak_batch_gets_no_g_s_by_lengths_it_cannot_support(tmp_path, monkeypatch):
    """Skalak C = 10 (the stiff pool, 12 capsules, seed 11) with ``--simulate`` and the levels
    C = 1, 2, 4, 8, 12 (144 kernel cases around the batch, some 5 core-minutes; cached): G_s by
    lengths after the Skalak-C candidate is an answer only where it can be one. Measured: C =
    10.6 [7.9, 13.2]; G_s by the contour fits 0.0254 [0.0076, 0.0432] N/m (truth 0.025), by
    lengths 0.0398 [-0.048, 0.128] from 3 capsules, left out with its reason (before: +110 %
    and no word; at the level C = 8 +33 %, 79 % a capsule)."""
    import json
    import subprocess
    import sys

    from capsmech.workflow.simulate import DATA_DIR_ENV

    monkeypatch.setenv(DATA_DIR_ENV, str(tmp_path / "cache"))
    drawn = ib.draw_batch(ib.load_pool(ib.STIFF_POOL), "SK_C10", tmp_path, "sk10", seed=11, n=12)
    out = tmp_path / "verdict.json"
    run = subprocess.run([sys.executable, "-m", "capsmech.cli", "diagnose", str(drawn.csv), "--simulate",
                          "--candidate", "SK_C", "--C-levels", "1,2,4,8,12", "--max-effects", "1", "--json", str(out)],
                         capture_output=True, text=True, timeout=6 * 3600, cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-2000:]
    (candidate,) = json.loads(out.read_text())["candidates"]
    contour, lengths = candidate["g_s_contour_fits"]["after"], candidate["g_s_lengths"]
    assert contour["interval"][0] <= ib.G_S <= contour["interval"][1], contour
    after = lengths["after"]
    holds = after["value"] is not None and after["interval"][0] <= ib.G_S <= after["interval"][1]
    assert lengths["after_left_out"] or holds, lengths
    if after["value"] is not None and after["interval"][0] <= 0:
        assert "interval reaches 0" in lengths["after_left_out"]
