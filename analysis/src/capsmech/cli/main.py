"""Command-line interface: ``capsmech simulate ...``, ``capsmech show CASE.h5``, and the
database workflow's steps ``capsmech run-case``, ``capsmech database assemble|show`` and
``capsmech figures``.

``simulate`` passes all its arguments through to the ``capsim`` kernel, streams
the kernel's output, returns the kernel's exit code, and then summarises the
case file named by ``--out`` if the run wrote one. ``show`` prints a case
file's parameters, status and steady values, and with ``--plot OUT.png`` draws
the deformation history and the shear-plane profile.

Errors in reading a case file, or a missing kernel, print
``capsmech: error: <message>`` to stderr and exit with status 2.
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from capsmech import __version__
from capsmech.imaging.extraction import ExtractionError
from capsmech.io.case import CaseFileError, CaseResult, read_case
from capsmech.io.database import DatabaseError
from capsmech.io.measurements import MeasurementError
from capsmech.workflow.grid import GridError
from capsmech.workflow.paths import capsim_executable
from capsmech.workflow.runner import CaseRunError

#: Exit status for errors reported by capsmech itself (argparse uses the same).
EXIT_ERROR = 2


# ---------------------------------------------------------------------------
# Pure formatting helpers
# ---------------------------------------------------------------------------


def _fmt(value: float) -> str:
    """Format a number compactly (6 significant digits); NaN prints as 'n/a'."""
    return "n/a" if isinstance(value, float) and math.isnan(value) else f"{value:.6g}"


def _units(text: str) -> str:
    """Return ``'[text]'``, with ``'[-]'`` for an empty (dimensionless) unit."""
    return f"[{text or '-'}]"


def format_summary(case: CaseResult) -> str:
    """Return a human-readable summary of a case.

    Parameters
    ----------
    case : CaseResult
        The case to describe.

    Returns
    -------
    str
        Multi-line text: file, flow, law and parameters, mesh, status and
        message, steady scalars with units, wall time and threads, versions.
    """
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
        f"law         {case.law}   nu_s = {_fmt(case.nu_s)}   C = {_fmt(case.C)}",
        f"Ca_s        {_fmt(case.Ca_s)}",
        f"a/l         {_fmt(case.a_over_l)}",
        f"mesh        {mesh_text}",
        f"dt          {_fmt(case.dt)} {_units(case.unit('history/t'))}",
        f"status      {case.status}",
        f"message     {case.message}",
    ]
    if case.steady:
        lines.append("steady:")
        width = max(len(name) for name in case.steady)
        for name in sorted(case.steady):
            value = case.steady[name]
            lines.append(f"  {name:<{width}} = {_fmt(value):>12} {_units(case.unit('steady/' + name))}")
    else:
        lines.append("steady      none (run did not reach steady state)")
    lines += [
        f"wall time   {case.wall_time_s:.3g} s on {case.threads} thread(s)",
        f"code        {case.code_version} (schema {case.schema_version})",
    ]
    return "\n".join(lines)


# ---------------------------------------------------------------------------
# Plotting
# ---------------------------------------------------------------------------


def _axis_label(case: CaseResult, group: str, name: str) -> str:
    """Return an axis label ``'name [units]'`` for dataset ``group/name``."""
    return f"{name} {_units(case.unit(f'{group}/{name}'))}"


def plot_case(case: CaseResult, out: str | Path) -> Path:
    """Draw a 2-panel PNG: deformation history and shear-plane profile.

    Left: D12 against t (or L1 and L2 against t when D12 is absent), with the
    steady value as a dashed line when there is one. Right: the contour in
    the shear plane x = 0, z against y, equal aspect.

    Parameters
    ----------
    case : CaseResult
        The case to plot.
    out : str or Path
        PNG file to write; its parent directory is created if needed.

    Returns
    -------
    Path
        The file written.
    """
    from matplotlib.figure import Figure  # no pyplot: no GUI backend needed

    out = Path(out)
    fig = Figure(figsize=(10, 4.2), layout="constrained")
    ax_h, ax_p = fig.subplots(1, 2)

    if case.flow == "tube":
        names = [n for n in ("L_z", "L_p", "v_c") if n in case.history]
    else:
        names = ["D12"] if "D12" in case.history else [n for n in ("L1", "L2") if n in case.history]
    if "t" in case.history and names:
        t = case.history["t"]
        for name in names:
            ax_h.plot(t, case.history[name], label=name)
            if name in case.steady:
                ax_h.axhline(case.steady[name], ls="--", lw=0.8, color="0.4", label=f"steady {name}")
        ax_h.set_xlabel(_axis_label(case, "history", "t"))
        ax_h.set_ylabel(", ".join(_axis_label(case, "history", n) for n in names))
        ax_h.legend(loc="best", fontsize="small")
    else:
        ax_h.text(0.5, 0.5, "no history", ha="center", va="center", transform=ax_h.transAxes)
    ax_h.set_title("deformation history")
    ax_h.grid(True, alpha=0.3)

    if "r" in case.profile:
        # Meridian mirrored about the axis: the capsule as the microscope sees it, flow to the right.
        r, z = case.profile["r"], case.profile["z"]
        ax_p.plot(list(z) + list(z[::-1]), list(r) + list(-r[::-1]), "-", lw=1.5)
        ax_p.axhline(1.0, color="0.3", lw=2)
        ax_p.axhline(-1.0, color="0.3", lw=2)
        ax_p.set_aspect("equal", adjustable="datalim")
        ax_p.set_xlabel(_axis_label(case, "profile", "z"))
        ax_p.set_ylabel(_axis_label(case, "profile", "r"))
    elif case.profile:
        y = list(case.profile["y"]) + [case.profile["y"][0]]  # close the contour
        z = list(case.profile["z"]) + [case.profile["z"][0]]
        ax_p.plot(y, z, "-", lw=1.5)
        ax_p.set_aspect("equal", adjustable="datalim")
        ax_p.set_xlabel(_axis_label(case, "profile", "y"))
        ax_p.set_ylabel(_axis_label(case, "profile", "z"))
    else:
        ax_p.text(0.5, 0.5, "no profile", ha="center", va="center", transform=ax_p.transAxes)
    ax_p.set_title("meridian in the tube (wall at r = l)" if case.flow == "tube" else "profile in the shear plane x = 0")
    ax_p.grid(True, alpha=0.3)

    fig.suptitle(f"{case.flow}, {case.law}, Ca_s = {_fmt(case.Ca_s)}: {case.status}")
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    return out


# ---------------------------------------------------------------------------
# Subcommands
# ---------------------------------------------------------------------------


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
    """Print a case summary, and optionally write its plot.

    Parameters
    ----------
    case_path : str or Path
        Case file to read.
    plot : str or Path, optional
        PNG file to write.

    Returns
    -------
    int
        0 on success.

    Raises
    ------
    CaseFileError, FileNotFoundError
        If the case file cannot be read.
    """
    case = read_case(case_path)
    print(format_summary(case))
    if plot is not None:
        print(f"plot        {plot_case(case, plot)}")
    return 0


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


def cmd_run_case(args: argparse.Namespace) -> int:
    """Run one workflow case (see :mod:`capsmech.workflow.runner` for the exit-code policy)."""
    from capsmech.workflow.runner import run_case

    kernel_args = [a for a in args.kernel_args if a != "--"]
    run_case(args.capsim or capsim_executable(), kernel_args, args.out,
             code_version=args.code_version, threads=args.threads)
    return 0


def cmd_kernel_version(args: argparse.Namespace) -> int:
    """Check that the built kernel writes the code_version its sources declare; record it."""
    from capsmech.workflow.runner import kernel_code_version

    found = kernel_code_version(args.capsim or capsim_executable())
    if args.expect and found != args.expect:
        raise CaseRunError(f"{args.capsim} writes code_version {found!r} but the kernel sources declare "
                           f"{args.expect!r}: the executable is stale, run `make build`")
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(found + "\n")
    print(found)
    return 0


def cmd_unlock_stale(args: argparse.Namespace) -> int:
    """Remove a Snakemake lock left by a killed workflow (never one of a live workflow)."""
    from capsmech.workflow.runner import clear_stale_lock, running_snakemake

    if clear_stale_lock(args.workdir):
        print(f"removed the stale Snakemake lock of {args.workdir} (left by a killed run)")
    elif running_snakemake(args.workdir):
        print(f"a Snakemake process is running in {args.workdir}: its lock is kept")
    return 0


def cmd_database(args: argparse.Namespace) -> int:
    """``database assemble``: case files -> database file; ``database show``: summarise one."""
    from capsmech.io.database import assemble_database, load_database
    from capsmech.workflow.grid import load_grid

    if args.action == "assemble":
        out = assemble_database(load_grid(args.grid), args.flow, args.cases, args.out)
        print(f"wrote {out}")
        args.database = out
    database = load_database(args.database)
    print(f"{database.path}: {database.flow} database of grid {database.provenance['grid_name']!r}, "
          f"kernel {database.provenance['code_version']}, created {database.provenance['created']}")
    for key, table in database.laws.items():
        counts = {s: int((table.status == s).sum()) for s in sorted(set(table.status))}
        print(f"  {key:<10} {len(table):4d} cases  " + ", ".join(f"{n} {s}" for s, n in counts.items()))
    return 0


def cmd_figures(args: argparse.Namespace) -> int:
    """Draw the paper's figures from one database, or from every database of a grid."""
    from capsmech.workflow.figures import draw_figures
    from capsmech.workflow.grid import FLOWS, load_grid

    grid = load_grid(args.grid) if args.grid else None
    if args.database:
        jobs = [(Path(args.database), Path(args.out) if args.out else None)]
    elif grid is not None:
        jobs = [(Path(grid["databases_dir"]) / f"{flow}.h5",
                 Path(args.out or Path(grid["results_dir"]) / "figures") / flow)
                for flow in FLOWS if flow in grid]
    else:
        raise GridError("figures: give --database DB.h5 or --grid GRID.yaml")
    for database, out in jobs:
        if out is None:
            raise GridError("figures: --out DIR is required with --database")
        for path in draw_figures(database, out, grid):
            print(f"wrote {path}")
    return 0


def cmd_fit(args: argparse.Namespace) -> int:
    """``fit-tube`` / ``fit-shear``: fit a measurement CSV against a database, print the table."""
    from capsmech.inversion.fitting import (
        SHEAR_RESULT_UNITS,
        TUBE_RESULT_UNITS,
        fit_shear,
        fit_tube,
        write_results,
    )
    from capsmech.io.database import load_database
    from capsmech.io.measurements import read_measurements

    flow = "tube" if args.command == "fit-tube" else "shear"
    capsules = read_measurements(args.measurements, flow)
    database = load_database(args.database)
    if database.flow != flow:
        raise DatabaseError(f"{args.database}: a {database.flow} database, {args.command} needs a {flow} one")
    fit, units = (fit_tube, TUBE_RESULT_UNITS) if flow == "tube" else (fit_shear, SHEAR_RESULT_UNITS)
    rows = fit(capsules, database, args.law or None)
    shown = ["id", "law", "a_over_l", "Ca_s", "G_s", "G_s_spread", "flag"] if flow == "tube" else \
        ["id", "law", "D12", "Ca_s", "a", "G_s", "flag"]
    shown = [k for k in shown if k in units]
    print("  ".join(f"{k:>10}" for k in shown))
    for row in rows:
        print("  ".join(f"{row[k]:>10.4g}" if isinstance(row[k], float) else f"{str(row[k]):>10}" for k in shown))
    for out in args.out or []:
        print(f"wrote {write_results(rows, units, out, database)}")
    return 0


def _effect_databases(paths: Sequence[str] | None) -> list[str]:
    """The effect databases diagnose reads: those named, else every data/databases/effects/*/tube.h5."""
    if paths is not None:
        return list(paths)
    return sorted(str(p) for p in Path("data/databases/effects").glob("*/tube.h5"))


DEFAULT_OFFCENTRE_TABLE = "data/databases/effects/offcentre/table.h5"


def _offcentre_table(path: str | None):
    """The off-centre table diagnose fits screened capsules with: the one named, else the
    shipped one when present; None for 'none'."""
    from capsmech.diagnosis.offcentre import OffcentreError, OffcentreTable

    if path == "none" or (path is None and not Path(DEFAULT_OFFCENTRE_TABLE).is_file()):
        return None
    try:
        return OffcentreTable.read(path or DEFAULT_OFFCENTRE_TABLE)
    except OffcentreError as err:
        raise DatabaseError(f"--offcentre-table: {err}") from None


def cmd_diagnose(args: argparse.Namespace) -> int:
    """``diagnose``: which candidate effect the batch's contour residuals support."""
    from capsmech.diagnosis.candidates import DatabaseSet, candidate_library
    from capsmech.diagnosis.diagnose import diagnose
    from capsmech.diagnosis.effect_grid import (
        case_count,
        estimated_core_minutes,
        write_grid,
    )
    from capsmech.diagnosis.report import write_report
    from capsmech.diagnosis.sequential import diagnose_sequential
    from capsmech.io.database import load_database
    from capsmech.io.measurements import read_measurements

    capsules = read_measurements(args.measurements, "tube")
    database = load_database(args.database)
    if database.flow != "tube":
        raise DatabaseError(f"{args.database}: a {database.flow} database, diagnose needs a tube one")
    effects = [load_database(path) for path in _effect_databases(args.effects_database)]
    for path, effect in zip(_effect_databases(args.effects_database), effects):
        if effect.flow != "tube":
            raise DatabaseError(f"{path}: a {effect.flow} database, diagnose needs a tube one")
    databases = DatabaseSet([database, *effects])
    if args.law not in database.laws:
        raise DatabaseError(f"{args.database}: no law {args.law!r} (it has {', '.join(database.laws)})")
    for key in args.other_law or []:
        if key not in databases.laws:
            raise DatabaseError(f"{args.database}: no law {key!r} (it has {', '.join(databases.laws)})")
    levels = {}
    for option in ("prestress_levels", "kb_levels"):
        text = getattr(args, option)
        try:
            levels[option] = [float(v) for v in text.split(",") if v.strip()]
        except ValueError:
            raise MeasurementError(f"--{option.replace('_', '-')}: not a comma-separated list of numbers: {text!r}") from None
        if any(v <= 0 for v in levels[option]):
            raise MeasurementError(f"--{option.replace('_', '-')}: levels must be > 0 (0 is the base law): {text!r}")
    candidates = candidate_library(args.law, list(database.laws), levels["prestress_levels"], args.other_law,
                                   kb_levels=levels["kb_levels"])
    if args.candidate:
        candidates = [c for c in candidates if c.name in args.candidate
                      or ("laws" in args.candidate and c.name.startswith("law "))]
    if args.max_effects < 1:
        raise MeasurementError(f"--max-effects: must be at least 1, got {args.max_effects}")
    offcentre_table = _offcentre_table(args.offcentre_table)
    try:
        if args.max_effects == 1:
            sequence = None
            result = diagnose(capsules, databases, args.law, candidates, offcentre_table=offcentre_table)
        else:
            names = {c.name for c in candidates}
            sequence = diagnose_sequential(
                capsules, databases, args.law,
                lambda law: [c for c in candidate_library(law, list(database.laws), levels["prestress_levels"],
                                                          args.other_law, kb_levels=levels["kb_levels"])
                             if c.name in names],
                max_effects=args.max_effects, offcentre_table=offcentre_table)
            result = sequence.rounds[0]
    except ValueError as err:
        raise MeasurementError(f"{args.measurements}: {err}") from None
    for r in result.results:
        if r.needs is None:
            continue
        path = write_grid(r.needs, Path(args.grid_dir) / f"{r.needs['name']}.yaml",
                          header=f"Written by capsmech diagnose {args.measurements}: the cases the {r.name} "
                                 "candidate needs.\nRun: make database GRID=" + r.needs["name"])
        print(f"capsmech diagnose: candidate {r.name} needs {case_count(r.needs)} cases "
              f"(~{estimated_core_minutes(r.needs, database, args.law):.0f} core-min): "
              f"make database GRID={r.needs['name']} (grid written to {path})")
    for capsule, why in result.excluded:
        print(f"capsmech diagnose: left out {capsule}: {why}")
    for fit in result.offcentre:
        print(f"capsmech diagnose: off-centre {fit.summary}")
    print(f"verdict: {result.verdict}")
    if sequence is not None and sequence.effects:
        for k, later in enumerate(sequence.rounds[1:], start=2):
            # The values each round was run with (the effects list holds the final ones).
            fixed = ", ".join(f"{r.chosen.name} = {r.chosen.theta:.3g}" for r in sequence.rounds[:k - 1])
            print(f"with {fixed} fixed: {later.verdict}")
        print(f"effects found: {sequence.verdict}; G_s {sequence.g_s[0][0]:.4g} -> {sequence.g_s[-1][0]:.4g} N/m")
    if args.out:
        print(f"wrote {write_report(result, args.out, Path(args.measurements).name)}")
        for k, later in enumerate(sequence.rounds[1:] if sequence is not None else [], start=2):
            out = Path(args.out).with_name(f"{Path(args.out).stem}_round{k}{Path(args.out).suffix}")
            print(f"wrote {write_report(later, out, Path(args.measurements).name + f' (round {k})')}")
    return 0


def cmd_make_batch(args: argparse.Namespace) -> int:
    """``make-batch``: a synthetic tube batch with undeclared effects (capsmech.diagnosis.undeclared_tube)."""
    from capsmech.diagnosis.undeclared_tube import make_batch, write_batch

    effects = args.effect or []
    strengths = args.strength or []
    if len(strengths) != len(effects):
        raise MeasurementError(f"--strength: give one per --effect ({len(effects)} effects, {len(strengths)} strengths)")
    try:
        batch = make_batch(dict(zip(effects, strengths)), n_capsules=args.n, law=args.law, g_s=args.g_s,
                           seed=args.seed, workers=args.workers)
    except ValueError as err:
        raise MeasurementError(str(err)) from None
    csv_path, truth = write_batch(batch, Path(args.out) / f"{args.name}.csv")
    print(f"wrote {csv_path} ({len(batch.rows)} capsules) and {truth}")
    return 0


def cmd_population(args: argparse.Namespace) -> int:
    """``population``: drift of G_s with Delta per law from fit-tube results; the law that fits."""
    from capsmech.inversion.fitting import write_results
    from capsmech.inversion.population import (
        POPULATION_UNITS,
        plot_population,
        population_rows,
        population_verdict,
        read_results,
    )

    rows = [row for path in args.results for row in read_results(path)]
    verdict = population_verdict(rows)
    drifts, best = verdict.drifts, verdict.best
    print(f"{'law':>10} {'n':>4} {'G_s [N/m]':>20} {'drift /unit Delta':>18} {'95 % interval':>20} {'p':>8}")
    for law, d in drifts.items():
        print(f"{law:>10} {d.n:>4} {d.mean:>10.4g} +- {d.std:<7.2g} {d.slope:>+18.3f} "
              f"[{d.ci_low:+.3f}, {d.ci_high:+.3f}] {d.p_value:>8.2g}")
    if verdict.shape is not None:
        shape = verdict.shape
        print(f"contour misfit H/a over the {shape.n} capsules every law fits: "
              + ", ".join(f"{law} median {m:.4f}" for law, m in shape.median.items())
              + "; paired signed-rank p: " + ", ".join(f"{a}/{b} {p:.2g}" for (a, b), p in shape.p_values.items()))
    if best is None:
        print(f"verdict: no law fits the batch ({verdict.reason})")
    else:
        print(f"verdict: {best}, G_s = {drifts[best].mean:.4g} +- {drifts[best].std:.2g} N/m ({verdict.reason})")
    if args.plot:
        print(f"wrote {plot_population(rows, drifts, args.plot)}")
    for out in args.out or []:
        print(f"wrote {write_results(population_rows(drifts, best), POPULATION_UNITS, out)}")
    return 0


def cmd_compare_methods(args: argparse.Namespace) -> int:
    """``compare-methods``: the paper's shear and tube moduli, before and after the viscosity
    ratio of its shear experiment (capsmech.inversion.microrheometry)."""
    from capsmech.inversion.microrheometry import compare_methods, comparison_table
    from capsmech.io.database import ShearDatabase, load_database

    base, with_lambda = load_database(args.database), load_database(args.lambda_database)
    for path, db in ((args.database, base), (args.lambda_database, with_lambda)):
        if not isinstance(db, ShearDatabase):
            raise DatabaseError(f"{path}: not a shear database")
    suffix = f"+lambda{args.lambda_value}"
    missing = [law + suffix for law in args.law if law + suffix not in with_lambda.laws]
    if missing:
        raise DatabaseError(f"{args.lambda_database}: no law group {', '.join(missing)} "
                            f"(it has {', '.join(with_lambda.laws)}); refill it with `make database GRID=microrheometry`")
    print(comparison_table(compare_methods(base, with_lambda, suffix, tuple(args.law))))
    return 0


def cmd_extract(args: argparse.Namespace) -> int:
    """``extract``: frames of a capsule in the tube -> measurement CSV, contours, report, overlays.

    Exit status 0 when at least one capsule was measured, 1 when none could be (the reasons
    are printed and the per-frame report is still written), 2 for unreadable files or bad
    options (``ExtractionError``).
    """
    from capsmech.imaging.extraction import (
        ExtractionError,
        ExtractionSettings,
        extract,
        measure_capsules,
        progress_printer,
        read_frames,
    )
    from capsmech.imaging.extraction_output import (
        PIXEL_UNITS_UM,
        RATE_UNITS_HZ,
        VISCOSITY_UNITS_PA_S,
        default_ids,
        parse_quantity,
        write_frame_report,
        write_measurements,
        write_overlay,
    )

    pixel_um = parse_quantity(args.pixel_size, "--pixel-size", PIXEL_UNITS_UM, "um") if args.pixel_size else None
    rate = parse_quantity(args.frame_rate, "--frame-rate", RATE_UNITS_HZ, "Hz") if args.frame_rate else None
    mu = parse_quantity(args.mu, "--mu", VISCOSITY_UNITS_PA_S, "Pa s") if args.mu else None
    settings = ExtractionSettings(max_asymmetry=args.max_asymmetry, max_line_width_px=args.max_line_width,
                                  min_good_frames=args.min_frames)
    stack = read_frames(args.frames, args.flow_direction)
    pixel_um = pixel_um or stack.pixel_size_um
    rate = rate or stack.frame_rate
    if pixel_um is None:
        raise ExtractionError("--pixel-size: required (the files carry no pixel size)")
    if rate is None:
        raise ExtractionError("--frame-rate: required (the files carry no frame interval)")
    walls, results = extract(stack, settings, progress_printer())
    out = Path(args.out)
    report = Path(args.report) if args.report else out.with_name(out.stem + "_frames.csv")
    write_frame_report(report, results)
    print(f"{len(stack)} frames of {stack.frames[0].shape[1]}x{stack.frames[0].shape[0]} px; tube radius "
          f"{walls.radius_px:.2f} px = {walls.radius_px * pixel_um:.4g} um, axis at row {walls.axis_row:.2f}; "
          f"pixel {pixel_um:g} um, {rate:g} frames/s")
    flags: dict[str, int] = {}
    for r in results:
        if r.flag:
            reason = r.flag.split(" (")[0]
            flags[reason] = flags.get(reason, 0) + 1
    good = sum(r.good for r in results)
    print(f"{good} frames measured" + (", flagged: " + ", ".join(f"{n} {k}" for k, n in sorted(flags.items()))
                                       if flags else "") + f" (per frame: {report})")
    capsules = measure_capsules(results, rate, settings)
    measured = [c for c in capsules if c.ok]
    ids = default_ids(args.id or Path(stack.labels[0].split("[")[0]).stem, len(capsules))
    for cap_id, cap in zip(ids, capsules):
        if not cap.ok:
            print(f"capsule {cap_id} (frames {cap.frames[0]}-{cap.frames[-1]}) not measured: {cap.problem}")
    if not measured:
        why = "no capsule in any frame" if not capsules else "no capsule had enough good frames"
        print(f"capsmech: nothing measured ({why}); {out} not written", file=sys.stderr)
        return 1
    kept_ids = [i for i, c in zip(ids, capsules) if c.ok]
    csv_path, _ = write_measurements(out, measured, results, walls, pixel_um, kept_ids, mu,
                                     source=" ".join(str(f) for f in args.frames), flow_direction=args.flow_direction)
    print(f"{'id':>12} {'frames':>7} {'L_z [um]':>16} {'L_p [um]':>16} {'v_c [mm/s]':>18}")
    for cap_id, cap in zip(kept_ids, measured):
        print(f"{cap_id:>12} {len(cap.good_frames):>7} {cap.L_z_px * pixel_um:>8.4g} +- {cap.L_z_spread_px * pixel_um:<4.2g}"
              f" {cap.L_p_px * pixel_um:>8.4g} +- {cap.L_p_spread_px * pixel_um:<4.2g}"
              f" {cap.v_c_px_s * pixel_um * 1e-3:>9.5g} +- {cap.v_c_se_px_s * pixel_um * 1e-3:<5.2g}")
        if args.overlay:
            frame = next(r for r in results if r.index == cap.representative)
            title = (f"{cap_id}, frame {frame.index}: L_z = {cap.L_z_px * pixel_um:.4g} um, L_p = "
                     f"{cap.L_p_px * pixel_um:.4g} um, tube radius {walls.radius_px * pixel_um:.4g} um, "
                     f"v_c = {cap.v_c_px_s * pixel_um * 1e-3:.4g} mm/s")
            print(f"wrote {write_overlay(Path(args.overlay) / f'{cap_id}.png', stack.frames[frame.index], frame, walls, title)}")
    print(f"wrote {csv_path}")
    return 0


# ---------------------------------------------------------------------------
# Entry point
# ---------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser of the ``capsmech`` command."""
    parser = argparse.ArgumentParser(
        prog="capsmech",
        description="Run the capsim kernel and inspect its HDF5 case files.",
    )
    parser.add_argument("--version", action="version", version=f"capsmech {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    sub.add_parser(
        "simulate",
        add_help=False,
        help="run bin/capsim with all following arguments (try: simulate --help)",
        description="Run bin/capsim; every argument is passed through to it.",
    )
    show = sub.add_parser("show", help="summarise a case file, optionally plot it")
    show.add_argument("case", metavar="CASE.h5", help="case file written by capsim")
    show.add_argument("--plot", metavar="OUT.png", help="write a 2-panel PNG (history, profile)")

    run = sub.add_parser("run-case", help="run one grid case for the workflow (records non-steady outcomes)")
    run.add_argument("--out", required=True, help="case file to produce")
    run.add_argument("--code-version", required=True, help="code_version the case file must carry")
    run.add_argument("--threads", type=int, default=1, help="OpenMP threads")
    run.add_argument("--capsim", help="kernel executable (default: bin/capsim or $CAPSIM)")
    run.add_argument("kernel_args", nargs=argparse.REMAINDER, help="-- then the kernel's case arguments")

    version = sub.add_parser("kernel-version", help="print (and check) the code_version the kernel writes")
    version.add_argument("--capsim", default=None, help="kernel executable (default: bin/capsim)")
    version.add_argument("--expect", help="fail unless the kernel writes this version")
    version.add_argument("--out", help="also write the version to this file")

    unlock = sub.add_parser("unlock-stale", help="remove the Snakemake lock a killed workflow left")
    unlock.add_argument("workdir", nargs="?", default=".", help="the workflow's working directory")

    database = sub.add_parser("database", help="assemble or summarise a database file")
    actions = database.add_subparsers(dest="action", required=True, metavar="ACTION")
    assemble = actions.add_parser("assemble", help="case files of a grid -> tube.h5 or shear.h5")
    assemble.add_argument("--grid", required=True, help="grid file (YAML or JSON)")
    assemble.add_argument("--flow", required=True, choices=("tube", "shear"))
    assemble.add_argument("--cases", required=True, help="directory holding <flow>/<law>/<case>.h5")
    assemble.add_argument("--out", required=True, help="database file to write")
    summary = actions.add_parser("show", help="summarise a database file")
    summary.add_argument("database", metavar="DB.h5")

    figures = sub.add_parser("figures", help="draw the paper's figures 2-6 from the databases")
    figures.add_argument("--database", metavar="DB.h5", help="one database (tube: figures 2-5, shear: 6)")
    figures.add_argument("--grid", help="grid file: its databases, and figure settings")
    figures.add_argument("--out", metavar="DIR", help="output directory (default: <results_dir>/figures/<flow>)")
    for name, flow in (("fit-tube", "tube"), ("fit-shear", "shear")):
        fit = sub.add_parser(name, help=f"fit measured capsules ({flow} CSV) against a {flow} database")
        fit.add_argument("measurements", metavar="CSV", help="measurement file (format: capsmech.io.measurements)")
        fit.add_argument("--database", default=f"data/databases/{flow}.h5", help="database file")
        fit.add_argument("--law", action="append", help="law key to fit with (repeatable; default: all)")
        fit.add_argument("--out", action="append", metavar="FILE", help="write the results (.csv or .h5; repeatable)")
    pop = sub.add_parser("population", help="which law gives a G_s that does not drift with deformation")
    pop.add_argument("results", nargs="+", metavar="RESULTS.csv", help="fit-tube results")
    pop.add_argument("--plot", metavar="FIG.png", help="draw G_s against Delta (paper figure 10)")
    pop.add_argument("--out", action="append", metavar="FILE", help="write the per-law table (.csv or .h5; repeatable)")
    diag = sub.add_parser("diagnose", help="which effect the base model lacks, from the batch's contour residuals")
    diag.add_argument("measurements", metavar="CSV", help="tube measurements with contour files")
    diag.add_argument("--database", default="data/databases/tube.h5", help="tube database file")
    diag.add_argument("--law", default="NH", help="base law key (default NH)")
    diag.add_argument("--other-law", action="append", metavar="KEY",
                      help="another law group to test as a candidate (repeatable), e.g. GH_nu0.5 or NH+prestress0.05 "
                           "(default: every other law of the database)")
    diag.add_argument("--effects-database", action="append", metavar="H5",
                      help="tube database of effect law groups (repeatable; default: data/databases/effects/*/tube.h5)")
    diag.add_argument("--prestress-levels", default="0.04,0.06,0.08", metavar="A1,A2,..",
                      help="pre-stress levels of the prestress candidate (default 0.04,0.06,0.08; empty: no candidate)")
    diag.add_argument("--kb-levels", default="0.0025,0.005,0.01", metavar="K1,K2,..",
                      help="bending stiffness levels of the kb candidate (default 0.0025,0.005,0.01; empty: no candidate)")
    diag.add_argument("--candidate", action="append", choices=("contour_offset", "tube_radius", "prestress", "kb", "laws"),
                      help="test only these candidates (repeatable; default all: the effect library)")
    diag.add_argument("--max-effects", type=int, default=2, metavar="N",
                      help="effects to look for one after another, each fixed before the next (default 2; 1: one)")
    diag.add_argument("--offcentre-table", metavar="H5",
                      help="antisymmetric modes to fit the offset of capsules screened out as asymmetric "
                           f"(default: {DEFAULT_OFFCENTRE_TABLE} when present; none: leave them out unfitted)")
    diag.add_argument("--grid-dir", default="config", metavar="DIR",
                      help="where grids of candidates that need simulations are written (default config)")
    diag.add_argument("--out", metavar="REPORT.md", help="write a Markdown report (figures beside it)")
    mb = sub.add_parser("make-batch", help="synthetic tube batch with an undeclared effect (truth in a separate file)")
    mb.add_argument("--effect", action="append", choices=("contour_offset", "tube_radius", "prestress", "kb", "GH_nu", "SK_C"),
                    help="effect to switch on (repeatable; none: no effect)")
    mb.add_argument("--strength", action="append", type=float, help="its strength (px, relative, alpha, k_b, nu_s, C)")
    mb.add_argument("--out", required=True, metavar="DIR", help="output folder")
    mb.add_argument("--name", default="batch", help="file stem (default batch)")
    mb.add_argument("-n", type=int, default=24, help="capsules (default 24)")
    mb.add_argument("--law", default="NH", help="base law (default NH)")
    mb.add_argument("--g-s", type=float, default=0.04, help="G_s of the material [N/m] (default 0.04)")
    mb.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    mb.add_argument("--workers", type=int, default=1, help="kernel runs at a time (default 1)")
    comp = sub.add_parser("compare-methods", help="the paper's microrheometry against its microfluidics, "
                          "before and after the viscosity ratio of its shear experiment")
    comp.add_argument("--database", default="data/databases/shear.h5", help="shear database made with lambda = 1")
    comp.add_argument("--lambda-database", default="data/databases/microrheometry/shear.h5",
                      help="shear database with the experiment's viscosity ratio (config/microrheometry.yaml)")
    comp.add_argument("--lambda-value", default="0.001", help="its viscosity ratio, as in the law keys (default 0.001)")
    comp.add_argument("--law", nargs="+", default=["NH", "GH_nu0.5", "GH_nu0.2"], help="base law keys")
    from capsmech.diagnosis.shear import add_parser as add_diagnose_shear
    add_diagnose_shear(sub)
    ext = sub.add_parser("extract", help="frames of capsules in the tube -> measurement CSV (fit-tube), contours, overlays")
    ext.add_argument("frames", nargs="+", metavar="FRAMES", help="multi-page TIFF, image files, directories or glob patterns, in frame order")
    ext.add_argument("--pixel-size", help="size of one pixel, e.g. 0.5um (bare numbers: um; default: the TIFF's metadata)")
    ext.add_argument("--frame-rate", help="frames per second, e.g. 1000 (default: the TIFF's frame interval)")
    ext.add_argument("--mu", help="viscosity of the liquid, e.g. 1.0 (Pa s) or 50mPa s: written as the mu column (needed for G_s)")
    ext.add_argument("--out", required=True, metavar="CSV", help="measurement file to write (the format fit-tube reads)")
    ext.add_argument("--overlay", metavar="DIR", help="write one PNG per capsule: its contour and the walls on a frame")
    ext.add_argument("--report", metavar="CSV", help="per-frame report (default: <out stem>_frames.csv)")
    ext.add_argument("--flow-direction", choices=("right", "left"), default="right",
                     help="direction of the flow in the images (left: the frames are mirrored first)")
    ext.add_argument("--id", help="capsule id (several capsules: ID-1, ID-2, ...; default: the first file's name)")
    ext.add_argument("--max-asymmetry", type=float, default=0.05,
                     help="flag frames whose two halves differ by more than this fraction of L_z/2 (default 0.05)")
    ext.add_argument("--max-line-width", type=float, default=10.0,
                     help="flag frames whose membrane line is wider than this, px (out of focus; default 10)")
    ext.add_argument("--min-frames", type=int, default=3, help="good frames a capsule needs to be measured (default 3)")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``capsmech`` command line.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name; defaults to ``sys.argv[1:]``.

    Returns
    -------
    int
        Exit status: the kernel's for ``simulate``, 0 for a successful
        ``show``, 2 for errors.
    """
    parser = build_parser()
    args, rest = parser.parse_known_args(list(sys.argv[1:] if argv is None else argv))
    if args.command != "simulate" and rest:
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    commands = {"run-case": cmd_run_case, "kernel-version": cmd_kernel_version, "unlock-stale": cmd_unlock_stale, "database": cmd_database, "figures": cmd_figures,
                "fit-tube": cmd_fit, "fit-shear": cmd_fit, "population": cmd_population, "extract": cmd_extract,
                "diagnose": cmd_diagnose, "make-batch": cmd_make_batch, "compare-methods": cmd_compare_methods}
    from capsmech.diagnosis.shear import cmd_diagnose_shear
    commands["diagnose-shear"] = cmd_diagnose_shear
    try:
        if args.command == "simulate":
            return cmd_simulate(rest)
        if args.command in commands:
            return commands[args.command](args)
        return cmd_show(args.case, args.plot)
    except (CaseFileError, FileNotFoundError, GridError, DatabaseError, CaseRunError, MeasurementError,
            ExtractionError) as exc:
        print(f"capsmech: error: {exc}", file=sys.stderr)
        return EXIT_ERROR


if __name__ == "__main__":
    sys.exit(main())
