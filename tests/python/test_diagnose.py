"""Closing the loop (capsmech.diagnose, issue 7): the effect a batch's data support.

On the shipped synthetic NH batch (kernel capsules off the grid, contours traced to +-1 px):
- as measured, no candidate is supported (the residual is within noise);
- with an undeclared contour offset of 1.5 px (the traced line outside the membrane, L_z
  longer by 3 px), the contour offset is supported, its interval holds 1.5 px, and the
  batch's G_s moves back towards the truth (0.04 N/m). A tube radius 2 % larger than the
  nominal one explains contours alone about as well (both make the capsule look larger
  against the tube): when it does, the verdict must say that the data cannot tell them apart.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from capsmech.diagnosis.candidates import contour_offset_candidate, offset_contour, tube_radius_candidate
from capsmech.diagnosis.diagnose import diagnose
from capsmech.io.catalog import database_path
from capsmech.io.database import load_database
from capsmech.io.measurements import read_measurements

# Each diagnosis refits the batch some 20 times (minutes): make validate, not make test.
pytestmark = pytest.mark.validate

ROOT = Path(__file__).resolve().parents[2]
G_S = 0.04


@pytest.fixture(scope="module")
def batch():
    return read_measurements(ROOT / "data" / "examples" / "tube_batch_NH.csv", "tube")


@pytest.fixture(scope="module")
def database():
    return load_database(database_path("tube-paper"))


def candidates():
    return [contour_offset_candidate("NH"), tube_radius_candidate("NH")]


def test_batch_as_measured_supports_no_effect(batch, database):
    result = diagnose(batch, database, "NH", candidates())
    assert result.chosen is None, result.verdict
    assert "within noise" in result.verdict


def test_undeclared_contour_offset_is_named_and_corrected(batch, database):
    delta_px = 1.5
    shifted = [replace(c, values={**c.values, "L_z": c["L_z"] + 2 * delta_px * c["pixel_size"]},
                       contour=offset_contour(c.contour, delta_px * c["pixel_size"])) for c in batch]
    result = diagnose(shifted, database, "NH", candidates())
    offset = next(r for r in result.results if r.name == "contour_offset")
    assert offset.supported, offset
    low, high = offset.interval
    assert low <= delta_px <= high
    assert abs(offset.g_s_after[0] - G_S) < abs(offset.g_s_before[0] - G_S)
    assert result.chosen is not None
    if result.chosen is not offset:
        assert offset in result.rivals and "cannot tell" in result.verdict, result.verdict


def test_cli_writes_the_report(tmp_path):
    from capsmech.cli.main import main

    report = tmp_path / "report.md"
    assert main(["diagnose", str(ROOT / "data" / "examples" / "tube_batch_NH.csv"), "--law", "NH",
                 "--other-law", "GH_nu0.5", "--out", str(report)]) == 0
    text = report.read_text()
    assert "**Verdict:** no candidate effect is supported" in text
    assert "| contour_offset |" in text and "| law GH_nu0.5 |" in text
