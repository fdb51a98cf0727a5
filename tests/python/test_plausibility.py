"""Unit slips are caught where they enter: implausible inputs warn with the slip named, absurd ones are refused.

The batch is the shipped NH example (made by the kernel, truth G_s = 0.04 N/m, mu 1 Pa s order);
its columns are rewritten here as a user who slipped would write them.
"""
from __future__ import annotations

import csv
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from capsmech.api import fit_tube
from capsmech.errors import InputWarning
from capsmech.io import plausibility
from capsmech.io.measurements import MeasurementError, read_measurements

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "data" / "examples" / "tube_batch_NH.csv"


def _rewritten(tmp_path: Path, header_from: str, header_to: str, scale_mu: float = 1.0, only_row: int | None = None) -> Path:
    """The example batch (contours dropped) with one header cell renamed and mu's values scaled."""
    lines = [line for line in EXAMPLE.read_text().splitlines() if not line.startswith("#")]
    rows = list(csv.reader(lines))
    header = rows[0][:-1]
    mu = header.index("mu [Pa s]")
    out = [[header_to if cell == header_from else cell for cell in header]]
    for i, row in enumerate(rows[1:]):
        row = row[:-1]
        if only_row is None or i == only_row:
            row[mu] = f"{float(row[mu]) * scale_mu:.6g}"
        out.append(row)
    path = tmp_path / "batch.csv"
    path.write_text("\n".join(",".join(row) for row in out) + "\n")
    return path


def _input_warnings(record: list[warnings.WarningMessage]) -> list[str]:
    return [str(w.message) for w in record if issubclass(w.category, InputWarning)]


def test_the_shipped_batch_is_plausible(tmp_path: Path) -> None:
    """The kernel-made example (real units throughout) gives no plausibility warning, nor does its fit."""
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        capsules = read_measurements(_rewritten(tmp_path, "", ""))
        results = fit_tube(capsules, laws="NH")
    assert not _input_warnings(record)
    fitted = results[results["flag"] == ""]["G_s"]
    assert 0.03 < fitted.median() < 0.05          # the truth is 0.04 N/m


def test_pascal_seconds_under_a_millipascal_header_warn_at_the_fit(tmp_path: Path) -> None:
    """Values in Pa s (about 1) under [mPa s]: each reads as a plausible 1 mPa s, but G_s comes out
    1000 times low (4e-5 N/m), below any capsule membrane: the fit's warning names that slip."""
    path = _rewritten(tmp_path, "mu [Pa s]", "mu [mPa s]")
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        results = fit_tube(read_measurements(path), laws="NH")
    fitted = results[results["flag"] == ""]["G_s"]
    assert fitted.median() == pytest.approx(1e-3 * 0.04, rel=0.25)
    messages = _input_warnings(record)
    assert len(messages) == 1
    assert "G_s" in messages[0] and "[mPa s]" in messages[0] and "below the plausible range" in messages[0]


def test_water_in_pascal_seconds_under_a_millipascal_header_warns_on_reading(tmp_path: Path) -> None:
    """0.001 (water in Pa s) under [mPa s] is 1e-6 Pa s, thinner than any liquid: a warning naming the rows."""
    path = _rewritten(tmp_path, "mu [Pa s]", "mu [mPa s]", scale_mu=1e-3)
    with pytest.warns(InputWarning, match=r"mu .* Pa s \(lines 2-\d+\) is below the plausible range.*\[mPa s\]"):
        read_measurements(path)


def test_one_absurd_row_is_an_error_naming_its_line(tmp_path: Path) -> None:
    """mu = 1e300 Pa s is no unit slip: the file is refused at that line and field."""
    path = _rewritten(tmp_path, "", "", scale_mu=1e300, only_row=2)
    with pytest.raises(MeasurementError, match=r"batch\.csv:4: field 'mu': .* not a physical value"):
        read_measurements(path)


def test_the_command_line_prints_the_slip_and_still_answers(tmp_path: Path) -> None:
    """The CLI shows the warning on one line and exits 0 (the fit is made; the user decides)."""
    path = _rewritten(tmp_path, "mu [Pa s]", "mu [mPa s]")
    done = subprocess.run([sys.executable, "-m", "capsmech.cli", "fit-tube", str(path), "--law", "NH"],
                          capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "capsmech: warning: the fitted G_s" in done.stderr and "Traceback" not in done.stderr


@pytest.mark.parametrize("name", sorted(plausibility.COLUMNS))
def test_every_slip_hint_brings_the_value_back(name: str) -> None:
    """Contract of the hints: a value off by a named slip's factor is out of range, and dividing by the
    factor (what the hint prints) lands inside it."""
    quantity = plausibility.COLUMNS[name]
    typical = (quantity.low * quantity.high) ** 0.5
    for factor, _ in quantity.slips:
        slipped = typical * factor
        if quantity.contains(slipped):
            continue                      # a slip the range cannot see at this value
        hint = plausibility.slip_hint(quantity, slipped)
        assert hint.startswith("; perhaps")
        assert quantity.contains(float(hint.split(" gives ")[1].split()[0]))
