"""The ``capsmech`` command: one subcommand per user job, each in its own module of
``capsmech.cli`` (case: simulate, show; extract; extract_shear: extract-shear; fit: fit-tube, fit-shear; population;
diagnose: diagnose, diagnose-shear, make-batch; compare: compare-methods; databases: databases,
database, figures), and the developers' commands under ``capsmech dev``.

Every error a user can cause prints ``capsmech: error: <message>`` (naming the file, line,
field or name at fault) on stderr and exits with status 2; never a traceback. An exception
that is not an input error (a bug) prints one ``capsmech: internal error: ...`` line and exits
1 (``CAPSMECH_TRACEBACK=1`` re-raises it).
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings
from collections.abc import Sequence
from typing import TextIO

from capsmech.cli.common import EXIT_ERROR
from capsmech.errors import CapsmechError, CapsmechWarning
from capsmech.version import __version__

DESCRIPTION = """\
capsmech: the shear modulus G_s of microcapsules' membranes from images of capsules flowing
in a capillary (or sheared in a Couette rheometer), compared with the simulations of the
capsim kernel (boundary integrals + membrane finite elements; NH, SK and GH laws).

A lab's path: extract (frames -> lengths and contours), fit-tube (-> a/l, Ca_s, G_s per capsule
and law), population (which law), diagnose (which effect the model lacks). Databases are
addressed by name (capsmech databases) or by file.

In every job (the workflow's database and figures commands aside): --out is the result
file (fit-tube's .csv or .h5, both read back by population), --report a Markdown report,
--json FILE the result as JSON, --law a law key (repeatable where several laws are fitted);
an output that exists is kept unless --force."""


#: The modules of ``capsmech.cli`` that register subcommands, in the order the help lists them.
JOBS = ("extract", "extract_shear", "fit", "population", "diagnose", "compare", "case", "databases", "dev")


class _VersionAction(argparse.Action):
    """``--version``: the package, the kernel it runs and the databases it ships, one line each
    (looked up only when asked: the kernel is run for its version)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: object,
                 option_string: str | None = None) -> None:
        from capsmech.io.catalog import database_versions
        from capsmech.workflow.paths import kernel_version

        print(f"capsmech {__version__}")
        print(f"kernel: {kernel_version()}")
        for name, version in database_versions().items():
            print(f"database {name}: {version}")
        parser.exit()


def build_parser(jobs: Sequence[str] = JOBS) -> argparse.ArgumentParser:
    """Return the argument parser of the ``capsmech`` command, with the subcommands of ``jobs``
    (modules of ``capsmech.cli``; all of them by default)."""
    parser = argparse.ArgumentParser(prog="capsmech", description=DESCRIPTION,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action=_VersionAction, nargs=0,
                        help="print the versions of the package, the kernel and the shipped databases, and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for job in jobs:
        importlib.import_module(f"capsmech.cli.{job}").register(sub)
    return parser


def _show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                  file: TextIO | None = None, line: str | None = None) -> None:
    """capsmech's warnings as one line each on stderr (``capsmech: warning: ...``), others as Python shows them."""
    if issubclass(category, CapsmechWarning):
        print(f"capsmech: warning: {message}", file=file or sys.stderr)
    else:
        _python_showwarning(message, category, filename, lineno, file, line)


_python_showwarning = warnings.showwarning


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``capsmech`` command line.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name; defaults to ``sys.argv[1:]``.

    Returns
    -------
    int
        Exit status: the kernel's for ``simulate``; 0 on success; 1 when a job could measure or
        fit nothing; 2 for errors.
    """
    shown, warnings.showwarning = warnings.showwarning, _show_warning
    try:
        return _run(argv)
    finally:
        warnings.showwarning = shown


def _run(argv: Sequence[str] | None) -> int:
    """``main`` with capsmech's warnings shown as one line."""
    arguments = list(sys.argv[1:] if argv is None else argv)
    # The workflow starts `capsmech dev run-case` once per database case: the developers'
    # commands alone are parsed there, without importing the user jobs' modules (pandas, scipy,
    # matplotlib: 1.2 s a process, more than a steady tube case takes in the kernel).
    parser = build_parser(("dev",) if arguments[:1] == ["dev"] else JOBS)
    args, rest = parser.parse_known_args(arguments)
    if args.command != "simulate" and rest:
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    try:
        if args.command == "simulate":
            return int(importlib.import_module("capsmech.cli.case").cmd_simulate(rest))
        return int(args.func(args))
    except (CapsmechError, FileNotFoundError) as exc:
        print(f"capsmech: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print("capsmech: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader of stdout went away (`capsmech ... | head`): stop quietly, as other tools do;
        # stdout is pointed at /dev/null so that the interpreter's last flush does not fail too.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except Exception as exc:
        # The last resort only: every input error has its own CapsmechError (tests fail on
        # this line as on a traceback). CAPSMECH_TRACEBACK=1 shows where it happened.
        if os.environ.get("CAPSMECH_TRACEBACK"):
            raise
        print(f"capsmech: internal error: {type(exc).__name__}: {exc} (a bug: please report the command; "
              "CAPSMECH_TRACEBACK=1 shows the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
