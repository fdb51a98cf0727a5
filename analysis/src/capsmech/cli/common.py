"""What every subcommand shares: the exit status of errors, number and unit formatting, tables
printed with their units, and the option kinds that must mean the same everywhere
(a database by name or path, a repeatable ``--law``)."""
from __future__ import annotations

import argparse

from capsmech.formatting import bracketed_unit, fmt, format_table

__all__ = ["EXIT_ERROR", "add_database_option", "add_law_option", "bracketed_unit", "fmt", "format_table"]

#: Exit status for errors reported by capsmech itself (argparse uses the same).
EXIT_ERROR = 2


def add_database_option(parser: argparse.ArgumentParser, default: str, what: str, option: str = "--database") -> None:
    """``--database``: a shipped database's name (``capsmech databases`` lists them) or a file."""
    parser.add_argument(option, default=default, metavar="NAME|H5",
                        help=f"{what}: a shipped database's name (see `capsmech databases`) or a database file "
                             f"(default {default})")


def add_law_option(parser: argparse.ArgumentParser, what: str = "law key to fit with") -> None:
    """``--law``: repeatable, one law key each time (the same in every command)."""
    parser.add_argument("--law", action="append", metavar="KEY",
                        help=f"{what} (repeatable, e.g. --law NH --law GH_nu0.5; default: every law of the database)")
