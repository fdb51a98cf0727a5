"""Measurement CSV files: unit conversion, and an error naming file, line and field for
every way a user can get a file wrong (nothing is half-read); what a spreadsheet adds when
it saves a CSV (byte-order mark, CRLF, ";" and decimal commas, Greek mu, extra columns,
another column order) reads the same as the plain file; the flow is inferred from the columns."""
from __future__ import annotations

import math
import warnings
from pathlib import Path

import pytest

from capsmech.errors import InputWarning
from capsmech.io.measurements import MeasurementError, read_measurements

SPREADSHEET = Path(__file__).resolve().parent / "data" / "spreadsheet"

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
    ("id,L_z [um],L_p [um],tube_radius [um]\nc1,abc,0,1\n", 2, "L_z"),                       # not a number
    ('id,L_z [um],L_p [um],tube_radius [um]\nc1,"100,5",0,1\n', 2, "L_z"),                   # decimal comma, ","
    ("id;L_z [um];L_p [um];tube_radius [um]\nc1;100;1,2,3;50\n", 2, "L_p"),                   # two commas, ";"
    ("id;L_z [um];L_p [um];tube_radius [um]\nc1;100;-0,5;50\n", 2, "L_p"),                    # negative, ";"
    ("id,L_z [\u03bcs],L_p [um],tube_radius [um]\nc1,1,0,1\n", 1, "L_z"),                     # Greek mu, bad unit
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


# --- Files a spreadsheet wrote -------------------------------------------------------------

def _cells(text: str, transform=lambda cells: cells, separator: str = ",") -> str:
    """``text`` with each non-comment line's cells passed through ``transform``, joined by ``separator``."""
    return "".join(line if line.startswith("#") else separator.join(transform(line.rstrip("\n").split(","))) + "\n"
                   for line in text.splitlines(keepends=True))


# Each habit alone, applied to TUBE; the file must read as TUBE does, with no warning.
HABITS = {
    "bom": lambda t: b"\xef\xbb\xbf" + t.encode(),
    "crlf": lambda t: t.replace("\n", "\r\n").encode(),
    "semicolon_decimal_comma": lambda t: _cells(t, lambda c: [x.replace(".", ",") for x in c], ";").encode(),
    "semicolon_decimal_point": lambda t: _cells(t, separator=";").encode(),
    "tab": lambda t: _cells(t, separator="\t").encode(),
    "greek_mu": lambda t: t.replace("[um]", "[\u03bcm]").encode(),
    "micro_sign": lambda t: t.replace("[um]", "[\u00b5m]").encode(),
    "micro_sign_cp1252": lambda t: t.replace("[um]", "[\u00b5m]").encode("cp1252"),   # Excel's plain "CSV"
    "nbsp_in_unit": lambda t: t.replace("Pa s", "Pa\u00a0s").encode(),
    "shuffled_columns": lambda t: _cells(t, lambda c: c[::-1]).encode(),
    "padded_with_empty_cells": lambda t: _cells(t, lambda c: c + ["", ""]).encode(),
}


@pytest.mark.parametrize("habit", HABITS)
def test_each_spreadsheet_habit_reads_as_the_plain_file(tmp_path, habit):
    plain = read_measurements(write(tmp_path, TUBE), "tube")
    path = tmp_path / f"{habit}.csv"
    path.write_bytes(HABITS[habit](TUBE))
    with warnings.catch_warnings():
        warnings.simplefilter("error")                   # nothing here is worth a warning
        assert read_measurements(path, "tube") == plain
        assert read_measurements(path) == plain          # and the flow is inferred


def test_semicolon_habit_really_has_decimal_commas(tmp_path):
    # Guards the test above: the transformed file is what a European spreadsheet writes.
    text = HABITS["semicolon_decimal_comma"](TUBE).decode()
    assert "c01;182,4;21,0;1,52;50,0;1,41" in text and "# two capsules, 100 um capillary" in text


@pytest.mark.parametrize("flow", ["tube", "shear"])
def test_spreadsheet_saved_file_equals_the_plain_one(flow):
    """BOM, CRLF, ";" with decimal commas, Greek mu and micro sign, a note column (with a quoted
    ";" in it), shuffled columns and padded rows, all at once, in committed bytes."""
    excel = SPREADSHEET / f"{flow}_excel.csv"
    raw = excel.read_bytes()
    assert raw.startswith(b"\xef\xbb\xbf") and b"\r\n" in raw and "\u03bcm".encode() in raw
    plain = read_measurements(SPREADSHEET / f"{flow}_plain.csv", flow)
    assert len(plain) == 4
    for explicit in (flow, None):
        with pytest.warns(InputWarning) as record:
            assert read_measurements(excel, explicit) == plain
        assert len(record) == 1
        assert str(record[0].message) == f"{excel}:2: ignored column(s) not in the {flow} format: 'note'"


def test_ignored_columns_warn_once_naming_exactly_them(tmp_path):
    text = ("id,colour,L_z [um],L_p [um],note,tube_radius [um],L1 [um]\n"
            "c1,red,100,10,first,50,3\nc2,blue,90,8,,50,4\n")
    path = write(tmp_path, text)
    with pytest.warns(InputWarning) as record:
        capsules = read_measurements(path, "tube")
    assert len(record) == 1
    # L1 is a shear column: in a tube file it is as foreign as a note.
    assert str(record[0].message).endswith("ignored column(s) not in the tube format: 'colour', 'note', 'L1 [um]'")
    assert [c.values for c in capsules] == [{"L_z": pytest.approx(100e-6), "L_p": pytest.approx(10e-6),
                                             "tube_radius": pytest.approx(50e-6)},
                                            {"L_z": pytest.approx(90e-6), "L_p": pytest.approx(8e-6),
                                             "tube_radius": pytest.approx(50e-6)}]


def test_a_refused_file_warns_of_nothing(tmp_path):
    path = write(tmp_path, "id,L_z [um],L_p [um],tube_radius [um],note\nc1,100,abc,50,x\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(MeasurementError, match=r"m.csv:2: field 'L_p'"):
            read_measurements(path)


def test_flow_is_inferred_from_the_columns(tmp_path):
    tube = read_measurements(write(tmp_path, TUBE, "t.csv"))
    assert tube == read_measurements(tmp_path / "t.csv", "tube")
    shear_text = "id,L1 [um],L2 [um],shear_rate [1/s],mu [mPa s]\ns1,52.1,23.5,350,756\n"
    shear = read_measurements(write(tmp_path, shear_text, "s.csv"))
    assert shear == read_measurements(tmp_path / "s.csv", "shear") and shear[0]["L1"] == pytest.approx(52.1e-6)
    # The flow decides the checks too: L2 > L1 is refused only because this is a shear file.
    write(tmp_path, "id,L1 [um],L2 [um],shear_rate [1/s],mu [Pa s]\ns1,20,30,350,1\n", "bad.csv")
    with pytest.raises(MeasurementError, match=r"bad.csv:2: field 'L2' must not exceed L1"):
        read_measurements(tmp_path / "bad.csv")


def test_columns_of_neither_flow_name_the_file_and_what_each_lacks(tmp_path):
    path = write(tmp_path, "# half of each\nid,L_z [um],L1 [um],mu [Pa s]\nc1,100,50,1\n", "half.csv")
    with pytest.raises(MeasurementError) as err:
        read_measurements(path)
    assert str(err.value) == (f"{path}:2: neither a tube nor a shear file, missing column(s) "
                              "for tube: L_p, tube_radius; for shear: L2, shear_rate")


def test_columns_of_both_flows_are_ambiguous_unless_the_flow_is_named(tmp_path):
    path = write(tmp_path, "id,L_z [um],L_p [um],tube_radius [um],L1 [um],L2 [um],shear_rate [1/s],mu [Pa s]\n"
                           "c1,100,10,50,60,25,350,1\n")
    with pytest.raises(MeasurementError, match=r"m.csv:1: .*both a tube and a shear file; name the flow"):
        read_measurements(path)
    with pytest.warns(InputWarning, match=r"not in the tube format: 'L1 \[um\]', 'L2 \[um\]', 'shear_rate \[1/s\]'$"):
        assert read_measurements(path, "tube")[0]["mu"] == 1.0


def test_an_explicit_flow_is_checked_against_the_columns(tmp_path):
    path = write(tmp_path, "id,L1 [um],L2 [um],shear_rate [1/s],mu [Pa s]\ns1,52.1,23.5,350,0.756\n")
    with pytest.raises(MeasurementError) as err:
        read_measurements(path, "tube")
    assert str(err.value) == (f"{path}:1: missing column(s) L_z, L_p, tube_radius for a tube file; "
                              "the header has the columns of a shear file")
    with pytest.raises(ValueError, match="flow must be"):
        read_measurements(path, "couette")


def test_a_misspelt_column_is_named_with_the_missing_one(tmp_path):
    path = write(tmp_path, "id,Lz [um],L_p [um],tube_radius [um]\nc1,100,10,50\n")
    with pytest.raises(MeasurementError, match=r"m.csv:1: missing column\(s\) L_z for a tube file; ignored: 'Lz \[um\]'"):
        read_measurements(path, "tube")


def test_bad_values_in_a_spreadsheet_file_still_name_file_line_and_field(tmp_path):
    raw = (SPREADSHEET / "tube_excel.csv").read_bytes()
    for old, new, field in [(b";12,9729;", b";abc;", "'L_p': 'abc' is not a number"),
                            (b";124,087;", b";-124,087;", "'L_z' must be positive"),
                            (b";s002;", b";s001;", "id 's001' already used on line 3")]:
        path = tmp_path / "bad.csv"
        path.write_bytes(raw.replace(old, new, 1))
        line = 4 if b"s001" in new else 3
        with pytest.raises(MeasurementError) as err:
            read_measurements(path)
        assert str(err.value).startswith(f"{path}:{line}: ") and field in str(err.value)
