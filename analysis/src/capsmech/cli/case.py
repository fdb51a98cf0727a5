"""``capsmech simulate``: one case with the ``capsim`` kernel; ``capsmech show``: a case file.

``simulate`` passes all its arguments through to the kernel (``capsmech.api.simulate``) but
capsmech's own ``--json FILE`` and ``--force``, streams its output, returns the kernel's exit
code, and then summarises the case file named by ``--out`` if the run wrote one.
``show`` prints a case file's parameters, status and steady values, and with ``--plot
OUT.png`` draws the deformation history and the profile (``capsmech.plotting.plot_case``).
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from capsmech.api import REFERENCE_GRID, database_settings, read_case, simulate
from capsmech.cli.common import (
    EXIT_ERROR,
    FIGURE_SUFFIXES,
    OutputPathError,
    add_force_option,
    add_json_option,
    bracketed_unit,
    fmt,
    plan_output,
    write_json,
)
from capsmech.io.case import CaseFileError, CaseResult

__all__ = ["REFERENCE_GRID", "case_record", "cmd_show", "cmd_simulate", "database_choices", "format_summary",
           "out_path_from_args", "register"]


def format_summary(case: CaseResult) -> str:
    """Return a human-readable summary of a case: file, flow, law and parameters, mesh, status
    and message, steady scalars with units, wall time and threads, versions."""
    if "meridian" in case.mesh:
        mesh_text = f"meridian of {case.mesh['meridian'].shape[0]} nodes (axisymmetric)"
    elif case.mesh:
        mesh_text = (f"level {case.mesh_level} ({case.mesh['nodes'].shape[0]} nodes, "
                     f"{case.mesh['triangles'].shape[0]} triangles)")
    else:
        mesh_text = f"level {case.mesh_level}"
    lines = [
        f"case        {case.path}",
        f"flow        {case.flow}",
        f"law         {case.law}   nu_s = {fmt(case.nu_s)}   C = {fmt(case.C)}",
        f"Ca_s        {fmt(case.Ca_s)}",
        f"a/l         {fmt(case.a_over_l)}",
        f"mesh        {mesh_text}",
        f"dt          {fmt(case.dt)} {bracketed_unit(case.unit('history/t'))}",
        f"status      {case.status}",
        f"message     {case.message}",
    ]
    if case.steady:
        lines.append("steady:")
        width = max(len(name) for name in case.steady)
        for name in sorted(case.steady):
            value = case.steady[name]
            lines.append(f"  {name:<{width}} = {fmt(value):>12} {bracketed_unit(case.unit('steady/' + name))}")
    else:
        lines.append("steady      none (run did not reach steady state)")
    lines += [
        f"wall time   {case.wall_time_s:.3g} s on {case.threads} thread(s)",
        f"code        {case.code_version} (schema {case.schema_version})",
    ]
    return "\n".join(lines)


def out_path_from_args(args: Sequence[str]) -> Path | None:
    """Return the case file named by ``--out PATH`` or ``--out=PATH`` in kernel arguments.

    Parameters
    ----------
    args : sequence of str
        Arguments passed through to capsim.

    Returns
    -------
    Path or None
        The last ``--out`` value, or None when there is none.
    """
    found: Path | None = None
    for i, arg in enumerate(args):
        if arg == "--out" and i + 1 < len(args):
            found = Path(args[i + 1])
        elif arg.startswith("--out="):
            found = Path(arg.split("=", 1)[1])
    return found


def case_record(case: CaseResult) -> dict[str, Any]:
    """A case as ``--json`` holds it: what ``format_summary`` prints, with each value's unit."""
    return {"case": case.path, "flow": case.flow, "law": case.law, "nu_s": case.nu_s, "C": case.C,
            "Ca_s": case.Ca_s, "a_over_l": case.a_over_l, "mesh_level": case.mesh_level, "dt": case.dt,
            "status": case.status, "message": case.message, "steady_state": case.is_steady,
            "steady": dict(case.steady), "effects": dict(case.effects),
            "units": {"dt": case.unit("history/t"), **{name: case.unit("steady/" + name) for name in case.steady}},
            "wall_time_s": case.wall_time_s, "threads": case.threads, "code_version": case.code_version,
            "schema_version": case.schema_version}


def cmd_show(case_path: str | Path, plot: str | Path | None = None, json_path: str | Path | None = None,
             force: bool = False) -> int:
    """Print a case summary, and optionally write its plot (PNG) and its JSON; 0 on success."""
    from capsmech.plotting import plot_case, save_figure

    planned = plan_output(plot, "--plot", FIGURE_SUFFIXES, force, create_parent=True) if plot is not None else None
    json_out = plan_output(json_path, "--json", (".json",), force) if json_path is not None else None
    case = read_case(case_path)
    print(format_summary(case))
    if planned is not None:
        print(f"plot        {save_figure(plot_case(case), planned.path)}"
              + (" (replaced the file that was there)" if planned.existed else ""))
    if json_out is not None:
        print(json_out.wrote(write_json(json_out.path, "show", case_record(case))))
    return 0


def database_choices(kernel_args: Sequence[str]) -> list[str]:
    """The reference grid's model choices that ``kernel_args`` leave open, as kernel flags
    (``capsmech.api.database_settings``); printed when added."""
    added = database_settings(kernel_args)
    if added:
        print(f"capsmech: the {REFERENCE_GRID} database's settings for this case: {' '.join(added)} "
              "(give the flags to choose otherwise)")
    return added


def _own_options(kernel_args: Sequence[str]) -> tuple[list[str], str | None, bool]:
    """capsmech's own options among the kernel's (``--json FILE``, ``--force``; the kernel has
    neither), and the arguments left for the kernel."""
    rest: list[str] = []
    json_path: str | None = None
    force = False
    items = iter(kernel_args)
    for arg in items:
        if arg == "--json":
            json_path = next(items, None)
            if json_path is None:
                raise OutputPathError("--json: give the file to write (FILE.json)")
        elif arg.startswith("--json="):
            json_path = arg.split("=", 1)[1]
        elif arg == "--force":
            force = True
        else:
            rest.append(arg)
    return rest, json_path, force


def cmd_simulate(kernel_args: Sequence[str]) -> int:
    """Run the capsim kernel with ``kernel_args`` (``capsmech.api.simulate``), streaming its output.

    The case file named by ``--out`` (an existing one is kept unless ``--force``) is summarised
    if this run wrote it, and with ``--json FILE`` written as ``show --json`` writes it.

    Parameters
    ----------
    kernel_args : sequence of str
        Arguments passed unchanged to ``bin/capsim`` (but ``--json FILE`` and ``--force``).

    Returns
    -------
    int
        The kernel's exit code (or 2 if it succeeded but its case file is unreadable).
    """
    kernel_args, json_path, force = _own_options(kernel_args)
    out = out_path_from_args(kernel_args)
    help_asked = "--help" in kernel_args or "-h" in kernel_args
    if out is not None and not help_asked:
        plan_output(out, "--out", (".h5", ".hdf5"), force, create_parent=True)
    json_out = plan_output(json_path, "--json", (".json",), force) if json_path is not None else None
    added = database_choices(kernel_args)
    run = simulate([*kernel_args, *added], database_defaults=False, output=sys.stdout)
    code = run.returncode
    if run.case_path is not None:
        print()
        try:
            cmd_show(run.case_path)
            if json_out is not None:
                print(json_out.wrote(write_json(json_out.path, "simulate", {
                    "arguments": run.arguments, "added": added, "returncode": code,
                    **case_record(read_case(run.case_path))})))
        except CaseFileError as exc:
            print(f"capsmech: error: {exc}", file=sys.stderr)
            return code if code != 0 else EXIT_ERROR
    elif json_out is not None:
        print(f"capsmech: no case file written: {json_out.path} not written", file=sys.stderr)
    return code


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``simulate`` and ``show``."""
    sub.add_parser(
        "simulate",
        add_help=False,
        help="run the capsim kernel on one case; every argument goes to it (try: simulate --help), but capsmech's "
             "own --json FILE (the case's summary as JSON) and --force (replace an existing --out)",
        description="Run bin/capsim; every argument is passed through to it.",
    )
    show = sub.add_parser("show", help="summarise a case file, optionally plot it")
    show.add_argument("case", metavar="CASE.h5", help="case file written by capsim")
    show.add_argument("--plot", metavar="OUT.png", help="write a 2-panel PNG (history, profile)")
    add_json_option(show, "the case's parameters, status and steady values with their units")
    add_force_option(show)
    show.set_defaults(func=lambda args: cmd_show(args.case, args.plot, args.json, args.force))
