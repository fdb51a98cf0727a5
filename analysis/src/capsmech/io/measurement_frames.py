"""Measurements as pandas DataFrames, in and out.

``read_batch`` reads a measurement file (``capsmech.io.measurements``) into a DataFrame in SI
units, the units in ``attrs``; ``capsules_from_frame`` takes a DataFrame back, or one a user
made (``pd.read_csv`` of a measurement file, units in the column names; or names alone with the
units in ``attrs["units"]``), and checks it row by row as a file is checked. Every
``capsmech.api`` function that takes measurements goes through it.
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from capsmech.io.measurement_columns import FLOWS, SI_UNITS, header_cell
from capsmech.io.measurement_sources import Row
from capsmech.io.measurements import Capsule, TableOrigin, read_flow_and_capsules, read_rows


def read_batch(path: str | Path, flow: str | None = None, contours_anywhere: bool = False) -> pd.DataFrame:
    """A measurement file (as ``read_measurements`` reads it) as a DataFrame in SI units.

    Returns
    -------
    DataFrame
        One row per capsule, in file order: ``id``, the file's measurement columns in SI units
        (m, m/s, Pa s, 1/s, rad; NaN where a cell is empty), ``contour`` when the file has one
        (each an (n, 2) array [m], or None) and ``line`` (the file's line). ``attrs``:
        ``units`` (column -> unit: ``"m"``, ``"m/s"``, ``"Pa s"``, ``"1/s"``, ``"rad"``, ``"1"``;
        ``""`` for id, contour's ``"m"``), ``flow`` (``"tube"`` or ``"shear"``) and ``source``
        (the file's path). Every ``capsmech.api`` function that takes measurements takes this
        frame, edited or not: it is checked again, and messages name the file's lines.
    """
    flow, capsules = read_flow_and_capsules(path, flow, contours_anywhere)
    return capsules_frame(capsules, flow, str(path))


def capsules_frame(capsules: Sequence[Capsule], flow: str, source: str = "") -> pd.DataFrame:
    """Capsules as ``read_batch`` gives them (``source``: the path their lines refer to)."""
    columns = FLOWS[flow]
    present = [name for name in columns if name != "contour" and any(name in c.values for c in capsules)]
    frame = pd.DataFrame({"id": [c.id for c in capsules],
                          **{name: [c[name] for c in capsules] for name in present}})
    units = {"id": "", **{name: SI_UNITS[columns[name][0]] for name in present}}
    if any(c.contour is not None for c in capsules):
        frame["contour"] = pd.Series([c.contour for c in capsules], dtype=object)
        units["contour"] = "m"
    frame["line"] = [c.line for c in capsules]
    units["line"] = ""
    frame.attrs.update(units=units, flow=flow, source=source)
    return frame


def capsules_from_frame(frame: pd.DataFrame, flow: str | None = None) -> list[Capsule]:
    """The capsules of a DataFrame, checked as a file's rows are.

    Parameters
    ----------
    frame : DataFrame
        One capsule per row; the columns named as a file's header is (``L_z [um]``, ``L_z
        (µm)``: what ``pd.read_csv`` gives), or by name alone with the unit in
        ``frame.attrs["units"]`` (what ``read_batch`` gives). A ``contour`` column holds a
        contour file's path (relative to the folder of ``attrs["source"]``, else the current
        folder) or an (n, 2) array in the column's unit.
    flow : {'tube', 'shear'} or None
        Which format; None infers it from the columns (or takes ``attrs["flow"]``).

    Raises
    ------
    MeasurementError
        As ``read_measurements``; a column without a unit is named. Rows are named by their
        file line when the frame came from ``read_batch``, else by their index label.
    """
    units = frame.attrs.get("units") or {}
    source = str(frame.attrs.get("source") or "")
    labels = list(frame.index)
    if str(frame.index.name).lower() == "id" and "id" not in {str(c).lower() for c in frame.columns}:
        frame = frame.reset_index()                     # pd.read_csv(..., index_col="id")
    header = []
    for column in frame.columns:
        cell = str(column)
        parsed = header_cell(cell)
        if parsed is not None and parsed[1] is None and units.get(cell) not in (None, ""):
            cell = f"{cell} [{units[cell]}]"
        header.append(cell)
    lines = frame["line"] if source and "line" in frame.columns else None
    if lines is not None and pd.api.types.is_integer_dtype(lines):
        origin = TableOrigin(source, Path(source).parent)
        numbers = [int(n) for n in lines]
    else:
        origin = TableOrigin("DataFrame", Path(source).parent if source else Path.cwd(), "", False, labels)
        numbers = list(range(1, len(frame) + 1))
    rows: list[Row] = [(0, header, False)]
    rows += [(number, list(values), False) for number, values in zip(numbers, frame.itertuples(index=False))]
    return read_rows(origin, iter(rows), flow or frame.attrs.get("flow"), contours_anywhere=False)[1]
