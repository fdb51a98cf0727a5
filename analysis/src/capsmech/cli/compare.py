"""``capsmech compare-methods``: the paper's microrheometry against its microfluidics, before and
after the viscosity ratio of its shear experiment (``capsmech.api.compare_methods``)."""
from __future__ import annotations

import argparse
from typing import Any

from capsmech.api import compare_methods
from capsmech.cli.common import add_database_option, add_force_option, add_json_option, plan_output, write_json
from capsmech.io.database import DatabaseError

#: The API's parameters as the command line names them, in its messages.
OPTIONS = {"compare_methods (database)": "compare-methods --database",
           "compare_methods (lambda_database)": "compare-methods --lambda-database"}
PREFIXES = {"laws:": "--law:", "lambda_database:": "--lambda-database:"}


def comparison_record(rows: list[Any]) -> dict[str, Any]:
    """The comparison as ``--json`` holds it: one object per law, moduli in N/m."""
    def pair(values: tuple[float, float] | None) -> dict[str, float] | None:
        return None if values is None else {"mean": values[0], "spread": values[1]}

    return {"units": {"G_s": "N/m", "D12": "1", "ratio": "1"},
            "laws": [{"law": r.law, "example_G_s_before": r.example_before, "example_G_s_after": r.example_after,
                      "D12_range": list(r.d12_range), "ratio_mean": r.ratio_mean, "ratio_range": list(r.ratio_range),
                      "microrheometry_G_s_before": pair(r.shear_before),
                      "microrheometry_G_s_after": pair(r.shear_after), "microfluidics_G_s": pair(r.tube),
                      "disagreement_before": r.disagreement(r.shear_before),
                      "disagreement_after": r.disagreement(r.shear_after)} for r in rows]}


def cmd_compare_methods(args: argparse.Namespace) -> int:
    """``compare-methods``: the paper's shear and tube moduli, before and after the viscosity
    ratio of its shear experiment."""
    from capsmech.inversion.microrheometry import comparison_table

    json_out = plan_output(args.json, "--json", (".json",), args.force) if args.json else None
    try:
        rows = compare_methods(args.database, args.lambda_database, args.lambda_value, args.law)
    except DatabaseError as err:
        text = str(err)
        for parameter, option in OPTIONS.items():
            text = text.replace(parameter, option)
        for prefix, option in PREFIXES.items():
            if text.startswith(prefix):
                text = option + text[len(prefix):]
        raise DatabaseError(text) from None
    print(comparison_table(rows))
    if json_out is not None:
        print(json_out.wrote(write_json(json_out.path, "compare-methods", comparison_record(rows))))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``compare-methods``."""
    comp = sub.add_parser("compare-methods", help="the paper's microrheometry against its microfluidics, "
                          "before and after the viscosity ratio of its shear experiment")
    add_database_option(comp, "shear-paper", "shear database made with lambda = 1")
    add_database_option(comp, "shear-microrheometry", "shear database with the experiment's viscosity ratio "
                        "(config/microrheometry.yaml)", option="--lambda-database")
    comp.add_argument("--lambda-value", default="0.001", help="its viscosity ratio, as in the law keys (default 0.001)")
    comp.add_argument("--law", action="append", metavar="KEY",
                      help="base law key (repeatable; default NH, GH_nu0.5 and GH_nu0.2)")
    add_json_option(comp, "the comparison per law (G_s in N/m before and after the viscosity ratio)")
    add_force_option(comp)
    comp.set_defaults(func=cmd_compare_methods)
