"""Label the shipped databases with their identity: root attributes ``name``, ``version`` and
``accuracy`` (and, for the off-centre table, ``grid_name``, ``grid`` and ``code_version``, which
the databases already carry).

Files the workflow makes now carry them (assemble_database writes the grid's
``<flow>.database``); this script adds them to the files made before, from the same grids
(config/*.yaml) and, for the off-centre table, from scripts/make_offcentre_table.py. It only
writes root attributes: every dataset and every other attribute is left as it is, which the
script checks (a digest of every dataset and group attribute, before and after).

    PYTHONPATH=analysis/src .venv/bin/python scripts/label_databases.py [--check]
"""
from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from capsmech.io.case import decode_str
from capsmech.io.catalog import CATALOG, database_path
from capsmech.workflow.assembly import database_identity
from capsmech.workflow.grid import load_grid

from make_offcentre_table import identity as offcentre_identity

ROOT = Path(__file__).resolve().parents[1]
#: The kernel that made the off-centre table: kernel/src/capsim_kinds.f90 declared 0.3.0 at
#: commit 5404484, which made the table (its case files are not shipped).
OFFCENTRE_CODE_VERSION = "0.3.0"


def grids_by_name() -> dict[str, dict[str, Any]]:
    """The grids of config/*.yaml, by their name."""
    grids = (load_grid(path) for path in sorted((ROOT / "config").glob("*.yaml")))
    return {grid["name"]: grid for grid in grids}


def wanted_attributes(name: str, path: Path, grids: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The identity a shipped file should carry, from its grid (or the off-centre table's script)."""
    if CATALOG[name].kind == "offcentre-table":
        return offcentre_identity(OFFCENTRE_CODE_VERSION)
    with h5py.File(path, "r") as f:
        grid_name, flow = decode_str(f.attrs["grid_name"]), decode_str(f.attrs["flow"])
    if grid_name not in grids:
        raise SystemExit(f"{path}: made by grid {grid_name!r}, which no config/*.yaml names")
    wanted = database_identity(grids[grid_name], flow)
    if wanted["name"] != name:
        raise SystemExit(f"{path}: config/{grid_name}.yaml names its {flow} database {wanted['name']!r}, "
                         f"the catalog {name!r}")
    return wanted


def content_digest(path: Path) -> str:
    """A digest of every dataset (values, dtype, shape) and of the attributes below the root."""
    digest = hashlib.sha256()

    def visit(item_name: str, item: h5py.Group | h5py.Dataset) -> None:
        digest.update(item_name.encode())
        for key in sorted(item.attrs):
            digest.update(key.encode() + repr(item.attrs[key]).encode())
        if isinstance(item, h5py.Dataset):
            data = item[()]
            digest.update(str((item.dtype, item.shape)).encode())
            digest.update(repr(data.tolist()).encode() if data.dtype == object else np.ascontiguousarray(data).tobytes())

    with h5py.File(path, "r") as f:
        f.visititems(visit)
    return digest.hexdigest()


def differs(found: Any, wanted: Any) -> bool:
    """Whether a root attribute as stored differs from the wanted value."""
    if found is None:
        return True
    if isinstance(wanted, str):
        return decode_str(found) != wanted
    return found != wanted


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only report; exit 1 when a file lacks its identity")
    args = parser.parse_args(argv)
    grids = grids_by_name()
    unlabelled = 0
    for name in CATALOG:
        path = database_path(name)
        wanted = wanted_attributes(name, path, grids)
        with h5py.File(path, "r") as f:
            changes = {k: v for k, v in wanted.items() if differs(f.attrs.get(k), v)}
        shown = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
        if not changes:
            print(f"{name:22s} {shown}: labelled")
            continue
        unlabelled += 1
        if args.check:
            print(f"{name:22s} {shown}: lacks {', '.join(changes)}")
            continue
        before = content_digest(path)
        with h5py.File(path, "r+") as f:
            f.attrs.update(changes)
        if content_digest(path) != before:
            raise SystemExit(f"{path}: its datasets changed while labelling it")
        print(f"{name:22s} {shown}: wrote {', '.join(changes)} (datasets unchanged)")
    return 1 if args.check and unlabelled else 0


if __name__ == "__main__":
    sys.exit(main())
