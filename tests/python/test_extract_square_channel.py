"""A film of a capsule in a square channel, extracted with ``--channel square`` and fitted
against the square-channel database: the measurement file says the channel (its ``half_width``),
so that fit-tube takes it, and the same film written as a tube's is refused by that database.

The frames are drawn by the test-side renderer (``capsmech.imaging.rendering``, not the
extraction under test) from one row of ``duct-dev`` (the 3D duct model's mid-plane outline):
walls at the channel's half-width from the axis, as a microscope focused on the mid-plane sees
a square channel through one face.
"""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from capsmech.cli.main import main
from capsmech.imaging.rendering import FrameStyle, outline_from_meridian, render_stack, write_tiff_stack
from capsmech.io.catalog import database_path
from capsmech.io.database import DatabaseError, load_database
from capsmech.io.measurements import read_measurements

G_S, MU, PIXEL_UM, HALF_WIDTH_PX, RATE = 0.04, 1.0, 0.5, 60.0, 1000.0
LAW, A_OVER_W, CA_S = "NH", 0.8, 0.08


@pytest.fixture(scope="module")
def duct_db():
    try:
        return load_database(database_path("duct-dev"))
    except (DatabaseError, OSError, KeyError) as err:
        pytest.skip(f"the square-channel database duct-dev is not there ({err})")


@pytest.fixture(scope="module")
def film(duct_db, tmp_path_factory):
    """A TIFF of the row's capsule crossing the view, and the row's (L_z, L_p, v_c/V) [w, V]."""
    rows = duct_db.law(LAW).steady_rows()
    i = int(np.argmin(np.abs(rows["a_over_l"] - A_OVER_W) + np.abs(rows["Ca_s"] - CA_S)))
    assert rows["a_over_l"][i] == pytest.approx(A_OVER_W) and rows["Ca_s"][i] == pytest.approx(CA_S)
    outline = outline_from_meridian(rows["profile_r"][i], rows["profile_z"][i])
    v_c = rows["vc_over_V"][i] * CA_S * G_S / MU                          # m/s
    frames = render_stack(outline, 16, 110.0, v_c / (PIXEL_UM * 1e-6) / RATE,
                          FrameStyle(tube_radius_px=HALF_WIDTH_PX, axis_row=99.6), seed=44)
    folder = tmp_path_factory.mktemp("square_film")
    return write_tiff_stack(folder / "capsule.tif", frames), (rows["L_z"][i], rows["L_p"][i], rows["vc_over_V"][i])


def _extract(film_path: Path, out: Path, *extra: str) -> int:
    return main(["extract", str(film_path), "--pixel-size", f"{PIXEL_UM}um", "--frame-rate", str(RATE),
                 "--mu", str(MU), "--out", str(out), *extra])


def test_extract_in_a_square_channel_writes_the_half_width_and_fit_tube_recovers_g_s(film, duct_db, tmp_path):
    tiff, (L_z, L_p, _) = film
    out = tmp_path / "square.csv"
    summary = tmp_path / "square.json"
    assert _extract(tiff, out, "--channel", "square", "--json", str(summary)) == 0
    header = next(line for line in out.read_text(encoding="utf-8").splitlines() if not line.startswith("#"))
    columns = [name.split(" [")[0] for name in next(csv.reader([header]))]
    # The walls' half distance is the channel's half-width; no tube radius is claimed.
    assert "half_width" in columns and "half_width_sigma" in columns and "tube_radius" not in columns
    (capsule,) = read_measurements(out, "tube")
    assert capsule.channel == "square"
    assert capsule["half_width"] == pytest.approx(HALF_WIDTH_PX * PIXEL_UM * 1e-6, rel=0.01)
    payload = json.loads(summary.read_text(encoding="utf-8"))
    assert payload["channel"] == "square" and payload["half_width_um"] == pytest.approx(HALF_WIDTH_PX * PIXEL_UM,
                                                                                         rel=0.01)
    # The lengths are the row's, to the image's pixel (1/60 of w).
    assert capsule["L_z"] / capsule["half_width"] == pytest.approx(L_z, abs=2 / HALF_WIDTH_PX)
    assert capsule["L_p"] / capsule["half_width"] == pytest.approx(L_p, abs=2 / HALF_WIDTH_PX)

    fitted = tmp_path / "fits.csv"
    assert main(["fit-tube", str(out), "--database", "duct-dev", "--law", LAW, "--out", str(fitted)]) == 0
    with fitted.open(encoding="utf-8") as f:
        (raw,) = list(csv.DictReader(line for line in f if not line.startswith("#")))
    row = {name.split(" [")[0]: value for name, value in raw.items()}
    assert float(row["a_over_l"]) == pytest.approx(A_OVER_W, abs=0.02)
    assert float(row["G_s"]) == pytest.approx(G_S, rel=0.06)


def test_the_same_film_written_as_a_tube_is_refused_by_the_square_channel_database(film, tmp_path, capsys):
    tiff, _ = film
    out = tmp_path / "tube.csv"
    assert _extract(tiff, out) == 0
    (capsule,) = read_measurements(out, "tube")
    assert capsule.channel == "tube"
    capsys.readouterr()
    assert main(["fit-tube", str(out), "--database", "duct-dev", "--law", LAW, "--out", str(tmp_path / "f.csv")]) == 2
    message = capsys.readouterr().err
    assert "half_width" in message and "tube_radius" in message and "Traceback" not in message


def test_an_unknown_channel_is_refused_before_any_file_is_written(film, tmp_path, capsys):
    tiff, _ = film
    out = tmp_path / "x.csv"
    with pytest.raises(SystemExit) as exit_info:
        _extract(tiff, out, "--channel", "rect")
    assert exit_info.value.code == 2 and not out.exists()
    assert "--channel" in capsys.readouterr().err
