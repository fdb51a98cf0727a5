"""Capsules in a square channel: the geometry a measurement file gives (``half_width``), checked
against the database's channel and stated in fit-tube's outputs, and the inversion of a batch
the kernel made in a square duct.

The batch is data/examples/duct_batch_NH.csv: six NH capsules simulated by ``capsim`` (3D
square duct, level 3) at G_s = 0.04 N/m, "measured" with 2 % noise and +-1 px contours by
scripts/make_duct_batch.py, which shares no code with the package. The fits need the shipped
square-channel database ``duct-dev``; those tests are skipped while it is not there.
"""
from __future__ import annotations

import csv
import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import capsmech
from capsmech.api import check_channel, fit_tube, with_channel_columns
from capsmech.cli.main import main
from capsmech.errors import DatabaseError, OutsideDatabaseWarning
from capsmech.io.database import TubeDatabase
from capsmech.io.measurement_frames import capsules_from_frame, read_batch
from capsmech.io.measurements import MeasurementError, read_measurements

ROOT = Path(__file__).resolve().parents[2]
DUCT_BATCH = ROOT / "data" / "examples" / "duct_batch_NH.csv"
DUCT_TRUTH = ROOT / "data" / "examples" / "duct_batch_NH_truth.csv"
TUBE_BATCH = ROOT / "data" / "examples" / "tube_batch_NH.csv"
DUCT_DATABASE = "duct-dev"


def _truth_g_s() -> float:
    with open(DUCT_TRUTH, encoding="utf-8") as stream:
        values = {float(row["G_s [N/m]"]) for row in csv.DictReader(stream)}
    assert len(values) == 1, "the batch is one material"
    return values.pop()


@pytest.fixture(scope="module")
def duct_db():
    try:
        return capsmech.load_database(DUCT_DATABASE)
    except DatabaseError as err:
        pytest.skip(f"the square-channel database {DUCT_DATABASE!r} is not shipped yet ({err})")


@pytest.fixture(scope="module")
def duct_fit(duct_db):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutsideDatabaseWarning)
        return fit_tube(DUCT_BATCH, duct_db, "NH")


def test_a_half_width_file_is_a_square_channel_whose_length_scale_is_the_half_width():
    capsules = read_measurements(DUCT_BATCH)
    assert {c.channel for c in capsules} == {"square"}
    # The databases' lengths are in the channel's length scale: 50 um, the half-width.
    assert all(math.isclose(c.length_scale, 50e-6) and c["tube_radius"] == c.length_scale for c in capsules)
    assert {c.channel for c in read_measurements(TUBE_BATCH)} == {"tube"}
    # A DataFrame read from the file and given back keeps the channel.
    assert {c.channel for c in capsules_from_frame(read_batch(DUCT_BATCH))} == {"square"}


def test_tube_radius_and_half_width_both_given_is_an_error_naming_the_line(tmp_path):
    path = tmp_path / "both.csv"
    path.write_text("# one channel or the other\nid,L_z [um],L_p [um],tube_radius [um],half_width [um]\n"
                    "c1,120,10,50,50\n", encoding="utf-8")
    with pytest.raises(MeasurementError, match=rf"{path}:2: columns 'tube_radius' and 'half_width' both given"):
        read_measurements(path)


def test_a_sigma_of_the_other_channel_is_an_error_naming_the_line(tmp_path):
    path = tmp_path / "sigma.csv"
    path.write_text("id,L_z [um],L_p [um],half_width [um],tube_radius_sigma [um]\nc1,120,10,50,1\n", encoding="utf-8")
    with pytest.raises(MeasurementError, match=rf"{path}:1: column 'tube_radius_sigma' .*give 'half_width_sigma'"):
        read_measurements(path)


def test_an_empty_half_width_is_an_error_naming_the_line(tmp_path):
    path = tmp_path / "empty.csv"
    path.write_text("id,L_z [um],L_p [um],half_width [um]\nc1,120,10,50\nc2,110,9,\n", encoding="utf-8")
    with pytest.raises(MeasurementError, match=rf"{path}:3: field 'half_width' is empty"):
        read_measurements(path)


def test_a_duct_batch_against_a_tube_database_is_refused_in_one_message(capsys):
    assert main(["fit-tube", str(DUCT_BATCH), "--database", "tube-paper", "--law", "NH"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert "square channel (column half_width)" in err and "tube-paper" in err and "circular tube" in err
    # diagnose reads the same geometry, and refuses it the same way.
    with pytest.raises(MeasurementError, match="square channel"):
        capsmech.diagnose(DUCT_BATCH, "tube-paper", "NH")


def test_a_tube_batch_against_the_duct_database_is_refused(duct_db):
    with pytest.raises(MeasurementError, match=r"circular tube \(column tube_radius\).*square channel"):
        fit_tube(TUBE_BATCH, duct_db, "NH")


def test_the_duct_batch_gives_the_true_G_s_within_its_intervals(duct_fit):
    g_s = _truth_g_s()
    fitted = duct_fit[duct_fit["flag"] == ""]
    assert len(fitted) == len(read_measurements(DUCT_BATCH)), "every capsule of the batch fitted"
    # Each capsule's contour fit within 12 % of the truth: the database's interpolation between
    # rows 0.1 apart in a/w, the velocity's 2 % noise and the contour's +-1 px. The interpolation
    # alone moves a capsule's G_s by -3.2 % to +9.3 % (noise-free contour fits of the kernel's own
    # shapes at a/w 0.65-0.86, Ca_s 0.05-0.09; the most at a/w 0.86, next to the grid's edge):
    # measured 11.6 % at most once the rows' outlines kept their poles (5.3 % before, on
    # outlines that lacked them), docs/validation/inversion.md#square-channel.
    assert ((fitted["G_s_shape"] / g_s - 1).abs() < 0.12).all()
    # The batch: NH's 95 % interval of the mean G_s (population's, with the database's
    # accuracy) holds the truth. Whether NH is also named the verdict depends on the contours'
    # goodness of fit, which the database's a/w spacing of 0.1 limits (docs/validation/inversion.md).
    row = capsmech.population_table(capsmech.population(duct_fit)).set_index("law").loc["NH"]
    assert row["G_s_low"] <= g_s <= row["G_s_high"]


@pytest.fixture(scope="module")
def duct_verdict(duct_db):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutsideDatabaseWarning)
        results = fit_tube(DUCT_BATCH, duct_db)
    return capsmech.population(results)


def test_the_nh_duct_batch_is_never_named_gh_nu05(duct_verdict):
    # Fitted with both of the database's laws, the NH batch is not given the wrong law: the
    # contours' chi2 holds the database's interpolation error (rows 0.1 apart in a/w), so NH's
    # best shapes reach the noise (chi2/dof 1.04 against the limit 1.74; 2.40 without it) and the
    # contours cannot tell the two laws apart (p = 0.28). Before that, GH_nu0.5 was named at
    # 0.0319 [0.0273, 0.0366] N/m.
    assert duct_verdict.kind in ("law", "cannot_tell"), duct_verdict.reason
    assert duct_verdict.best in (None, "NH"), duct_verdict.reason
    assert "NH" in duct_verdict.candidates
    low, high = duct_verdict.evidence["NH"].g_s_interval
    assert low <= _truth_g_s() <= high


def test_no_wrong_law_is_named_with_an_interval_that_misses_the_truth(duct_verdict):
    # Fitted with both of the database's laws, the NH batch gets NH, or a tie whose one G_s
    # interval holds the truth: never GH_nu0.5 alone. On duct-dev (a/w steps of 0.1) the
    # contours cannot tell the two laws apart; the tie's interval is the hull of theirs, which
    # do not overlap (knowing the law would narrow it).
    g_s = _truth_g_s()
    verdict = duct_verdict
    assert verdict.kind in ("law", "cannot_tell"), verdict.reason
    if verdict.kind == "law":
        assert verdict.best == "NH", verdict.reason
    assert verdict.g_s_interval is not None and verdict.g_s_interval[0] <= g_s <= verdict.g_s_interval[1]


def test_the_rows_stated_errors_raise_the_chi2_floor_behind_the_rim_only_where_stated(duct_db):
    from capsmech.inversion.fitting import tube_inverter
    from capsmech.inversion.sharp_edge import SMOOTH_FLOOR_REL, parachute_depth, profile_floor

    inverter = tube_inverter(duct_db, "NH")
    L_z_rel, L_p_rel = inverter.stated_error(0.8, 0.08)
    rows = duct_db.law("NH")
    stated = np.asarray(rows.column("L_p_mesh_error_rel"), float)
    # The largest that the rows of the grid cell around the point state, one of the rows' values.
    assert math.isfinite(L_p_rel) and np.any(np.isclose(stated, L_p_rel)) and 0 < L_p_rel < 0.1
    meridian = inverter.profile(0.8, 0.08)
    length = float(np.ptp(meridian[:, 1]))
    plain = profile_floor(meridian, length, 64)
    raised = profile_floor(meridian, length, 64, stated_error_rel=(L_z_rel, L_p_rel))
    assert np.all(raised >= plain)
    assert math.isclose(raised.max(), max(plain.max(), L_p_rel * parachute_depth(meridian)), rel_tol=1e-12)
    assert math.isclose(raised[0], max(SMOOTH_FLOOR_REL, L_z_rel) * length, rel_tol=1e-12)   # the front
    # A database that states nothing (the tube databases) keeps the floor it had.
    assert np.array_equal(profile_floor(meridian, length, 64, stated_error_rel=(math.nan, math.nan)), plain)


def test_fit_tube_states_the_channel_in_every_output(duct_db, tmp_path, capsys):
    out, h5, report = tmp_path / "fit.csv", tmp_path / "fit.h5", tmp_path / "fit.json"
    assert main(["fit-tube", str(DUCT_BATCH), "--database", str(duct_db.path), "--law", "NH", "--out", str(out),
                 "--out", str(h5), "--json", str(report)]) == 0
    printed = capsys.readouterr().out
    assert "channel: a square channel (lengths in its half-width), aspect 1, l = half-width 50 um" in printed
    for path in (out, h5):
        results = capsmech.read_results(path)
        assert set(results["channel"]) == {"square"}
        assert set(results["channel_aspect"]) == {1.0}
        assert all(math.isclose(v, 50e-6) for v in results["length_scale"])
        assert results.attrs["units"]["length_scale"] == "m"
    document = json.loads(report.read_text())
    assert (document["channel"], document["channel_aspect"]) == ("square", 1.0)
    assert {row["channel"] for row in document["rows"]} == {"square"}


def test_a_tube_fit_states_its_channel_too():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutsideDatabaseWarning)
        results = fit_tube(read_measurements(TUBE_BATCH)[:2], "tube-paper", "NH")
    assert results.attrs["channel"]["channel"] == "tube" and results.attrs["channel"]["channel_aspect"] == 1.0
    written = with_channel_columns(results)
    assert list(written.columns[:5]) == ["id", "law", "channel", "channel_aspect", "length_scale"]
    assert set(written["channel"]) == {"tube"} and all(math.isclose(v, 50e-6) for v in written["length_scale"])
    assert list(written.attrs["units"]) == list(written.columns)


@pytest.mark.parametrize("channel, aspect", [("rect", 0.5), ("square", 0.8)])
def test_a_rectangular_channel_database_is_refused_for_want_of_a_height(channel, aspect):
    database = TubeDatabase(path="duct.h5", flow="tube", laws={},
                            provenance={"name": "duct-rect", "channel": channel, "aspect": aspect})
    with pytest.raises(MeasurementError, match=rf"batch.csv: duct-rect is a database of channel '{channel}', aspect "
                                               rf"{aspect:g}; capsules are fitted in circular tubes"):
        check_channel(read_measurements(DUCT_BATCH), database, "batch.csv")


def test_a_database_of_just_enough_rows_has_neighbours_that_never_change():
    # A database with exactly the fit's 14 points (a grid being filled) has no 15th: the KD-tree
    # answers an infinite distance, and the 14 nearest are those points wherever the fit goes.
    from capsmech.inversion.tube_batch import _half_gap

    distance = np.array([[0.1, 0.2, np.inf], [0.1, 0.2, 0.4]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gap = _half_gap(distance, 2)
    assert gap[0] == np.inf and gap[1] == pytest.approx(0.1)
