"""The Python reproducers of the second outside fault campaign, run as a user runs them.

The contract for each: exit 2 and one line ``capsmech: error: ...`` naming the file (and the
line and field, or the member), no traceback and no "internal error", nothing written or read
outside its place, memory bounded. ``test_files_in_their_place.py``, ``test_full_disk.py``,
``test_frame_memory_bounds.py`` and ``test_rtdc_data_elsewhere.py`` pin the first form of each
fault; these are the campaign's exact inputs and the forms that were still open: ids given to
extract-shear, a contour reached through a symbolic link, diagnose's way to allow contours
elsewhere, HDF5 databases and results files whose data live in another file (they were
followed), HDF5 output on a full disk (its error was two lines), a read-only file system, the
exact 60 x 8000 x 8000 px TIFF under an address-space limit, and the smoke database named.
"""
from __future__ import annotations

import resource
import shutil
import subprocess
import sys
import zlib
from pathlib import Path

import h5py
import numpy as np
import pytest
import small_disk
import tifffile

from capsmech.io.catalog import database_path
from capsmech.io.database import DatabaseError, load_database
from capsmech.io.measurements import MeasurementError, read_measurements
from capsmech.io.results import ResultsFileError, read_results_table

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "data" / "examples" / "tube_batch_NH.csv"
FILM = ROOT / "data" / "examples" / "frames" / "capsule_NH.tif"
HEADER = "id,L_z [um],L_p [um],v_c [mm/s],tube_radius [um],mu [Pa s],pixel_size [um],contour [px]"
#: What no test input may make a command print.
CRASH_WORDS = ("Traceback", "internal error", "Error allocating")


def capsmech(*args: str, cwd: Path, address_space: int | None = None) -> subprocess.CompletedProcess:
    """The command as a user runs it; `address_space` [bytes] bounds its memory (RLIMIT_AS)."""
    def limit() -> None:
        if address_space is not None:
            resource.setrlimit(resource.RLIMIT_AS, (address_space, address_space))
    return subprocess.run([sys.executable, "-m", "capsmech.cli", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=120, preexec_fn=limit)


def one_error_line(result: subprocess.CompletedProcess) -> str:
    assert result.returncode == 2, (result.returncode, result.stderr)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("capsmech: error: "), result.stderr
    assert not any(word in result.stderr for word in CRASH_WORDS), result.stderr
    return lines[0]


def tree(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


# -- names from user input never leave the output folder -------------------------------------------------------

@pytest.mark.parametrize("capsule_id", ["../../ESCAPED", "{absolute}"])
def test_extract_shear_refuses_an_id_that_is_a_path_before_any_file(tmp_path: Path, capsule_id: str) -> None:
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    given = capsule_id.format(absolute=tmp_path / "ABS")
    line = one_error_line(capsmech("extract-shear", str(FILM), "--id", given, "--shear-rate", "350", "--mu", "0.756",
                                   "--pixel-size", "0.5um", "--out", "m.csv", cwd=work))
    assert "--id" in line and repr(given) in line
    assert tree(tmp_path) == ["a", "a/b"]


# -- contours are read only inside the measurement file's folder ----------------------------------------------

def _batch_naming(tmp_path: Path, cell: str) -> Path:
    batch = tmp_path / "batch"
    batch.mkdir()
    (batch / "link.txt").symlink_to("/etc/passwd")
    (batch / "m.csv").write_text(f"{HEADER}\na,120,10,3,50,1,0.5,{cell}\n")
    return batch / "m.csv"


@pytest.mark.parametrize("cell", ["../../../../etc/passwd", "../" * 40 + "etc/passwd", "link.txt"])
def test_a_contour_cell_reaching_outside_is_refused_unread(tmp_path: Path, cell: str) -> None:
    """The campaign's cell, one that does reach /etc/passwd, and a link in the folder to it."""
    with pytest.raises(MeasurementError, match=r"m\.csv:2: field 'contour': .* outside the measurement file's "
                                                r"folder") as refused:
        read_measurements(_batch_naming(tmp_path, cell))
    assert "root:" not in str(refused.value) and "nologin" not in str(refused.value)   # nothing echoed


def test_diagnose_takes_the_option_its_refusal_names(tmp_path: Path) -> None:
    """Contours in a sibling folder: refused on one line naming '--contours-anywhere'; diagnose
    takes it (it answered 'unrecognized arguments') and then reads the contours: the run goes on
    to the database, which is too small."""
    batch, elsewhere = tmp_path / "batch", tmp_path / "elsewhere"
    batch.mkdir()
    shutil.copytree(EXAMPLE.with_name("tube_batch_NH_contours"), elsewhere / "contours")
    text = EXAMPLE.read_text().replace("tube_batch_NH_contours/", "../elsewhere/contours/")
    (batch / "m.csv").write_text(text)
    refused = one_error_line(capsmech("diagnose", "batch/m.csv", cwd=tmp_path))
    assert "--contours-anywhere" in refused
    allowed = one_error_line(capsmech("diagnose", "batch/m.csv", "--contours-anywhere", "--database", "tube-smoke",
                                      cwd=tmp_path))
    assert "steady rows" in allowed and "outside the measurement file's folder" not in allowed


# -- HDF5 inputs are read from their own bytes only -----------------------------------------------------------

def _relinked(source: Path, path: Path, how: str) -> Path:
    """A copy of `source` whose top-level members live in another file (a copy of it, beside)."""
    other = path.with_name("elsewhere.h5")
    shutil.copy(source, other)
    with h5py.File(source) as src, h5py.File(path, "w") as f:
        for key, value in src.attrs.items():
            f.attrs[key] = value
        for key in src:
            if how == "external link":
                f[key] = h5py.ExternalLink(str(other), "/" + key)
            else:
                _virtual_tree(f, key, src[key], other, "/" + key)
    return path


def _virtual_tree(group: h5py.Group, name: str, item: h5py.Group | h5py.Dataset, other: Path, target: str) -> None:
    """`item` as virtual datasets of `other`, group by group (a database's law holds datasets and
    groups of datasets, e.g. its folds)."""
    if isinstance(item, h5py.Group):
        group.create_group(name)
        for key, value in item.attrs.items():
            group[name].attrs[key] = value
        for child, value in item.items():
            _virtual_tree(group[name], child, value, other, f"{target}/{child}")
    else:
        _virtual(group, name, item, other, target)


def _virtual(group: h5py.Group, name: str, item: h5py.Dataset, other: Path, target: str) -> None:
    layout = h5py.VirtualLayout(shape=item.shape, dtype=item.dtype)
    layout[...] = h5py.VirtualSource(str(other), target, shape=item.shape)
    group.create_virtual_dataset(name, layout)
    for key, value in item.attrs.items():
        group[name].attrs[key] = value


@pytest.mark.parametrize("how,words", [("external link", "is an external link to"),
                                       ("virtual dataset", "is a virtual dataset")])
def test_a_database_whose_data_live_in_another_file_is_refused(tmp_path: Path, how: str, words: str) -> None:
    path = _relinked(database_path("tube-paper"), tmp_path / "db.h5", how)
    with pytest.raises(DatabaseError, match=words) as refused:
        load_database(path)
    assert str(path) in str(refused.value) and "elsewhere.h5" in str(refused.value)


def test_a_virtual_dataset_of_the_file_itself_is_read(tmp_path: Path, results_h5: Path) -> None:
    """HDF5 names a source in the same file '.': such a dataset is the file's own data."""
    with h5py.File(results_h5, "r+") as f:
        layout = h5py.VirtualLayout(shape=(3,), dtype=float)
        layout[...] = h5py.VirtualSource(".", "G_s", shape=(3,))
        f.create_virtual_dataset("G_s_view", layout)
        f["G_s_view"].attrs["units"] = "N/m"
        f.attrs["columns"] = [*f.attrs["columns"], "G_s_view"]
    rows, units = read_results_table(results_h5, ("id", "law", "G_s_view"))
    assert [float(r["G_s_view"]) for r in rows] == [0.04, 0.041, 0.039] and units["G_s_view"] == "N/m"


@pytest.fixture()
def results_h5(tmp_path: Path) -> Path:
    """A results table in fit-tube's HDF5 layout (1-D columns with a 'units' attribute, their
    order in the root's 'columns'), written here by hand."""
    path = tmp_path / "results.h5"
    columns = {"id": (["a", "b", "c"], ""), "law": (["NH"] * 3, ""), "Delta": ([0.1, 0.2, 0.3], "1"),
               "G_s": ([0.04, 0.041, 0.039], "N/m"), "flag": ([""] * 3, "")}
    with h5py.File(path, "w") as f:
        f.attrs["columns"] = list(columns)
        for name, (values, unit) in columns.items():
            f[name] = np.asarray(values, dtype=float) if unit else np.array(values, dtype=h5py.string_dtype())
            f[name].attrs["units"] = unit
    return path


@pytest.mark.parametrize("how", ["external link", "virtual dataset"])
def test_a_results_file_whose_columns_live_in_another_file_is_refused(tmp_path: Path, results_h5: Path,
                                                                      how: str) -> None:
    path = _relinked(results_h5, tmp_path / "linked.h5", how)
    with pytest.raises(ResultsFileError, match="own file only") as refused:
        read_results_table(path, ("id", "law", "G_s"))
    assert str(path) in str(refused.value)


def test_population_says_it_on_one_line(tmp_path: Path, results_h5: Path) -> None:
    path = _relinked(results_h5, tmp_path / "linked.h5", "external link")
    line = one_error_line(capsmech("population", str(path), cwd=tmp_path))
    assert str(path) in line and "external link" in line


def test_an_infinite_g_s_in_an_hdf5_results_file_is_refused(results_h5: Path) -> None:
    with h5py.File(results_h5, "r+") as f:
        f["G_s"][0] = -np.inf                        # what the cell '-1e30806632' reads as
    with pytest.raises(ResultsFileError, match="G_s.*infinite") as refused:
        read_results_table(results_h5, ("id", "law", "G_s"))
    assert str(results_h5) in str(refused.value)


# -- a full or read-only disk: one line, no partial file ------------------------------------------------------

def on_a_small_disk(tmp_path: Path, read_only: bool, *args: str) -> tuple[int, str, list[str]]:
    """``capsmech *args`` (DISK: the small disk's folder) on a full one-page disk."""
    command = [sys.executable, "-m", "capsmech.cli", *(a.replace("DISK", str(tmp_path / "disk")) for a in args)]
    return small_disk.on_a_small_disk(tmp_path, *command, read_only=read_only, timeout=120, cwd=tmp_path)


@pytest.mark.parametrize("read_only,args,written", [
    (False, ("fit-tube", str(EXAMPLE), "--law", "NH", "--out", "DISK/r.h5"), "r.h5"),
    (False, ("extract", str(FILM), "--out", "DISK/m.csv"), "m_frames.csv"),
    (True, ("fit-tube", str(EXAMPLE), "--law", "NH", "--out", "DISK/r.csv"), "r.csv"),
])
def test_an_output_on_a_full_or_read_only_disk_is_one_line_and_leaves_nothing(
        tmp_path: Path, read_only: bool, args: tuple[str, ...], written: str) -> None:
    rc, stderr, left = on_a_small_disk(tmp_path, read_only, *args)
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert rc == 2 and len(lines) == 1, stderr
    if read_only:                                                 # seen before any work
        assert lines[0] == f"capsmech: error: --out {tmp_path}/disk/{written}: folder {tmp_path}/disk is not writable"
    else:                                                         # the system's reason on the same line
        assert lines[0] == f"capsmech: error: {tmp_path}/disk/{written}: cannot write: No space left on device"
    assert not any(word in stderr for word in CRASH_WORDS), stderr
    assert left == []                                             # neither the file nor its .tmp


# -- sizes: fields, frames ------------------------------------------------------------------------------------

@pytest.mark.parametrize("command,text", [
    ("population", "id,law,Delta [1],G_s [N/m],flag\na,NH,0.1,{long},\n"),
    ("fit-tube", "id,{long}\na,1\n"),
])
def test_a_140000_character_field_is_one_line_naming_file_and_line(tmp_path: Path, command: str, text: str) -> None:
    path = tmp_path / "long.csv"
    path.write_text(text.format(long="1" * 140_000))
    line = one_error_line(capsmech(command, "long.csv", cwd=tmp_path))
    assert line.startswith("capsmech: error: long.csv:") and "field larger than field limit" in line
    assert len(line) < 300


def _the_campaigns_tiff(path: Path) -> Path:
    """60 zlib-compressed pages of 8000x8000 px with a sparse grid of bright dots: 3.8 MB on disk,
    3.8 GB decoded. Each page is one strip, encoded once and written 60 times."""
    side, pages = 8000, 60
    page = np.zeros((side, side), dtype=np.uint8)
    page[::500, ::500] = 200
    strip = zlib.compress(page.tobytes(), 6)
    with tifffile.TiffWriter(path) as tif:
        tif.write((strip for _ in range(pages)), shape=(pages, side, side), dtype=np.uint8, compression="zlib",
                  rowsperstrip=side)
    return path


@pytest.mark.parametrize("command", [
    ("extract", "TIFF", "--pixel-size", "0.5um", "--frame-rate", "1000", "--out", "m.csv"),
    ("extract-shear", "TIFF", "--pixel-size", "0.5um", "--shear-rate", "350", "--mu", "0.756", "--out", "m.csv"),
])
def test_the_campaigns_compressed_tiff_is_refused_within_2_gib(tmp_path: Path, command: tuple[str, ...]) -> None:
    tiff = _the_campaigns_tiff(tmp_path / "bomb.tif")
    assert tiff.stat().st_size < 5 * 2**20
    args = [str(tiff) if a == "TIFF" else a for a in command]
    line = one_error_line(capsmech(*args, cwd=tmp_path, address_space=2 * 2**30))    # it grew to 4.2 GB
    assert "bomb.tif" in line and "8000x8000" in line
    assert tree(tmp_path) == ["bomb.tif"]


# -- databases too small to fit against -----------------------------------------------------------------------

def test_fit_tube_against_the_smoke_database_names_it(tmp_path: Path) -> None:
    """The campaign's command: no --law, so every law of tube-smoke."""
    line = one_error_line(capsmech("fit-tube", str(EXAMPLE), "--database", "tube-smoke", cwd=tmp_path))
    assert "tube-smoke" in line and str(database_path("tube-smoke")) in line
    assert "steady rows" in line and "at least" in line


def test_diagnose_against_the_smoke_database_names_it(tmp_path: Path) -> None:
    """The same database through diagnose (which sees it among the effect databases): the
    file and the law named, as fit-tube does, not the bare inverter's message."""
    line = one_error_line(capsmech("diagnose", str(EXAMPLE), "--database", "tube-smoke", "--law", "NH", cwd=tmp_path))
    assert str(database_path("tube-smoke")) in line and "law NH" in line
    assert "steady rows" in line and "at least" in line
    assert line.count(str(database_path("tube-smoke"))) == 1
    # fit-tube's own naming of the database leaves the inverter's alone: named once
    fit_line = one_error_line(capsmech("fit-tube", str(EXAMPLE), "--database", "tube-smoke", "--law", "NH", cwd=tmp_path))
    assert fit_line.count(str(database_path("tube-smoke"))) == 1 and "tube-smoke (" in fit_line


@pytest.mark.parametrize("given,words", [("/dev/zero", "not a regular file"), ("{folder}", "a folder")])
def test_a_database_path_that_is_no_file_is_said_for_what_it_is(tmp_path: Path, given: str, words: str) -> None:
    """It was called 'neither a shipped database nor an existing file', though it exists."""
    given = given.format(folder=tmp_path)
    with pytest.raises(DatabaseError, match=words) as refused:
        load_database(given)
    assert repr(given) in str(refused.value) and "tube-paper" in str(refused.value)
