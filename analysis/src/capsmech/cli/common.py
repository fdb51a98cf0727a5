"""What every subcommand shares: the exit status of errors, number and unit formatting, tables
printed with their units, and the option kinds that must mean the same everywhere
(a database by name or path, a repeatable ``--law``)."""
from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any, cast

from capsmech.formatting import bracketed_unit, fmt, format_table

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["EXIT_ERROR", "add_database_option", "add_law_option", "bracketed_unit", "fmt", "format_table", "records"]

#: Exit status for errors reported by capsmech itself (argparse uses the same).
EXIT_ERROR = 2


def records(frame: pd.DataFrame) -> list[dict[str, Any]]:
    """The rows of a results DataFrame as dicts (``frame.to_dict("records")``)."""
    # pandas types the keys as Hashable; the columns of capsmech's frames are str.
    return cast("list[dict[str, Any]]", frame.to_dict("records"))


def add_database_option(parser: argparse.ArgumentParser, default: str, what: str, option: str = "--database") -> None:
    """``--database``: a shipped database's name (``capsmech databases`` lists them) or a file."""
    parser.add_argument(option, default=default, metavar="NAME|H5",
                        help=f"{what}: a shipped database's name (see `capsmech databases`) or a database file "
                             f"(default {default})")


def add_law_option(parser: argparse.ArgumentParser, what: str = "law key to fit with") -> None:
    """``--law``: repeatable, one law key each time (the same in every command)."""
    parser.add_argument("--law", action="append", metavar="KEY",
                        help=f"{what} (repeatable, e.g. --law NH --law GH_nu0.5; default: every law of the database)")
