"""What every subcommand shares: the exit status of errors, number and unit formatting, tables
printed with their units, and the option kinds that must mean the same everywhere
(a database by name or path, a repeatable ``--law``, ``--json FILE``, ``--force``).

One rule for every output file: it is checked before the work that fills it
(:func:`plan_output`), and an existing file is kept unless ``--force`` is given; with it the
file is replaced and the line that says it was written says so (``wrote X (replaced ...)``).

Every ``--json FILE`` is one object (:func:`write_json`): ``"capsmech"`` (the version that wrote
it), ``"command"``, ``"schema"`` (:data:`JSON_SCHEMA`), then the command's own fields; tables as
``"units"`` (column -> unit, ``""`` for text) and ``"rows"`` (one object per row); a number
without a value is ``null`` (never NaN: the file is strict JSON)."""
from __future__ import annotations

import argparse
import json
import math
import os
import stat
import warnings
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from capsmech.errors import CapsmechError, InputWarning
from capsmech.formatting import bracketed_unit, fmt, format_table
from capsmech.io.atomic import write_text_atomically
from capsmech.version import __version__

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["EXIT_ERROR", "FIGURE_SUFFIXES", "JSON_SCHEMA", "TABLE_SUFFIXES", "OutputPathError", "PlannedOutput",
           "add_base_law_option", "add_database_option", "add_force_option", "add_json_option", "add_law_option", "add_report_option", "bracketed_unit",
           "check_output", "fmt", "format_table", "json_ready", "plan_output", "records", "report_option", "table_json", "write_json"]

#: Exit status for errors reported by capsmech itself (argparse uses the same).
EXIT_ERROR = 2
#: Results tables (``write_results``): CSV with units in the header, or HDF5.
TABLE_SUFFIXES = (".csv", ".h5", ".hdf5")
#: The layout of every ``--json`` file (a new number only when a field changes meaning or goes).
JSON_SCHEMA = 1
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


@dataclass(frozen=True)
class PlannedOutput:
    """An output file checked before the work: its path, and whether a file was there then."""

    path: Path
    existed: bool

    def wrote(self, written: str | Path | None = None) -> str:
        """The line that says the file was written (and replaced, if it was there)."""
        return f"wrote {written or self.path}" + (" (replaced the file that was there)" if self.existed else "")


def plan_output(path: str | Path, option: str, suffixes: Collection[str], force: bool,
                create_parent: bool = False) -> PlannedOutput:
    """``check_output``, and the one rule for existing files: kept unless ``force``.

    Raises
    ------
    OutputPathError
        As ``check_output``; or the file exists and ``force`` is False (the message says
        ``--force`` replaces it).
    """
    out = check_output(path, option, suffixes, create_parent)
    existed = out.exists()
    if existed and not force:
        raise OutputPathError(f"{option} {path}: exists; kept (give --force to replace it)")
    return PlannedOutput(out, existed)


def json_ready(value: Any) -> Any:
    """``value`` as strict JSON holds it: NaN and infinities as None, numpy scalars and arrays
    as Python numbers and lists, paths as text, mappings and sequences element by element."""
    if isinstance(value, Mapping):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if isinstance(value, (str, bool)) or value is None:
        return value
    if isinstance(value, Path):
        return str(value)
    if hasattr(value, "tolist"):            # numpy scalars and arrays
        return json_ready(value.tolist())
    if isinstance(value, int):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    return str(value)


def table_json(frame: pd.DataFrame) -> dict[str, Any]:
    """A results DataFrame as ``--json`` holds it: ``units`` and ``rows``."""
    return {"units": dict(frame.attrs.get("units", {})), "rows": json_ready(records(frame))}


def write_json(path: str | Path, command: str, payload: Mapping[str, Any]) -> Path:
    """Write a command's ``--json`` file whole or not at all: the common head (version,
    command, schema) and ``payload``, strict JSON (see the module)."""
    document = {"capsmech": __version__, "command": command, "schema": JSON_SCHEMA, **json_ready(payload)}
    return write_text_atomically(path, json.dumps(document, indent=2, allow_nan=False) + "\n")


def add_json_option(parser: argparse.ArgumentParser, what: str) -> None:
    """``--json FILE.json``: the command's result as JSON (layout: ``write_json``)."""
    parser.add_argument("--json", metavar="FILE.json", help=f"write {what} as JSON")


class _OneLawAction(argparse.Action):
    """``--law`` where a command takes one base law: given twice, an error (not the last kept)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        given = [*getattr(namespace, "_laws_given", []), str(values)]
        namespace._laws_given = given
        if len(given) > 1:
            parser.error(f"--law: one base law key here, given {', '.join(given)} (--law is repeated where "
                         "several laws are fitted: fit-tube, fit-shear, compare-methods)")
        setattr(namespace, self.dest, values)


def add_base_law_option(parser: argparse.ArgumentParser, what: str, default: str = "NH") -> None:
    """``--law KEY`` where a command works from one base law (diagnose, diagnose-shear,
    make-batch): the same spelling as the repeatable ``--law``, a repeat refused."""
    parser.add_argument("--law", action=_OneLawAction, default=default, metavar="KEY",
                        help=f"{what} (one; default {default})")


def add_report_option(parser: argparse.ArgumentParser, what: str) -> None:
    """``--report REPORT.md``: a Markdown report (``--out`` names result files everywhere; the
    Markdown report's old spelling ``--out REPORT.md`` still works, with a warning)."""
    parser.add_argument("--report", metavar="REPORT.md", help=f"write {what}")
    parser.add_argument("--out", dest="report_as_out", metavar="REPORT.md", help=argparse.SUPPRESS)


def report_option(args: argparse.Namespace) -> str | None:
    """The Markdown report asked for (``--report``, or the deprecated ``--out REPORT.md``, said
    in a warning)."""
    if args.report_as_out is None:
        return cast("str | None", args.report)
    if args.report is not None:
        raise OutputPathError("--out: the Markdown report is given by --report; give it once")
    warnings.warn(f"--out {args.report_as_out}: the Markdown report's option is now --report (--out names "
                  "result files in every command); --out REPORT.md will go", InputWarning, stacklevel=2)
    return cast("str", args.report_as_out)


def add_force_option(parser: argparse.ArgumentParser) -> None:
    """``--force``: replace output files that exist (by default they are kept and the command stops)."""
    parser.add_argument("--force", action="store_true",
                        help="replace output files that exist (by default an existing output is kept: an error)")


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
