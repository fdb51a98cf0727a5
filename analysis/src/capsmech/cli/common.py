"""What every subcommand shares: the exit status of errors, number and unit formatting, tables
printed with their units, and the option kinds that must mean the same everywhere
(a database by name or path, a repeatable ``--law``)."""
from __future__ import annotations

import argparse
import os
import stat
from collections.abc import Collection
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from capsmech.errors import CapsmechError
from capsmech.formatting import bracketed_unit, fmt, format_table

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["EXIT_ERROR", "FIGURE_SUFFIXES", "TABLE_SUFFIXES", "OutputPathError", "add_database_option", "add_law_option", "bracketed_unit",
           "check_output", "fmt", "format_table", "records"]

#: Exit status for errors reported by capsmech itself (argparse uses the same).
EXIT_ERROR = 2
#: Results tables (``write_results``): CSV with units in the header, or HDF5.
TABLE_SUFFIXES = (".csv", ".h5", ".hdf5")
#: Figures (``capsmech.plotting.save_figure``): the formats matplotlib writes without extras.
FIGURE_SUFFIXES = (".png", ".pdf", ".svg", ".eps", ".ps", ".jpg", ".jpeg", ".tif", ".tiff", ".webp")


class OutputPathError(CapsmechError, ValueError):
    """An output path that cannot be written: refused before any work is done."""


def check_output(path: str | Path, option: str, suffixes: Collection[str], create_parent: bool = False) -> Path:
    """Refuse an output path before the work that fills it: wrong suffix, a directory, a
    device or pipe (which the temporary-file-and-rename write would replace), a folder that
    does not exist (unless it is created) or cannot be written.

    Parameters
    ----------
    path : str or Path
        The output file given.
    option : str
        The option that gave it (``--out``), for the message.
    suffixes : collection of str
        The suffixes accepted, as the writer spells them (with the dot, lower case).
    create_parent : bool
        The writer creates missing folders: a missing parent is not an error.

    Returns
    -------
    Path
        The path.

    Raises
    ------
    OutputPathError
        Naming the option, the path and what is wrong.
    """
    out = Path(path)
    where = f"{option} {path}"
    if out.is_dir():
        raise OutputPathError(f"{where}: is a directory (expected a file name ending in {', '.join(suffixes)})")
    if out.suffix not in suffixes:
        raise OutputPathError(f"{where}: unknown suffix {out.suffix or '(none)'!r}; expected one of "
                              f"{', '.join(suffixes)}")
    if out.exists() and not stat.S_ISREG(out.stat().st_mode):
        raise OutputPathError(f"{where}: exists and is not a regular file (a device, pipe or socket)")
    parent = out.parent
    while create_parent and not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise OutputPathError(f"{where}: folder {out.parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputPathError(f"{where}: folder {parent} is not writable")
    return out


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
