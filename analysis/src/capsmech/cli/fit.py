"""``capsmech fit-tube`` and ``capsmech fit-shear``: a measurement CSV fitted against a database.

Prints one line per (capsule, law) with units; writes the results (.csv or .h5). Exit status 1
when no capsule could be fitted by any law (the reasons are printed), 2 for bad input.
"""
from __future__ import annotations

import argparse
import sys
import warnings

from capsmech.api import as_database, check_laws, fit_shear, fit_tube
from capsmech.cli.common import (
    TABLE_SUFFIXES,
    add_database_option,
    add_law_option,
    check_output,
    format_table,
    records,
)
from capsmech.errors import OutsideDatabaseWarning
from capsmech.inversion.fitting import write_results
from capsmech.io.measurements import read_measurements

#: Columns printed (all are written to --out).
SHOWN = {"tube": ["id", "law", "a_over_l", "Ca_s", "G_s", "G_s_spread", "flag"],
         "shear": ["id", "law", "D12", "Ca_s", "a", "G_s", "G_s_spread", "flag"]}


def cmd_fit(args: argparse.Namespace) -> int:
    """``fit-tube`` / ``fit-shear``: fit, print the table, write the results."""
    flow = "tube" if args.command == "fit-tube" else "shear"
    for out in args.out or []:
        check_output(out, "--out", TABLE_SUFFIXES)
    database = as_database(args.database, flow, args.command)
    laws = check_laws(database, args.law, "--law")
    capsules = read_measurements(args.measurements, flow, contours_anywhere=args.contours_anywhere)
    with warnings.catch_warnings():
        # The table's flag column says it per row, and the summary below in one line.
        warnings.simplefilter("ignore", OutsideDatabaseWarning)
        if flow == "tube":
            results = fit_tube(capsules, database, laws, progress=sys.stderr.isatty())
        else:
            results = fit_shear(capsules, database, laws)
    units = results.attrs["units"]
    print(format_table(records(results), SHOWN[flow], units))
    for out in args.out or []:
        print(f"wrote {write_results(records(results), units, out, database)}")
    fitted = results[results["flag"] == ""]
    unfitted = results[results["flag"] != ""]
    if not unfitted.empty:
        print(f"{len(unfitted)} of {len(results)} fits have no value: "
              + ", ".join(f"{n} {code}" for code, n in unfitted["flag"].value_counts().items())
              + " (the reasons are in the results' 'reason' column)")
    if fitted.empty:
        print(f"capsmech: no capsule of {args.measurements} could be fitted with {', '.join(laws)}", file=sys.stderr)
        return 1
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``fit-tube`` and ``fit-shear``."""
    for name, flow in (("fit-tube", "tube"), ("fit-shear", "shear")):
        fit = sub.add_parser(name, help=f"fit measured capsules ({flow} CSV) against a {flow} database")
        fit.add_argument("measurements", metavar="CSV", help="measurement file (format: capsmech.io.measurements)")
        add_database_option(fit, f"{flow}-paper", f"{flow} database")
        add_law_option(fit)
        fit.add_argument("--out", action="append", metavar="FILE", help="write the results (.csv or .h5; repeatable)")
        fit.add_argument("--contours-anywhere", action="store_true",
                         help="read contour files outside the measurement file's folder too (by default refused)")
        fit.set_defaults(func=cmd_fit)
