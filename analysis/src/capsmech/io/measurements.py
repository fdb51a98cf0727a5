"""Measured capsules: the CSV format that ``capsmech fit-tube`` and ``fit-shear`` read.

Format
------
One capsule per row; the header names each column and its unit in brackets. Lines starting
with ``#`` are comments. Column names are case-sensitive.

Tube (``fit-tube``)::

    # capsules in a 100 um capillary, glycerol at 20 C
    id,L_z [um],L_p [um],v_c [mm/s],tube_radius [um],mu [Pa s]
    c01,182.4,21.0,1.52,50.0,1.41

required ``id``, ``L_z``, ``L_p``, ``tube_radius``; ``v_c`` and ``mu`` are needed for G_s;
optional ``V`` (mean flow velocity, when the flow rate is known), ``pixel_size`` (then
lengths may be given in ``px``) and ``contour``: the path (relative to the CSV's folder) of
the capsule's contour file, in the unit of the column's header, e.g. ``contour [px]``::

    id,L_z [um],L_p [um],v_c [mm/s],tube_radius [um],mu [Pa s],pixel_size [um],contour [px]
    c01,182.4,21.0,1.52,50.0,1.41,0.5,contours/c01.txt

A contour file is what ImageJ's "Save XY Coordinates" writes: two columns x y (tab, space
or comma separated, one optional header line), the capsule's mid-line in a plane through
the tube axis, x along the axis with the flow in +x (see ``capsmech.io.contours``). With a
contour, ``fit-tube`` measures the misfit H/a of the fitted profile and the contour's
asymmetry, and flags the capsule when either is too large. Optional ``contour_noise`` (a
length): one contour's tracing noise measured across the video frames (``capsmech extract``
writes it); the contour's chi2 then takes the larger of it and the noise of the contour's two
halves (``capsmech.inversion.noise``). Optional ``tube_radius_sigma`` (a length): the tube
radius's standard uncertainty from the walls' positions (``capsmech extract`` writes it;
``fit-tube`` carries it into the spreads of a/l, Ca_s and G_s, ``capsmech.inversion.fitting``).

Shear (``fit-shear``)::

    id,L1 [um],L2 [um],shear_rate [1/s],mu [Pa s]
    s01,52.1,23.5,350,0.756

required ``id``, ``L1``, ``L2`` (semi-axes in the shear plane), ``shear_rate``, ``mu``;
optional ``theta`` (inclination of the major axis to the flow direction, in (0, 90) deg, unit
``deg`` or ``rad``), which ``diagnose-shear`` uses when given; optional ``D12_err``
(dimensionless, unit ``1`` or none): D12's uncertainty, which ``fit-shear`` turns into G_s's
spread (``capsmech extract-shear`` writes it, at two standard deviations).

Units: lengths m, mm, um (or µm), nm, px (with a ``pixel_size`` column); velocities m/s, mm/s,
um/s; viscosity Pa s, mPa s, cP; shear rate 1/s. Micro may be written ``u``, the micro sign
(U+00B5) or the Greek mu (U+03BC). Everything is converted to SI on reading.

Files a spreadsheet wrote
-------------------------
What a spreadsheet's "Save as CSV" adds is accepted: a UTF-8 byte-order mark (or, failing
UTF-8, Windows-1252 text: Excel's plain "CSV", or else Latin-1), CRLF line endings, a ``;`` (or tab) separator
instead of ``,`` (the one the header line uses most), columns in any order, rows padded with
empty cells, and columns that are not part of the format (e.g. ``note``): those are ignored
with one ``capsmech.errors.InputWarning`` naming them. Decimal commas (``0,5``) are accepted
only when the separator is ``;`` (with ``,`` as separator a decimal comma cannot be told from
a field break); decimal points are accepted with every separator.

The flow (tube or shear) is the one the caller names, or else the one whose required columns
the header has; a header that has those of both, or of neither, is an error that names the
columns each flow lacks.

Comments and ids that start with ``#``
--------------------------------------
A line whose first character (after blanks) is ``#`` is a comment, also after the header: a
row commented out is left out of the batch. A capsule whose id starts with ``#`` is written
with its id quoted (``"#c01",182.4,...``); a comment line after the header that has the
fields of a capsule row (an id, and a number in each required column) is still a comment,
but is named in an ``InputWarning``, so that a capsule is never dropped silently.

Limits
------
A file may hold at most ``MAX_CAPSULES`` (100,000) capsule rows and ``MAX_FILE_BYTES``
(32 MiB); a larger one is refused at once, naming the file (and the first row past the
limit), and is never read whole into memory. Fitting 100,000 capsules takes minutes per law
(about 2.5 ms per capsule and law on one core), with a progress bar on a terminal; split a
larger batch into files. A contour file may hold at most
``capsmech.io.contours.MAX_CONTOUR_BYTES``.

Errors
------
Any problem (unknown unit, missing column, empty or non-numeric value, NaN, negative or zero
length, duplicate id, a binary file, a file over the limits, an unreadable or degenerate
contour) raises ``MeasurementError`` naming the file, the line and the field. A file is read
whole or not at all: a batch is never half-processed.
"""
from __future__ import annotations

import csv
import math
import re
import warnings
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capsmech.errors import CapsmechError, InputWarning
from capsmech.io import plausibility
from capsmech.io.contours import ContourError, contour_problem, read_contour
from capsmech.io.text import read_text, split_lines

LENGTH_UNITS = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "nm": 1e-9, "px": None}
VELOCITY_UNITS = {"m/s": 1.0, "mm/s": 1e-3, "um/s": 1e-6, "µm/s": 1e-6}
VISCOSITY_UNITS = {"Pa s": 1.0, "Pa.s": 1.0, "mPa s": 1e-3, "mPa.s": 1e-3, "cP": 1e-3}
RATE_UNITS = {"1/s": 1.0, "s^-1": 1.0}
ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180}
DIMENSIONLESS_UNITS = {"": 1.0, "1": 1.0}

#: Column -> (kind, required) per flow.
TUBE_COLUMNS = {"L_z": ("length", True), "L_p": ("length", True), "tube_radius": ("length", True),
                "v_c": ("velocity", False), "mu": ("viscosity", False), "V": ("velocity", False),
                "pixel_size": ("length", False), "contour": ("length", False), "contour_noise": ("length", False),
                "tube_radius_sigma": ("length", False)}
SHEAR_COLUMNS = {"L1": ("length", True), "L2": ("length", True), "shear_rate": ("rate", True),
                 "mu": ("viscosity", True), "pixel_size": ("length", False), "theta": ("angle", False),
                 "D12_err": ("number", False)}
UNITS: dict[str, Mapping[str, float | None]] = {"length": LENGTH_UNITS, "velocity": VELOCITY_UNITS, "viscosity": VISCOSITY_UNITS, "rate": RATE_UNITS,
         "angle": ANGLE_UNITS, "number": DIMENSIONLESS_UNITS}
#: Columns where zero is a measurement (no rear dimple; an exact value), not a slip.
ZERO_ALLOWED = frozenset({"L_p", "tube_radius_sigma", "D12_err"})
HEADER = re.compile(r"^\s*(?P<name>[A-Za-z_][A-Za-z0-9_]*)\s*(\[(?P<unit>[^\]]*)\])?\s*$")
#: A header cell read: column name, unit, scale to SI (None for id, and for px until a row's pixel_size).
Column = tuple[str, str, float | None]
FLOWS = {"tube": TUBE_COLUMNS, "shear": SHEAR_COLUMNS}
#: Text columns ``capsmech extract`` writes for the reader of the file (not for the fit): skipped
#: without the warning an unknown column gets.
NOTE_COLUMNS = frozenset({"width_check"})
#: Separators tried on the header line; decimal commas only go with ";".
SEPARATORS = (",", ";", "\t")
#: Most capsule rows a measurement file may hold (a batch; split a larger one).
MAX_CAPSULES = 100_000
#: Largest measurement file read [bytes] (100,000 rows of ~300 characters).
MAX_FILE_BYTES = 32 * 2**20


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
    """

    id: str
    values: dict[str, float]
    line: int
    contour: np.ndarray | None = None

    def __getitem__(self, name: str) -> float:
        return self.values.get(name, math.nan)


def _unit(text: str) -> str:
    """A header's unit as the unit tables spell it: micro as ``u``, whitespace single spaces."""
    # Spreadsheets and keyboards give both the micro sign and the Greek mu, and may put a
    # non-breaking space in "Pa s"; all mean the same unit.
    return " ".join(text.replace("\u00b5", "u").replace("\u03bc", "u").split())


def _names(row: list[str]) -> list[str | None]:
    """Each header cell's column name, None where the cell is not ``name [unit]``."""
    return [match["name"] if (match := HEADER.match(cell)) else None for cell in row]


def _missing(names: set[str], flow: str) -> list[str]:
    return [c for c, (_, required) in FLOWS[flow].items() if required and c not in names]


def _infer_flow(path: Path, line: int, row: list[str]) -> str:
    """The flow whose required columns the header has; an error unless exactly one has them all."""
    names = {name for name in _names(row) if name}
    fits = [flow for flow in FLOWS if not _missing(names, flow)]
    if len(fits) == 1:
        return fits[0]
    if fits:
        raise MeasurementError(f"{path}:{line}: the header has the required columns of both a tube and a shear "
                               "file; name the flow ('tube' or 'shear')")
    lacks = "; ".join(f"for {flow}: {', '.join(_missing(names, flow))}" for flow in FLOWS)
    raise MeasurementError(f"{path}:{line}: neither a tube nor a shear file, missing column(s) {lacks}")


def _parse_header(path: Path, line: int, row: list[str], flow: str) -> tuple[list[Column | None], list[str]]:
    """Each header cell's (name, unit, SI scale), None where the column is ignored; and the ignored cells."""
    columns = FLOWS[flow]
    parsed: list[Column | None] = []
    ignored: list[str] = []
    seen = set()
    for i, cell in enumerate(row):
        match = HEADER.match(cell)
        if not match or (match["name"] != "id" and match["name"] not in columns):
            parsed.append(None)
            if not (match and match["name"] in NOTE_COLUMNS):
                ignored.append(cell.strip() or f"(unnamed column {i + 1})")
            continue
        name, unit = match["name"], _unit(match["unit"] or "")
        if name in seen:
            raise MeasurementError(f"{path}:{line}: column {name!r} appears twice")
        seen.add(name)
        if name == "id":
            parsed.append((name, "", None))
            continue
        kind = columns[name][0]
        if unit not in UNITS[kind]:
            raise MeasurementError(f"{path}:{line}: column {name!r}: unknown {kind} unit {unit!r} "
                                   f"(expected one of {', '.join(UNITS[kind])})")
        if name == "pixel_size" and unit == "px":
            raise MeasurementError(f"{path}:{line}: column 'pixel_size' needs a physical length unit, not px")
        parsed.append((name, unit, UNITS[kind][unit]))
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
        raise MeasurementError(f"{path}:{line}: missing column(s) {', '.join(missing)} for a {flow} file{hint}")
    return parsed, ignored


def _is_comment(line: str) -> bool:
    """A comment line: its first character after blanks is ``#`` (a quoted ``"#id"`` is not)."""
    return line.lstrip().startswith("#")


def _separator(lines: list[str]) -> str:
    """The separator the header line (the first that is not blank or a comment) uses most."""
    for text in lines:
        if text.strip(",;\t \"") and not _is_comment(text):
            return max(SEPARATORS, key=text.count)       # ties (none at all) go to ","
    return ","


def _cells(path: Path, text: str, separator: str, number: int) -> list[str]:
    """One line's cells; a cell beyond the csv module's limit (128 kB) is no measurement."""
    try:
        return next(csv.reader([text], delimiter=separator), [])
    except csv.Error as err:
        raise MeasurementError(f"{path}:{number}: {err} (no field of a measurement file is that long)") from None


def _rows(path: Path, lines: list[str], separator: str) -> Iterator[tuple[int, list[str]]]:
    """The non-blank lines as (line number, cells); comment lines come after the header, as
    (-line number, cells without the '#'), so that a row commented out can be recognised."""
    header_seen = False
    for number, text in enumerate(lines, start=1):
        if not text.strip(" \t" + separator):
            continue
        if _is_comment(text):
            if header_seen:
                yield -number, _cells(path, text.lstrip()[1:], separator, number)
            continue
        row = _cells(path, text, separator, number)
        if any(cell.strip() for cell in row):
            header_seen = True
            yield number, row


def _parse_row(path: Path, line: int, row: list[str], parsed: list[Column | None], columns: Mapping[str, tuple[str, bool]],
               separator: str) -> tuple[str, dict[str, tuple[float, str, float | None]], tuple[str, str, float | None] | None]:
    """One capsule row: (id, column -> (value, unit, SI scale), the contour cell or None)."""
    if len(row) > len(parsed) and not any(c.strip() for c in row[len(parsed):]):
        row = row[:len(parsed)]
    if len(row) != len(parsed):
        raise MeasurementError(f"{path}:{line}: {len(row)} fields, the header has {len(parsed)}")
    raw: dict[str, tuple[float, str, float | None]] = {}
    capsule_id = ""
    contour_cell: tuple[str, str, float | None] | None = None
    for column, cell in zip(parsed, row):
        if column is None:
            continue
        name, unit, scale = column
        cell = cell.strip()
        if name == "id":
            if not cell:
                raise MeasurementError(f"{path}:{line}: field 'id' is empty")
            capsule_id = cell
            continue
        if name == "contour":
            if cell:
                contour_cell = (cell, unit, scale)
            continue
        if not cell:
            if columns[name][1]:
                raise MeasurementError(f"{path}:{line}: field {name!r} is empty")
            continue
        try:
            # "0,5" is a decimal comma only where "," cannot be the separator.
            value = float(cell.replace(",", ".") if separator == ";" else cell)
        except ValueError:
            raise MeasurementError(f"{path}:{line}: field {name!r}: {cell!r} is not a number") from None
        if not math.isfinite(value):
            raise MeasurementError(f"{path}:{line}: field {name!r} is {cell} (not finite)")
        if value < 0 or (value == 0 and name not in ZERO_ALLOWED):
            raise MeasurementError(f"{path}:{line}: field {name!r} must be positive, got {cell}")
        raw[name] = (value, unit, scale)
    return capsule_id, raw, contour_cell


def _row_like_id(path: Path, line: int, row: list[str], parsed: list[Column | None],
                 columns: Mapping[str, tuple[str, bool]], separator: str) -> str | None:
    """``'<line> (#<id>)'`` when a comment line after the header reads as a capsule row, else None."""
    try:
        capsule_id, _, _ = _parse_row(path, line, row, parsed, columns, separator)
    except MeasurementError:
        return None
    return f"{line} (#{capsule_id})"


def read_measurements(path: str | Path, flow: str | None = None, contours_anywhere: bool = False) -> list[Capsule]:
    """Read a tube or shear measurement CSV (see the module docstring) into SI units.

    Parameters
    ----------
    path : str or Path
        The CSV file: ``,``, ``;`` or tab separated, UTF-8 (with or without a byte-order mark)
        or Windows-1252, any line endings. Decimal commas (``0,5``) are accepted only in a
        ``;``-separated file.
    flow : {'tube', 'shear'} or None
        Which format; None (default) infers it from the header's columns.
    contours_anywhere : bool
        Read contour files wherever the ``contour`` cells point. By default a contour must lie in
        the measurement file's folder or below it: a file received from elsewhere cannot make
        the reader open ``../../etc/passwd`` and echo its lines in an error.

    Returns
    -------
    list of Capsule
        One per row, in file order, values in SI units.

    Raises
    ------
    MeasurementError
        On any malformed content, naming file, line and field; with ``flow=None``, also when the
        columns fit neither flow or both.

    Warns
    -----
    InputWarning
        Once, naming the columns that are not part of the format and are ignored.
    """
    path = Path(path)
    if flow is not None and flow not in FLOWS:
        raise ValueError(f"flow must be 'tube', 'shear' or None, got {flow!r}")
    lines = split_lines(read_text(path, MAX_FILE_BYTES, "measurement file", MeasurementError))
    separator = _separator(lines)
    rows = _rows(path, lines, separator)
    first = next(rows, None)
    if first is None:
        raise MeasurementError(f"{path}: no header line")
    header_line, header = first
    while header and not header[-1].strip():            # spreadsheets pad rows with empty cells
        header = header[:-1]
    if flow is None:
        flow = _infer_flow(path, header_line, header)
    columns = FLOWS[flow]
    parsed, ignored = _parse_header(path, header_line, header, flow)
    capsules: list[Capsule] = []
    ids: dict[str, int] = {}
    commented: list[str] = []
    for line, row in rows:
        if line < 0:
            # A comment after the header: named when it has the fields of a capsule row.
            if (capsule_like := _row_like_id(path, -line, row, parsed, columns, separator)) is not None:
                commented.append(capsule_like)
            continue
        if len(capsules) == MAX_CAPSULES:
            raise MeasurementError(f"{path}:{line}: more than {MAX_CAPSULES} capsule rows, the most one file may "
                                   "hold (split the batch into several files)")
        capsule_id, raw, contour_cell = _parse_row(path, line, row, parsed, columns, separator)
        if capsule_id in ids:
            raise MeasurementError(f"{path}:{line}: id {capsule_id!r} already used on line {ids[capsule_id]}")
        ids[capsule_id] = line
        values: dict[str, float] = {}
        pixel: float | None = None
        if "pixel_size" in raw:
            size, _, size_scale = raw["pixel_size"]
            assert size_scale is not None  # a physical length: the header refuses pixel_size in px
            pixel = size * size_scale
        for name, (value, unit, scale) in raw.items():
            if unit == "px":
                if pixel is None:
                    raise MeasurementError(f"{path}:{line}: field {name!r} is in px but the row has no pixel_size")
                values[name] = value * pixel
            else:
                assert scale is not None  # px is the only unit without an SI scale
                values[name] = value * scale
            if not math.isfinite(values[name]) or (values[name] == 0 and value != 0):
                raise MeasurementError(f"{path}:{line}: field {name!r}: {value:g} {unit} is out of range once "
                                       f"converted to SI ({values[name]:g})")
            # A zero L_p (no rear dimple) is a measurement, not a slip: only positive values are ranged.
            if name in plausibility.COLUMNS and values[name] > 0 and plausibility.COLUMNS[name].absurd(values[name]):
                quantity = plausibility.COLUMNS[name]
                raise MeasurementError(f"{path}:{line}: field {name!r}: {value:g} {unit} is not a physical value "
                                       f"(plausible: {quantity.low:g}-{quantity.high:g} {quantity.unit}, and no unit "
                                       "slip brings it there)")
        contour = None
        if contour_cell is not None:
            contour = _read_row_contour(path, line, contour_cell, pixel, contours_anywhere)
        capsules.append(Capsule(id=capsule_id, values=values, line=line, contour=contour))
    if not capsules:
        raise MeasurementError(f"{path}: no capsule rows after the header")
    for capsule in capsules:
        if flow == "tube" and capsule["L_p"] >= capsule["L_z"]:
            raise MeasurementError(f"{path}:{capsule.line}: field 'L_p' must be smaller than L_z")
        if flow == "shear" and capsule["L2"] > capsule["L1"]:
            raise MeasurementError(f"{path}:{capsule.line}: field 'L2' must not exceed L1 (L1 is the major semi-axis)")
        if flow == "shear" and capsule["D12_err"] >= 1:
            raise MeasurementError(f"{path}:{capsule.line}: field 'D12_err' must be below 1 (D12 lies in [0, 1))")
        if flow == "shear" and capsule["theta"] >= math.pi / 2:
            raise MeasurementError(f"{path}:{capsule.line}: field 'theta' must be below 90 deg (the major axis's "
                                   "inclination to the flow direction)")
    # Warned only once the file is read: a file that is refused warns of nothing.
    for name, quantity in plausibility.COLUMNS.items():
        outside = [c for c in capsules if math.isfinite(c[name]) and c[name] > 0 and not quantity.contains(c[name])]
        sentence = plausibility.out_of_range(name, quantity, (c[name] for c in outside),
                                             _lines([c.line for c in outside])) if outside else None
        if sentence:
            warnings.warn(f"{path}: {sentence}", InputWarning, stacklevel=2)
    if ignored:
        warnings.warn(f"{path}:{header_line}: ignored column(s) not in the {flow} format: "
                      f"{', '.join(repr(c) for c in ignored)}", InputWarning, stacklevel=2)
    if commented:
        warnings.warn(f"{path}: comment line(s) {', '.join(commented)} have the fields of a capsule row and are "
                      "left out; if an id starts with '#', quote it (\"#c01\",...)", InputWarning, stacklevel=2)
    return capsules


def _lines(numbers: list[int]) -> str:
    """``'line 4'``, ``'lines 2-14'`` or ``'lines 2, 5, 9 ...'`` for the rows a warning is about."""
    if len(numbers) == 1:
        return f"line {numbers[0]}"
    if numbers == list(range(numbers[0], numbers[-1] + 1)):
        return f"lines {numbers[0]}-{numbers[-1]}"
    return "lines " + ", ".join(str(n) for n in numbers[:5]) + (" ..." if len(numbers) > 5 else "")


def _read_row_contour(path: Path, line: int, cell: tuple[str, str, float | None], pixel: float | None,
                      anywhere: bool = False) -> np.ndarray:
    """The contour file a row names, in metres."""
    name, unit, scale = cell
    contour_path = Path(name) if Path(name).is_absolute() else path.parent / name
    folder = path.parent.resolve()
    if not anywhere and not contour_path.resolve().is_relative_to(folder):
        raise MeasurementError(f"{path}:{line}: field 'contour': {name!r} lies outside the measurement file's folder "
                               f"{folder}; contours are read only from there and below (move it there, or allow "
                               "contours anywhere: --contours-anywhere, contours_anywhere=True)")
    if unit == "px":
        if pixel is None:
            raise MeasurementError(f"{path}:{line}: field 'contour' is in px but the row has no pixel_size")
        scale = pixel
    try:
        contour = read_contour(contour_path)
    except ContourError as err:
        raise MeasurementError(f"{path}:{line}: field 'contour': {err}") from None
    contour = contour * scale
    problem = contour_problem(contour)
    if problem is not None:
        raise MeasurementError(f"{path}:{line}: field 'contour': {contour_path} in metres: {problem}")
    return contour
