"""The columns of a measurement table: their names, kinds and units, and each unit's scale to SI.

A header cell is ``name [unit]`` or ``name (unit)``. Names are matched without regard to case
(``l_z [um]`` is ``L_z``), and so are units (``MPA S`` is ``mPa s``: no two accepted units
differ only in case); micro may be written ``u``, ``µ`` (U+00B5) or ``μ`` (U+03BC), and the
product in ``Pa s`` with a space, a no-break space, ``·``, ``*`` or ``.``.

The units are a short table per kind of quantity, not a unit library such as pint: a
measurement column takes one of a handful of units, ``px`` is not a physical unit (its scale is
the row's ``pixel_size``), and a table lists in one line, in the error, the units a column
accepts; pint would add a dependency and a registry to load for no unit a lab uses.
"""
from __future__ import annotations

import math
import re
from collections.abc import Mapping

LENGTH_UNITS = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "nm": 1e-9, "px": None}
VELOCITY_UNITS = {"m/s": 1.0, "mm/s": 1e-3, "um/s": 1e-6, "µm/s": 1e-6}
VISCOSITY_UNITS = {"Pa s": 1.0, "Pa.s": 1.0, "mPa s": 1e-3, "mPa.s": 1e-3, "cP": 1e-3}
RATE_UNITS = {"1/s": 1.0, "s^-1": 1.0}
ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180}
DIMENSIONLESS_UNITS = {"": 1.0, "1": 1.0}
UNITS: dict[str, Mapping[str, float | None]] = {"length": LENGTH_UNITS, "velocity": VELOCITY_UNITS,
                                                "viscosity": VISCOSITY_UNITS, "rate": RATE_UNITS,
                                                "angle": ANGLE_UNITS, "number": DIMENSIONLESS_UNITS}
#: The unit each kind is converted to on reading (what ``DataFrame.attrs["units"]`` names).
SI_UNITS = {"length": "m", "velocity": "m/s", "viscosity": "Pa s", "rate": "1/s", "angle": "rad", "number": "1"}
#: A unit of each kind as a lab would write it, for the examples in messages.
EXAMPLE_UNITS = {"length": "um", "velocity": "mm/s", "viscosity": "mPa s", "rate": "1/s", "angle": "deg", "number": "1"}

#: Column -> (kind, required) per flow.
TUBE_COLUMNS = {"L_z": ("length", True), "L_p": ("length", True), "tube_radius": ("length", True),
                "v_c": ("velocity", False), "mu": ("viscosity", False), "V": ("velocity", False),
                "pixel_size": ("length", False), "contour": ("length", False), "contour_noise": ("length", False),
                "tube_radius_sigma": ("length", False), "half_width": ("length", False),
                "half_width_sigma": ("length", False)}
SHEAR_COLUMNS = {"L1": ("length", True), "L2": ("length", True), "shear_rate": ("rate", True),
                 "mu": ("viscosity", True), "pixel_size": ("length", False), "theta": ("angle", False),
                 "D12_err": ("number", False)}
FLOWS = {"tube": TUBE_COLUMNS, "shear": SHEAR_COLUMNS}
#: The channel a tube file's length-scale column says, with that column's uncertainty column: a
#: circular tube gives its radius, a square channel its half-width (the radius of its inscribed
#: circle). A file gives one of them; either stands for the required ``tube_radius``.
CHANNEL_COLUMNS = {"tube_radius": ("tube", "tube_radius_sigma"), "half_width": ("square", "half_width_sigma")}
#: The channels a tube file can be of (the shapes of ``CHANNEL_COLUMNS``).
CHANNEL_SHAPES = tuple(shape for shape, _ in CHANNEL_COLUMNS.values())


def length_scale_columns(channel: str) -> tuple[str, str]:
    """The length-scale column of a channel's measurement file and its uncertainty column:
    ``("tube_radius", "tube_radius_sigma")`` for ``"tube"``, ``("half_width", ...)`` for
    ``"square"``."""
    for name, (shape, sigma) in CHANNEL_COLUMNS.items():
        if shape == channel:
            return name, sigma
    raise ValueError(f"channel: {channel!r} is none of {', '.join(CHANNEL_SHAPES)}")
#: A required column -> the columns that may stand in its place.
ALTERNATIVES = {"tube_radius": ("half_width",)}
#: Columns where zero is a measurement (no rear dimple; an exact value), not a slip.
ZERO_ALLOWED = frozenset({"L_p", "tube_radius_sigma", "half_width_sigma", "D12_err"})
#: Text columns ``capsmech extract`` writes for the reader of the file (not for the fit): skipped
#: without the warning an unknown column gets.
NOTE_COLUMNS = frozenset({"width_check"})

HEADER = re.compile(r"^\s*(?P<name>[A-Za-z_][A-Za-z0-9_]*)\s*(?:\[(?P<bracket>[^\]]*)\]|\((?P<paren>[^)]*)\))?\s*$")
#: Lower-case name -> the name as the format spells it.
_NAMES = {name.lower(): name for name in ["id", *NOTE_COLUMNS, *TUBE_COLUMNS, *SHEAR_COLUMNS]}


def _spelling(unit: str) -> str:
    """A unit folded for look-up: micro as ``u``, the product in ``Pa s`` a single space, lower case."""
    unit = unit.replace("\u00b5", "u").replace("\u03bc", "u").replace("\u00b7", " ").replace("*", " ")
    return " ".join(unit.split()).lower()


#: Kind -> folded spelling -> (the table's first spelling, scale to SI).
_LOOKUP: dict[str, dict[str, tuple[str, float | None]]] = {kind: {} for kind in UNITS}
for _kind, _table in UNITS.items():
    for _unit, _scale in _table.items():
        _LOOKUP[_kind].setdefault(_spelling(_unit), (_unit, _scale))


def header_cell(cell: str) -> tuple[str, str | None] | None:
    """A header cell's column name (as the format spells it, when it is one of the format's)
    and its unit as written (None when the cell names no unit); None when the cell is not
    ``name``, ``name [unit]`` or ``name (unit)``."""
    match = HEADER.match(cell)
    if not match:
        return None
    unit = match["bracket"] if match["bracket"] is not None else match["paren"]
    return _NAMES.get(match["name"].lower(), match["name"]), unit


def unit_scale(kind: str, unit: str) -> tuple[str, float | None] | None:
    """The table's spelling of ``unit`` and its scale to SI (None for px); None when ``kind``
    has no such unit."""
    return _LOOKUP[kind].get(_spelling(unit))


def accepted_units(kind: str) -> str:
    """The units of ``kind``, one spelling each, for a message."""
    return ", ".join(unit for unit in UNITS[kind] if unit and "\u00b5" not in unit and "." not in unit)
