"""``capsmech fit-tube`` and ``capsmech fit-shear``: a measurement CSV fitted against a database.

Prints one line per (capsule, law) with units, and for ``fit-tube`` the channel the fit was made
in; writes the results (``--out``: .csv or .h5, both read back by ``population`` and
``capsmech.read_results``) and ``--json``, ``fit-tube``'s with the channel in every row
(``channel``, ``channel_aspect``, ``length_scale``: ``capsmech.api.with_channel_columns``).
Exit status 1 when no capsule could be fitted by any law (the reasons are printed), 2 for bad
input (a measurement file of another channel than the database's among them).

The job walks CLI -> ``capsmech.api`` once: the database is loaded once (``api.as_database``,
whose object the fit and the results' provenance share) and the laws are checked once, by the
fit (its messages name the API's parameters; they are given back under the options' names).
"""
from __future__ import annotations

import argparse
import sys
import warnings
from typing import Any

import pandas as pd

from capsmech.api import CHANNEL_WORDS, as_database, check_channel, fit_shear, fit_tube, with_channel_columns
from capsmech.cli.common import (
    TABLE_SUFFIXES,
    add_database_option,
    add_force_option,
    add_json_option,
    add_law_option,
    format_table,
    plan_output,
    records,
    table_json,
    write_json,
)
from capsmech.errors import OutsideDatabaseWarning
from capsmech.inversion.fitting import write_results
from capsmech.io.database import Database, DatabaseError
from capsmech.io.measurements import read_measurements

#: Columns printed (all are written to --out and --json).
SHOWN = {"tube": ["id", "law", "a_over_l", "Ca_s", "critical_Ca_s", "G_s", "G_s_spread", "flag"],
         "shear": ["id", "law", "D12", "Ca_s", "a", "G_s", "G_s_spread", "flag"]}


def _fit(flow: str, command: str, capsules: Any, database: Database, laws: list[str] | None) -> pd.DataFrame:
    """The API's fit, its errors worded with the command's options."""
    try:
        if flow == "tube":
            return fit_tube(capsules, database, laws, progress=sys.stderr.isatty())
        return fit_shear(capsules, database, laws)
    except DatabaseError as err:
        text = str(err)
        if text.startswith("laws:"):
            raise DatabaseError("--law:" + text.removeprefix("laws:")) from None
        raise


def fit_summary(results: pd.DataFrame) -> dict[str, Any]:
    """How many (capsule, law) fits have a value, and how many have none by flag code."""
    unfitted = results[results["flag"] != ""]
    return {"fits": len(results), "fitted": len(results) - len(unfitted),
            "unfitted_by_flag": {str(code): int(n) for code, n in unfitted["flag"].value_counts().items()}}


def channel_summary(results: pd.DataFrame, database: Database) -> str | None:
    """The channel of a fit-tube run in one line (None without one): which channel, its aspect,
    and the length scale l the lengths were divided by."""
    channel = results.attrs.get("channel")
    if channel is None:
        return None
    scales = sorted({round(v * 1e6, 6) for v in channel["length_scale"].values()})
    name = "half-width" if channel["channel"] != "tube" else "radius"
    scale = f"{scales[0]:.4g}" if len(scales) == 1 else f"{scales[0]:.4g}-{scales[-1]:.4g}"
    return (f"channel: {CHANNEL_WORDS.get(channel['channel'], channel['channel'])}, aspect "
            f"{channel['channel_aspect']:g}, l = {name} {scale} um (database {database.name or database.path})")


def cmd_fit(args: argparse.Namespace) -> int:
    """``fit-tube`` / ``fit-shear``: fit, print the table, write the results."""
    flow = "tube" if args.command == "fit-tube" else "shear"
    outs = [plan_output(out, "--out", TABLE_SUFFIXES, args.force) for out in args.out or []]
    json_out = plan_output(args.json, "--json", (".json",), args.force) if args.json else None
    database = as_database(args.database, flow, args.command)
    capsules = read_measurements(args.measurements, flow, contours_anywhere=args.contours_anywhere)
    if flow == "tube":
        # Here, where the message can name the file (the API sees the capsules).
        check_channel(capsules, database, str(args.measurements))
    with warnings.catch_warnings():
        # The table's flag column says it per row, and the summary below in one line.
        warnings.simplefilter("ignore", OutsideDatabaseWarning)
        results = _fit(flow, args.command, capsules, database, args.law)
    laws = list(dict.fromkeys(results["law"])) if not results.empty else list(args.law or [])
    print(format_table(records(results), SHOWN[flow], results.attrs["units"]))
    channel = channel_summary(results, database)
    if channel:
        print(channel)
    results = with_channel_columns(results)
    units = results.attrs["units"]
    for out in outs:
        print(out.wrote(write_results(records(results), units, out.path, database)))
    summary = fit_summary(results)
    if json_out is not None:
        payload = {"measurements": str(args.measurements), "database": str(database.path),
                   "database_code_version": str(database.provenance.get("code_version", "")), "laws": laws,
                   **({"channel": database.channel, "channel_aspect": database.aspect} if flow == "tube" else {}),
                   **summary, **table_json(results)}
        print(json_out.wrote(write_json(json_out.path, args.command, payload)))
    unfitted = summary["fits"] - summary["fitted"]
    if unfitted:
        print(f"{unfitted} of {summary['fits']} fits have no value: "
              + ", ".join(f"{n} {code}" for code, n in summary["unfitted_by_flag"].items())
              + " (the reasons are in the results' 'reason' column)")
    if not summary["fitted"]:
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
        fit.add_argument("--out", action="append", metavar="FILE",
                         help="write the results (.csv or .h5, both read back by population and read_results; "
                              "repeatable)")
        add_json_option(fit, "the results (one row per capsule and law, with units and flags)")
        add_force_option(fit)
        fit.add_argument("--contours-anywhere", action="store_true",
                         help="read contour files outside the measurement file's folder too (by default refused)")
        fit.set_defaults(func=cmd_fit)
