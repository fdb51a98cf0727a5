"""Measured capsules: the tables that ``capsmech fit-tube``, ``fit-shear`` and ``diagnose`` read.

The format is described in full in ``docs/reference/file-formats.md`` (Measurement CSV). In short:
one capsule per row; the header names each column and its unit, ``L_z [um]`` or ``L_z (um)``,
names in any case; lines starting with ``#`` are comments. Tube::

    # capsules in a 100 um capillary, glycerol at 20 C
    id,L_z [um],L_p [um],v_c [mm/s],tube_radius [um],mu [Pa s],pixel_size [um],contour [px]
    c01,182.4,21.0,1.52,50.0,1.41,0.5,contours/c01.txt

required ``id``, ``L_z``, ``L_p``, ``tube_radius`` (``v_c`` and ``mu`` for G_s); optional ``V``,
``pixel_size`` (lengths then in ``px``), ``contour`` (a contour file's path relative to the
table's folder, in the unit of the header; ``capsmech.io.contours``), ``contour_noise`` and
``tube_radius_sigma``. Capsules in a square channel give its ``half_width`` (and
``half_width_sigma``) instead of ``tube_radius`` (and its sigma): the column says the channel
(``Capsule.channel``), and a file gives one of the two. Shear::

    id,L1 [um],L2 [um],shear_rate [1/s],mu [Pa s]
    s01,52.1,23.5,350,0.756

required ``id``, ``L1``, ``L2``, ``shear_rate``, ``mu``; optional ``theta`` and ``D12_err``. The
units each kind of column takes are those of ``capsmech.io.measurement_columns``; everything is
converted to SI on reading.

Where the rows come from (``capsmech.io.measurement_sources``): a text file in UTF-8, UTF-16 or
Windows-1252, separated by ``,``, ``;`` or tab; or the first sheet of an ``.xlsx`` workbook
(openpyxl); or a pandas DataFrame (``capsmech.io.measurement_frames``). Decimal commas are read
wherever a comma cannot be a field break (``;`` or tab separator, a sheet); in a
``,``-separated file they are refused with a hint. Columns that are not part of the format
are ignored with one ``InputWarning`` naming them. A comment line after the header that has the
fields of a capsule row is named in an ``InputWarning``, so that a capsule is never dropped
silently (quote an id that starts with ``#``). A file holds at most ``MAX_CAPSULES`` rows and
``MAX_FILE_BYTES`` bytes.

Any problem raises ``MeasurementError`` naming the file, the line and the field (a DataFrame:
its row's index label); a table is read whole or not at all.
"""
from __future__ import annotations

import math
import re
import warnings
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from capsmech.errors import CapsmechError, InputWarning
from capsmech.io import plausibility
from capsmech.io.contours import ContourError, contour_problem, read_contour
from capsmech.io.measurement_columns import (
    ALTERNATIVES,
    CHANNEL_COLUMNS,
    EXAMPLE_UNITS,
    FLOWS,
    NOTE_COLUMNS,
    UNITS,
    ZERO_ALLOWED,
    accepted_units,
    header_cell,
    unit_scale,
)
from capsmech.io.measurement_sources import Row, open_source

__all__ = ["FLOWS", "MAX_CAPSULES", "MAX_FILE_BYTES", "UNITS", "Capsule", "MeasurementError", "TableOrigin",
           "read_flow_and_capsules", "read_measurements", "read_rows"]

#: A header cell read: column name, unit, scale to SI (None for id, and for px until a row's pixel_size).
Column = tuple[str, str, float | None]
#: Most capsule rows a measurement file may hold (a batch; split a larger one).
MAX_CAPSULES = 100_000
#: Largest measurement file read [bytes] (100,000 rows of ~300 characters).
MAX_FILE_BYTES = 32 * 2**20
#: Columns of ``measurement_frames.read_batch``'s frame that are not measurements: skipped when it comes back.
FRAME_COLUMNS = frozenset({"line"})
DECIMAL_COMMA = re.compile(r"[+-]?\d+,\d+")


class MeasurementError(CapsmechError, ValueError):
    """A measurement file that cannot be read; the message names file, line and field."""


@dataclass(frozen=True)
class Capsule:
    """One measured capsule, in SI units (m, m/s, Pa s, 1/s); absent values are NaN.

    Attributes
    ----------
    id : str
        Capsule identifier.
    values : dict[str, float]
        Column name -> value [SI].
    line : int
        Line of the file it came from.
    contour : np.ndarray or None
        Contour (n, 2) of image coordinates [m] (x along the tube axis), when the row names one.

    ``capsule["tube_radius"]`` (and ``"tube_radius_sigma"``) is the channel's length scale l, in
    which the tube databases hold their lengths, whichever column gave it: a tube's radius or a
    square channel's half-width (``half_width``, the radius of the channel's inscribed circle).
    """

    id: str
    values: dict[str, float]
    line: int
    contour: np.ndarray | None = None

    def __getitem__(self, name: str) -> float:
        if name not in self.values and name in _LENGTH_SCALE_STANDS_IN:
            name = _LENGTH_SCALE_STANDS_IN[name]
        return self.values.get(name, math.nan)

    @property
    def channel(self) -> str:
        """str: ``'square'`` for a capsule measured in a square channel (its row gives
        ``half_width``), else ``'tube'`` (a circular tube; and a shear capsule)."""
        return "square" if "half_width" in self.values else "tube"

    @property
    def length_scale(self) -> float:
        """float: the channel's length scale l [m]: the tube's radius or the channel's half-width."""
        return self["tube_radius"]


#: The tube radius's columns -> the square channel's that stand for them (``Capsule.__getitem__``).
_LENGTH_SCALE_STANDS_IN = {"tube_radius": "half_width", "tube_radius_sigma": "half_width_sigma"}


@dataclass(frozen=True)
class TableOrigin:
    """Where a table's rows come from: what messages name, and how numbers are written there.

    A file names ``path:line``; a DataFrame names its rows by index label (line k is the k-th
    row). Line 0 is a DataFrame's columns (a file's lines start at 1).
    """

    name: str
    folder: Path                               # where a relative contour path starts
    separator: str = ","                       # "" for a sheet or a DataFrame
    decimal_comma: bool = False
    labels: Sequence[object] | None = None     # a DataFrame's index

    def at(self, line: int) -> str:
        """Where line ``line`` is: ``'path:line'``, ``'DataFrame row <label>'``."""
        if line == 0:
            return f"{self.name} columns"
        return f"{self.name}:{line}" if self.labels is None else f"{self.name} {self.row(line)}"

    def row(self, line: int) -> str:
        """Line ``line`` in words: ``'line 3'``, or a DataFrame's ``'row <label>'``."""
        return f"line {line}" if self.labels is None else f"row {self.labels[line - 1]!r}"


def _names(row: Sequence[object]) -> list[str | None]:
    """Each header cell's column name, None where the cell is not ``name [unit]``."""
    return [parsed[0] if (parsed := header_cell(str(cell))) else None for cell in row]


def _missing(names: set[str], flow: str) -> list[str]:
    return [c for c, (_, required) in FLOWS[flow].items()
            if required and c not in names and not names & set(ALTERNATIVES.get(c, ()))]


def _check_channel_columns(origin: TableOrigin, line: int, names: set[str]) -> None:
    """One channel per file: one length-scale column (``CHANNEL_COLUMNS``), and its own sigma."""
    given = [name for name in CHANNEL_COLUMNS if name in names]
    if len(given) > 1:
        raise MeasurementError(f"{origin.at(line)}: columns {' and '.join(repr(n) for n in given)} both given: a file "
                               "is of one channel, a circular tube (tube_radius) or a square channel (half_width)")
    for name, (channel, sigma) in CHANNEL_COLUMNS.items():
        if sigma in names and name not in names:
            raise MeasurementError(f"{origin.at(line)}: column {sigma!r} is the uncertainty of {name!r} "
                                   f"({channel}), which the file does not give"
                                   + "".join(f"; with {other!r}, give {CHANNEL_COLUMNS[other][1]!r}"
                                             for other in given))


def _infer_flow(origin: TableOrigin, line: int, row: Sequence[object]) -> str:
    """The flow whose required columns the header has; an error unless exactly one has them all."""
    names = {name for name in _names(row) if name}
    fits = [flow for flow in FLOWS if not _missing(names, flow)]
    if len(fits) == 1:
        return fits[0]
    if fits:
        raise MeasurementError(f"{origin.at(line)}: the header has the required columns of both a tube and a shear "
                               "file; name the flow ('tube' or 'shear')")
    lacks = "; ".join(f"for {flow}: {', '.join(_missing(names, flow))}" for flow in FLOWS)
    raise MeasurementError(f"{origin.at(line)}: neither a tube nor a shear file, missing column(s) {lacks}")


def _parse_header(origin: TableOrigin, line: int, row: Sequence[object],
                  flow: str) -> tuple[list[Column | None], list[str]]:
    """Each header cell's (name, unit, SI scale), None where the column is ignored; and the ignored cells."""
    columns = FLOWS[flow]
    parsed: list[Column | None] = []
    ignored: list[str] = []
    unitless: list[str] = []
    seen = set()
    for i, cell in enumerate(str(c) for c in row):
        header = header_cell(cell)
        if header is None or header[0] in FRAME_COLUMNS or (header[0] != "id" and header[0] not in columns):
            parsed.append(None)
            if not (header and (header[0] in NOTE_COLUMNS or header[0] in FRAME_COLUMNS)):
                ignored.append(cell.strip() or f"(unnamed column {i + 1})")
            continue
        name, written = header
        if name in seen:
            raise MeasurementError(f"{origin.at(line)}: column {name!r} appears twice")
        seen.add(name)
        if name == "id":
            parsed.append((name, "", None))
            continue
        kind = columns[name][0]
        if written is None and kind != "number":
            unitless.append(name)
            parsed.append(None)
            continue
        unit = unit_scale(kind, written or "")
        if unit is None:
            raise MeasurementError(f"{origin.at(line)}: column {name!r}: unknown {kind} unit {written!r} "
                                   f"(expected one of {accepted_units(kind)})")
        if name == "pixel_size" and unit[0] == "px":
            raise MeasurementError(f"{origin.at(line)}: column 'pixel_size' needs a physical length unit, not px")
        parsed.append((name, *unit))
    if unitless:
        where = "the column name" if origin.labels is None else "the column name or DataFrame.attrs['units']"
        kind = columns[unitless[0]][0]
        raise MeasurementError(f"{origin.at(line)}: column(s) {', '.join(unitless)} without a unit; write it in "
                               f"{where}, e.g. '{unitless[0]} [{EXAMPLE_UNITS[kind]}]' ({kind} units: "
                               f"{accepted_units(kind)})")
    _check_channel_columns(origin, line, seen)
    missing = _missing(seen, flow)
    if "id" not in seen:
        missing.insert(0, "id")
    if missing:
        # A misspelt header ("Lz [um]") is ignored, so name what was not understood too.
        other = "shear" if flow == "tube" else "tube"
        hint = ""
        if not _missing({n for n in _names(row) if n}, other):
            hint = f"; the header has the columns of a {other} file"
        elif ignored:
            hint = f"; ignored: {', '.join(repr(c) for c in ignored)}"
        raise MeasurementError(f"{origin.at(line)}: missing column(s) {', '.join(missing)} for a {flow} file{hint}")
    return parsed, ignored


def _is_missing(cell: object) -> bool:
    """A DataFrame's empty cell: None or a pandas missing value (NaN, NA, NaT)."""
    return cell is None or cell is pd.NA or cell is pd.NaT or (isinstance(cell, (float, np.floating)) and math.isnan(cell))


def _number(origin: TableOrigin, line: int, name: str, cell: object) -> float | None:
    """A cell's value, None when it is empty."""
    if _is_missing(cell):
        return None
    if isinstance(cell, (int, float, np.integer, np.floating)) and not isinstance(cell, bool):
        value = float(cell)
        text = repr(value)
    else:
        text = str(cell).strip()
        if not text:
            return None
        try:
            # "0,5" is a decimal comma only where "," cannot be the separator.
            value = float(text.replace(",", ".") if origin.decimal_comma else text)
        except ValueError:
            raise MeasurementError(f"{origin.at(line)}: field {name!r}: {text!r} is not a number"
                                   f"{_comma_hint(origin, text)}") from None
    if not math.isfinite(value):
        raise MeasurementError(f"{origin.at(line)}: field {name!r} is {text} (not finite)")
    if value < 0 or (value == 0 and name not in ZERO_ALLOWED):
        raise MeasurementError(f"{origin.at(line)}: field {name!r} must be positive, got {text}")
    return value


def _comma_hint(origin: TableOrigin, text: str) -> str:
    if not DECIMAL_COMMA.fullmatch(text) or origin.decimal_comma:
        return ""
    if origin.labels is not None:
        return " (a decimal comma? read the file with pd.read_csv(..., decimal=','))"
    return (" (a decimal comma? a ','-separated file needs decimal points, or save it with ';' as the separator; "
            "a thousands separator is not read either)")


def _parse_row(origin: TableOrigin, line: int, row: Sequence[object], parsed: list[Column | None],
               columns: Mapping[str, tuple[str, bool]]
               ) -> tuple[str, dict[str, tuple[float, str, float | None]], tuple[object, str, float | None] | None]:
    """One capsule row: (id, column -> (value, unit, SI scale), the contour cell or None)."""
    if len(row) > len(parsed) and not any(str(c).strip() for c in row[len(parsed):]):
        row = row[:len(parsed)]
    if len(row) != len(parsed):
        hint = ("; decimal commas in a ','-separated file? use decimal points, or ';' as the separator"
                if len(row) > len(parsed) and origin.separator == "," and any(DECIMAL_COMMA.fullmatch(
                    f"{a},{b}") for a, b in zip(row, row[1:])) else "")
        raise MeasurementError(f"{origin.at(line)}: {len(row)} fields, the header has {len(parsed)}{hint}")
    raw: dict[str, tuple[float, str, float | None]] = {}
    capsule_id = ""
    contour_cell: tuple[object, str, float | None] | None = None
    for column, cell in zip(parsed, row):
        if column is None:
            continue
        name, unit, scale = column
        if name == "id":
            capsule_id = "" if _is_missing(cell) else str(cell).strip()
            if not capsule_id:
                raise MeasurementError(f"{origin.at(line)}: field 'id' is empty")
            continue
        if name == "contour":
            if isinstance(cell, np.ndarray) or (isinstance(cell, str) and cell.strip()):
                contour_cell = (cell.strip() if isinstance(cell, str) else cell, unit, scale)
            continue
        value = _number(origin, line, name, cell)
        if value is None:
            if columns[name][1] or name in CHANNEL_COLUMNS:
                raise MeasurementError(f"{origin.at(line)}: field {name!r} is empty")
            continue
        raw[name] = (value, unit, scale)
    return capsule_id, raw, contour_cell


def _row_like_id(origin: TableOrigin, line: int, row: list[str], parsed: list[Column | None],
                 columns: Mapping[str, tuple[str, bool]]) -> str | None:
    """``'<line> (#<id>)'`` when a comment line after the header reads as a capsule row, else None."""
    try:
        capsule_id, _, _ = _parse_row(origin, line, row, parsed, columns)
    except MeasurementError:
        return None
    return f"{line} (#{capsule_id})"


def _si_values(origin: TableOrigin, line: int, raw: Mapping[str, tuple[float, str, float | None]]
               ) -> tuple[dict[str, float], float | None]:
    """A row's values in SI units, and its pixel size [m] (None without one)."""
    values: dict[str, float] = {}
    pixel: float | None = None
    if "pixel_size" in raw:
        size, _, size_scale = raw["pixel_size"]
        assert size_scale is not None  # a physical length: the header refuses pixel_size in px
        pixel = size * size_scale
    for name, (value, unit, scale) in raw.items():
        if unit == "px":
            if pixel is None:
                raise MeasurementError(f"{origin.at(line)}: field {name!r} is in px but the row has no pixel_size")
            values[name] = value * pixel
        else:
            assert scale is not None  # px is the only unit without an SI scale
            values[name] = value * scale
        if not math.isfinite(values[name]) or (values[name] == 0 and value != 0):
            raise MeasurementError(f"{origin.at(line)}: field {name!r}: {value:g} {unit} is out of range once "
                                   f"converted to SI ({values[name]:g})")
        # A zero L_p (no rear dimple) is a measurement, not a slip: only positive values are ranged.
        if name in plausibility.COLUMNS and values[name] > 0 and plausibility.COLUMNS[name].absurd(values[name]):
            quantity = plausibility.COLUMNS[name]
            raise MeasurementError(f"{origin.at(line)}: field {name!r}: {value:g} {unit} is not a physical value "
                                   f"(plausible: {quantity.low:g}-{quantity.high:g} {quantity.unit}, and no unit "
                                   "slip brings it there)")
    return values, pixel


def _check_batch(origin: TableOrigin, flow: str, capsules: list[Capsule]) -> None:
    """The checks between a row's fields."""
    for capsule in capsules:
        where = origin.at(capsule.line)
        if flow == "tube" and capsule["L_p"] >= capsule["L_z"]:
            raise MeasurementError(f"{where}: field 'L_p' must be smaller than L_z")
        if flow == "shear" and capsule["L2"] > capsule["L1"]:
            raise MeasurementError(f"{where}: field 'L2' must not exceed L1 (L1 is the major semi-axis)")
        if flow == "shear" and capsule["D12_err"] >= 1:
            raise MeasurementError(f"{where}: field 'D12_err' must be below 1 (D12 lies in [0, 1))")
        if flow == "shear" and capsule["theta"] >= math.pi / 2:
            raise MeasurementError(f"{where}: field 'theta' must be below 90 deg (the major axis's "
                                   "inclination to the flow direction)")


def read_rows(origin: TableOrigin, rows: Iterator[Row], flow: str | None,
              contours_anywhere: bool) -> tuple[str, list[Capsule]]:
    """The flow and the capsules of a table's rows (a header, then capsule and comment rows),
    checked as ``read_measurements`` describes."""
    if flow is not None and flow not in FLOWS:
        raise ValueError(f"flow must be 'tube', 'shear' or None, got {flow!r}")
    first = next((row for row in rows if not row[2]), None)
    if first is None:
        raise MeasurementError(f"{origin.name}: no header line")
    header_line, header, _ = first
    while header and not str(header[-1]).strip():       # spreadsheets pad rows with empty cells
        header = header[:-1]
    if flow is None:
        flow = _infer_flow(origin, header_line, header)
    columns = FLOWS[flow]
    parsed, ignored = _parse_header(origin, header_line, header, flow)
    capsules: list[Capsule] = []
    ids: dict[str, int] = {}
    commented: list[str] = []
    for line, row, comment in rows:
        if comment:
            # A comment after the header: named when it has the fields of a capsule row.
            if (capsule_like := _row_like_id(origin, line, row, parsed, columns)) is not None:
                commented.append(capsule_like)
            continue
        if len(capsules) == MAX_CAPSULES:
            raise MeasurementError(f"{origin.at(line)}: more than {MAX_CAPSULES} capsule rows, the most one file may "
                                   "hold (split the batch into several files)")
        capsule_id, raw, contour_cell = _parse_row(origin, line, row, parsed, columns)
        if capsule_id in ids:
            raise MeasurementError(f"{origin.at(line)}: id {capsule_id!r} already used on {origin.row(ids[capsule_id])}")
        ids[capsule_id] = line
        values, pixel = _si_values(origin, line, raw)
        contour = None
        if contour_cell is not None:
            contour = _read_row_contour(origin, line, contour_cell, pixel, contours_anywhere)
        capsules.append(Capsule(id=capsule_id, values=values, line=line, contour=contour))
    if not capsules:
        raise MeasurementError(f"{origin.name}: no capsule rows after the header")
    _check_batch(origin, flow, capsules)
    # Warned only once the table is read: a table that is refused warns of nothing.
    for name, quantity in plausibility.COLUMNS.items():
        outside = [c for c in capsules if math.isfinite(c[name]) and c[name] > 0 and not quantity.contains(c[name])]
        sentence = plausibility.out_of_range(name, quantity, (c[name] for c in outside),
                                             _lines(origin, [c.line for c in outside])) if outside else None
        if sentence:
            warnings.warn(f"{origin.name}: {sentence}", InputWarning, stacklevel=4)
    if ignored:
        warnings.warn(f"{origin.at(header_line)}: ignored column(s) not in the {flow} format: "
                      f"{', '.join(repr(c) for c in ignored)}", InputWarning, stacklevel=4)
    if commented:
        warnings.warn(f"{origin.name}: comment line(s) {', '.join(commented)} have the fields of a capsule row and "
                      "are left out; if an id starts with '#', quote it (\"#c01\",...)", InputWarning, stacklevel=4)
    return flow, capsules


def read_measurements(path: str | Path, flow: str | None = None, contours_anywhere: bool = False) -> list[Capsule]:
    """Read a tube or shear measurement file (see the module docstring) into SI units.

    Parameters
    ----------
    path : str or Path
        The file: a CSV (``,``, ``;`` or tab separated; UTF-8, UTF-16 or Windows-1252; any line
        endings) or an ``.xlsx`` workbook's first sheet (needs openpyxl).
    flow : {'tube', 'shear'} or None
        Which format; None (default) infers it from the header's columns.
    contours_anywhere : bool
        Read contour files wherever the ``contour`` cells point. By default a contour must lie in
        the measurement file's folder or below it: a file received from elsewhere cannot make
        the reader open ``../../etc/passwd`` and echo its lines in an error.

    Returns
    -------
    list of Capsule
        One per row, in file order, values in SI units (``capsmech.io.measurement_frames.read_batch``:
        the same as a DataFrame).

    Raises
    ------
    MeasurementError
        On any malformed content, naming file, line and field; with ``flow=None``, also when the
        columns fit neither flow or both.

    Warns
    -----
    InputWarning
        Once, naming the columns that are not part of the format and are ignored; and for
        values outside their plausible range (``capsmech.io.plausibility``).
    """
    return read_flow_and_capsules(path, flow, contours_anywhere)[1]


def read_flow_and_capsules(path: str | Path, flow: str | None, contours_anywhere: bool) -> tuple[str, list[Capsule]]:
    """``read_measurements``, with the flow (the one given, or the one the header's columns say)."""
    path = Path(path)
    source = open_source(path, MAX_FILE_BYTES, "measurement file", MeasurementError)
    origin = TableOrigin(str(path), path.parent, source.separator, source.decimal_comma)
    return read_rows(origin, source.rows, flow, contours_anywhere)


def _lines(origin: TableOrigin, numbers: list[int]) -> str:
    """``'line 4'``, ``'lines 2-14'`` or ``'lines 2, 5, 9 ...'`` for the rows a warning is about."""
    if origin.labels is not None:
        labels = [str(origin.labels[n - 1]) for n in numbers]
        return ("row " if len(labels) == 1 else "rows ") + ", ".join(labels[:5]) + (" ..." if len(labels) > 5 else "")
    if len(numbers) == 1:
        return f"line {numbers[0]}"
    if numbers == list(range(numbers[0], numbers[-1] + 1)):
        return f"lines {numbers[0]}-{numbers[-1]}"
    return "lines " + ", ".join(str(n) for n in numbers[:5]) + (" ..." if len(numbers) > 5 else "")


def _read_row_contour(origin: TableOrigin, line: int, cell: tuple[object, str, float | None], pixel: float | None,
                      anywhere: bool = False) -> np.ndarray:
    """The contour a row names (a file, or an array a DataFrame holds), in metres."""
    value, unit, scale = cell
    if unit == "px":
        if pixel is None:
            raise MeasurementError(f"{origin.at(line)}: field 'contour' is in px but the row has no pixel_size")
        scale = pixel
    assert scale is not None
    if isinstance(value, np.ndarray):
        contour, contour_path = np.asarray(value, dtype=float), "the contour"
    else:
        name = str(value)
        path = Path(name) if Path(name).is_absolute() else origin.folder / name
        folder = origin.folder.resolve()
        if not anywhere and not path.resolve().is_relative_to(folder):
            raise MeasurementError(f"{origin.at(line)}: field 'contour': {name!r} lies outside the measurement "
                                   f"file's folder {folder}; contours are read only from there and below (move it "
                                   "there, or allow contours anywhere: --contours-anywhere, contours_anywhere=True)")
        try:
            contour, contour_path = read_contour(path), str(path)
        except ContourError as err:
            raise MeasurementError(f"{origin.at(line)}: field 'contour': {err}") from None
    contour = contour * scale
    problem = contour_problem(contour) if contour.ndim == 2 and contour.shape[1:] == (2,) else "not an (n, 2) array"
    if problem is not None:
        raise MeasurementError(f"{origin.at(line)}: field 'contour': {contour_path} in metres: {problem}")
    return contour
