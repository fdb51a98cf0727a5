"""``capsmech databases`` (the shipped databases by name), ``capsmech database assemble|show``
(the workflow's assembly of case files, a database's summary) and ``capsmech figures`` (the
paper's figures 2-6 drawn from databases)."""
from __future__ import annotations

import argparse
from pathlib import Path

from capsmech.cli.common import add_force_option, add_json_option, plan_output, write_json
from capsmech.workflow.grid import GridError


def cmd_databases(args: argparse.Namespace) -> int:
    """``databases``: list the shipped databases: name, flow, what it holds, its accuracy."""
    from capsmech.io.catalog import database_versions, shipped_databases

    json_out = plan_output(args.json, "--json", (".json",), args.force) if args.json else None
    entries = shipped_databases()
    for entry in entries:
        print(f"{entry.name:<22} {entry.flow:<6} {entry.description}")
        if entry.accuracy:
            print(f"{'':<22} {'':<6} accuracy: {entry.accuracy}")
    if json_out is not None:
        versions = database_versions()
        listed = [{"name": e.name, "flow": e.flow, "kind": e.kind, "description": e.description,
                   "accuracy": e.accuracy, "path": str(e.path), "version": versions.get(e.name)} for e in entries]
        print(json_out.wrote(write_json(json_out.path, "databases", {"databases": listed})))
    return 0


def cmd_database(args: argparse.Namespace) -> int:
    """``database assemble``: case files -> database file; ``database show``: summarise one."""
    from capsmech.io.database import load_database
    from capsmech.workflow.assembly import assemble_database
    from capsmech.workflow.grid import load_grid

    if args.action == "simulate":
        return _simulate_laws(args)
    if args.action == "assemble":
        out = assemble_database(load_grid(args.grid), args.flow, args.cases, args.out, branches_dir=args.branches)
        print(f"wrote {out}")
        args.database = out
    database = load_database(args.database)
    print(f"{database.path}: {database.flow} database of grid {database.provenance['grid_name']!r}, "
          f"kernel {database.provenance['code_version']}, created {database.provenance['created']}")
    for key, table in database.laws.items():
        counts = {s: int((table.status == s).sum()) for s in sorted(set(table.status))}
        print(f"  {key:<10} {len(table):4d} cases  " + ", ".join(f"{n} {s}" for s, n in counts.items()))
        if table.critical is not None:
            ends = [f"a/l {a:g}: {ca:.4g} ({kind})" for a, ca, kind in
                    zip(table.critical["a_over_l"], table.critical["Ca_s"], table.critical["kind"]) if ca == ca]
            print(f"  {'':<10} steady branch ends at Ca_s " + ("; ".join(ends) if ends else "nowhere inside the grid"))
    return 0


def _simulate_laws(args: argparse.Namespace) -> int:
    """``database simulate``: new law groups over an existing database's tube grid, through the
    workflow (local or the profile given), cached under the user's data directory."""
    import sys

    from tqdm import tqdm

    from capsmech.api import as_database
    from capsmech.workflow.simulate import cached_grid, case_count, law_grid, simulate_grid

    like = as_database(args.like, "tube", "database simulate --like")
    grid = law_grid(like.grid, args.law, like.accuracy)
    _, folder = cached_grid(grid)
    cases = case_count(grid)
    print(f"capsmech database simulate: {', '.join(args.law)} over the {like.grid_name!r} grid: {cases} cases "
          f"({args.profile or 'local profile'}) into {folder}", flush=True)
    with tqdm(total=cases, desc="simulating", unit="step", disable=not sys.stderr.isatty()) as bar:
        def advance(done: int, total: int) -> None:
            bar.total, bar.n = total, done
            bar.refresh()

        path = simulate_grid(grid, profile=args.profile, cores=args.cores, progress=advance)
    print(f"wrote {path}")
    args.database = path
    return cmd_database(argparse.Namespace(action="show", database=path))


def cmd_figures(args: argparse.Namespace) -> int:
    """Draw the paper's figures from one database, or from every database of a grid."""
    from capsmech.workflow.figures import draw_figures
    from capsmech.workflow.grid import FLOWS, load_grid

    grid = load_grid(args.grid) if args.grid else None
    if args.database:
        jobs = [(Path(args.database), Path(args.out) if args.out else None)]
    elif grid is not None:
        jobs = [(Path(grid["databases_dir"]) / f"{flow}.h5",
                 Path(args.out or Path(grid["results_dir"]) / "figures") / flow)
                for flow in FLOWS if flow in grid]
    else:
        raise GridError("figures: give --database DB.h5 or --grid GRID.yaml")
    for database, out in jobs:
        if out is None:
            raise GridError("figures: --out DIR is required with --database")
        for path in draw_figures(database, out, grid):
            print(f"wrote {path}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``databases``, ``database`` and ``figures``."""
    listing = sub.add_parser("databases", help="list the shipped databases (names for --database)")
    add_json_option(listing, "the list (name, flow, what it holds, its accuracy, its file and version)")
    add_force_option(listing)
    listing.set_defaults(func=cmd_databases)
    database = sub.add_parser("database", help="assemble (workflow) or summarise a database file")
    actions = database.add_subparsers(dest="action", required=True, metavar="ACTION")
    assemble = actions.add_parser("assemble", help="case files of a grid -> tube.h5 or shear.h5")
    assemble.add_argument("--grid", required=True, help="grid file (YAML or JSON)")
    assemble.add_argument("--flow", required=True, choices=("tube", "shear"))
    assemble.add_argument("--cases", required=True, help="directory holding <flow>/<law>/<case>.h5")
    assemble.add_argument("--branches", help="directory holding tube/<law>/a<a/l>.h5, the branch files of a grid "
                                             "computed by continuation: their critical Ca_s go into the database")
    assemble.add_argument("--out", required=True, help="database file to write")
    simulate = actions.add_parser("simulate", help="a database of new law groups over an existing database's tube "
                                                   "grid, through the workflow (cached under the user's data directory)")
    simulate.add_argument("--law", action="append", required=True, metavar="KEY",
                          help="law key to simulate, e.g. SK_C5 or GH_nu0.35 or NH+prestress0.03 (repeatable)")
    simulate.add_argument("--like", default="tube-paper", metavar="NAME|H5",
                          help="the database whose nodes and settings to use (default tube-paper)")
    simulate.add_argument("--profile", metavar="DIR",
                          help="Snakemake profile (default the local one; e.g. workflow/profiles/slurm)")
    simulate.add_argument("--cores", type=int, metavar="N", help="cores of a local run (default the profile's)")
    summary = actions.add_parser("show", help="summarise a database (name or file)")
    summary.add_argument("database", metavar="NAME|H5")
    database.set_defaults(func=cmd_database)
    figures = sub.add_parser("figures", help="draw the paper's figures 2-6 from the databases")
    figures.add_argument("--database", metavar="NAME|H5", help="one database (tube: figures 2-5, shear: 6)")
    figures.add_argument("--grid", help="grid file: its databases, and figure settings")
    figures.add_argument("--out", metavar="DIR", help="output directory (default: <results_dir>/figures/<flow>)")
    figures.set_defaults(func=cmd_figures)
