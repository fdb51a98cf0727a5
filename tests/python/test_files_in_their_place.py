"""Nothing read outside its place, and every user's mistake one clear line (not an internal error).

Reproducers of an outside campaign: a contour cell ``../../../../etc/passwd`` was opened and a
line of it echoed in the error; a 140,000-character field gave "internal error: field larger
than field limit"; ``fit-tube --database tube-smoke`` gave "internal error: ValueError: ... needs
at least 14".
"""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from capsmech.io.measurements import MeasurementError, read_measurements

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "data" / "examples" / "tube_batch_NH.csv"
HEADER = "id,L_z [um],L_p [um],v_c [mm/s],tube_radius [um],mu [Pa s],pixel_size [um],contour [px]"


def capsmech(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "capsmech.cli", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=300)


def one_error_line(result: subprocess.CompletedProcess) -> str:
    assert result.returncode == 2, (result.returncode, result.stderr)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("capsmech: error: "), result.stderr
    assert "internal error" not in result.stderr and "Traceback" not in result.stderr
    return lines[0]


@pytest.fixture()
def secret(tmp_path: Path) -> Path:
    """A contour-shaped file outside the batch's folder, whose content must never be read."""
    outside = tmp_path / "elsewhere" / "secret.txt"
    outside.parent.mkdir()
    angles = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    outside.write_text("\n".join(f"{50 + 20 * np.cos(a):.3f} {50 + 20 * np.sin(a):.3f}" for a in angles) + "\n")
    return outside


@pytest.mark.parametrize("cell", ["../elsewhere/secret.txt", "{absolute}", "sub/../../elsewhere/secret.txt"])
def test_a_contour_outside_the_batch_folder_is_refused_unread(tmp_path: Path, secret: Path, cell: str) -> None:
    batch = tmp_path / "batch"
    (batch / "sub").mkdir(parents=True)
    csv = batch / "m.csv"
    csv.write_text(f"{HEADER}\na,120,10,3,50,1,0.5,{cell.format(absolute=secret)}\n")
    with pytest.raises(MeasurementError, match=r"m\.csv:2: field 'contour': .* lies outside the measurement file's "
                                                r"folder") as refused:
        read_measurements(csv)
    assert "50." not in str(refused.value)                   # nothing of the file's content is echoed
    # The user may allow it, and the same contour is then read.
    capsule = read_measurements(csv, contours_anywhere=True)[0]
    assert capsule.contour is not None and capsule.contour.shape == (40, 2)


def test_the_command_refuses_it_on_one_line_and_allows_it_on_request(tmp_path: Path, secret: Path) -> None:
    batch = tmp_path / "batch"
    batch.mkdir()
    (batch / "m.csv").write_text(f"{HEADER}\na,120,10,3,50,1,0.5,../elsewhere/secret.txt\n")
    line = one_error_line(capsmech("fit-tube", "batch/m.csv", "--law", "NH", cwd=tmp_path))
    assert "--contours-anywhere" in line
    allowed = capsmech("fit-tube", "batch/m.csv", "--law", "NH", "--contours-anywhere", cwd=tmp_path)
    assert "outside the measurement file's folder" not in allowed.stderr and "Traceback" not in allowed.stderr


def test_contours_in_a_subfolder_are_read_as_before(tmp_path: Path) -> None:
    """The shipped batch names its contours in a subfolder: all are read, from a copy anywhere."""
    shutil.copy(EXAMPLE, tmp_path / EXAMPLE.name)
    shutil.copytree(EXAMPLE.with_name("tube_batch_NH_contours"), tmp_path / "tube_batch_NH_contours")
    capsules = read_measurements(tmp_path / EXAMPLE.name)
    assert capsules and all(c.contour is not None for c in capsules)


def test_a_field_beyond_the_csv_limit_is_one_line_naming_the_file(tmp_path: Path) -> None:
    csv = tmp_path / "long.csv"
    csv.write_text(f"{HEADER.rsplit(',', 2)[0]}\na,{'1' * 140_000},10,3,50,1\n")
    line = one_error_line(capsmech("fit-tube", "long.csv", "--law", "NH", cwd=tmp_path))
    assert "long.csv:2:" in line and "field larger than field limit" in line


def test_a_database_too_small_to_fit_against_is_a_user_error(tmp_path: Path) -> None:
    line = one_error_line(capsmech("fit-tube", str(EXAMPLE), "--database", "tube-smoke", "--law", "NH", cwd=tmp_path))
    assert "steady rows" in line and "at least" in line


@pytest.mark.parametrize("cell", ["-1e30806632", "inf", "1e400"])
def test_an_infinite_result_cell_is_refused_by_population(tmp_path: Path, cell: str) -> None:
    """fit-tube writes 'nan' for no value, never an infinity: such a cell is damage, named by line and field."""
    results = tmp_path / "r.csv"
    results.write_text(f"id,law,Delta [1],G_s [N/m],flag\na,NH,0.1,{cell},\nb,NH,0.1,0.04,\n")
    line = one_error_line(capsmech("population", "r.csv", cwd=tmp_path))
    assert "r.csv:2: field 'G_s'" in line and "infinite" in line


FILM = ROOT / "data" / "examples" / "frames" / "capsule_NH.tif"


@pytest.mark.parametrize("capsule_id", ["../../ESCAPED", "{absolute}", "a/b", "..", ".hidden", "x" * 101])
def test_an_id_that_is_not_a_plain_name_is_refused_before_any_file(tmp_path: Path, capsule_id: str) -> None:
    """An id names its contour file: ``--id ../../ESCAPED`` wrote outside the output folders."""
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    given = capsule_id.format(absolute=tmp_path / "abs")
    line = one_error_line(capsmech("extract", str(FILM), "--id", given, "--out", "m.csv", cwd=work))
    assert "--id" in line and "cannot be an id" in line
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == ["a", "a/b"]


def test_a_plain_id_names_the_contour_file_inside_the_output_folder(tmp_path: Path) -> None:
    done = capsmech("extract", str(FILM), "--id", "cap.01-x", "--out", "m.csv", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    names = sorted(p.name for p in (tmp_path / "m_contours").iterdir())
    assert names and all(n == "cap.01-x.txt" or n.startswith("cap.01-x-") for n in names)
