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
    ``profile_points``, ``capsmech_version``, ``length_scale``; a tube database also
    ``channel`` (``tube``, ``square`` or ``rect``) and ``aspect`` (the duct's height over its
    width), read as ``'tube'`` and 1 from a file made before they were recorded.
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

In a duct database (``channel`` square or rect) the length scale is the duct's half-width w:
``a_over_l`` is a/w and the lengths' unit ``l`` stands for w (``length_scale`` says so, as the
kernel's case files do); ``profile_r``/``profile_z`` is the capsule's outline in the plane y = 0
(x > 0), the section through the duct's mid-plane that a microscope focused there shows (the
projected silhouette would hide the rear dimple of a parachute).

Rows that did not reach a steady state keep their parameters, status and message, and
carry NaN in every result column and profile: they are recorded, never dropped.

A tube law group may hold ``critical`` (``CRITICAL_GROUP``): per a/l of the grid, the Ca_s where
its steady branch ends (``a_over_l``, ``Ca_s``, ``kind``, ``message``), found by the kernel's
continuation over the grid's Ca_s; read by :meth:`Database.critical`.

Every dataset is written with HDF5's Fletcher-32 checksum filter (chunked): a flipped bit in
a stored value makes the read fail, and :func:`load_database` reports the file as damaged
instead of returning a wrong number. Files written before the filter are read as they are.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import h5py
import numpy as np
from numpy.typing import ArrayLike

from capsmech.errors import DatabaseError
from capsmech.io.case import (
    STATUSES,
    decode_str,
    require_hdf5_file,
)
from capsmech.io.catalog import database_path
from capsmech.io.hdf5_inputs import data_elsewhere

if TYPE_CHECKING:
    import pandas as pd

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
#: The length scale of a duct database (channel square or rect), as the kernel writes it.
DUCT_LENGTH_SCALE = "w (duct half-width)"
TEXT_COLUMNS = ("status", "message")
#: Accuracy columns a database may hold (read as NaN where a file made before them lacks them):
#: name -> units. Shear: the estimated relative change of D12 still to come when the run stopped
#: (time), the D12 of the same case on the grid's other mesh level (``mesh_check``: the finer
#: one, or the cases' own level where the rows come from the finer one), the estimated relative
#: mesh error of the row's D12 from the two (:func:`mesh_error_rel`), and the mesh level the
#: row's values come from. Tube (3D model, ``tube.mesh_check``): for L_z, L_p and vc_over_V the
#: value of the same case on the other mesh level (``<column>_mesh_check``) and the estimated
#: relative mesh error of the row's value (``<column>_mesh_error_rel``), and the row's level.
ACCURACY_COLUMNS: dict[str, dict[str, str]] = {
    "tube": {"L_z_mesh_check": "l", "L_p_mesh_check": "l", "vc_over_V_mesh_check": "1",
             "L_z_mesh_error_rel": "1", "L_p_mesh_error_rel": "1", "vc_over_V_mesh_error_rel": "1", "mesh_level": "1"},
    "shear": {"D12_time_error_rel": "1", "D12_mesh_check": "1", "D12_mesh_error_rel": "1", "mesh_level": "1"},
}
#: Observed order of the shear D12's mesh convergence is about 2.4 (levels 2-4, validation page
#: "shear flow"); the mesh-error estimate assumes the lower 2, which makes it larger.
MESH_ERROR_ORDER = 2.0
#: Optional subgroup of a tube law group: where its steady branch ends, per a/l (datasets
#: a_over_l, Ca_s, kind and optionally message), found by continuation (a branch grid's
#: assembly, or scripts/add_folds.py for a database computed case by case).
CRITICAL_GROUP = "critical"


def mesh_error_rel(d12: ArrayLike, d12_finer: ArrayLike, levels_apart: int, of: str = "coarse",
                   order: float = MESH_ERROR_ORDER) -> np.ndarray:
    """Estimated relative mesh error of a quantity (D12, L_z ...) from the same case on two
    meshes (Richardson), with ``r = 2**levels_apart`` (each level halves the element size) and
    ``p = order``: of the coarser value (``of='coarse'``), ``|D12_finer - D12| / D12 * r**p /
    (r**p - 1)``; of the finer value (``of='finer'``), ``|D12_finer - D12| / D12_finer /
    (r**p - 1)``. NaN where either is missing."""
    d, f = np.asarray(d12, dtype=float), np.asarray(d12_finer, dtype=float)
    gain = (2.0 ** levels_apart) ** order
    with np.errstate(invalid="ignore", divide="ignore"):
        if of == "finer":
            return np.abs(f - d) / np.abs(f) / (gain - 1.0)
        if of != "coarse":
            raise ValueError(f"of must be 'coarse' or 'finer', not {of!r}")
        return np.abs(f - d) / np.abs(d) * gain / (gain - 1.0)


def expected_units(flow: str) -> dict[str, str]:
    """Return the units of every dataset of a law group of a ``flow`` database."""
    names, length = PROFILES[flow]
    units = {name: unit for name, (_, unit) in PARAMETERS[flow].items()}
    units.update({name: unit for name, (_, _, unit) in RESULTS[flow].items()})
    units.update(ACCURACY_COLUMNS[flow])
    units.update({"wall_time_s": "s", "status": "", "message": ""})
    units.update({f"profile_{c}": length for c in names})
    return units


# ---------------------------------------------------------------------------
# Pure numerics
# ---------------------------------------------------------------------------


# ---------------------------------------------------------------------------
# Assembly
# ---------------------------------------------------------------------------


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
    critical : dict[str, numpy.ndarray] or None
        Tube databases computed by continuation: ``a_over_l``, ``Ca_s`` (the critical capillary
        number where the steady branch ends; NaN where it does not end inside the grid),
        ``kind`` (``fold``, ``mesh_limit``, ``none: ...`` or ``failed: ...``) and, where
        recorded, ``message`` (the kernel's words), one entry per a/l; None in a database whose
        folds were not searched (``scripts/add_folds.py`` adds them to one computed case by case).
    """

    key: str
    columns: dict[str, np.ndarray]
    status: np.ndarray
    message: np.ndarray
    profiles: dict[str, np.ndarray]
    units: dict[str, str]
    attrs: dict[str, Any] = field(default_factory=dict)
    critical: dict[str, np.ndarray] | None = None

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

    def critical_at(self, a_over_l: float) -> tuple[float, str]:
        """The critical Ca_s at ``a_over_l`` and what it is: linear in ln Ca_s between the two
        a/l of the ``critical`` group around it (exact on one of them); NaN where it is not known
        (no ``critical`` group, ``a_over_l`` outside its a/l, or a neighbour without an end
        inside the grid). The kind is the neighbours' (``fold``, ``mesh_limit``; both when they
        differ), ``''`` where the value is NaN."""
        if self.critical is None or not np.isfinite(a_over_l):
            return math.nan, ""
        order = np.argsort(self.critical["a_over_l"])
        sizes, values = self.critical["a_over_l"][order], self.critical["Ca_s"][order]
        kinds = self.critical["kind"][order]
        if not sizes.size or a_over_l < sizes[0] or a_over_l > sizes[-1]:
            return math.nan, ""
        upper = min(int(np.searchsorted(sizes, a_over_l)), sizes.size - 1)
        lower = upper if sizes[upper] == a_over_l else upper - 1
        pair = values[[lower, upper]]
        if not np.all(np.isfinite(pair) & (pair > 0)):
            return math.nan, ""
        weight = 0.0 if upper == lower else (a_over_l - sizes[lower]) / (sizes[upper] - sizes[lower])
        kind = "/".join(dict.fromkeys(str(k).split(":")[0] for k in kinds[[lower, upper]]))
        return float(np.exp((1 - weight) * np.log(pair[0]) + weight * np.log(pair[1]))), kind

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

    @property
    def channel(self) -> str:
        """str: the tube flow's channel, ``'tube'`` (circular, lengths in the radius l),
        ``'square'`` or ``'rect'`` (a duct, lengths in its half-width w); ``'tube'`` for a file
        made before the channel was recorded, and for a shear database."""
        return str(self.provenance.get("channel", "tube"))

    @property
    def aspect(self) -> float:
        """float: the duct's height over its width (1 for a tube, a square duct, or a file made
        before it was recorded)."""
        return float(self.provenance.get("aspect", 1.0))

    def __repr__(self) -> str:
        grid = json.loads(self.provenance.get("grid", "{}")).get(self.flow, {})
        axes = " x ".join(f"{len(grid[axis])} {label}" for axis, label in (("a_over_l", "a/l"), ("Ca_s", "Ca_s"))
                          if axis in grid)
        keys = list(self.laws)
        laws = ", ".join(keys[:6]) + (f" (+{len(keys) - 6} more)" if len(keys) > 6 else "")
        size = f"{self.provenance.get('case_count', sum(len(t) for t in self.laws.values()))} cases"
        flow = self.flow if self.channel == "tube" else f"{self.flow} ({self.channel} duct, lengths in w)"
        return (f"<{type(self).__name__} {self.name or self.path!r}: {flow}, laws {laws}; "
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

    def critical(self, law: str) -> pd.DataFrame:
        """Where the steady branch of one law ends, per a/l of the grid: columns ``a_over_l``,
        ``critical_Ca_s`` (NaN where the branch does not end inside the grid's Ca_s, or its
        search failed), ``kind`` (``fold``: the branch turns back, no steady shape above it,
        continuous elongation; ``mesh_limit``: it leaves what the mesh resolves; ``unstable``
        (a 3D branch): its steady shapes stop being stable there; ``none: ...``,
        ``failed: ...``) and ``message`` (the kernel's words, where recorded). Empty where the
        database records no ends (``scripts/add_folds.py`` adds them); the KeyError of
        :meth:`law` for a law it does not have."""
        import pandas as pd

        table = self.law(law)
        if table.critical is None:
            return pd.DataFrame(columns=["a_over_l", "critical_Ca_s", "kind", "message"])
        ends = table.critical
        return pd.DataFrame({"a_over_l": ends["a_over_l"], "critical_Ca_s": ends["Ca_s"], "kind": ends["kind"],
                             "message": ends.get("message", ends["kind"])})

    def critical_Ca_s(self) -> pd.DataFrame:
        """Where each law's steady branch ends: columns ``law``, ``a_over_l``, ``critical_Ca_s``
        (NaN where the branch does not end inside the grid) and ``kind`` (``fold``: the branch
        turns back, continuous elongation beyond; ``mesh_limit``: it leaves what the mesh
        resolves). Empty for a database computed case by case (no continuation)."""
        import pandas as pd

        frames = [pd.DataFrame({"law": key, "a_over_l": table.critical["a_over_l"],
                                "critical_Ca_s": table.critical["Ca_s"], "kind": table.critical["kind"]})
                  for key, table in self.laws.items() if table.critical is not None]
        if not frames:
            return pd.DataFrame(columns=["law", "a_over_l", "critical_Ca_s", "kind"])
        return pd.concat(frames, ignore_index=True)


class TubeDatabase(Database):
    """Tube-flow database: columns a_over_l, Ca_s, L_z, L_p, vc_over_V per law."""


class ShearDatabase(Database):
    """Shear-flow database: columns Ca_s, D12, L1/L2/L3_over_a, theta per law."""


def _read(dataset: h5py.Dataset, where: str, text: bool = False) -> np.ndarray:
    """A dataset's values; a DatabaseError naming the file and dataset when they cannot be read
    (its Fletcher-32 checksum fails: a damaged file)."""
    try:
        return np.asarray(dataset.asstr()[()] if text else dataset[()])
    except (OSError, ValueError, TypeError) as exc:
        raise DatabaseError(f"{where}: dataset '{dataset.name}' cannot be read (damaged file: a checksum fails, "
                            f"{exc}); restore the file, or reassemble it with the workflow") from None


def _load_law(group: h5py.Group, flow: str, where: str, points: int) -> LawTable:
    """Read and check one law group: every dataset present, with its units and shape."""
    units = expected_units(flow)
    found_units: dict[str, str] = {}
    # Accuracy columns are optional (files made before them are read with NaN there).
    absent = [name for name in ACCURACY_COLUMNS[flow] if name not in group]
    for name in absent:
        del units[name]
    for name, unit in units.items():
        if name not in group:
            raise DatabaseError(f"{where}: '/{group.name.lstrip('/')}' has no dataset '{name}'")
        if "units" not in group[name].attrs:
            raise DatabaseError(f"{where}: '{group[name].name}' has no 'units' attribute")
        found_units[name] = decode_str(group[name].attrs["units"])
        if found_units[name] != unit:
            raise DatabaseError(f"{where}: '{group[name].name}' has units {found_units[name]!r}, "
                                f"expected {unit!r}")
    status = np.array(_read(group["status"], where, text=True), dtype=str)
    rows = len(status)
    columns: dict[str, np.ndarray] = {}
    profiles: dict[str, np.ndarray] = {}
    for name in units:
        if name in TEXT_COLUMNS:
            continue
        data = np.asarray(_read(group[name], where), dtype=float)
        shape = (rows, points) if name.startswith("profile_") else (rows,)
        if data.shape != shape:
            raise DatabaseError(f"{where}: '{group[name].name}' has shape {data.shape}, expected {shape}")
        data.setflags(write=False)
        (profiles if name.startswith("profile_") else columns)[name] = data
    for name in ACCURACY_COLUMNS[flow]:
        if name not in columns:
            missing = np.full(rows, np.nan)
            missing.setflags(write=False)
            columns[name] = missing
            found_units[name] = ACCURACY_COLUMNS[flow][name]
    unknown = sorted(set(status) - set(STATUSES))
    if unknown:
        raise DatabaseError(f"{where}: '{group.name}/status' holds unknown statuses {unknown}")
    return LawTable(
        key=group.name.lstrip("/"), columns=columns, status=status,
        message=np.array(_read(group["message"], where, text=True), dtype=str), profiles=profiles,
        units=found_units, attrs={k: v for k, v in group.attrs.items()},
        critical=_load_critical(group, where),
    )


def _load_critical(group: h5py.Group, where: str) -> dict[str, np.ndarray] | None:
    """The law group's critical Ca_s per a/l (None when it has none), checked for shape."""
    if CRITICAL_GROUP not in group:
        return None
    ends = group[CRITICAL_GROUP]
    missing = [name for name in ("a_over_l", "Ca_s", "kind") if name not in ends]
    if missing:
        raise DatabaseError(f"{where}: '{ends.name}' has no dataset {missing[0]!r}")
    critical = {"a_over_l": np.asarray(_read(ends["a_over_l"], where), dtype=float),
                "Ca_s": np.asarray(_read(ends["Ca_s"], where), dtype=float),
                "kind": np.array(_read(ends["kind"], where, text=True), dtype=str)}
    if "message" in ends:
        critical["message"] = np.array(_read(ends["message"], where, text=True), dtype=str)
    if len({len(values) for values in critical.values()}) != 1:
        raise DatabaseError(f"{where}: '{ends.name}' datasets differ in length")
    return critical


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
        version, or a column is missing, has other units or another length, or the file is
        truncated or damaged (a dataset's Fletcher-32 checksum fails); the message names the
        file (and the dataset where it is known).
    """

    path = database_path(path)
    where = require_hdf5_file(path, "database", DatabaseError)
    try:
        return _load_open_database(path, where)
    except DatabaseError:
        raise
    except (OSError, KeyError, ValueError, RuntimeError, TypeError) as exc:
        # h5py's errors on a truncated file, a damaged structure or a dataset whose Fletcher-32
        # checksum does not match what it holds.
        raise DatabaseError(f"{where}: cannot read the database (truncated or damaged file: {exc}); "
                            "restore it, or reassemble it with the workflow") from None


def _load_open_database(path: Path, where: str) -> TubeDatabase | ShearDatabase:
    """``load_database`` on a file known to exist and to carry HDF5's signature."""
    with h5py.File(path, "r") as f:
        elsewhere = data_elsewhere(f)
        if elsewhere is not None:
            raise DatabaseError(f"{where}: {elsewhere}; a database is read from its own file only")
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
