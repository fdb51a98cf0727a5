"""Make the off-centre table (analysis/src/capsmech/databases/effects/offcentre/table.h5, shipped as
``offcentre``, capsmech.io.catalog): the antisymmetric mode of an off-centre capsule over (a/l, Ca_s)
(issue 7, the fitted off-centre position; ``capsmech.diagnosis.offcentre``).

NH, a/l 0.7/0.75/0.8/0.85 x Ca_s 0.035/0.05/0.075/0.1/0.14; at each point a capsule held b0 = 0.025 l off the
axis (``--offset-mode held``) and a centred one, 3D tube, level 3, wall 0.28/0.14 l over 6 l,
to t = 6 or their steady state; 2-3 minutes a case on one core. Case files are kept in
--cases and reused when present.

    PYTHONPATH=analysis/src .venv/bin/python scripts/make_offcentre_table.py [--cases DIR] [--jobs N]
"""
from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import h5py

from capsmech.diagnosis.offcentre import build_table
from capsmech.diagnosis.synthetic import run_tube_3d
from capsmech.io.case import read_case

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "analysis" / "src" / "capsmech" / "databases" / "effects" / "offcentre" / "table.h5"
A_OVER_L, CA_S, B0 = (0.7, 0.75, 0.8, 0.85), (0.035, 0.05, 0.075, 0.1, 0.14), 0.025
#: The 3D runs' settings, shared with scripts/make_offcentre_batch.py.
SETTINGS = {"level": 3, "wall": (0.28, 0.14), "tube_length": 6.0, "t_max": 6.0}
#: The table's identity (root attributes, as a database's; scripts/label_databases.py adds them to an older file).
#: The accuracy is that of the README's "Off-centre capsule" (MODE_RELATIVE_ERROR of capsmech.diagnosis.offcentre).
IDENTITY = {"name": "offcentre", "version": 1, "grid_name": "offcentre",
            "accuracy": "3D tube, level 3: the mode differs by 10-15 % between mesh levels 2 and 3 and its bilinear "
                        "interpolation misses the grid's mid-points by 10-14 % (fits take 20 % of b as its error)"}


def identity(code_version: str) -> dict[str, object]:
    """The root attributes that name the table: IDENTITY, its grid (JSON) and the kernel's code version."""
    grid = {"law": "NH", "a_over_l": list(A_OVER_L), "Ca_s": list(CA_S), "b0": B0,
            "settings": {**SETTINGS, "wall": list(SETTINGS["wall"])}}
    return {**IDENTITY, "grid": json.dumps(grid, sort_keys=True), "code_version": code_version}


def case_path(cases: Path, a: float, ca: float, b: float, mode: str = "held", t: float | None = None) -> Path:
    tail = "" if t is None else f"_t{t:g}"
    return cases / (f"a{a:g}_ca{ca:g}_b0.h5" if b == 0 else f"a{a:g}_ca{ca:g}_b{b:g}_{mode}{tail}.h5")


def parse_run_args(doc: str, cases: str, out: Path, argv: list[str] | None) -> argparse.Namespace:
    """--cases (kernel case files, kept and reused), --jobs (runs at once), --out; folders made."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--cases", type=Path, default=ROOT / "results" / cases, help="kernel case files")
    parser.add_argument("--jobs", type=int, default=2, help="kernel runs at once (one core each)")
    parser.add_argument("--out", type=Path, default=out)
    args = parser.parse_args(argv)
    args.cases.mkdir(parents=True, exist_ok=True)
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_run_args(__doc__, "offcentre_table", OUT, argv)
    runs = [(a, ca, b) for a in A_OVER_L for ca in CA_S for b in (0.0, B0)]

    def run(job: tuple[float, float, float]) -> Path:
        a, ca, b = job
        path = run_tube_3d(a, ca, case_path(args.cases, a, ca, b), SETTINGS["t_max"], offset=b, offset_mode="held",
                           level=SETTINGS["level"], wall=SETTINGS["wall"], tube_length=SETTINGS["tube_length"],
                           wall_cache=args.cases)
        print(f"{path.name}", flush=True)
        return path

    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        list(pool.map(run, runs))
    pairs = [(read_case(case_path(args.cases, a, ca, B0)), read_case(case_path(args.cases, a, ca, 0.0)))
             for a in A_OVER_L for ca in CA_S]
    source = (f"capsim 3D tube, NH, level {SETTINGS['level']}, wall {SETTINGS['wall'][0]}/{SETTINGS['wall'][1]} l over "
              f"{SETTINGS['tube_length']:g} l, held at b0 = {B0} l and centred, to t = {SETTINGS['t_max']:g} or steady "
              "(scripts/make_offcentre_table.py)")
    table = build_table(pairs, source)
    table.write(args.out)
    versions = sorted({case.code_version for pair in pairs for case in pair})
    with h5py.File(args.out, "r+") as f:
        f.attrs.update(identity(", ".join(versions)))
    print(f"wrote {args.out}")
    for i, a in enumerate(table.a_over_l):
        for j, ca in enumerate(table.Ca_s):
            print(f"a/l {a:g} Ca_s {ca:g}: peak m {table.mode[i, j].max():.2f}, per b^2: "
                  + ", ".join(f"{k} {v[i, j]:+.1f}" for k, v in table.second_order.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
