"""``capsmech compare-methods``: the paper's microrheometry against its microfluidics, before and
after the viscosity ratio of its shear experiment."""
from __future__ import annotations

import argparse

from capsmech.api import as_database, check_laws
from capsmech.cli.common import add_database_option
from capsmech.io.database import DatabaseError


def cmd_compare_methods(args: argparse.Namespace) -> int:
    """``compare-methods``: the paper's shear and tube moduli, before and after the viscosity
    ratio of its shear experiment (capsmech.inversion.microrheometry)."""
    from capsmech.inversion.microrheometry import compare_methods, comparison_table

    base = as_database(args.database, "shear", "compare-methods --database")
    with_lambda = as_database(args.lambda_database, "shear", "compare-methods --lambda-database")
    laws = check_laws(base, args.law or ["NH", "GH_nu0.5", "GH_nu0.2"], "--law")
    suffix = f"+lambda{args.lambda_value}"
    missing = [law + suffix for law in laws if law + suffix not in with_lambda.laws]
    if missing:
        raise DatabaseError(f"{args.lambda_database}: no law group {', '.join(missing)} "
                            f"(it has {', '.join(with_lambda.laws)}); refill it with `make database GRID=microrheometry`")
    print(comparison_table(compare_methods(base, with_lambda, suffix, tuple(laws))))
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
    comp.set_defaults(func=cmd_compare_methods)
