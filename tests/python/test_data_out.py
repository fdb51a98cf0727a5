"""Data out that comes back in: every results file a command writes is read by another, every
command that reports a result writes it as JSON too, and an existing output is kept unless
``--force``.

- fit-tube's ``--out`` in both formats (.csv, .h5) reads back into ``population`` and
  ``capsmech.read_results``, with the same verdict and G_s (to the CSV's 6 digits);
- an HDF5 results file written here with h5py alone (not by capsmech) is read with its values
  and units; a file of another kind (a database) is refused in one line naming a dataset;
- each ``--json`` parses as strict JSON with the common head, and holds the values the command
  prints or writes to its CSV (fit-tube, fit-shear, population, compare-methods, diagnose-shear,
  extract, extract-shear, show, simulate, databases);
- a second run onto an existing output stops with exit 2 and keeps the file; ``--force``
  replaces it and says so.
"""
from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

import capsmech
from capsmech.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "data" / "examples"
LAWS = ("NH", "GH_nu0.5")


def run(argv: list[str]) -> int:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", capsmech.CapsmechWarning)
        return main(argv)


def strict_json(path: Path, command: str) -> dict:
    """The file as strict JSON (NaN refused), with the head every --json file has."""
    def no_constant(name: str) -> None:
        raise AssertionError(f"{path}: {name} is not JSON")

    data = json.loads(path.read_text(encoding="utf-8"), parse_constant=no_constant)
    assert data["command"] == command and data["capsmech"] == capsmech.__version__ and data["schema"] == 1
    return data


def csv_rows(path: Path) -> tuple[list[dict[str, str]], dict[str, str]]:
    """A results CSV read with the csv module: rows, and units from the 'name [unit]' header."""
    import csv

    lines = [line for line in path.read_text(encoding="utf-8").splitlines() if not line.startswith("#")]
    reader = csv.reader(lines)
    header = next(reader)
    names = [cell.split(" [")[0] for cell in header]
    units = {name: (cell[cell.index("[") + 1:-1] if "[" in cell else "") for name, cell in zip(names, header)}
    return [dict(zip(names, row)) for row in reader], units


def same_number(json_value: float | None, text: str, rel: float = 1e-5) -> bool:
    if json_value is None:
        return text.strip() in ("", "nan")
    return float(text) == pytest.approx(json_value, rel=rel, abs=1e-300)


@pytest.fixture(scope="module")
def fits(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The shipped NH example batch fitted once, written to CSV, HDF5 and JSON in one run."""
    folder = tmp_path_factory.mktemp("fits")
    paths = {suffix: folder / f"fit.{suffix}" for suffix in ("csv", "h5", "json")}
    assert run(["fit-tube", str(EXAMPLES / "tube_batch_NH.csv"), *[a for law in LAWS for a in ("--law", law)],
                "--out", str(paths["csv"]), "--out", str(paths["h5"]), "--json", str(paths["json"])]) == 0
    return paths


def test_population_reads_fit_tubes_hdf5_as_its_csv(fits: dict[str, Path], tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    from_csv, from_h5 = capsmech.population(fits["csv"]), capsmech.population(fits["h5"])
    assert from_csv.kind == from_h5.kind == "law" and from_csv.best == from_h5.best == "NH"
    assert from_csv.candidates == from_h5.candidates
    # The CSV holds 6 significant digits, the HDF5 file every one: G_s agrees to the CSV's.
    assert from_h5.g_s == pytest.approx(from_csv.g_s, rel=1e-5)
    assert from_h5.g_s_interval == pytest.approx(from_csv.g_s_interval, rel=1e-5)
    assert {law: e.status for law, e in from_h5.evidence.items()} == \
        {law: e.status for law, e in from_csv.evidence.items()}
    # The command line alike: the same verdict line from both files, once the numbers are rounded.
    lines = []
    for suffix in ("csv", "h5"):
        assert run(["population", str(fits[suffix]), "--json", str(tmp_path / f"{suffix}.json")]) == 0
        lines.append(next(t for t in capsys.readouterr().out.splitlines() if t.startswith("verdict: ")))
        data = strict_json(tmp_path / f"{suffix}.json", "population")
        assert data["law"] == "NH" and data["G_s"] == pytest.approx(from_csv.g_s, rel=1e-5)
    assert lines[0] == lines[1]


def test_read_results_gives_both_formats_the_same_table(fits: dict[str, Path]) -> None:
    csv_frame, h5_frame = capsmech.read_results(fits["csv"]), capsmech.read_results(fits["h5"])
    assert list(h5_frame.columns) == list(csv_frame.columns)
    assert h5_frame.attrs["units"] == csv_frame.attrs["units"]
    assert h5_frame.attrs["units"]["G_s"] == "N/m"
    for column, unit in csv_frame.attrs["units"].items():
        if unit:
            np.testing.assert_allclose(h5_frame[column].to_numpy(float), csv_frame[column].to_numpy(float),
                                       rtol=6e-6, equal_nan=True)
        else:
            assert list(h5_frame[column]) == list(csv_frame[column])
    # Every digit of the HDF5 file, read here with h5py alone.
    with h5py.File(fits["h5"], "r") as f:
        np.testing.assert_array_equal(h5_frame["G_s"].to_numpy(float), f["G_s"][()])


def test_an_hdf5_table_written_without_capsmech_is_read_with_its_units(tmp_path: Path) -> None:
    path = tmp_path / "by_hand.h5"
    g_s = np.array([0.041, 0.0395, np.nan])
    with h5py.File(path, "w") as f:
        # No column order recorded: HDF5 lists the datasets by name.
        for name, values, unit in (("id", ["a", "b", "c"], ""), ("law", ["NH"] * 3, ""),
                                   ("Delta", [0.1, 0.2, 0.3], "1"), ("G_s", g_s, "N/m"),
                                   ("flag", ["", "", "no_root"], "")):
            data = np.array(values, dtype=h5py.string_dtype()) if unit == "" else np.array(values, dtype=float)
            f.create_dataset(name, data=data).attrs["units"] = unit
    frame = capsmech.read_results(path)
    assert frame.attrs["units"] == {"Delta": "1", "G_s": "N/m", "flag": "", "id": "", "law": ""}
    np.testing.assert_array_equal(frame["G_s"].to_numpy(float), g_s)
    assert list(frame["id"]) == ["a", "b", "c"] and list(frame["flag"]) == ["", "", "no_root"]


def test_an_hdf5_file_of_another_kind_is_refused_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    from capsmech.io.catalog import database_path

    database = database_path("tube-paper")
    assert main(["population", str(database)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"capsmech: error: {database}") and "\n" not in err
    assert "dataset" in err and "NUL byte" not in err


def test_fit_tube_json_holds_the_csv_values(fits: dict[str, Path]) -> None:
    data = strict_json(fits["json"], "fit-tube")
    rows, units = csv_rows(fits["csv"])
    assert data["units"] == units and data["laws"] == list(LAWS)
    assert len(data["rows"]) == len(rows) == data["fits"]
    assert data["fitted"] == sum(1 for r in rows if r["flag"] == "")
    for got, row in zip(data["rows"], rows):
        for name, unit in units.items():
            if unit:
                assert same_number(got[name], row[name]), (name, got[name], row[name])
            else:
                assert got[name] == row[name]


def test_fit_shear_json_holds_the_printed_values(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    batch = EXAMPLES / "undeclared" / "shear_batch_L.csv"
    out = tmp_path / "shear.json"
    assert run(["fit-shear", str(batch), "--law", "NH", "--json", str(out), "--out", str(tmp_path / "s.h5")]) == 0
    printed = capsys.readouterr().out
    data = strict_json(out, "fit-shear")
    assert data["units"]["G_s"] == "N/m" and data["units"]["a"] == "m"
    back = capsmech.read_results(tmp_path / "s.h5")
    for got, (_, row) in zip(data["rows"], back.iterrows()):
        assert got["id"] == row["id"] and (got["G_s"] is None) == math.isnan(row["G_s"])
        if got["G_s"] is not None:
            assert got["G_s"] == row["G_s"]
            # The printed table, 4 significant digits.
            line = next(t for t in printed.splitlines() if t.split()[:2] == [got["id"], "NH"])
            assert any(float(cell) == pytest.approx(got["G_s"], rel=1e-3) for cell in line.split()[2:]
                       if re.fullmatch(r"[-+0-9.e]+", cell))


def test_compare_methods_json_holds_the_printed_table(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "compare.json"
    assert run(["compare-methods", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    data = strict_json(out, "compare-methods")
    assert [r["law"] for r in data["laws"]] == ["NH", "GH_nu0.5", "GH_nu0.2"]
    for law in data["laws"]:
        line = next(t for t in printed.splitlines() if t.startswith(f"| {law['law']} |"))
        ratio = float(re.search(r"×([0-9.]+)", line).group(1))
        assert ratio == pytest.approx(law["ratio_mean"], abs=5e-4)
        before = float(re.search(r": ([0-9.]+) -> ([0-9.]+) \|", line).group(1))
        assert before == pytest.approx(law["example_G_s_before"], abs=5e-5)


def test_diagnose_shear_json_holds_the_printed_verdict(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "diag.json"
    assert run(["diagnose-shear", str(EXAMPLES / "undeclared" / "shear_batch_L.csv"), "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    data = strict_json(out, "diagnose-shear")
    assert f"verdict: {data['verdict_text']}" in printed
    for candidate in data["candidates"]:
        line = next(t for t in printed.splitlines() if t.startswith(f"{candidate['name']}: "))
        if candidate["note"]:
            assert candidate["note"] in line
        else:
            assert f"BIC drop {candidate['bic_drop']:.1f}" in line
            assert ("not supported" not in line) == candidate["supported"]
    assert (data["chosen"] is None) == (data["verdict"] == "none")


def test_databases_json_names_what_the_list_prints(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "databases.json"
    assert run(["databases", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    data = strict_json(out, "databases")
    names = [line.split()[0] for line in printed.splitlines() if line[:1].strip() and not line.startswith("wrote ")]
    assert [d["name"] for d in data["databases"]] == names
    for entry in data["databases"]:
        assert Path(entry["path"]).is_file()
        if entry["kind"] == "database":
            # The version the file itself records, read here with h5py.
            with h5py.File(entry["path"], "r") as f:
                assert str(f.attrs["code_version"]) in entry["version"]


def test_extract_json_holds_the_measurement_csv(tmp_path: Path) -> None:
    out, js = tmp_path / "m.csv", tmp_path / "m.json"
    assert run(["extract", str(EXAMPLES / "frames" / "capsule_NH.tif"), "--mu", "1", "--out", str(out),
                "--json", str(js)]) == 0
    data = strict_json(js, "extract")
    measured = [r for r in data["rows"] if r["flag"] == ""]
    rows, units = csv_rows(out)
    assert [r["id"] for r in rows] == [r["id"] for r in measured]
    assert data["units"]["L_z"] == units["L_z"] == "um"
    for got, row in zip(measured, rows):
        for name in ("L_z", "L_p", "v_c"):
            assert same_number(got[name], row[name], rel=1e-4), name


def test_extract_shear_json_holds_the_measurement_csv(tmp_path: Path) -> None:
    from shear_frames import draw_frame, ellipse_outline
    from skimage.io import imsave

    frame = draw_frame([(ellipse_outline(30.0, 18.0, 35.0), (100.0, 90.0))], (180, 200), seed=1)
    image = tmp_path / "couette.png"
    imsave(image, frame, check_contrast=False)
    out, js = tmp_path / "s.csv", tmp_path / "s.json"
    assert run(["extract-shear", str(image), "--pixel-size", "1um", "--shear-rate", "100", "--mu", "1",
                "--out", str(out), "--json", str(js)]) == 0
    data = strict_json(js, "extract-shear")
    rows, units = csv_rows(out)
    assert len(data["rows"]) == len(rows) == 1
    # The drawn ellipse: D12 = (30 - 18) / (30 + 18) = 0.25, to the outline's pixels.
    assert data["rows"][0]["D12"] == pytest.approx(0.25, abs=0.02)
    assert data["units"]["L1"] == "um" and data["shear_rate"] == 100.0 and data["mu"] == 1.0
    lengths = {name: float(value) for name, value in rows[0].items() if name in ("L1", "L2")}
    # The CSV holds lengths in m (fit-shear's units), the JSON in um, as the table prints them.
    scale = 1e6 if units.get("L1") == "m" else 1.0
    for name, value in lengths.items():
        assert value * scale == pytest.approx(data["rows"][0][name], rel=1e-4)


@pytest.fixture(scope="module")
def kernel_case(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A short shear case run through ``capsmech simulate --json`` (skipped without a kernel)."""
    from capsmech.workflow.paths import capsim_executable

    try:
        capsim_executable()
    except FileNotFoundError as err:
        pytest.skip(f"no kernel: {err}")
    folder = tmp_path_factory.mktemp("case")
    case, js = folder / "case.h5", folder / "simulate.json"
    proc = subprocess.run([sys.executable, "-m", "capsmech.cli", "simulate", "--flow", "shear", "--law", "NH",
                           "--ca", "0.1", "--level", "1", "--t-max", "0.05", "--quiet", "--threads", "1",
                           "--out", str(case), "--json", str(js)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return case, js


def test_simulate_and_show_json_hold_the_case(kernel_case: tuple[Path, Path], tmp_path: Path) -> None:
    case, js = kernel_case
    simulated = strict_json(js, "simulate")
    # The run's own arguments, and what the kernel wrote in its file (read here with h5py).
    assert simulated["returncode"] == 0 and simulated["arguments"][:2] == ["--flow", "shear"]
    assert simulated["flow"] == "shear" and simulated["law"] == "NH" and simulated["Ca_s"] == 0.1
    with h5py.File(case, "r") as f:
        status = f.attrs["status"]
        assert simulated["status"] == (status.decode() if isinstance(status, bytes) else str(status)).strip()
    shown = tmp_path / "show.json"
    assert run(["show", str(case), "--json", str(shown)]) == 0
    data = strict_json(shown, "show")
    for key in ("flow", "law", "Ca_s", "status", "steady", "units", "code_version", "mesh_level"):
        assert data[key] == simulated[key]


def test_an_existing_output_is_kept_unless_force(fits: dict[str, Path], tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "pop.csv"
    out.write_text("a lab's own file\n", encoding="utf-8")
    assert main(["population", str(fits["csv"]), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"--out {out}: exists" in err and "--force" in err
    assert out.read_text(encoding="utf-8") == "a lab's own file\n"
    assert main(["population", str(fits["csv"]), "--out", str(out), "--force"]) == 0
    assert f"wrote {out} (replaced the file that was there)" in capsys.readouterr().out
    assert capsmech.read_results(out)["law"].iloc[0] in LAWS
    # The check comes before the work: a refused --json leaves the --out given with it unwritten.
    fresh = tmp_path / "fresh.h5"
    assert main(["population", str(fits["csv"]), "--out", str(fresh), "--json", str(out)]) == 2
    assert not fresh.exists()
