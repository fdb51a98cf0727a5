"""Measurements as labs keep them: the same capsules written as a UTF-16 or BOM export, with
units in ``( )``, lower-case headers, decimal commas, an ``.xlsx`` sheet, or handed over as a
pandas DataFrame (``pd.read_csv`` of the file, units in the column names or in ``attrs``), give
the same fitted G_s as the plain CSV; each way of getting it wrong gives one message that names
the file (or the DataFrame), the line (or row) and the field.

The capsules are the first three of the shipped NH example batch (kernel-made), read here with
the standard library's csv module, not with the reader under test; every variant is written by
this file (openpyxl writes the workbook).
"""
from __future__ import annotations

import csv
import importlib.util
import sys
from pathlib import Path

import pandas as pd
import pytest

from capsmech import api
from capsmech.io.database import load_database
from capsmech.io.measurement_frames import read_batch
from capsmech.io.measurements import MeasurementError, read_measurements

EXAMPLE = Path(__file__).resolve().parents[2] / "data" / "examples" / "tube_batch_NH.csv"
#: Column, unit as the canonical file writes it, the same unit spelt otherwise.
COLUMNS = [("L_z", "um", "µm"), ("L_p", "um", "μm"), ("v_c", "mm/s", "mm/s"), ("tube_radius", "um", "µm"),
           ("mu", "Pa s", "Pa·s")]
HAS_OPENPYXL = importlib.util.find_spec("openpyxl") is not None


def _example_rows(n: int = 3) -> list[list[str]]:
    """The first ``n`` capsules of the example batch: id and the COLUMNS' values as written there."""
    lines = [line for line in EXAMPLE.read_text(encoding="utf-8").splitlines() if not line.startswith("#")]
    records = list(csv.DictReader(lines))[:n]
    return [[r["id"], *(r[f"{name} [{unit}]"] for name, unit, _ in COLUMNS)] for r in records]


ROWS = _example_rows()
HEADER = ["id", *(f"{name} [{unit}]" for name, unit, _ in COLUMNS)]


def _text(header: list[str], rows: list[list[str]], separator: str = ",", comma: bool = False) -> str:
    cells = [header, *([c.replace(".", ",") for c in row] if comma else row for row in rows)]
    return "# three capsules of the NH example\n" + "\n".join(separator.join(row) for row in cells) + "\n"


@pytest.fixture(scope="module")
def database():
    return load_database("tube-dev")


@pytest.fixture(scope="module")
def canonical(tmp_path_factory, database) -> pd.Series:
    path = tmp_path_factory.mktemp("canonical") / "batch.csv"
    path.write_text(_text(HEADER, ROWS), encoding="utf-8")
    g_s = api.fit_tube(path, database, "NH")["G_s"]
    assert g_s.notna().all() and ((g_s > 0.02) & (g_s < 0.08)).all()     # the batch was made at G_s 0.04 N/m
    return g_s


def _write_xlsx(path: Path, header: list[str], rows: list[list[str]]) -> None:
    openpyxl = pytest.importorskip("openpyxl", reason="openpyxl (optional) is not installed")
    book = openpyxl.Workbook()
    sheet = book.active
    sheet.append(["# three capsules of the NH example"])
    sheet.append(header)
    for row in rows:
        sheet.append([row[0], *(float(c) for c in row[1:])])     # numbers as numeric cells
    book.save(path)


#: Each form a lab's tools write, as (file name, writer of the file).
FORMS = {
    "utf16_tab_export": ("batch.txt", lambda p: p.write_text(_text(HEADER, ROWS, "\t"), encoding="utf-16")),
    "utf16_without_bom": ("batch.csv", lambda p: p.write_bytes(_text(HEADER, ROWS).encode("utf-16-le"))),
    "utf8_bom": ("batch.csv", lambda p: p.write_text(_text(HEADER, ROWS), encoding="utf-8-sig")),
    "parenthesised_units": ("batch.csv", lambda p: p.write_text(_text(
["id", *(f"{name} ({other})" for name, _, other in COLUMNS)], ROWS), encoding="utf-8")),
    "lower_case_headers": ("batch.csv", lambda p: p.write_text(_text(
        ["ID", *(f"{name.lower()} [{unit.upper() if name == 'mu' else unit}]" for name, unit, _ in COLUMNS)],
        ROWS), encoding="utf-8")),
    "middle_dot_unit": ("batch.csv", lambda p: p.write_text(_text(
        ["id", *(f"{name} [{other if name == 'mu' else unit}]" for name, unit, other in COLUMNS)], ROWS),
        encoding="utf-8")),
    "semicolon_decimal_comma": ("batch.csv", lambda p: p.write_text(_text(HEADER, ROWS, ";", comma=True),
                                                                     encoding="cp1252")),
    "tab_decimal_comma": ("batch.tsv", lambda p: p.write_text(_text(HEADER, ROWS, "\t", comma=True))),
    "xlsx": ("batch.xlsx", lambda p: _write_xlsx(p, HEADER, ROWS)),
}


@pytest.mark.parametrize("form", FORMS)
def test_each_file_form_gives_the_canonical_g_s(tmp_path, form, database, canonical):
    name, write = FORMS[form]
    path = tmp_path / name
    write(path)
    fitted = api.fit_tube(path, database, "NH")
    assert list(fitted["id"]) == [row[0] for row in ROWS]
    assert fitted["G_s"].to_numpy() == pytest.approx(canonical.to_numpy(), rel=1e-12)


def _frames(tmp_path: Path) -> dict[str, pd.DataFrame]:
    path = tmp_path / "batch.csv"
    path.write_text(_text(HEADER, ROWS), encoding="utf-8")
    european = tmp_path / "european.csv"
    european.write_text(_text(HEADER, ROWS, ";", comma=True), encoding="utf-8")
    plain_names = pd.read_csv(path, comment="#").rename(columns=lambda c: c.split(" [")[0])
    plain_names.attrs["units"] = {name: unit for name, unit, _ in COLUMNS}
    return {"read_csv": pd.read_csv(path, comment="#"),
            "read_csv_decimal_comma": pd.read_csv(european, comment="#", sep=";", decimal=","),
            "units_in_attrs": plain_names,
            "read_batch": read_batch(path)}


def test_each_dataframe_gives_the_canonical_g_s(tmp_path, database, canonical):
    for form, frame in _frames(tmp_path).items():
        fitted = api.fit_tube(frame, database, "NH")
        assert fitted["G_s"].to_numpy() == pytest.approx(canonical.to_numpy(), rel=1e-12), form


def test_read_batch_is_si_with_units_in_attrs(tmp_path):
    path = tmp_path / "batch.csv"
    path.write_text(_text(HEADER, ROWS), encoding="utf-8")
    frame = read_batch(path)
    assert frame.attrs["units"] == {"id": "", "L_z": "m", "L_p": "m", "tube_radius": "m", "v_c": "m/s", "mu": "Pa s",
                                    "line": ""}
    assert frame.attrs["flow"] == "tube" and frame.attrs["source"] == str(path)
    assert list(frame["id"]) == [row[0] for row in ROWS] and list(frame["line"]) == [3, 4, 5]
    assert frame["L_z"].to_numpy() == pytest.approx([float(row[1]) * 1e-6 for row in ROWS], rel=1e-15)
    assert frame["v_c"].to_numpy() == pytest.approx([float(row[3]) * 1e-3 for row in ROWS], rel=1e-15)
    assert [c.values for c in read_measurements(path)] == frame[["L_z", "L_p", "tube_radius", "v_c", "mu"]].to_dict(
        "records")


def test_an_edited_batch_frame_is_checked_and_named_by_the_files_line(tmp_path, database):
    path = tmp_path / "batch.csv"
    path.write_text(_text(HEADER, ROWS), encoding="utf-8")
    frame = read_batch(path)
    frame.loc[1, "L_p"] = frame.loc[1, "L_z"] * 2
    with pytest.raises(MeasurementError) as err:
        api.fit_tube(frame, database, "NH")
    assert str(err.value) == f"{path}:4: field 'L_p' must be smaller than L_z"


def _refusal(call) -> str:
    with pytest.raises(MeasurementError) as err:
        call()
    return str(err.value)


def test_a_dataframe_without_units_names_every_column_missing_one(tmp_path, database):
    frame = pd.DataFrame([[row[0], *map(float, row[1:])] for row in ROWS], columns=["id", *(c[0] for c in COLUMNS)])
    message = _refusal(lambda: api.fit_tube(frame, database, "NH"))
    assert message.startswith("DataFrame columns: column(s) L_z, L_p, v_c, tube_radius, mu without a unit")
    assert "DataFrame.attrs['units']" in message and "'L_z [um]'" in message


def test_a_dataframe_row_is_named_by_its_index_label(database):
    frame = pd.DataFrame([[row[0], *map(float, row[1:])] for row in ROWS], columns=HEADER,
                         index=["first", "second", "third"])
    frame.loc["second", "mu [Pa s]"] = float("nan")
    frame.loc["third", "L_z [um]"] = -5.0
    assert _refusal(lambda: api.fit_tube(frame, database, "NH")) == "DataFrame row 'third': field 'L_z' must be " \
                                                                    "positive, got -5.0"


def test_decimal_commas_read_without_decimal_get_the_pandas_hint(tmp_path, database):
    path = tmp_path / "european.csv"
    path.write_text(_text(HEADER, ROWS, ";", comma=True), encoding="utf-8")
    frame = pd.read_csv(path, comment="#", sep=";")
    message = _refusal(lambda: api.fit_tube(frame, database, "NH"))
    assert message.startswith("DataFrame row 0: field 'L_z': '") and "decimal=','" in message


@pytest.mark.parametrize("quoted", [True, False])
def test_decimal_commas_in_a_comma_separated_file_are_hinted_at_their_line(tmp_path, quoted):
    path = tmp_path / "batch.csv"
    rows = [[f'"{c}"' if quoted and i else c for i, c in enumerate(row)] for row in ROWS]
    path.write_text(_text(HEADER, rows, ",", comma=True), encoding="utf-8")
    message = _refusal(lambda: read_measurements(path))
    assert message.startswith(f"{path}:3: ") and "decimal comma" in message
    assert ("field 'L_z'" in message) if quoted else ("fields, the header has 6" in message)


@pytest.mark.parametrize("column, cell, accepted", [
    (1, "L_z (inch)", "unknown length unit 'inch' (expected one of m, mm, um, nm, px)"),
    (2, "l_p [ms]", "unknown length unit 'ms' (expected one of m, mm, um, nm, px)"),
    (3, "V_C [um]", "unknown velocity unit 'um' (expected one of m/s, mm/s, um/s)"),   # a length as velocity
])
def test_an_unknown_unit_names_the_column_and_the_units_accepted(tmp_path, column, cell, accepted):
    path = tmp_path / "batch.csv"
    header = [*HEADER[:column], cell, *HEADER[column + 1:]]
    path.write_text(_text(header, ROWS), encoding="utf-8")
    name = COLUMNS[column - 1][0]
    assert _refusal(lambda: read_measurements(path)) == f"{path}:2: column '{name}': {accepted}"


def test_a_workbook_without_openpyxl_says_what_to_install(tmp_path, monkeypatch):
    path = tmp_path / "batch.xlsx"
    path.write_bytes(b"PK\x03\x04" + bytes(64))
    monkeypatch.setitem(sys.modules, "openpyxl", None)        # an import of it now fails
    assert _refusal(lambda: read_measurements(path)) == (f"{path}: an Excel workbook; reading it needs openpyxl "
                                                         "(pip install openpyxl), or save the sheet as CSV")


@pytest.mark.skipif(not HAS_OPENPYXL, reason="openpyxl (optional) is not installed")
def test_bad_workbooks_name_the_file_and_the_sheets_row(tmp_path):
    damaged = tmp_path / "damaged.xlsx"
    damaged.write_bytes(b"PK\x03\x04" + bytes(64))
    assert _refusal(lambda: read_measurements(damaged)).startswith(f"{damaged}: not a readable .xlsx workbook")
    path = tmp_path / "batch.xlsx"
    _write_xlsx(path, HEADER, [ROWS[0], [ROWS[1][0], "-1", *ROWS[1][2:]]])
    assert _refusal(lambda: read_measurements(path)) == f"{path}:4: field 'L_z' must be positive, got -1"


def test_an_xls_workbook_is_refused_with_what_to_save_it_as(tmp_path):
    path = tmp_path / "batch.xls"
    path.write_bytes(b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1" + bytes(504))
    assert "save it as .xlsx or CSV" in _refusal(lambda: read_measurements(path))


def test_something_else_than_measurements_is_one_clear_error(database):
    assert _refusal(lambda: api.fit_tube(42, database, "NH")) == ("measurements: a file path, a pandas DataFrame "
                                                                  "or a list of Capsule, not int")
    assert "not list" in _refusal(lambda: api.fit_tube([{"id": "c1"}], database, "NH"))


SHEAR = Path(__file__).resolve().parent / "data" / "spreadsheet" / "shear_plain.csv"


def test_a_shear_batch_as_a_dataframe_gives_the_files_g_s():
    database = load_database("shear-dev")
    from_file = api.fit_shear(SHEAR, database, "NH")["G_s"]
    assert from_file.notna().all() and ((from_file > 0.02) & (from_file < 0.08)).all()   # made at 0.04 N/m
    frames = {"read_csv": pd.read_csv(SHEAR, comment="#"), "id_as_index": pd.read_csv(SHEAR, comment="#", index_col="id"),
              "read_batch": read_batch(SHEAR)}
    for form, frame in frames.items():
        fitted = api.fit_shear(frame, database, "NH")
        assert fitted["G_s"].to_numpy() == pytest.approx(from_file.to_numpy(), rel=1e-12), form


def test_contours_come_along_in_every_form(tmp_path, monkeypatch, database):
    """A capsule of the example batch with its contour file: the contour's misfit H/a is
    the same from the file, from ``read_batch`` (contours held as arrays) and from
    ``pd.read_csv`` (contour paths, relative to the current folder)."""
    lines = EXAMPLE.read_text(encoding="utf-8").splitlines()
    header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    kept = lines[header:header + 2]
    (tmp_path / "contours").mkdir()
    for row in kept[1:]:
        contour = row.rsplit(",", 1)[1]
        (tmp_path / "contours" / Path(contour).name).write_bytes((EXAMPLE.parent / contour).read_bytes())
    path = tmp_path / "batch.csv"
    path.write_text("\n".join(line.replace("tube_batch_NH_contours/", "contours/") for line in kept) + "\n")
    from_file = api.fit_tube(path, database, "NH")
    assert from_file["H_over_a"].notna().all()
    monkeypatch.chdir(tmp_path)
    for form, frame in {"read_batch": read_batch(path), "read_csv": pd.read_csv("batch.csv")}.items():
        fitted = api.fit_tube(frame, database, "NH")
        for column in ("G_s", "H_over_a"):
            assert fitted[column].to_numpy() == pytest.approx(from_file[column].to_numpy(), rel=1e-12), (form, column)
