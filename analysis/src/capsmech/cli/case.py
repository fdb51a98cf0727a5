"""``capsmech simulate``: one case with the ``capsim`` kernel; ``capsmech show``: a case file.

``simulate`` passes all its arguments through to the kernel, streams its output, returns the
kernel's exit code, and then summarises the case file named by ``--out`` if the run wrote one.
``show`` prints a case file's parameters, status and steady values, and with ``--plot
OUT.png`` draws the deformation history and the profile (``capsmech.plotting.plot_case``).
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from capsmech.cli.common import EXIT_ERROR, FIGURE_SUFFIXES, bracketed_unit, check_output, fmt
from capsmech.io.case import CaseFileError, CaseResult, read_case
from capsmech.workflow.paths import capsim_executable


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


def cmd_show(case_path: str | Path, plot: str | Path | None = None) -> int:
    """Print a case summary, and optionally write its plot (PNG); 0 on success."""
    from capsmech.plotting import plot_case, save_figure

    if plot is not None:
        check_output(plot, "--plot", FIGURE_SUFFIXES, create_parent=True)
    case = read_case(case_path)
    print(format_summary(case))
    if plot is not None:
        print(f"plot        {save_figure(plot_case(case), plot)}")
    return 0


#: The grid whose model choices a single case takes when the user gives none: the paper's, so that
#: a case run by hand is comparable with (and as steady as) the shipped databases' cases.
REFERENCE_GRID = "paper"


def _flag_value(args: Sequence[str], flag: str) -> str | None:
    for i, arg in enumerate(args):
        if arg == flag and i + 1 < len(args):
            return args[i + 1]
        if arg.startswith(flag + "="):
            return arg.split("=", 1)[1]
    return None


def database_choices(kernel_args: Sequence[str]) -> list[str]:
    """The paper grid's model choices (integrator, bending regularisation) that ``kernel_args``
    leave open, as kernel flags; printed when added. None for a namelist run, a branch, an
    unreadable Ca_s or where the grid file is not at hand (an installed package)."""
    flow, ca = _flag_value(kernel_args, "--flow"), _flag_value(kernel_args, "--ca")
    if flow not in ("tube", "shear") or ca is None or "--help" in kernel_args or "-h" in kernel_args \
            or _flag_value(kernel_args, "--namelist") is not None or _flag_value(kernel_args, "--branch-ca"):
        return []
    from capsmech.workflow.grid import GridError, load_grid, model_choice_flags
    from capsmech.workflow.paths import repo_root

    try:
        Ca_s = float(ca)
        grid = load_grid(repo_root() / "config" / f"{REFERENCE_GRID}.yaml")
    except (ValueError, FileNotFoundError, GridError):
        return []
    flags = model_choice_flags(grid, flow, Ca_s)
    added = [item for flag, value in zip(flags[::2], flags[1::2])
             if _flag_value(kernel_args, flag) is None for item in (flag, value)]
    if added:
        print(f"capsmech: the {REFERENCE_GRID} database's settings for this case: {' '.join(added)} "
              "(give the flags to choose otherwise)")
    return added


def cmd_simulate(kernel_args: Sequence[str]) -> int:
    """Run the capsim kernel with ``kernel_args``, streaming its output.

    The parent directory of ``--out`` is created first. After the run, the
    case file named by ``--out`` is summarised if this run wrote it.

    Parameters
    ----------
    kernel_args : sequence of str
        Arguments passed unchanged to ``bin/capsim``.

    Returns
    -------
    int
        The kernel's exit code (or 2 if it succeeded but its case file is unreadable).
    """
    exe = capsim_executable()
    kernel_args = [*kernel_args, *database_choices(kernel_args)]
    out = out_path_from_args(kernel_args)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
    started = time.time()
    sys.stdout.flush()
    with subprocess.Popen(
        [str(exe), *kernel_args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        bufsize=1,
    ) as proc:
        assert proc.stdout is not None
        try:
            for line in proc.stdout:
                sys.stdout.write(line)
                sys.stdout.flush()
            code = proc.wait()
        except KeyboardInterrupt:
            proc.terminate()
            proc.wait()
            return 130
    if out is not None and out.is_file() and out.stat().st_mtime >= started - 1.0:
        print()
        try:
            cmd_show(out)
        except CaseFileError as exc:
            print(f"capsmech: error: {exc}", file=sys.stderr)
            return code if code != 0 else EXIT_ERROR
    return code


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``simulate`` and ``show``."""
    sub.add_parser(
        "simulate",
        add_help=False,
        help="run the capsim kernel on one case; every argument goes to it (try: simulate --help)",
        description="Run bin/capsim; every argument is passed through to it.",
    )
    show = sub.add_parser("show", help="summarise a case file, optionally plot it")
    show.add_argument("case", metavar="CASE.h5", help="case file written by capsim")
    show.add_argument("--plot", metavar="OUT.png", help="write a 2-panel PNG (history, profile)")
    show.set_defaults(func=lambda args: cmd_show(args.case, args.plot))
