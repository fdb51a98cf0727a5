"""Bad input from outside never gives a traceback (issue 25, item 4; the Python half of item 2).

Each defect the issue lists has a test here that failed before its fix. The contract of every
refusal is ``refused``: exit status 2, exactly one ``capsmech: error: ...`` line on stderr that
names the file (and the line and field where there is one), no traceback, and nothing on
stdout that says the work was done. The commands run in this process (``capsmech.cli.main``),
so that an exception escaping the CLI fails the test as a traceback would; a few run as
``python -m capsmech.cli`` in a subprocess, as a user runs them.
"""
from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

from capsmech import fit_tube
from capsmech.cli.main import main
from capsmech.errors import DatabaseError, InputWarning
from capsmech.io import measurements
from capsmech.io.catalog import CATALOG, database_path
from capsmech.io.contours import MAX_CONTOUR_BYTES, ContourError, read_contour
from capsmech.io.database import load_database
from capsmech.io.measurements import MeasurementError, read_measurements
from capsmech.workflow.assembly import _write_dataset
from capsmech.workflow.paths import capsim_executable

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "data" / "examples"
TUBE_HEADER = "id,L_z [um],L_p [um],v_c [mm/s],tube_radius [um],mu [Pa s]"
CONTOUR_HEADER = TUBE_HEADER + ",pixel_size [um],contour [px]"


def refused(capsys: pytest.CaptureFixture[str], argv: list[str], *names: str) -> str:
    """Run the CLI on ``argv``: exit 2, one error line naming each of ``names``; returns it."""
    code = main(argv)
    out, err = capsys.readouterr()
    errors = [line for line in err.splitlines() if not line.startswith("capsmech: warning:")]
    assert code == 2, (code, out, err)
    assert len(errors) == 1 and errors[0].startswith("capsmech: error: "), err
    assert "Traceback" not in out + err and "internal error" not in err
    for name in names:
        assert str(name) in errors[0], (name, errors[0])
    return errors[0]


def run_module(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "capsmech.cli", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT)


def ellipse(n: int = 60, a: float = 20.0, b: float = 12.0) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([100 + a * np.cos(t), 50 + b * np.sin(t)])


def write_contour_batch(tmp_path: Path, points: np.ndarray, name: str = "c.txt") -> Path:
    np.savetxt(tmp_path / name, points)
    csv = tmp_path / "batch.csv"
    csv.write_text(f"{CONTOUR_HEADER}\nc1,124,12,3.1,50,1,0.5,{name}\n")
    return csv


# --- Encodings -------------------------------------------------------------------------------


def test_latin1_measurement_file_is_read(tmp_path: Path) -> None:
    # 0x81 and 0x8d are not Windows-1252: before, such a file was refused (or a traceback).
    csv = tmp_path / "latin1.csv"
    csv.write_bytes(f"# r\xe9sum\xe9 \x81\x8d\n{TUBE_HEADER},note\nc1,124,12,3.1,50,1,d\xe9j\xe0 \x81\n"
                    .encode("latin-1"))
    with pytest.warns(InputWarning, match="note"):
        capsules = read_measurements(csv, "tube")
    assert [c.id for c in capsules] == ["c1"]
    assert capsules[0]["L_z"] == pytest.approx(124e-6)


def test_latin1_contour_file_is_read_by_fit_tube(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # The first capsule of the example batch, its contour file with a Latin-1 comment.
    batch = (EXAMPLES / "tube_batch_NH.csv").read_text().splitlines()
    header, row = next(line for line in batch if line.startswith("id,")), next(line for line in batch if line[:4] == "s001")
    contour = tmp_path / "c.txt"
    contour.write_bytes(b"# trac\xe9 \x81\n" + (EXAMPLES / "tube_batch_NH_contours" / "s001.txt").read_bytes())
    assert len(read_contour(contour)) > 8
    csv = tmp_path / "batch.csv"
    csv.write_text(f"{header}\n{row.split(',tube_batch_NH_contours')[0]},c.txt\n")
    assert main(["fit-tube", str(csv), "--database", "tube-dev", "--law", "NH"]) == 0
    assert "error" not in capsys.readouterr().err


def test_latin1_results_file_is_read_by_population(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    results = tmp_path / "results.csv"
    assert main(["fit-tube", str(EXAMPLES / "tube_batch_NH.csv"), "--database", "tube-dev",
                 "--out", str(results)]) == 0
    results.write_bytes(results.read_bytes().replace(b"s001", b"s\xe9\x81"))
    capsys.readouterr()
    assert main(["population", str(results)]) == 0
    assert "error" not in capsys.readouterr().err


# --- Degenerate contours ---------------------------------------------------------------------

DEGENERATE = {
    "all points equal": np.ones((20, 2)),
    "collinear": np.column_stack([np.linspace(0, 10, 20), 2 * np.linspace(0, 10, 20)]),
    "collinear along the axis": np.column_stack([np.linspace(0, 10, 20), np.full(20, 3.0)]),
    "scale 1e-300": 1e-300 * ellipse(),
    "scale 1e+300": 1e300 * ellipse(),
    "folded onto itself": np.vstack([ellipse(30)[:15], ellipse(30)[14::-1]]),
}


@pytest.mark.parametrize("kind", list(DEGENERATE))
def test_degenerate_contour_is_refused_naming_file_line_and_field(kind: str, tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    csv = write_contour_batch(tmp_path, DEGENERATE[kind])
    refused(capsys, ["fit-tube", str(csv), "--database", "tube-dev", "--law", "NH"],
            f"{csv}:2", "'contour'", tmp_path / "c.txt")


def test_contour_that_underflows_once_in_metres_is_refused(tmp_path: Path) -> None:
    # Extents of 2.4e-57 px are within the file's range; times a pixel of 0.5 um they are not.
    csv = write_contour_batch(tmp_path, 1e-58 * ellipse())
    with pytest.raises(MeasurementError, match=r"batch\.csv:2: field 'contour'.*in metres"):
        read_measurements(csv, "tube")


# --- One bad row flagged, not the batch lost -------------------------------------------------


def test_huge_length_is_refused_at_its_line(tmp_path: Path) -> None:
    """A length of 1e300 um is no unit slip (a factor 1e6 beyond any capsule): the file is refused
    at that line and field, not fitted into an 'outside the database' row."""
    csv = tmp_path / "huge.csv"
    csv.write_text(f"{TUBE_HEADER}\nok,120,10,3,50,1\nbad,1e300,10,3,50,1\n")
    with pytest.raises(MeasurementError, match=r"huge\.csv:3: field 'L_z': 1e\+300 um is not a physical value"):
        fit_tube(csv, "tube-dev", "NH")


def test_a_length_outside_the_database_is_flagged_and_the_batch_fitted(tmp_path: Path) -> None:
    """A length of 1 m is implausible but within a unit slip's reach (a warning): its row is flagged as
    outside the database, and the rest of the batch fitted."""
    csv = tmp_path / "long.csv"
    csv.write_text(f"{TUBE_HEADER}\nbad,1e6,10,3,50,1\nok,120,10,3,50,1\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        results = fit_tube(csv, "tube-dev", "NH")
    flags = dict(zip(results["id"], results["flag"]))
    assert flags == {"bad": "outside_database", "ok": ""}
    assert "database" in results.set_index("id").loc["bad", "reason"]


# --- Databases: truncated, damaged, checksummed ----------------------------------------------


@pytest.fixture(scope="module")
def smoke_database() -> bytes:
    return database_path("tube-smoke").read_bytes()


@pytest.mark.parametrize("fraction", [0.0, 0.01, 0.25, 0.5, 0.9, 1.0])
def test_truncated_database_is_refused_by_name(fraction: float, smoke_database: bytes, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    # From 100 bytes to one byte short of the whole file.
    size = 100 + int(fraction * (len(smoke_database) - 101))
    path = tmp_path / "tube.h5"
    path.write_bytes(smoke_database[:size])
    with pytest.raises(DatabaseError, match=str(path)):
        load_database(path)
    refused(capsys, ["fit-tube", str(EXAMPLES / "tube_batch_NH.csv"), "--database", str(path)], path)


@pytest.mark.validate
def test_database_truncated_at_every_size_is_refused(smoke_database: bytes, tmp_path: Path) -> None:
    path = tmp_path / "tube.h5"
    for size in range(100, len(smoke_database)):
        path.write_bytes(smoke_database[:size])
        with pytest.raises(DatabaseError, match=str(path)):
            load_database(path)


def _flip_byte_in(path: Path, dataset: str, offset: int = 3) -> None:
    with h5py.File(path, "r") as f:
        where = f[dataset].id.get_chunk_info(0).byte_offset + offset
    data = bytearray(path.read_bytes())
    data[where] ^= 0x10
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("dataset", ["NH/L_z", "NH/Ca_s", "NH/profile_r", "NH/status", "GH_nu0.5/vc_over_V"])
def test_flipped_byte_in_a_dataset_is_reported_not_read(dataset: str, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "tube.h5"
    shutil.copy(database_path("tube-smoke"), path)
    _flip_byte_in(path, dataset)
    with pytest.raises(DatabaseError, match=f"{path}: dataset '/{dataset}' cannot be read"):
        load_database(path)
    refused(capsys, ["fit-tube", str(EXAMPLES / "tube_batch_NH.csv"), "--database", str(path)], path, dataset)


@pytest.mark.parametrize("name", list(CATALOG))
def test_every_shipped_dataset_carries_a_checksum(name: str) -> None:
    with h5py.File(database_path(name), "r") as f:
        unchecked: list[str] = []
        f.visititems(lambda key, obj: unchecked.append(key)
                     if isinstance(obj, h5py.Dataset) and not obj.fletcher32 else None)
    assert unchecked == []


def test_assembly_writes_checksummed_datasets_that_read_back(tmp_path: Path) -> None:
    with h5py.File(tmp_path / "db.h5", "w") as f:
        group = f.create_group("NH")
        _write_dataset(group, "L_z", [1.5, np.nan, 2.25], "l")
        _write_dataset(group, "message", ["steady: ok", "", "caf\u00e9 failed"], "")
    with h5py.File(tmp_path / "db.h5", "r") as f:
        assert f["NH/L_z"].fletcher32 and f["NH/message"].fletcher32
        assert f["NH/message"].attrs["units"] == ""
        assert list(f["NH/message"].asstr()[()]) == ["steady: ok", "", "caf\u00e9 failed"]
        np.testing.assert_array_equal(f["NH/L_z"][()], [1.5, np.nan, 2.25])


@pytest.fixture(scope="module")
def case_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small shear case written by the kernel (skipped without one)."""
    try:
        capsim = capsim_executable()
    except FileNotFoundError as err:
        pytest.skip(f"no kernel: {err}")
    out = tmp_path_factory.mktemp("case") / "case.h5"
    subprocess.run([str(capsim), "--flow", "shear", "--law", "NH", "--ca", "0.1", "--level", "1", "--t-max", "0.05",
                    "--quiet", "--threads", "1", "--out", str(out)], check=True, timeout=120)
    return out


@pytest.mark.parametrize("fraction", [0.0, 0.3, 0.7, 1.0])
def test_truncated_case_file_is_refused_by_name(fraction: float, case_file: Path, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    data = case_file.read_bytes()
    path = tmp_path / "case.h5"
    path.write_bytes(data[:100 + int(fraction * (len(data) - 101))])
    refused(capsys, ["show", str(path)], path)


def test_flipped_byte_in_a_checksummed_case_file_is_reported(case_file: Path, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    # The kernel's own Fletcher-32 is the kernel's part of item 2; the reader is checked here on
    # the case file rewritten with the filter (scripts/checksum_databases.py works on any file).
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        from checksum_databases import add_checksums
    finally:
        sys.path.remove(str(ROOT / "scripts"))
    path = tmp_path / "case.h5"
    shutil.copy(case_file, path)
    add_checksums(path)
    assert main(["show", str(path)]) == 0
    capsys.readouterr()
    _flip_byte_in(path, "history/D12")
    refused(capsys, ["show", str(path)], path, "corrupt")


# --- Options checked before the work ---------------------------------------------------------


def test_unknown_law_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    refused(capsys, ["fit-tube", str(EXAMPLES / "tube_batch_NH.csv"), "--database", "tube-dev", "--law", "XX"],
            "--law", "'XX'", "NH")


@pytest.mark.parametrize("out", ["x.txt", "folder", "missing/x.csv"])
def test_bad_out_is_refused_before_the_fit(out: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "folder").mkdir()
    line = refused(capsys, ["fit-tube", str(EXAMPLES / "tube_batch_NH.csv"), "--database", "tube-dev",
                            "--out", str(tmp_path / out)], "--out", tmp_path / out)
    assert "is a directory" in line or "suffix" in line or "does not exist" in line


def test_bad_out_leaves_no_table_printed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["fit-shear", str(EXAMPLES / "tube_batch_NH.csv"), "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().out == ""        # refused before the database, the CSV or the fit


def test_out_on_a_pipe_or_device_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # The temporary-file-and-rename write would replace them with a regular file.
    pipe = tmp_path / "pipe.csv"
    os.mkfifo(pipe)
    refused(capsys, ["fit-tube", str(EXAMPLES / "tube_batch_NH.csv"), "--database", "tube-dev",
                     "--out", str(pipe)], "--out", pipe, "not a regular file")
    assert stat.S_ISFIFO(pipe.stat().st_mode)
    refused(capsys, ["population", str(EXAMPLES / "tube_batch_NH.csv"), "--json", "/dev/null"], "--json",
            "/dev/null")


def test_run_case_out_directory_is_refused_before_the_kernel(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    # A kernel that does not exist proves nothing was run.
    refused(capsys, ["dev", "run-case", "--out", str(tmp_path), "--code-version", "0", "--capsim",
                     str(tmp_path / "no-capsim"), "--", "--flow", "shear", "--law", "NH", "--ca", "0.1"],
            "--out", tmp_path, "directory")


def test_unknown_grid_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    refused(capsys, ["dev", "check-grid", str(ROOT / "config" / "typo.yaml")], "typo.yaml", "smoke")


def test_grid_that_is_not_yaml_names_its_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    grid = tmp_path / "bad.yaml"
    grid.write_text("name: x\ntube: [1,\n")
    refused(capsys, ["dev", "check-grid", str(grid)], f"{grid}:3", "not YAML")


def test_make_database_checks_the_grid_before_snakemake() -> None:
    recipe = (ROOT / "Makefile").read_text().split("\ndatabase: setup\n")[1].split("\n\n")[0]
    lines = [line.strip() for line in recipe.splitlines()]
    assert "check-grid config/$(GRID).yaml" in lines[0]
    assert any("$(SNAKEMAKE)" in line for line in lines[1:])


# --- Results files for population ------------------------------------------------------------


def test_population_on_an_empty_file_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    refused(capsys, ["population", str(empty)], empty)


def test_population_on_a_measurement_file_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    path = EXAMPLES / "tube_batch_NH.csv"
    refused(capsys, ["population", str(path)], path, "id", "law")


def test_population_on_shear_results_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    shear = tmp_path / "shear.csv"
    shear.write_text("id,L1 [um],L2 [um],shear_rate [1/s],mu [Pa s]\ns1,52.1,23.5,350,0.756\n")
    results = tmp_path / "fit.csv"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        main(["fit-shear", str(shear), "--database", "shear-dev", "--out", str(results)])
    capsys.readouterr()
    refused(capsys, ["population", str(results)], results, "Delta")


def test_population_header_only_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "header.csv"
    path.write_text("id,law,Delta [1],G_s [N/m],H_over_a [1],flag,reason\n")
    refused(capsys, ["population", str(path)], path, "no result rows")


def test_population_row_with_missing_fields_names_its_line(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "short.csv"
    path.write_text("id,law,Delta [1],G_s [N/m],flag,reason\nc1,NH,0.1,0.04,,\nc2,NH\n")
    refused(capsys, ["population", str(path)], f"{path}:3")


# --- Comments and ids ------------------------------------------------------------------------


def test_quoted_id_starting_with_hash_is_a_capsule(tmp_path: Path) -> None:
    csv = tmp_path / "hash.csv"
    csv.write_text(f'{TUBE_HEADER}\n"#1",120,10,3,50,1\nok,121,10,3,50,1\n')
    assert [c.id for c in read_measurements(csv, "tube")] == ["#1", "ok"]


def test_commented_row_is_named_not_dropped_silently(tmp_path: Path) -> None:
    csv = tmp_path / "hash.csv"
    csv.write_text(f"# made by hand\n{TUBE_HEADER}\n#1,120,10,3,50,1\n# a note\nok,121,10,3,50,1\n")
    with pytest.warns(InputWarning, match=r"hash\.csv: comment line\(s\) 3 \(#1\)") as caught:
        capsules = read_measurements(csv, "tube")
    assert [c.id for c in capsules] == ["ok"]
    assert "4" not in str(caught[0].message).split("line(s)")[1].split("have")[0]   # a plain comment is not named


# --- Size limits -----------------------------------------------------------------------------


def test_rows_beyond_the_limit_are_refused_naming_the_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(measurements, "MAX_CAPSULES", 5)
    csv = tmp_path / "big.csv"
    csv.write_text(TUBE_HEADER + "\n" + "".join(f"c{i},120,10,3,50,1\n" for i in range(6)))
    with pytest.raises(MeasurementError, match=r"big\.csv:7: more than 5 capsule rows"):
        read_measurements(csv, "tube")
    csv.write_text(TUBE_HEADER + "\n" + "".join(f"c{i},120,10,3,50,1\n" for i in range(5)))
    assert len(read_measurements(csv, "tube")) == 5


def test_million_row_file_is_refused_at_once(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    csv = tmp_path / "million.csv"
    row = "c{},120.5,10.25,3.125,50,1\n"
    with open(csv, "w") as stream:
        stream.write(TUBE_HEADER + "\n")
        stream.writelines(row.format(i) for i in range(1_000_000))
    refused(capsys, ["fit-tube", str(csv), "--database", "tube-dev", "--law", "NH"], csv, "split")


@pytest.mark.parametrize("target", ["csv", "contour"])
def test_dev_zero_is_refused_without_reading_it_whole(target: str, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    if target == "csv":
        refused(capsys, ["fit-tube", "/dev/zero", "--database", "tube-dev"], "/dev/zero", "MiB")
    else:
        csv = tmp_path / "zero.csv"
        csv.write_text(f"{TUBE_HEADER},contour [um]\nc1,120,10,3,50,1,/dev/zero\n")
        refused(capsys, ["fit-tube", str(csv), "--database", "tube-dev"], f"{csv}:2", "'contour'", "/dev/zero")


def test_contour_over_the_limit_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "long.txt"
    line = b"123.456 78.9\n"
    path.write_bytes(line * (MAX_CONTOUR_BYTES // len(line) + 1))
    with pytest.raises(ContourError, match="larger than 8 MiB"):
        read_contour(path)


def test_binary_file_is_refused_naming_its_line(tmp_path: Path) -> None:
    path = tmp_path / "binary.csv"
    path.write_bytes(TUBE_HEADER.encode() + b"\nc1,120,10,3,50,1\n\x00\x01\x02")
    with pytest.raises(MeasurementError, match=r"binary\.csv:3: a NUL byte"):
        read_measurements(path, "tube")


# --- As a user runs it -----------------------------------------------------------------------


def test_module_run_prints_one_line_and_no_traceback(tmp_path: Path) -> None:
    csv = write_contour_batch(tmp_path, DEGENERATE["all points equal"])
    result = run_module("fit-tube", str(csv), "--database", "tube-dev", "--law", "NH")
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("capsmech: error: ")
    assert "Traceback" not in result.stdout + result.stderr


def test_closed_pipe_ends_quietly(tmp_path: Path) -> None:
    # `capsmech fit-tube ... | head`: the reader goes away long before the table's 3,000 lines
    # are printed (more than a pipe's buffer); no traceback, no "internal error".
    csv = tmp_path / "batch.csv"
    csv.write_text(TUBE_HEADER + "\n" + "".join(f"c{i},{120 + i % 10},10,3,50,1\n" for i in range(3000)))
    err = tmp_path / "err.txt"
    subprocess.run(f"'{sys.executable}' -m capsmech.cli fit-tube '{csv}' --database tube-dev --law NH 2>'{err}' "
                   "| head -c 10 >/dev/null", shell=True, check=True, timeout=300, cwd=ROOT)
    assert err.read_text() == ""
