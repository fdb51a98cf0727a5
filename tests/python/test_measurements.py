"""Measurement CSV files: unit conversion, and an error naming file, line and field for
every way a user can get a file wrong (nothing is half-read)."""
from __future__ import annotations

import math
from pathlib import Path

import pytest

from capsmech.io.measurements import MeasurementError, read_measurements

TUBE = """# two capsules, 100 um capillary
id,L_z [um],L_p [um],v_c [mm/s],tube_radius [um],mu [Pa s]
c01,182.4,21.0,1.52,50.0,1.41
c02,150.0,0,1.70,50.0,1.41
"""


def write(tmp_path, text, name="m.csv"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_tube_file_is_read_in_si_units(tmp_path):
    capsules = read_measurements(write(tmp_path, TUBE), "tube")
    assert [c.id for c in capsules] == ["c01", "c02"]
    c = capsules[0]
    assert c["L_z"] == pytest.approx(182.4e-6) and c["tube_radius"] == pytest.approx(50e-6)
    assert c["v_c"] == pytest.approx(1.52e-3) and c["mu"] == pytest.approx(1.41)
    assert math.isnan(c["V"]) and c.line == 3
    assert capsules[1]["L_p"] == 0.0                  # a convex rear is a valid measurement


def test_pixels_are_converted_with_the_pixel_size(tmp_path):
    text = "id,L_z [px],L_p [px],tube_radius [px],pixel_size [um]\nc1,364.8,42,100,0.5\n"
    c = read_measurements(write(tmp_path, text), "tube")[0]
    assert c["L_z"] == pytest.approx(182.4e-6) and c["tube_radius"] == pytest.approx(50e-6)


def test_shear_file_units(tmp_path):
    text = "id,L1 [um],L2 [um],shear_rate [1/s],mu [mPa s]\ns1,52.1,23.5,350,756\n"
    c = read_measurements(write(tmp_path, text), "shear")[0]
    assert c["L1"] == pytest.approx(52.1e-6) and c["mu"] == pytest.approx(0.756)


BAD = [
    ("id,L_z [um],L_p [um]\nc1,1,0\n", 1, "tube_radius"),                                   # missing column
    ("id,L_z [inch],L_p [um],tube_radius [um]\nc1,1,0,1\n", 1, "L_z"),                       # unknown unit
    ("id,L_z [um],L_p [um],tube_radius [um],colour\nc1,1,0,1,red\n", 1, "colour"),           # unknown column
    ("id,L_z [um],L_p [um],tube_radius [um]\nc1,abc,0,1\n", 2, "L_z"),                       # not a number
    ("id,L_z [um],L_p [um],tube_radius [um]\nc1,nan,0,1\n", 2, "L_z"),                       # NaN
    ("id,L_z [um],L_p [um],tube_radius [um]\nc1,100,-3,50\n", 2, "L_p"),                     # negative
    ("id,L_z [um],L_p [um],tube_radius [um]\nc1,100,10,\n", 2, "tube_radius"),               # empty
    ("id,L_z [um],L_p [um],tube_radius [um]\nc1,100,10,50\nc1,90,5,50\n", 3, "c1"),          # duplicate id
    ("id,L_z [um],L_p [um],tube_radius [um]\nc1,100,10\n", 2, "fields"),                     # short row
    ("id,L_z [um],L_p [um],tube_radius [um]\nc1,100,120,50\n", 2, "L_p"),                    # L_p >= L_z
    ("id,L_z [px],L_p [px],tube_radius [px]\nc1,100,10,50\n", 2, "pixel_size"),              # px without size
    ("# only a comment\n", None, "no header"),
    ("id,L_z [um],L_p [um],tube_radius [um]\n", None, "no capsule"),
]


@pytest.mark.parametrize("text,line,field", BAD, ids=[b[2] + f"-{i}" for i, b in enumerate(BAD)])
def test_malformed_files_name_file_line_and_field(tmp_path, text, line, field):
    path = write(tmp_path, text, "bad.csv")
    with pytest.raises(MeasurementError) as err:
        read_measurements(path, "tube")
    message = str(err.value)
    assert str(path) in message and field in message
    if line is not None:
        assert f"{path}:{line}:" in message


def test_missing_file_is_an_error_naming_it(tmp_path):
    with pytest.raises(MeasurementError, match="cannot read"):
        read_measurements(tmp_path / "absent.csv", "tube")


@pytest.mark.parametrize("args, message", [
    (["--law", "XX"], "no law 'XX'"),
    (["--other-law", "GH_nu9"], "no law 'GH_nu9'"),
])
def test_diagnose_refuses_unknown_law_keys(args, message, capsys):
    from capsmech.cli.main import main

    root = Path(__file__).resolve().parents[2]
    assert main(["diagnose", str(root / "data" / "examples" / "tube_batch_NH.csv"), *args]) == 2
    assert message in capsys.readouterr().err
