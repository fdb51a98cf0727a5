"""Database files: the case files of a grid assembled into one table per membrane law.

Layout of ``tube.h5`` / ``shear.h5`` (``format = 'capsmech-database'``, version 1)
-------------------------------------------------------------------------------------
Root attributes (identity and provenance)
    ``name`` (e.g. ``'tube-paper'``, the name :mod:`capsmech.io.catalog` ships it under),
    ``version`` (of the database, an integer), ``accuracy`` (one line: the mesh and how
    close its results are to a finer one) - all three from the grid's ``<flow>.database``;
    ``format``, ``format_version``, ``flow``, ``grid_name``, ``grid`` (the whole grid as
    JSON), ``settings`` (the flow's mesh and time settings as JSON), ``code_version`` (of
    the kernel that wrote every case), ``created`` (UTC, ISO 8601), ``case_count``,
    ``profile_points``, ``capsmech_version``, ``length_scale``.
    Files made before the identity was recorded gained it with ``scripts/label_databases.py``.
``/<law key>`` (``NH``, ``SK_C1``, ``GH_nu0.5`` ...), attributes ``law``, ``nu_s``, ``C``
(NaN when the law has no such parameter), ``case_count``, ``steady_count``; one row per
case of the grid, in grid order, with 1-D datasets
    tube: ``a_over_l``, ``Ca_s``, ``L_z``, ``L_p``, ``vc_over_V``;
    shear: ``Ca_s``, ``D12``, ``L1_over_a``, ``L2_over_a``, ``L3_over_a``, ``theta``;
    both: ``wall_time_s``, ``status`` and ``message`` (text),
and 2-D ``profile_r``/``profile_z`` (tube meridian, pole to pole) or ``profile_y``/
``profile_z`` (shear-plane contour, closed), (rows, profile_points), resampled at equal
arclength. Every dataset has a ``units`` attribute ('1' for dimensionless, '' for text).

Rows that did not reach a steady state keep their parameters, status and message, and
carry NaN in every result column and profile: they are recorded, never dropped.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from capsmech import __version__
from capsmech.errors import CapsmechError
from capsmech.io.case import (
    EFFECT_DEFAULTS,
    STATUSES,
    CaseResult,
    decode_str,
    require_hdf5_file,
)
from capsmech.workflow.grid import (
    Case,
    expand_cases,
    flow_settings,
    grid_json,
    parse_law,
)
from capsmech.workflow.runner import read_outcome

FORMAT = "capsmech-database"
FORMAT_VERSION = 1

#: Parameter columns: name -> (Case attribute, units).
PARAMETERS: dict[str, dict[str, tuple[str, str]]] = {
    "tube": {"a_over_l": ("a_over_l", "1"), "Ca_s": ("Ca_s", "1")},
    "shear": {"Ca_s": ("Ca_s", "1")},
}
#: Result columns: name -> (``/steady`` dataset of the case file, its units there, units here).
RESULTS: dict[str, dict[str, tuple[str, str, str]]] = {
    "tube": {"L_z": ("L_z", "l", "l"), "L_p": ("L_p", "l", "l"), "vc_over_V": ("v_c", "V", "1")},
    "shear": {"D12": ("D12", "1", "1"), "L1_over_a": ("L1", "a", "1"), "L2_over_a": ("L2", "a", "1"),
              "L3_over_a": ("L3", "a", "1"), "theta": ("theta", "rad", "rad")},
}
#: Profile coordinates and their units (tube lengths in l, shear lengths in a).
PROFILES: dict[str, tuple[tuple[str, ...], str]] = {"tube": (("r", "z"), "l"), "shear": (("y", "z"), "a")}
LENGTH_SCALE = {"tube": "l (tube radius)", "shear": "a (capsule radius)"}
TEXT_COLUMNS = ("status", "message")


class DatabaseError(CapsmechError, ValueError):
    """A database cannot be assembled or loaded; the message names the file and the item."""


def database_identity(grid: Mapping[str, Any], flow: str) -> dict[str, Any]:
    """Return the identity a grid gives its ``flow`` database: name, version, accuracy.

    Parameters
    ----------
    grid : mapping
        The validated grid; its optional ``<flow>.database`` holds ``name``, ``version`` and
        ``accuracy``.
    flow : str
        'tube' or 'shear'.

    Returns
    -------
    dict
        ``name`` (default ``'<flow>-<grid name>'``), ``version`` (default 1) and
        ``accuracy`` (default ``'not stated by grid <grid name>'``).
    """
    given = grid.get(flow, {}).get("database", {})
    return {"name": str(given.get("name", f"{flow}-{grid['name']}")),
            "version": int(given.get("version", 1)),
            "accuracy": str(given.get("accuracy", f"not stated by grid {grid['name']}"))}


def expected_units(flow: str) -> dict[str, str]:
    """Return the units of every dataset of a law group of a ``flow`` database."""
    names, length = PROFILES[flow]
    units = {name: unit for name, (_, unit) in PARAMETERS[flow].items()}
    units.update({name: unit for name, (_, _, unit) in RESULTS[flow].items()})
    units.update({"wall_time_s": "s", "status": "", "message": ""})
    units.update({f"profile_{c}": length for c in names})
    return units


# ---------------------------------------------------------------------------
# Pure numerics
# ---------------------------------------------------------------------------


def resample_by_arclength(x: np.ndarray, y: np.ndarray, n: int, closed: bool) -> np.ndarray:
    """Resample a polyline to ``n`` points equally spaced in arclength.

    Parameters
    ----------
    x, y : numpy.ndarray
        Coordinates of the polyline's points, in order.
    n : int
        Number of output points.
    closed : bool
        True for a closed contour (the segment back to the first point counts, and the
        first point is not repeated); False for an open curve (both ends kept).

    Returns
    -------
    numpy.ndarray
        Shape (2, n): resampled x and y.
    """
    points = np.column_stack([x, y]).astype(float)
    if closed:
        points = np.vstack([points, points[:1]])
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    targets = np.linspace(0.0, s[-1], n, endpoint=not closed)
    return np.vstack([np.interp(targets, s, points[:, 0]), np.interp(targets, s, points[:, 1])])


# ---------------------------------------------------------------------------
# Assembly
# ---------------------------------------------------------------------------


def _check_case_matches(case: Case, result: CaseResult, path: Path) -> None:
    """Fail when a case file is not the run the grid asks for (wrong file in the place)."""
    expected = parse_law(case.law.key)
    pairs = [("flow", case.flow, result.flow), ("law", expected.name, result.law)]
    mismatch = [f"{name} {found!r}, grid wants {want!r}" for name, want, found in pairs if want != found]
    numbers = [("Ca_s", case.Ca_s, result.Ca_s)]
    if case.a_over_l is not None:
        numbers.append(("a_over_l", case.a_over_l, result.a_over_l))
    if expected.nu_s is not None:
        numbers.append(("nu_s", expected.nu_s, result.nu_s))
    if expected.C is not None:
        numbers.append(("C", expected.C, result.C))
    wanted_effects = dict(expected.effects)
    for name, neutral in EFFECT_DEFAULTS.items():
        numbers.append((name, wanted_effects.get(name, neutral), result.effects.get(name, neutral)))
    mismatch += [f"{name} {found!r}, grid wants {want!r}" for name, want, found in numbers
                 if not math.isclose(want, found, rel_tol=1e-12, abs_tol=1e-15)]
    if mismatch:
        raise DatabaseError(f"{path}: not the case of the grid: " + "; ".join(mismatch))


def _case_row(case: Case, path: Path, points: int) -> dict[str, Any]:
    """Read one case file (or failure record) into a database row."""
    if not path.is_file():
        raise DatabaseError(f"{path}: case file missing (run the workflow to compute it)")
    status, message, code_version, result = read_outcome(path)
    flow = case.flow
    row: dict[str, Any] = {name: getattr(case, attr) for name, (attr, _) in PARAMETERS[flow].items()}
    row.update(status=status, message=message, code_version=code_version,
               wall_time_s=math.nan if result is None else result.wall_time_s)
    names, _ = PROFILES[flow]
    row.update({name: math.nan for name in RESULTS[flow]})
    row.update({f"profile_{c}": np.full(points, np.nan) for c in names})
    if result is None:
        return row
    _check_case_matches(case, result, path)
    if status != "steady":
        return row
    for name, (source, unit, _) in RESULTS[flow].items():
        found = result.unit(f"steady/{source}")
        if found != unit:
            raise DatabaseError(f"{path}: '/steady/{source}' has units {found!r}, expected {unit!r}")
        row[name] = result.steady_value(source)
    for c in names:
        if result.unit(f"profile/{c}") != PROFILES[flow][1]:
            raise DatabaseError(f"{path}: '/profile/{c}' has units {result.unit(f'profile/{c}')!r}, "
                                f"expected {PROFILES[flow][1]!r}")
    resampled = resample_by_arclength(result.profile[names[0]], result.profile[names[1]], points,
                                      closed=flow == "shear")
    row.update({f"profile_{c}": resampled[i] for i, c in enumerate(names)})
    return row


def _write_dataset(group: h5py.Group, name: str, data: Any, units: str) -> None:
    """Write one dataset with its ``units`` attribute (text as variable-length UTF-8)."""
    if name in TEXT_COLUMNS:
        ds = group.create_dataset(name, data=np.array(data, dtype=object), dtype=h5py.string_dtype())
    else:
        ds = group.create_dataset(name, data=np.asarray(data, dtype=float))
    ds.attrs["units"] = units


def assemble_database(grid: Mapping[str, Any], flow: str, cases_dir: str | Path, out: str | Path,
                      *, created: str | None = None) -> Path:
    """Assemble the case files of one flow of a grid into a database file.

    Parameters
    ----------
    grid : mapping
        The validated grid (see :mod:`capsmech.workflow.grid`).
    flow : str
        'tube' or 'shear'.
    cases_dir : str or Path
        Directory holding ``<flow>/<law>/<case>.h5``.
    out : str or Path
        Database file to write (``OUT.tmp`` first, renamed when complete).
    created : str, optional
        Creation time recorded in the provenance; default now (UTC, ISO 8601).

    Returns
    -------
    Path
        The database file.

    Raises
    ------
    DatabaseError
        If a case file is missing, is not the grid's case, has unexpected units, or the
        cases were written by different kernel versions.
    """
    cases = expand_cases(grid, flow)
    if not cases:
        raise DatabaseError(f"grid {grid['name']!r} has no {flow} cases")
    points = int(grid.get("profile_points", 64))
    cases_dir, out = Path(cases_dir), Path(out)
    rows: dict[str, list[dict[str, Any]]] = {}
    for case in cases:
        rows.setdefault(case.law.key, []).append(_case_row(case, cases_dir / case.relative_path, points))
    versions = sorted({row["code_version"] for law_rows in rows.values() for row in law_rows})
    if len(versions) != 1:
        raise DatabaseError(f"{cases_dir}: {flow} cases were written by several kernel versions {versions}: "
                            "rerun the workflow so that every case is recomputed by one kernel")
    units = expected_units(flow)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    with h5py.File(tmp, "w") as f:
        f.attrs.update({
            **database_identity(grid, flow),
            "format": FORMAT, "format_version": FORMAT_VERSION, "flow": flow,
            "grid_name": grid["name"], "grid": grid_json(grid),
            "settings": json.dumps(flow_settings(grid, flow), sort_keys=True),
            "code_version": versions[0],
            "created": created or datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "case_count": len(cases), "profile_points": points,
            "capsmech_version": __version__, "length_scale": LENGTH_SCALE[flow],
        })
        for key, law_rows in rows.items():
            law = parse_law(key)
            group = f.create_group(key)
            group.attrs.update({
                "law": law.name,
                "nu_s": math.nan if law.nu_s is None else law.nu_s,
                "C": math.nan if law.C is None else law.C,
                **{name: dict(law.effects).get(name, neutral) for name, neutral in EFFECT_DEFAULTS.items()},
                "case_count": len(law_rows),
                "steady_count": sum(row["status"] == "steady" for row in law_rows),
            })
            for name, unit in units.items():
                _write_dataset(group, name, [row[name] for row in law_rows], unit)
    os.replace(tmp, out)
    return out


# ---------------------------------------------------------------------------
# Loading
# ---------------------------------------------------------------------------


@dataclass(frozen=True, eq=False, repr=False)
class LawTable:
    """The rows of one membrane law in a database.

    Attributes
    ----------
    key : str
        Law key, e.g. ``'GH_nu0.5'``.
    columns : dict[str, numpy.ndarray]
        Numeric columns (parameters, results, ``wall_time_s``), 1-D, one entry per row;
        results are NaN where the case is not steady.
    status, message : numpy.ndarray
        Text per row.
    profiles : dict[str, numpy.ndarray]
        ``profile_<coordinate>`` arrays of shape (rows, profile_points).
    units : dict[str, str]
        Units of every dataset.
    attrs : dict[str, Any]
        The group's attributes (law, nu_s, C, counts).
    """

    key: str
    columns: dict[str, np.ndarray]
    status: np.ndarray
    message: np.ndarray
    profiles: dict[str, np.ndarray]
    units: dict[str, str]
    attrs: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.status)

    def __repr__(self) -> str:
        return f"<LawTable {self.key}: {len(self)} rows, {int(self.steady.sum())} steady>"

    @property
    def steady(self) -> np.ndarray:
        """numpy.ndarray: boolean mask of the rows that reached a steady state."""
        return self.status == "steady"

    def column(self, name: str, steady_only: bool = True) -> np.ndarray:
        """Return a numeric column, by default only its steady rows."""
        values = self.columns[name]
        return values[self.steady] if steady_only else values

    def steady_rows(self) -> dict[str, np.ndarray]:
        """Return every numeric column and profile restricted to the steady rows.

        This is the table an inversion interpolates in: no NaN, one entry (or one profile
        row) per steady case, in grid order.
        """
        rows = self.steady
        return {name: values[rows] for name, values in {**self.columns, **self.profiles}.items()}


@dataclass(frozen=True, eq=False, repr=False)
class Database:
    """A loaded database file: one :class:`LawTable` per law key, and its provenance.

    Attributes
    ----------
    path : str
        The file.
    flow : str
        'tube' or 'shear'.
    laws : dict[str, LawTable]
        One table per law key, in the grid's order.
    provenance : dict[str, Any]
        Every root attribute of the file.
    """

    path: str
    flow: str
    laws: dict[str, LawTable]
    provenance: dict[str, Any]

    @property
    def name(self) -> str:
        """str: the database's name (``'tube-paper'`` ...; ``''`` in a file made before names)."""
        return str(self.provenance.get("name", ""))

    @property
    def version(self) -> int | None:
        """int or None: the database's version (None in a file made before versions)."""
        version = self.provenance.get("version")
        return None if version is None else int(version)

    @property
    def accuracy(self) -> str:
        """str: one line on the database's accuracy (``''`` in a file made before it was recorded)."""
        return str(self.provenance.get("accuracy", ""))

    @property
    def code_version(self) -> str:
        """str: the version of the kernel that computed every case."""
        return str(self.provenance.get("code_version", ""))

    @property
    def grid_name(self) -> str:
        """str: the name of the grid the database was computed from."""
        return str(self.provenance.get("grid_name", ""))

    def __repr__(self) -> str:
        grid = json.loads(self.provenance.get("grid", "{}")).get(self.flow, {})
        axes = " x ".join(f"{len(grid[axis])} {label}" for axis, label in (("a_over_l", "a/l"), ("Ca_s", "Ca_s"))
                          if axis in grid)
        keys = list(self.laws)
        laws = ", ".join(keys[:6]) + (f" (+{len(keys) - 6} more)" if len(keys) > 6 else "")
        size = f"{self.provenance.get('case_count', sum(len(t) for t in self.laws.values()))} cases"
        return (f"<{type(self).__name__} {self.name or self.path!r}: {self.flow}, laws {laws}; "
                f"{size}{f' ({axes} per law)' if axes else ''}>")

    @property
    def grid(self) -> dict[str, Any]:
        """dict: the grid the database was computed from."""
        return json.loads(self.provenance["grid"])

    def law(self, key: str) -> LawTable:
        """Return the table of one law; the KeyError lists the laws there are."""
        if key not in self.laws:
            raise KeyError(f"{self.path}: no law {key!r}; available: {', '.join(self.laws)}")
        return self.laws[key]


class TubeDatabase(Database):
    """Tube-flow database: columns a_over_l, Ca_s, L_z, L_p, vc_over_V per law."""


class ShearDatabase(Database):
    """Shear-flow database: columns Ca_s, D12, L1/L2/L3_over_a, theta per law."""


def _load_law(group: h5py.Group, flow: str, where: str, points: int) -> LawTable:
    """Read and check one law group: every dataset present, with its units and shape."""
    units = expected_units(flow)
    found_units: dict[str, str] = {}
    for name, unit in units.items():
        if name not in group:
            raise DatabaseError(f"{where}: '/{group.name.lstrip('/')}' has no dataset '{name}'")
        if "units" not in group[name].attrs:
            raise DatabaseError(f"{where}: '{group[name].name}' has no 'units' attribute")
        found_units[name] = decode_str(group[name].attrs["units"])
        if found_units[name] != unit:
            raise DatabaseError(f"{where}: '{group[name].name}' has units {found_units[name]!r}, "
                                f"expected {unit!r}")
    status = np.array(group["status"].asstr()[()], dtype=str)
    rows = len(status)
    columns, profiles = {}, {}
    for name in units:
        if name in TEXT_COLUMNS:
            continue
        data = np.asarray(group[name][()], dtype=float)
        shape = (rows, points) if name.startswith("profile_") else (rows,)
        if data.shape != shape:
            raise DatabaseError(f"{where}: '{group[name].name}' has shape {data.shape}, expected {shape}")
        data.setflags(write=False)
        (profiles if name.startswith("profile_") else columns)[name] = data
    unknown = sorted(set(status) - set(STATUSES))
    if unknown:
        raise DatabaseError(f"{where}: '{group.name}/status' holds unknown statuses {unknown}")
    return LawTable(
        key=group.name.lstrip("/"), columns=columns, status=status,
        message=np.array(group["message"].asstr()[()], dtype=str), profiles=profiles,
        units=found_units, attrs={k: v for k, v in group.attrs.items()},
    )


def load_database(path: str | Path) -> TubeDatabase | ShearDatabase:
    """Load a database, by name or by path, and check its format, columns and units.

    Parameters
    ----------
    path : str or Path
        The name of a shipped database (``'tube-paper'``, ``'shear-paper'`` ...; see
        :mod:`capsmech.io.catalog`) or the path of a ``tube.h5`` / ``shear.h5`` written by
        :func:`assemble_database`.

    Returns
    -------
    TubeDatabase or ShearDatabase
        According to the file's ``flow`` attribute.

    Raises
    ------
    DatabaseError
        If ``path`` is neither a shipped database's name nor an existing file (a
        :class:`capsmech.io.catalog.DatabaseNotFoundError`, also a FileNotFoundError; the
        message lists the shipped names); if it is not a capsmech database of a known
        version, or a column is missing, has other units or another length (the message
        names the file and dataset).
    """
    from capsmech.io.catalog import database_path  # the catalog imports this module

    path = database_path(path)
    where = require_hdf5_file(path, "database", DatabaseError)
    with h5py.File(path, "r") as f:
        provenance = {k: decode_str(v) if isinstance(v, (bytes, str, np.bytes_)) else v
                      for k, v in f.attrs.items()}
        if provenance.get("format") != FORMAT or provenance.get("format_version") != FORMAT_VERSION:
            raise DatabaseError(f"{where}: not a {FORMAT} file of version {FORMAT_VERSION} "
                                f"(format={provenance.get('format')!r}, "
                                f"version={provenance.get('format_version')!r})")
        flow = provenance.get("flow")
        if flow not in PARAMETERS:
            raise DatabaseError(f"{where}: root attribute 'flow' is {flow!r}, expected 'tube' or 'shear'")
        points = int(provenance["profile_points"])
        # HDF5 lists groups alphabetically; keep the grid's order of laws.
        grid_order = json.loads(provenance.get("grid", "{}")).get(flow, {}).get("laws", [])
        keys = [k for k in grid_order if k in f] + sorted(k for k in f if k not in grid_order)
        laws = {key: _load_law(f[key], flow, where, points) for key in keys}
    cls = TubeDatabase if flow == "tube" else ShearDatabase
    return cls(path=where, flow=flow, laws=laws, provenance=provenance)
