"""Results files written by ``capsmech fit-tube --out FILE.csv``, read back for ``population``.

A results CSV has one header line of ``name [unit]`` cells (``name`` alone for text columns)
and one row per (capsule, law). Reading one checks what ``population`` relies on, so that a
file of another kind (a measurement file, fit-shear results, an empty or cut file) is refused
with a message that names the file, the line and the field, never read into nonsense:

* the columns ``REQUIRED`` are there (for ``population``; any table: no column required) (the message names those missing, and what the file
  looks like instead);
* every row has the header's number of fields (trailing empty cells are padding);
* every column with a unit holds numbers (``nan`` for none);
* there is at least one row.

The text is read as every user file is (``capsmech.io.text``: bounded, UTF-8, Windows-1252 or
Latin-1). Values stay the strings the file holds; ``population`` converts them.
"""
from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path

from capsmech.errors import CapsmechError
from capsmech.io.text import read_text, split_lines

#: Columns population needs (fit-tube writes them all).
REQUIRED = ("id", "law", "Delta", "G_s", "flag")
#: Largest results file read [bytes]: 100,000 capsules with five laws.
MAX_RESULTS_BYTES = 256 * 2**20


class ResultsFileError(CapsmechError, ValueError):
    """A results file that cannot be read; the message names file, line and field."""


def _kind_hint(names: list[str]) -> str:
    """What a file without the results' columns looks like, in words."""
    if {"L_z", "L_p"} <= set(names):
        return " (it looks like a tube measurement file: give fit-tube's results, `fit-tube CSV --out RESULTS.csv`)"
    if "D12" in names or "L1" in names:
        return " (it looks like a shear file or fit-shear's results: population compares tube fits)"
    return " (expected the results that `capsmech fit-tube --out RESULTS.csv` writes)"


def _cells(path: Path, number: int, text: str) -> list[str]:
    try:
        return next(csv.reader([text]), [])
    except csv.Error as err:
        raise ResultsFileError(f"{path}:{number}: {err} (no field of a results file is that long)") from None


def read_results_csv(path: str | Path, required: Sequence[str] = REQUIRED) -> list[dict[str, str]]:
    """Read a fit-tube results CSV into rows of strings, checked (see the module).

    Parameters
    ----------
    path : str or Path
        The results file.
    required : sequence of str
        The columns it must have (default ``REQUIRED``, those of fit-tube's results that
        ``population`` needs; ``()`` reads any table ``write_results`` wrote).

    Returns
    -------
    list of dict
        One dict per row: column name (without its unit) -> the cell's text.

    Raises
    ------
    ResultsFileError
        The file is unreadable, binary or too large, has no header or no rows, lacks a
        required column, has a row of another length or a non-number in a numeric column
        (the message names the file, the line and the field).
    """
    path = Path(path)
    lines = split_lines(read_text(path, MAX_RESULTS_BYTES, "results file", ResultsFileError))
    rows = ((number, _cells(path, number, text)) for number, text in enumerate(lines, start=1) if text.strip())
    first = next(rows, None)
    if first is None:
        raise ResultsFileError(f"{path}: empty: no header line (expected fit-tube's results)")
    header_line, header = first
    cells = [cell.strip() for cell in header]
    names = [cell.split(" [")[0].strip() for cell in cells]
    numeric = [cell.endswith("]") and " [" in cell for cell in cells]
    missing = [name for name in required if name not in names]
    if missing:
        raise ResultsFileError(f"{path}:{header_line}: no column {', '.join(missing)}{_kind_hint(names)}")
    out: list[dict[str, str]] = []
    for number, row in rows:
        if len(row) > len(names) and not any(cell.strip() for cell in row[len(names):]):
            row = row[:len(names)]
        if len(row) != len(names):
            raise ResultsFileError(f"{path}:{number}: {len(row)} fields, the header has {len(names)}")
        for name, is_number, cell in zip(names, numeric, row):
            if is_number and cell.strip():
                try:
                    value = float(cell)
                except ValueError:
                    raise ResultsFileError(f"{path}:{number}: field {name!r}: {cell!r} is not a number") from None
                # fit-tube writes 'nan' for no value, never an infinity: '-1e30806632' is damage.
                if math.isinf(value):
                    raise ResultsFileError(f"{path}:{number}: field {name!r}: {cell[:40]!r} is infinite once read "
                                           "(no result is)")
        out.append(dict(zip(names, row)))
    if not out:
        raise ResultsFileError(f"{path}: no result rows after the header")
    return out
