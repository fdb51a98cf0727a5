"""Record in a tube database where each steady branch ends (the fold: the critical Ca_s of
continuous elongation, per law and a/l), without refilling its rows.

The database's rows were time-stepped case by case; the fold is found by the kernel's
continuation (``capsim --branch-ca``), one branch per (law, a/l) of the grid that made the
database, with the database's own settings (mesh, time limit of the cases the branch
time-steps) and the law group's parameters (law, nu_s, C and its effects: prestress, kb, lambda,
offset). The branch runs over the grid's own Ca_s, as the workflow's branch grids do, so that
the fold is the one a branch grid would record. Its case files are thrown away (the rows stay
those of the database); its branch file is kept under ``<results_dir>/folds`` (a rerun reuses
the branch files of the same kernel and request).

Each law group whose branches are all there gets a ``critical`` group (``a_over_l``, ``Ca_s``,
``kind``, ``message``: the kernel's own words on how the branch ended), which
``capsmech.io.database`` reads (``Database.critical``). The file is rewritten whole
(``FILE.tmp`` then rename): every group, attribute and dataset outside the ``critical`` groups
is checked to be byte for byte what it was (the digest of scripts/checksum_databases.py), and
every new dataset has the Fletcher-32 checksum the shipped databases carry.

    PYTHONPATH=analysis/src:scripts .venv/bin/python scripts/add_folds.py config/dev.yaml \
        [--laws NH ...] [--jobs 2] [--threads 1]

(``make folds GRID=dev``.)
"""
from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from checksum_databases import digest, unchecked_datasets

from capsmech.io.atomic import atomic_path
from capsmech.io.case import EFFECT_DEFAULTS, decode_str
from capsmech.io.database import CRITICAL_GROUP, DatabaseError
from capsmech.workflow.assembly import critical_rows, write_critical_group
from capsmech.workflow.grid import Branch, case_settings, flow_settings, load_grid, parse_law
from capsmech.workflow.runner import reproduces_results, write_branch_failure

ROOT = Path(__file__).resolve().parents[1]

#: What the ``critical`` groups say of the accuracy of a fold. The branch file gives no error
#: bar: the search interpolates where the branch's slope in Ca_s changes sign between two
#: arclength points, and where it starts depends on the Ca_s requested. Measured
#: (docs/validation/databases.md, "Folds"): the same law, a/l and mesh over two grids' Ca_s
#: (dev and paper) agree to 5e-9 at a/l 0.85-1 and differ by 7.2e-4 relative at 1.05; the
#: mesh moves it by percents (NH a/l 0.85 at 64, 96, 128 meridian elements: 0.1337, 0.1266,
#: 0.1297), as it moves the rows' last steady Ca_s.
FOLD_ACCURACY = ("the fold of the rows' mesh; the kernel states no error of it. The search's estimate moved by up to "
                 "7e-4 relative with the Ca_s requested (NH a/l 1.05: 0.07551 over the dev grid's Ca_s, 0.07557 over "
                 "the paper grid's); the mesh moves it by percents (NH a/l 0.85 at 64, 96, 128 meridian elements: "
                 "0.1337, 0.1266, 0.1297)")


def fold_branches(grid: Mapping[str, Any], laws: Sequence[str] | None = None,
                  from_ca: float | None = None) -> list[Branch]:
    """The branches that find the folds of a grid's tube database: one per (law, a/l), over the
    grid's Ca_s in increasing order (from ``from_ca`` on where given), with the tube cases'
    settings (those of the first Ca_s, as a branch grid's)."""
    spec = grid["tube"]
    values = tuple(sorted(float(ca) for ca in spec["Ca_s"] if from_ca is None or float(ca) >= from_ca - 1e-12))
    if not values:
        raise SystemExit(f"--from-ca {from_ca:g}: above every Ca_s of the grid")
    settings = case_settings(grid, "tube", values[0])
    keys = [key for key in spec["laws"] if laws is None or key in laws]
    return [Branch(parse_law(key), float(a), values, settings) for key in keys for a in spec["a_over_l"]]


def kernel_version(capsim: Path) -> str:
    """The version ``capsim --version`` prints (``capsim 0.3.5`` -> ``0.3.5``)."""
    out = subprocess.run([str(capsim), "--version"], capture_output=True, text=True, check=True).stdout
    return out.split()[-1]


def check_database_is_the_grids(path: Path, grid: Mapping[str, Any]) -> str:
    """Refuse a database that the grid did not make (other name, settings or law parameters);
    return the kernel version of its rows."""
    with h5py.File(path, "r") as f:
        found = {"grid_name": decode_str(f.attrs["grid_name"]), "flow": decode_str(f.attrs["flow"])}
        if found != {"grid_name": grid["name"], "flow": "tube"}:
            raise DatabaseError(f"{path}: made by {found}, not by the tube flow of grid {grid['name']!r}")
        settings = json.loads(decode_str(f.attrs["settings"]))
        wanted = flow_settings(grid, "tube")
        if settings != wanted:
            raise DatabaseError(f"{path}: its tube settings {settings} are not the grid's {wanted}")
        missing = [key for key in grid["tube"]["laws"] if key not in f]
        if missing:
            raise DatabaseError(f"{path}: no law group {missing[0]!r} of the grid")
        for key in grid["tube"]["laws"]:
            law, attrs = parse_law(key), f[key].attrs
            pairs = [("nu_s", law.nu_s), ("C", law.C),
                     *((name, dict(law.effects).get(name, neutral)) for name, neutral in EFFECT_DEFAULTS.items())]
            differ = [f"{name} {float(attrs[name])!r}, the law key says {want!r}" for name, want in pairs
                      if want is not None and not math.isclose(float(attrs[name]), want, rel_tol=1e-12, abs_tol=1e-15)]
            if decode_str(attrs["law"]) != law.name:
                differ.insert(0, f"law {decode_str(attrs['law'])!r}, the key says {law.name!r}")
            if differ:
                raise DatabaseError(f"{path}: law group {key!r}: " + "; ".join(differ))
        return decode_str(f.attrs["code_version"])


def _branch_file_is_current(path: Path, branch: Branch, code_version: str) -> bool:
    """Whether a branch file already there is this branch's, by this kernel (a rerun skips it):
    its requested Ca_s end with this branch's (a branch from a lower Ca_s over the same top of
    the grid finds the same end, and cost more)."""
    if not path.is_file():
        return False
    try:
        with h5py.File(path, "r") as f:
            requested = decode_str(f.attrs.get("requested_Ca_s", ""))
            version = decode_str(f.attrs["code_version"])
    except (OSError, KeyError):
        return False
    wanted = [f"{ca:g}" for ca in branch.Ca_s]
    return version == code_version and requested.split(",")[-len(wanted):] == wanted


def run_fold_branch(capsim: Path, branch: Branch, folds_dir: Path, code_version: str, threads: int) -> tuple[str, float]:
    """Run one branch; keep its branch file (``folds_dir/tube/<law>/a<a/l>.h5``), throw its case
    files away. A kernel that fails leaves a branch file saying so (no critical Ca_s), not the
    cases one by one (the rows are the database's). Returns the kind and the wall time (s)."""
    summary = folds_dir / branch.relative_path
    if _branch_file_is_current(summary, branch, code_version):
        return "reused", 0.0
    summary.parent.mkdir(parents=True, exist_ok=True)
    cases = Path(tempfile.mkdtemp(prefix="cases_", dir=folds_dir))
    (cases / "tube" / branch.law.key).mkdir(parents=True)
    args = branch.kernel_args(cases, summary)
    argv = [str(capsim), *args, "--threads", str(threads), "--quiet"]
    start = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True)
    wall = time.perf_counter() - start
    shutil.rmtree(cases, ignore_errors=True)
    lines = [line for line in proc.stderr.strip().splitlines() if line.strip()]
    if proc.returncode == 2:
        # The kernel refused its arguments: the request is wrong, not the branch.
        raise SystemExit(f"{' '.join(argv)}: {lines[-1] if lines else 'refused (exit 2)'}")
    if proc.returncode != 0 or not summary.is_file():
        reason = f"capsim exited with code {proc.returncode}: {lines[-1] if lines else 'no message on stderr'}"
        write_branch_failure(summary, message=reason, code_version=code_version, kernel_args=args)
    with h5py.File(summary, "r") as f:
        return decode_str(f.attrs["critical_kind"]), wall


#: How a 3D grid's branch ends are found: the 3D branch has no arclength continuation, so its
#: end is where Newton-Krylov from the previous steady shape stops converging (bisected), which a
#: fold causes but a hard solve can too.
CRITICAL_METHOD_3D = ("continuation in Ca_s by Newton-Krylov from the previous steady shape (capsim --branch-ca, "
                      "3D model, over the grid's Ca_s), the end bisected to 1 %; an end that the grid's own steady "
                      "rows above it contradict is 'failed: branch lost', not a fold; NaN: no end inside the grid's Ca_s")


def reconcile_3d_ends(rows: dict[str, dict[str, list]], database: Path) -> list[str]:
    """Check each 3D branch end against the database's own rows, solved case by case: where a
    row of the same law and a/l is steady above the end, the branch's Newton-Krylov lost the
    branch there (no fold: the steady shapes go on), and the end becomes ``failed: branch lost``
    with no critical Ca_s. Returns one line per end so changed."""
    changed = []
    with h5py.File(database, "r") as f:
        for key, law in rows.items():
            group = f[key]
            a_rows, ca_rows = group["a_over_l"][()], group["Ca_s"][()]
            steady = np.array([decode_str(v) for v in group["status"][()]]) == "steady"
            for i, (a, critical, kind) in enumerate(zip(law["a_over_l"], law["Ca_s"], law["kind"])):
                if kind != "fold" or not math.isfinite(critical):
                    continue
                above = np.isclose(a_rows, a) & steady & (ca_rows > critical)
                if not above.any():
                    continue
                beyond = float(ca_rows[above].max())
                law["kind"][i] = (f"failed: branch lost at Ca_s {critical:.4g} (Newton-Krylov from the branch found no "
                                  f"steady shape), yet the grid's row at Ca_s {beyond:g} is steady: not a fold")
                law["message"][i] = f"{law['message'][i]}; {law['kind'][i]}"
                law["Ca_s"][i] = math.nan
                changed.append(f"{key} a/l {a:g}: {law['kind'][i]}")
    return changed


def is_critical(name: str) -> bool:
    """Whether an HDF5 path lies in a law group's ``critical`` group."""
    parts = name.strip("/").split("/")
    return len(parts) >= 2 and parts[1] == CRITICAL_GROUP


def _copy_attributes(source: h5py.HLObject, target: h5py.HLObject) -> None:
    """Every attribute with its own HDF5 type and bytes (low level: nothing converted)."""
    for name in source.attrs:
        attr = h5py.h5a.open(source.id, name.encode())
        copy = h5py.h5a.create(target.id, name.encode(), attr.get_type(), attr.get_space())
        copy.write(_attribute_values(attr))


def _attribute_values(attr: h5py.h5a.AttrID) -> np.ndarray:
    buf = np.empty(attr.shape, dtype=attr.dtype)
    attr.read(buf)
    return buf


def add_critical_groups(path: Path, rows: Mapping[str, Mapping[str, list]], attrs: Mapping[str, Any]) -> None:
    """Rewrite the database at ``path`` with a ``critical`` group in each law group of ``rows``
    (replacing one there), the rest copied as it is (HDF5's object copy: types, filters,
    attributes). Fails, leaving the file as it was, unless the digest of everything outside the
    ``critical`` groups is unchanged and every dataset has its Fletcher-32 checksum."""
    before = digest(path, skip=is_critical)
    with atomic_path(path) as tmp:
        with h5py.File(path, "r") as source, h5py.File(tmp, "w") as target:
            _copy_attributes(source, target)
            for key, group in source.items():
                copy = target.create_group(key)
                _copy_attributes(group, copy)
                for name in group:
                    if name == CRITICAL_GROUP and key in rows:
                        continue  # replaced below
                    source.copy(group[name], copy, name=name)
                if key in rows:
                    write_critical_group(copy, rows[key], attrs)
        after = digest(tmp, skip=is_critical)
        if after != before:
            raise DatabaseError(f"{path}: the rewritten file differs outside its critical groups "
                                f"(digest {after[:16]} != {before[:16]}); left as it was")
        unchecked = unchecked_datasets(tmp)
        if unchecked:
            raise DatabaseError(f"{path}: {unchecked[0]} would have no Fletcher-32 checksum; left as it was")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("grid", help="the grid that made the database (config/<name>.yaml, or its name)")
    parser.add_argument("--laws", nargs="+", help="only these law keys (default: every law of the grid)")
    parser.add_argument("--jobs", type=int, default=1, help="branches run at once (default 1)")
    parser.add_argument("--from-ca", type=float, metavar="CA",
                        help="start each branch at this Ca_s of the grid (default its lowest): the rows below are "
                             "the database's; a 3D branch from its lowest Ca_s costs most there (a level-3 duct "
                             "branch of NH a/w 0.6 took 1600 s on one loaded thread from Ca_s 0.02)")
    parser.add_argument("--threads", type=int, default=1, help="threads of each kernel run (default 1)")
    parser.add_argument("--capsim", type=Path, default=ROOT / "bin" / "capsim")
    parser.add_argument("--database", type=Path, help="the database file (default: the grid's databases_dir/tube.h5)")
    parser.add_argument("--folds-dir", type=Path, help="where the branch files go (default: <results_dir>/folds)")
    args = parser.parse_args(argv)
    grid_path = Path(args.grid) if args.grid.endswith((".yaml", ".yml", ".json")) else ROOT / "config" / f"{args.grid}.yaml"
    grid = load_grid(grid_path)
    if "tube" not in grid:
        raise SystemExit(f"{grid_path}: no tube flow: no folds to find")
    database = args.database or ROOT / grid["databases_dir"] / "tube.h5"
    folds_dir = args.folds_dir or ROOT / grid["results_dir"] / "folds"
    unknown = sorted(set(args.laws or []) - set(grid["tube"]["laws"]))
    if unknown:
        raise SystemExit(f"{grid_path}: no law {unknown[0]!r} in the grid ({', '.join(grid['tube']['laws'])})")
    rows_version = check_database_is_the_grids(database, grid)
    code_version = kernel_version(args.capsim)
    branches = fold_branches(grid, args.laws, args.from_ca)
    three_d = dict(branches[0].settings).get("model", "axi") == "3d"
    # A fold must come from the kernel of its rows, or from one that reproduces them; the 3D
    # branch's ends changed with its stability check (kernel 0.3.6), so a 3D grid needs its own.
    if code_version != rows_version and (three_d or not reproduces_results(code_version, rows_version, "tube")):
        raise SystemExit(f"{args.capsim} is kernel {code_version}, the rows are kernel {rows_version}: "
                         "a fold must come from the kernel of its rows")

    def run(branch: Branch) -> None:
        kind, wall = run_fold_branch(args.capsim, branch, folds_dir, code_version, args.threads)
        print(f"{branch.law.key} a/l {branch.a_over_l:g}: {kind} ({wall:.1f} s)", flush=True)

    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        list(pool.map(run, branches))
    rows = critical_rows(branches, folds_dir, code_version)
    attrs = {"kernel_settings": json.dumps(dict(branches[0].settings), sort_keys=True),
             "requested_Ca_s": ",".join(f"{ca:g}" for ca in branches[0].Ca_s),
             "code_version": code_version, "accuracy": FOLD_ACCURACY}
    if three_d:
        attrs["method"] = CRITICAL_METHOD_3D
        attrs["accuracy"] = ("the end of the rows' mesh, bisected to 1 % relative in Ca_s (the midpoint of the last "
                             "steady and the first failed Ca_s, both in each message); the mesh's effect on it was not "
                             "measured")
        for line in reconcile_3d_ends(rows, database):
            print(f"{database}: {line}")
    add_critical_groups(database, rows, attrs)
    for key, law in rows.items():
        ends = ", ".join(f"{a:g}: {ca:.4g} ({kind.split(':')[0]})" for a, ca, kind in
                         zip(law["a_over_l"], law["Ca_s"], law["kind"]))
        print(f"{database}: {key} critical Ca_s by a/l {ends}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
