"""The databases shipped with capsmech, addressed by name.

The database files made by the workflow (``config/<grid>.yaml``) that capsmech ships live in
the package itself, ``capsmech/databases/``, and are found with :mod:`importlib.resources`:
from a source checkout, an editable install or an installed wheel alike, whatever the
current directory. Each file carries its identity in its root attributes (``name``,
``version``, ``grid_name``, ``code_version``, ``accuracy``; see
:mod:`capsmech.io.database`).

Names
-----
=========================  =====  ==================================================
``tube-paper``             tube   the paper grid (fitting default)
``shear-paper``            shear  the paper grid (fitting default)
``tube-prestress``         tube   effect library: NH with pre-stress (``diagnose``)
``tube-kb``                tube   effect library: NH with bending stiffness (``diagnose``)
``offcentre``              tube   off-centre table (:mod:`capsmech.diagnosis.offcentre`)
``shear-microrheometry``   shear  viscosity ratio 0.001 (``compare-methods``)
``tube-smoke``             tube   coarse workflow check (tests)
``shear-smoke``            shear  coarse workflow check (tests)
``tube-dev``               tube   development grid of the example batches
``shear-dev``              shear  development grid of the example batches
``duct-dev``               tube   square duct (lengths in its half-width w), 3D model
=========================  =====  ==================================================

Typical use::

    from capsmech.io.catalog import database_path
    from capsmech.io.database import load_database
    db = load_database("tube-paper")            # same as load_database(database_path("tube-paper"))
"""

from __future__ import annotations

import atexit
import contextlib
import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import h5py

from capsmech.errors import DatabaseError
from capsmech.io.case import decode_str

#: The package folder (below ``capsmech``) that holds the shipped files.
PACKAGE_FOLDER = "databases"


class DatabaseNotFoundError(DatabaseError, FileNotFoundError):
    """Neither a shipped database's name nor an existing file (a DatabaseError and a FileNotFoundError)."""


@dataclass(frozen=True)
class CatalogEntry:
    """One shipped file as the catalog knows it (its identity is in the file).

    Attributes
    ----------
    name : str
        Catalog name, e.g. ``'tube-paper'``.
    flow : str
        ``'tube'`` or ``'shear'``.
    kind : str
        ``'database'`` (a capsmech database, :func:`capsmech.io.database.load_database`) or
        ``'offcentre-table'`` (:meth:`capsmech.diagnosis.offcentre.OffcentreTable.read`).
    resource : str
        Path of the file below ``capsmech/databases/`` ('/'-separated).
    description : str
        What it is for, one line.
    """

    name: str
    flow: str
    kind: str
    resource: str
    description: str


@dataclass(frozen=True)
class ShippedDatabase:
    """A shipped file, found on disk.

    Attributes
    ----------
    name, flow, kind, description : str
        As in :class:`CatalogEntry`.
    path : Path
        The file.
    accuracy : str
        The file's one-line statement of its accuracy (root attribute ``accuracy``; ``''``
        when the file has none).
    """

    name: str
    flow: str
    kind: str
    path: Path
    description: str
    accuracy: str


#: Every shipped file, by name.
CATALOG: dict[str, CatalogEntry] = {entry.name: entry for entry in (
    CatalogEntry("tube-paper", "tube", "database", "tube.h5",
                 "paper grid: NH, SK_C1, GH_nu0.5/0.2/0, a/l 0.70-1.10 x Ca_s 0.01-5 (config/paper.yaml)"),
    CatalogEntry("shear-paper", "shear", "database", "shear.h5",
                 "paper grid: NH, GH_nu0.5/0.2/0, Ca_s 0.01-1, viscosity ratio 1 (config/paper.yaml)"),
    CatalogEntry("tube-prestress", "tube", "database", "effects/prestress/tube.h5",
                 "effect library of diagnose: NH+prestress0.04/0.06/0.08 (config/effects_prestress.yaml)"),
    CatalogEntry("tube-kb", "tube", "database", "effects/kb/tube.h5",
                 "effect library of diagnose: NH+kb0.0025/0.005/0.01 (config/effects_kb.yaml)"),
    CatalogEntry("offcentre", "tube", "offcentre-table", "effects/offcentre/table.h5",
                 "off-centre table: antisymmetric mode of a capsule held off the axis, NH, "
                 "a/l 0.7-0.85 x Ca_s 0.035-0.14 (scripts/make_offcentre_table.py)"),
    CatalogEntry("shear-microrheometry", "shear", "database", "microrheometry/shear.h5",
                 "viscosity ratio 0.001: NH, GH_nu0.5/0.2, Ca_s 0.15-1 (config/microrheometry.yaml)"),
    CatalogEntry("tube-smoke", "tube", "database", "smoke/tube.h5",
                 "smoke grid: coarse end-to-end check of the workflow, not for fitting (config/smoke.yaml)"),
    CatalogEntry("shear-smoke", "shear", "database", "smoke/shear.h5",
                 "smoke grid: coarse end-to-end check of the workflow, not for fitting (config/smoke.yaml)"),
    CatalogEntry("tube-dev", "tube", "database", "dev/tube.h5",
                 "development grid of the example batches: NH, GH_nu0.5 (config/dev.yaml)"),
    CatalogEntry("shear-dev", "shear", "database", "dev/shear.h5",
                 "development grid of the example batches: NH, GH_nu0.5/0.2 (config/dev.yaml)"),
    CatalogEntry("duct-dev", "tube", "database", "duct-dev/tube.h5",
                 "square duct, lengths in its half-width w, outline in the mid-plane y = 0: NH, GH_nu0.5, "
                 "a/w 0.6-0.9 x Ca_s 0.02-0.15, 3D model level 3 (config/duct-dev.yaml)"),
)}

#: The tube databases of effect law groups that ``diagnose`` reads by default.
EFFECT_DATABASES: tuple[str, ...] = ("tube-kb", "tube-prestress")
#: The off-centre table ``diagnose`` reads by default.
OFFCENTRE_TABLE = "offcentre"

# Files extracted from a zipped package live until the interpreter exits.
_EXTRACTED = contextlib.ExitStack()
atexit.register(_EXTRACTED.close)


def catalog_names() -> list[str]:
    """Return the names of the shipped files, in catalog order."""
    return list(CATALOG)


def _resource_path(entry: CatalogEntry) -> Path:
    """The shipped file of ``entry`` on the file system (extracted once if the package is zipped)."""
    resource = resources.files("capsmech").joinpath(PACKAGE_FOLDER, *entry.resource.split("/"))
    if isinstance(resource, Path):
        return resource
    return Path(_EXTRACTED.enter_context(resources.as_file(resource)))


def _shipped_path(name: str) -> Path:
    """The file of the catalog's ``name``; DatabaseNotFoundError when the package lacks it."""
    path = _resource_path(CATALOG[name])
    if not path.is_file():
        raise DatabaseNotFoundError(f"shipped database {name!r} is missing from the installed package "
                                    f"(expected at {path}): reinstall capsmech")
    return path


def database_path(name_or_path: str | Path) -> Path:
    """Return the file of a shipped database given its name, or an existing file given its path.

    Parameters
    ----------
    name_or_path : str or Path
        A catalog name (``'tube-paper'``, ... see :data:`CATALOG`) or the path of a file.
        A catalog name given as a str wins over a file of the same name in the current
        directory; given as a Path, the file wins.

    Returns
    -------
    Path
        The file (a shipped file inside the installed package, or the path as given).

    Raises
    ------
    DatabaseError
        If ``name_or_path`` is neither a catalog name nor an existing file (the message lists
        the catalog's names), or if a shipped file is missing from the installed package.
        It is also a FileNotFoundError (:class:`DatabaseNotFoundError`).
    """
    text = os.fspath(name_or_path)
    if isinstance(name_or_path, str) and text in CATALOG:
        return _shipped_path(text)
    path = Path(name_or_path)
    if path.is_file():
        return path
    if text in CATALOG:  # a name given as a Path, and no such file here
        return _shipped_path(text)
    if path.exists():
        kind = "a folder" if path.is_dir() else "not a regular file (a device, pipe or socket)"
        raise DatabaseNotFoundError(f"{text!r}: {kind}, not a database file; shipped databases: {', '.join(CATALOG)}")
    raise DatabaseNotFoundError(f"{str(name_or_path)!r}: neither a shipped database nor an existing file; "
                                f"shipped databases: {', '.join(CATALOG)}")


def _accuracy(path: Path) -> str:
    """The ``accuracy`` root attribute of a file ('' when it has none)."""
    try:
        with h5py.File(path, "r") as f:
            return decode_str(f.attrs["accuracy"]) if "accuracy" in f.attrs else ""
    except (OSError, TypeError) as exc:
        raise DatabaseError(f"{path}: cannot read the shipped database (truncated or damaged: {exc}); "
                            "reinstall capsmech") from None


def shipped_databases() -> list[ShippedDatabase]:
    """Return every shipped file with its path, description and statement of accuracy.

    Returns
    -------
    list of ShippedDatabase
        In catalog order; ``accuracy`` read from each file's root attributes.
    """
    found = []
    for name, entry in CATALOG.items():
        path = database_path(name)
        found.append(ShippedDatabase(name=name, flow=entry.flow, kind=entry.kind, path=path,
                                     description=entry.description, accuracy=_accuracy(path)))
    return found


def effect_database_paths() -> list[Path]:
    """Return the tube databases of effect law groups that ``diagnose`` reads by default.

    Returns
    -------
    list of Path
        The files of :data:`EFFECT_DATABASES` (bending stiffness, pre-stress), in that order.
    """
    return [database_path(name) for name in EFFECT_DATABASES]


def offcentre_table_path() -> Path:
    """Return the shipped off-centre table (read with ``OffcentreTable.read``).

    Returns
    -------
    Path
        The file of the catalog's ``'offcentre'`` entry.
    """
    return database_path(OFFCENTRE_TABLE)


def database_versions() -> dict[str, str]:
    """Each shipped database's ``grid_name`` and the kernel ``code_version`` that filled it.

    Returns
    -------
    dict
        Name -> ``'grid paper, kernel 0.3.5'`` (``'unreadable'`` for a damaged file), in catalog order.
    """
    versions = {}
    for name in CATALOG:
        try:
            with h5py.File(database_path(name), "r") as f:
                grid = decode_str(f.attrs.get("grid_name", "?"))
                code = decode_str(f.attrs.get("code_version", "?"))
            versions[name] = f"grid {grid}, kernel {code}"
        except (OSError, TypeError, DatabaseError):
            versions[name] = "unreadable"
    return versions
