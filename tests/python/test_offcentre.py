"""Off-centre capsules in a tube batch (issue 7, the off-centre position).

data/examples/undeclared/offcentre.csv (``scripts/make_offcentre.py``) holds five capsules of
batch_A's material simulated by the 3D tube kernel after a release off the axis (a/l 0.7-0.8,
b = 0.08-0.1 l), caught while they migrate back (r_c 0.009-0.07 l), their contours traced on
the section through the tube axis. Facts checked:
- an off-centre capsule's contour is up-down asymmetric, roughly in proportion to its offset
  (measured: 0.04-0.07 a at r_c 0.02-0.07 l), far above tracing noise (the flag's limit is
  1 % of a, or one pixel);
- the inversion flags it, and ``diagnose`` leaves it out (with its reason) instead of fitting
  an effect to it: batch_A with the off-centre capsules added still supports no candidate, and
  none of batch_A's own capsules is left out.
"""
from __future__ import annotations

import csv
from pathlib import Path

import pytest

from capsmech.diagnosis.candidates import contour_offset_candidate, tube_radius_candidate
from capsmech.diagnosis.diagnose import diagnose
from capsmech.inversion.fitting import fit_tube_rows
from capsmech.io.catalog import database_path
from capsmech.io.database import load_database
from capsmech.io.measurements import read_measurements

ROOT = Path(__file__).resolve().parents[2]
BATCHES = ROOT / "data" / "examples" / "undeclared"
TUBE = database_path("tube-paper")
#: Off-centre capsules further than this from the axis [l] must be flagged (the one caught at
#: r_c 0.009 l is allowed either way: its asymmetry is near the limit).
CLEARLY_OFF = 0.02


@pytest.fixture(scope="module")
def offcentre():
    capsules = read_measurements(BATCHES / "offcentre.csv", "tube")
    with open(BATCHES / "offcentre_truth.csv", newline="", encoding="utf-8") as stream:
        truth = {row["id"]: row for row in csv.DictReader(stream)}
    return capsules, truth


def test_off_centre_capsules_are_flagged_asymmetric_by_the_inversion(offcentre):
    capsules, truth = offcentre
    rows = fit_tube_rows(capsules, load_database(TUBE), laws=["NH"])
    for row in rows:
        r_c = float(truth[row["id"]]["r_c"])
        if r_c > CLEARLY_OFF:
            assert row["flag"] == "asymmetric" and row["reason"].startswith("asymmetric contour"), (row["id"], r_c, row["asymmetry"])
            assert row["asymmetry"] > 0.5 * r_c / float(truth[row["id"]]["a_over_l"])


def test_diagnose_leaves_off_centre_capsules_out_and_finds_nothing_in_batch_a(offcentre):
    capsules, truth = offcentre
    batch_a = read_measurements(BATCHES / "batch_A.csv", "tube")
    result = diagnose([*batch_a, *capsules], load_database(TUBE), "NH",
                      [contour_offset_candidate("NH"), tube_radius_candidate("NH")], refine_evaluations=0)
    left_out = {capsule for capsule, _ in result.excluded}
    clearly_off = {k for k, row in truth.items() if float(row["r_c"]) > CLEARLY_OFF}
    assert clearly_off <= left_out <= set(truth)          # no capsule of batch_A is left out
    assert all("off-centre or not steady" in why for _, why in result.excluded)
    assert result.chosen is None
    assert len(result.base.chi2) == len(batch_a) + len(truth) - len(left_out)
