"""Results files written by ``capsmech fit-tube --out FILE.csv|FILE.h5`` (and every other
``--out`` table), read back for ``population`` and ``capsmech.read_results``.

Both formats ``write_results`` writes come back in: :func:`read_results_file` tells them apart
by their first bytes (HDF5's signature, else text), whatever the file is called.

A results HDF5 file holds one 1-D dataset per column, all of one length, each with a ``units``
attribute (``""`` for a text column); it is checked as the CSV is (the columns required, at
least one row), and a file of another kind (a case file, a database) is refused naming the
dataset that does not fit.

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
from typing import Any

from capsmech.errors import CapsmechError
from capsmech.io.hdf5_inputs import data_elsewhere
from capsmech.io.text import read_text, split_lines

#: Columns population needs (fit-tube writes them all).
REQUIRED = ("id", "law", "Delta", "G_s", "flag")
#: Largest results file read [bytes]: 100,000 capsules with five laws.
MAX_RESULTS_BYTES = 256 * 2**20
#: The first bytes of every HDF5 file (at offset 0 for the files h5py writes).
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


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
    return _read_csv(path, required)[0]


def _read_csv(path: str | Path, required: Sequence[str]) -> tuple[list[dict[str, str]], dict[str, str]]:
    """``read_results_csv``'s rows, and each column's unit from the header (``""``: text)."""
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
    units = {name: cell[cell.index(" [") + 2:-1].strip() if is_number else ""
             for name, is_number, cell in zip(names, numeric, cells)}
    return out, units


def is_hdf5(path: str | Path) -> bool:
    """Whether ``path`` starts with HDF5's signature (False when it cannot be read: the text
    reader then says why)."""
    try:
        with open(path, "rb") as stream:
            return stream.read(len(HDF5_SIGNATURE)) == HDF5_SIGNATURE
    except (OSError, ValueError):
        return False


def _number_text(value: Any) -> str:
    """A number as the rows of a CSV hold it, without losing a digit (repr round-trips)."""
    number = float(value)
    return "nan" if math.isnan(number) else repr(number)


def read_results_h5(path: str | Path, required: Sequence[str] = REQUIRED) -> tuple[list[dict[str, str]], dict[str, str]]:
    """Read a results HDF5 file (``write_results``' ``.h5``) into rows of strings, checked.

    Parameters
    ----------
    path : str or Path
        The file.
    required : sequence of str
        The columns it must have (as ``read_results_csv``).

    Returns
    -------
    rows : list of dict
        One dict per row: column -> the value as text (numbers with every digit, as ``repr``).
    units : dict
        Column -> unit (``""`` for text columns), in the file's order.

    Raises
    ------
    ResultsFileError
        Unreadable, not a results table (a group, a dataset that is not 1-D, columns of
        different lengths, no ``units`` attribute), a column missing, no rows, an infinite value.
    """
    import h5py
    import numpy as np

    path = Path(path)
    try:
        stream = h5py.File(path, "r")
    except OSError as err:
        raise ResultsFileError(f"{path}: cannot read the results file as HDF5: {err}") from None
    with stream:
        elsewhere = data_elsewhere(stream)
        if elsewhere is not None:
            raise ResultsFileError(f"{path}: {elsewhere}; a results file is read from its own file only")
        # write_results records its column order; a file without it is read in HDF5's (by name).
        order = [str(n.decode() if isinstance(n, bytes) else n) for n in stream.attrs.get("columns", [])]
        names = order if order and set(order) == set(stream.keys()) else list(stream.keys())
        missing = [name for name in required if name not in names]
        if missing:
            raise ResultsFileError(f"{path}: no dataset {', '.join(missing)}{_kind_hint(names)}")
        columns: dict[str, list[str]] = {}
        units: dict[str, str] = {}
        length = None
        for name in names:
            item = stream[name]
            if not isinstance(item, h5py.Dataset) or item.ndim != 1 or "units" not in item.attrs:
                raise ResultsFileError(f"{path}: {name!r} is not a results column (a 1-D dataset with a 'units' "
                                       f"attribute){_kind_hint(names)}")
            if length is not None and item.shape[0] != length:
                raise ResultsFileError(f"{path}: column {name!r} has {item.shape[0]} rows, the others {length}")
            length = item.shape[0]
            unit = item.attrs["units"]
            units[name] = unit.decode() if isinstance(unit, bytes) else str(unit)
            if units[name]:
                values = np.asarray(item[()], dtype=float)
                bad = np.flatnonzero(np.isinf(values))
                if bad.size:
                    raise ResultsFileError(f"{path}: column {name!r}, row {int(bad[0]) + 1}: infinite (no result is)")
                columns[name] = [_number_text(v) for v in values]
            else:
                columns[name] = [str(v) for v in item.asstr()[()]] if item.dtype.kind in "OS" \
                    else [str(v) for v in item[()]]
    if not length:
        raise ResultsFileError(f"{path}: no result rows")
    rows = [{name: columns[name][i] for name in names} for i in range(length)]
    return rows, units


def read_results_table(path: str | Path,
                       required: Sequence[str] = REQUIRED) -> tuple[list[dict[str, str]], dict[str, str]]:
    """Read a results file of either format ``write_results`` writes (CSV or HDF5, told apart
    by the file's first bytes), checked: rows of strings as ``read_results_csv`` returns them,
    and each column's unit (``""`` for text)."""
    if is_hdf5(path):
        return read_results_h5(path, required)
    return _read_csv(path, required)


def read_results_file(path: str | Path, required: Sequence[str] = REQUIRED) -> list[dict[str, str]]:
    """``read_results_table``'s rows."""
    return read_results_table(path, required)[0]
