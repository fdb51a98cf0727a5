"""``capsmech diagnose`` (tube batches) and ``capsmech diagnose-shear`` (Couette batches): which
effect the base model lacks, from what the fits leave; and ``capsmech make-batch``, synthetic
tube batches with an undeclared effect to check the method on."""
from __future__ import annotations

import argparse
import math
import sys
import warnings
from functools import cache
from pathlib import Path

from capsmech.api import as_database, diagnose, diagnose_shear, make_batch, write_batch
from capsmech.cli.common import (
    add_base_law_option,
    add_database_option,
    add_force_option,
    add_json_option,
    add_report_option,
    plan_output,
    report_option,
    write_json,
)
from capsmech.diagnosis.shear import ERROR_PX, LAMBDA_VALUE, PIXEL_SIZE, THETA_ERROR
from capsmech.errors import CapsmechError, InputWarning
from capsmech.io.measurements import MeasurementError, read_measurements


def _levels(text: str, option: str) -> list[float]:
    """A comma-separated list of positive levels (empty: no such candidate)."""
    name = "--" + option.replace("_", "-")
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise MeasurementError(f"{name}: not a comma-separated list of numbers: {text!r}") from None
    if any(not (math.isfinite(v) and v > 0) for v in values):
        raise MeasurementError(f"{name}: levels must be > 0 (0 is the base law): {text!r}")
    return values


def cmd_diagnose(args: argparse.Namespace) -> int:
    """``diagnose``: which candidate effect the batch's contour residuals support."""
    from capsmech.diagnosis.effect_grid import cost_text, write_grid
    from capsmech.diagnosis.record import diagnosis_record
    from capsmech.diagnosis.report import batch_heterogeneity, write_report
    from capsmech.diagnosis.sequential import SequentialDiagnosis

    levels = {option: _levels(getattr(args, option), option) for option in ("prestress_levels", "kb_levels")}
    # Outputs are checked before the minutes of work that fill them.
    report_path = report_option(args)
    report = plan_output(report_path, "--report", (".md",), args.force, create_parent=True) if report_path else None
    json_out = plan_output(args.json, "--json", (".json",), args.force) if args.json else None
    if args.profile and not args.simulate:
        raise MeasurementError("--profile: only with --simulate (it says where the simulations run)")
    database = as_database(args.database, "tube", "diagnose")
    effect_databases = list(args.effects_database) if args.effects_database else None
    family_levels = _family_levels(args)
    simulated: dict[str, Path] = {}
    extensions: list[str] = []
    while True:
        outcome = _diagnose_batch(args, database, effect_databases, levels, family_levels)
        sequence: SequentialDiagnosis | None
        if isinstance(outcome, SequentialDiagnosis):
            sequence, result = outcome, outcome.rounds[0]
        else:
            sequence, result = None, outcome
        rounds = sequence.rounds if sequence is not None else [result]
        needs = {_grid_identity(r.needs): (r.name, r.needs) for one in rounds for r in one.results
                 if r.needs is not None}
        if not args.simulate:
            break
        if not needs or set(needs) <= set(simulated):
            # Nothing left to compute: a strength at an edge of its levels gets a level beyond it.
            added = _extend_levels(rounds, levels, family_levels) if len(extensions) < MAX_LEVEL_EXTENSIONS else ""
            if not added:
                break
            extensions.append(added)
            print(f"capsmech diagnose: {added}", flush=True)
            continue
        # Effects on demand: compute what the candidates need, then diagnose again with it.
        for identity, (candidate, grid) in needs.items():
            if identity not in simulated:
                simulated[identity] = _simulate(args, candidate, grid, database)
        if effect_databases is None:
            from capsmech.io.catalog import effect_database_paths

            effect_databases = [str(p) for p in effect_database_paths()]
        effect_databases += [str(p) for p in simulated.values() if str(p) not in effect_databases]
    for one in rounds:
        for r in one.results:
            if r.needs is None or _grid_identity(r.needs) in simulated:
                continue
            path = write_grid(r.needs, Path(args.grid_dir) / f"{r.needs['name']}.yaml",
                              header=f"Written by capsmech diagnose {args.measurements}: the cases the {r.name} "
                                     "candidate needs.\nRun: make database GRID=" + r.needs["name"])
            print(f"capsmech diagnose: candidate {r.name} needs {cost_text(r.needs, database, args.law)}: "
                  f"make database GRID={r.needs['name']} (grid written to {path}), or diagnose --simulate")
    for one in rounds:
        for r in one.results:
            if r.edge and r.supported and r.name in LEVEL_OPTIONS:
                print(f"capsmech diagnose: {r.name} = {r.theta:.3g} is not bracketed by its levels "
                      f"({', '.join(f'{v:g}' for v in r.levels)})"
                      + ("" if args.simulate else ": rerun with --simulate (it adds levels until they bracket it)"))
    for capsule, why in result.excluded:
        print(f"capsmech diagnose: left out {capsule}: {why}")
    for fit in result.offcentre:
        print(f"capsmech diagnose: off-centre {fit.summary}")
    print(f"verdict: {result.verdict}")
    # A batch of several materials has no single G_s, whatever effect explains its shapes.
    mixture = batch_heterogeneity(result)
    if mixture is not None and not mixture.one_material:
        print(f"capsmech diagnose: {mixture.line()}")
    # The diagnosis as --json writes it, made once: the console says no number the JSON leaves out.
    record = cache(lambda: diagnosis_record(outcome, Path(args.measurements).name))
    if sequence is not None and sequence.effects:
        for k, later in enumerate(sequence.rounds[1:], start=2):
            # The values each round was run with (the effects list holds the final ones).
            # Every round before round k chose an effect (a round that chooses none is the last).
            chosen = [r.chosen for r in sequence.rounds[:k - 1] if r.chosen is not None]
            fixed = ", ".join(f"{c.name} = {c.theta:.3g}" for c in chosen)
            print(f"with {fixed} fixed: {later.verdict}")
        if sequence.kind == "effect":
            (before, _, n_before), (after, _, n_after) = sequence.g_s_lengths[0], sequence.g_s_lengths[-1]
            # G_s by lengths after is said only where --json gives it, else why it is left out.
            left_out = record()["g_s"]["lengths"].get("after_left_out")
            lengths_after = f"-> left out: {left_out}" if left_out else f"-> {after:.4g} N/m ({n_after})"
            print(f"effects found: {sequence.verdict}; G_s by the lengths (measured on the contours, inverted) {before:.4g} N/m "
                  f"({n_before} capsules) {lengths_after}; by the contour fits "
                  f"{sequence.g_s[0][0]:.4g} -> {sequence.g_s[-1][0]:.4g} N/m")
        else:
            print(f"verdict for the batch: {sequence.verdict}")
    if json_out is not None:
        print(json_out.wrote(write_json(json_out.path, "diagnose", record())))
    if report is not None:
        print(report.wrote(write_report(result, report.path, Path(args.measurements).name)))
        for k, later in enumerate(sequence.rounds[1:] if sequence is not None else [], start=2):
            out = report.path.with_name(f"{report.path.stem}_round{k}{report.path.suffix}")
            print(f"wrote {write_report(later, out, Path(args.measurements).name + f' (round {k})')}")
    return 0


def _grid_identity(grid: dict) -> str:
    """What a candidate's grid computes: its name (one per candidate) and its law groups. A
    level added to a family whose grid already ran asks for the same name with the new level's
    group only, and must be computed too. (The nodes are left out: a law group once simulated
    is in a database, and no candidate asks for it again.)"""
    return grid["name"] + ":" + ",".join(grid["tube"]["laws"])


#: Candidates whose levels --simulate extends, and the option (or law family) holding them.
LEVEL_OPTIONS = {"prestress": "prestress_levels", "kb": "kb_levels", "SK_C": "SK_C", "GH_nu": "GH_nu"}
#: Levels --simulate adds at most, one at a time, to bracket strengths at an edge of theirs.
MAX_LEVEL_EXTENSIONS = 3


def _level_list(name: str, levels: dict[str, list[float]], family_levels: dict[str, list[float]]) -> list[float]:
    """The levels of a candidate (an option's or a law family's; empty when the databases'
    own are used)."""
    option = LEVEL_OPTIONS[name]
    return levels[option] if option in levels else family_levels.get(option, [])


def _extend_levels(rounds, levels: dict[str, list[float]], family_levels: dict[str, list[float]]) -> str:
    """Add one level beyond the first supported strength found at an edge of its levels (the
    last spacing continued; below the lowest level, half of it where the spacing would reach 0
    or where the strength lies between the base law and the lowest level), in ``levels`` or
    ``family_levels``; what was added, in words ("" when none)."""
    for one in rounds:
        for r in one.results:
            if not (r.edge and r.supported) or r.name not in LEVEL_OPTIONS:
                continue
            current = sorted(_level_list(r.name, levels, family_levels))
            if not current or (len(current) < 2 and r.edge != "base"):
                continue
            if r.edge == "high":
                new = current[-1] + (current[-1] - current[-2])
            elif r.edge == "base":
                # Between the base law and the lowest level: a level halfway.
                new = current[0] / 2
            else:
                new = current[0] - (current[1] - current[0])
                new = new if new > 0 else current[0] / 2
            option = LEVEL_OPTIONS[r.name]
            (levels if option in levels else family_levels)[option] = sorted([*current, round(new, 6)])
            where = ("lies between the base law and its lowest level" if r.edge == "base" else
                     "sits at the edge of its levels")
            return f"{r.name} = {r.theta:.3g} {where} {current}: adding the level {new:g} and diagnosing again"
    return ""


def _diagnose_batch(args: argparse.Namespace, database, effect_databases: list[str] | None,
                    levels: dict[str, list[float]], family_levels: dict[str, list[float]]):
    """One diagnosis of the batch with the databases known so far."""
    # Contours outside the file's folder are read only when the user allows it (as fit-tube).
    batch = read_measurements(args.measurements, "tube", contours_anywhere=True) if args.contours_anywhere \
        else args.measurements
    try:
        return diagnose(batch, database, args.law, effect_databases=effect_databases,
                        other_laws=args.other_law, prestress_levels=levels["prestress_levels"],
                        kb_levels=levels["kb_levels"], family_levels=family_levels,
                        candidates=args.candidate, max_effects=args.max_effects,
                        offcentre_table=None if args.offcentre_table == "none" else args.offcentre_table,
                        progress=sys.stderr.isatty())
    except ValueError as err:
        if isinstance(err, CapsmechError):
            raise
        raise MeasurementError(f"{args.measurements}: {err}") from None


def _family_levels(args: argparse.Namespace) -> dict[str, list[float]]:
    """--C-levels and --nu-s-levels as law-family levels (an empty text: no such candidate)."""
    from capsmech.diagnosis.law_family import LAW_FAMILIES

    out = {}
    for family, option in (("SK_C", "C_levels"), ("GH_nu", "nu_s_levels")):
        text = getattr(args, option)
        if text is None:
            # --simulate computes the family's default levels; without it, the databases' levels.
            if args.simulate:
                out[family] = list(LAW_FAMILIES[family][1])
            continue
        name = "--" + option.replace("_", "-")
        try:
            values = [float(v) for v in text.split(",") if v.strip()]
        except ValueError:
            raise MeasurementError(f"{name}: not a comma-separated list of numbers: {text!r}") from None
        if values and (len(values) < 2 or not all(math.isfinite(v) for v in values)):
            raise MeasurementError(f"{name}: give at least two finite levels (empty: no candidate), got {text!r}")
        out[family] = values
    return out


def _simulate(args: argparse.Namespace, candidate: str, grid: dict, database) -> Path:
    """Run the grid a candidate needs through the workflow (cached), with an estimate first."""
    from tqdm import tqdm

    from capsmech.diagnosis.effect_grid import cost_text
    from capsmech.workflow.simulate import cached_grid, case_count, simulate_grid

    placed, folder = cached_grid(grid)
    cases = case_count(grid)
    if (folder / "tube.h5").is_file():
        print(f"capsmech diagnose: candidate {candidate}: {cases} cases found in the cache {folder}")
        return folder / "tube.h5"
    print(f"capsmech diagnose: candidate {candidate} needs {cost_text(grid, database, args.law)}, "
          f"{args.profile or 'local profile'}; computing them into {folder}", flush=True)
    with tqdm(total=None, desc=f"simulating {candidate}", unit="step", disable=not sys.stderr.isatty()) as bar:
        def advance(done: int, total: int) -> None:
            bar.total = total
            bar.n = done
            bar.refresh()

        path = simulate_grid(grid, profile=args.profile, cores=args.cores, progress=advance)
    print(f"capsmech diagnose: candidate {candidate}: simulated, database {path}")
    return path


def batch_path(out: str, name: str | None) -> Path:
    """The batch's measurement file: ``--out FILE.csv``; the old spelling ``--out DIR`` (with
    ``--name STEM``) still gives ``DIR/STEM.csv``, with a warning."""
    path = Path(out)
    if path.suffix == ".csv" and name is None:
        return path
    if path.suffix == ".csv":
        raise MeasurementError("--name: only with the old --out DIR; give the file itself, --out DIR/NAME.csv")
    warnings.warn(f"--out {out}: a folder; --out now names the batch's measurement file "
                  f"(--out {path / ((name or 'batch') + '.csv')}); --out DIR and --name will go", InputWarning,
                  stacklevel=2)
    return path / f"{name or 'batch'}.csv"


def cmd_make_batch(args: argparse.Namespace) -> int:
    """``make-batch``: a synthetic tube batch with undeclared effects (``api.make_batch``)."""
    effects = args.effect or []
    strengths = args.strength or []
    if len(strengths) != len(effects):
        raise MeasurementError(f"--strength: give one per --effect ({len(effects)} effects, {len(strengths)} strengths)")
    csv_out = plan_output(batch_path(args.out, args.name), "--out", (".csv",), args.force, create_parent=True)
    truth_out = plan_output(csv_out.path.with_name(f"{csv_out.path.stem}_truth.csv"), "--out (its truth file)",
                            (".csv",), args.force, create_parent=True)
    json_out = plan_output(args.json, "--json", (".json",), args.force) if args.json else None
    batch = make_batch(dict(zip(effects, strengths)), n_capsules=args.n, law=args.law, g_s=args.g_s,
                       seed=args.seed, workers=args.workers)
    csv_path, truth = write_batch(batch, csv_out.path)
    print(f"{csv_out.wrote(csv_path)} ({len(batch.rows)} capsules); {truth_out.wrote(truth)}")
    if json_out is not None:
        payload = {"measurements": str(csv_path), "truth": str(truth), "effects": batch.effects,
                   "capsules": len(batch.rows), "law": args.law, "G_s": args.g_s, "units": {"G_s": "N/m"},
                   "seed": args.seed}
        print(json_out.wrote(write_json(json_out.path, "make-batch", payload)))
    return 0


def cmd_diagnose_shear(args: argparse.Namespace) -> int:
    """``diagnose-shear``: print the verdict (and write the report and the JSON)."""
    from capsmech.diagnosis.shear import write_report
    from capsmech.imaging.extraction_output import PIXEL_UNITS_UM, parse_quantity

    report_path = report_option(args)
    report = plan_output(report_path, "--report", (".md",), args.force, create_parent=True) if report_path else None
    json_out = plan_output(args.json, "--json", (".json",), args.force) if args.json else None
    pixel_size = parse_quantity(args.pixel_size, "--pixel-size", PIXEL_UNITS_UM, "um")
    try:
        result = diagnose_shear(args.measurements, args.database, args.lambda_database, args.law,
                                lambda_value=args.lambda_value, pixel_size=pixel_size * 1e-6,
                                error_px=args.error_px, theta_error=math.radians(args.theta_error))
    except CapsmechError as err:
        # The API names its parameters; the command line its options.
        text = str(err)
        for parameter, option in (("diagnose_shear (database)", "diagnose-shear --database"),
                                  ("diagnose_shear (lambda_database)", "diagnose-shear --lambda-database")):
            text = text.replace(parameter, option)
        for parameter in ("law", "lambda_value", "error_px", "theta_error"):
            if text.startswith(parameter + ":"):
                text = "--" + parameter.replace("_", "-") + text[len(parameter):]
        if text.startswith("pixel_size:"):
            text = f"--pixel-size: must be a positive size, got {args.pixel_size}"
        raise type(err)(text) from None
    for r in result.results:
        state = r.note or (f"BIC drop {r.bic_drop:.1f}, CV p = {r.cv_p_value:.2g}, "
                           f"{'supported' if r.supported else 'not supported'}")
        print(f"{r.name}: {state}")
    print(f"verdict: {result.verdict}")
    if json_out is not None:
        print(json_out.wrote(write_json(json_out.path, "diagnose-shear", shear_record(result, args))))
    if report is not None:
        print(report.wrote(write_report(result, report.path, Path(args.measurements).name)))
    return 0


def shear_record(result, args: argparse.Namespace) -> dict:
    """A shear diagnosis as ``--json`` holds it: the verdict, the chosen candidate and every
    candidate's criteria (G_s [N/m] with its standard error and the database's share)."""
    def candidate(r) -> dict:
        return {"name": r.name, "law": r.law, "capsules": r.capsules, "supported": r.supported, "note": r.note,
                "chi2_base": r.chi2_base, "chi2": r.chi2, "bic_drop": r.bic_drop, "cv_gain": r.cv_gain,
                "cv_gain_error": r.cv_gain_error, "cv_p_value": r.cv_p_value,
                "G_s_before": {"value": r.g_s_before[0], "std_error": r.g_s_before[1],
                               "database_error": r.g_s_systematic[0]},
                "G_s_after": {"value": r.g_s_after[0], "std_error": r.g_s_after[1],
                              "database_error": r.g_s_systematic[1]},
                "drift_p_before": r.drift_p_before, "drift_p_after": r.drift_p_after}

    return {"batch": str(args.measurements), "base_law": result.base_law,
            "verdict": "effect" if result.chosen is not None else "none", "verdict_text": result.verdict,
            "chosen": result.chosen.name if result.chosen is not None else None,
            "cannot_tell_from": [r.name for r in result.rivals],
            "units": {"G_s": "N/m", "chi2": "1", "bic_drop": "1", "cv_gain": "1 per capsule"},
            "candidates": [candidate(r) for r in result.results]}


def _add_diagnose_shear(sub: argparse._SubParsersAction) -> None:
    """The ``diagnose-shear`` subcommand's arguments."""
    p = sub.add_parser("diagnose-shear", help="which effect (viscosity ratio, law) a shear batch's G_s drift supports")
    p.add_argument("measurements", metavar="CSV", help="shear measurements (capsmech.io.measurements format)")
    add_database_option(p, "shear-paper", "shear database made with lambda = 1")
    add_database_option(p, "shear-microrheometry", "shear database at the candidate viscosity ratio "
                        "(law keys <law>+lambda<X>)", option="--lambda-database")
    p.add_argument("--lambda-value", default=LAMBDA_VALUE, help=f"that viscosity ratio, as in the law keys (default {LAMBDA_VALUE})")
    add_base_law_option(p, "base law key")
    p.add_argument("--pixel-size", default=f"{PIXEL_SIZE * 1e6:g}um",
                   help="pixel size of the noise model where the CSV has no pixel_size column, e.g. 0.5um "
                        f"(bare numbers: um; default {PIXEL_SIZE * 1e6:g}um)")
    p.add_argument("--error-px", type=float, default=ERROR_PX, help="error bound of each semi-axis [px] (default 1)")
    p.add_argument("--theta-error", type=float, default=math.degrees(THETA_ERROR),
                   help="standard deviation of a measured theta [deg], for batches with a theta column (default 1)")
    add_report_option(p, "a Markdown report (figure beside it)")
    add_json_option(p, "the verdict and every candidate's criteria and G_s")
    add_force_option(p)
    p.set_defaults(func=cmd_diagnose_shear)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``diagnose``, ``diagnose-shear`` and ``make-batch``."""
    diag = sub.add_parser("diagnose", help="which effect the base model lacks, from the batch's contour residuals")
    diag.add_argument("measurements", metavar="CSV", help="tube measurements with contour files")
    add_database_option(diag, "tube-paper", "base tube database")
    add_base_law_option(diag, "base law key")
    diag.add_argument("--other-law", action="append", metavar="KEY",
                      help="another law group to test as a candidate (repeatable), e.g. GH_nu0.5 or NH+prestress0.05 "
                           "(default: every other law of the database)")
    diag.add_argument("--effects-database", action="append", metavar="NAME|H5",
                      help="tube database of effect law groups (repeatable; default: the shipped tube-prestress "
                           "and tube-kb)")
    diag.add_argument("--prestress-levels", default="0.04,0.06,0.08", metavar="A1,A2,..",
                      help="pre-stress levels of the prestress candidate (default 0.04,0.06,0.08; empty: no candidate)")
    diag.add_argument("--kb-levels", default="0.0025,0.005,0.01", metavar="K1,K2,..",
                      help="bending stiffness levels of the kb candidate (default 0.0025,0.005,0.01; empty: no candidate)")
    diag.add_argument("--C-levels", dest="C_levels", metavar="C1,C2,..",
                      help="levels of the Skalak C candidate, a law family fitted between its levels (default: "
                           "those the databases hold, 1,2,4,8 with --simulate; empty: no candidate)")
    diag.add_argument("--nu-s-levels", dest="nu_s_levels", metavar="N1,N2,..",
                      help="levels of the GH nu_s candidate (default 0,0.2,0.5; empty: no candidate)")
    diag.add_argument("--simulate", action="store_true",
                      help="compute the simulations a candidate needs (through the workflow, cached under the "
                           "user's data directory by grid and kernel version), then diagnose with them")
    diag.add_argument("--profile", metavar="DIR",
                      help="Snakemake profile of --simulate (default the local one; e.g. workflow/profiles/slurm)")
    diag.add_argument("--cores", type=int, metavar="N", help="cores of a local --simulate (default the profile's)")
    diag.add_argument("--candidate", action="append", choices=("contour_offset", "tube_radius", "prestress", "kb",
                                                                "SK_C", "GH_nu", "laws"),
                      help="test only these candidates (repeatable; default all: the effect library)")
    diag.add_argument("--max-effects", type=int, default=2, metavar="N",
                      help="effects to look for one after another, each fixed before the next (default 2; 1: one)")
    diag.add_argument("--offcentre-table", default="offcentre", metavar="NAME|H5",
                      help="antisymmetric modes to fit the offset of capsules screened out as asymmetric "
                           "(default: the shipped table 'offcentre'; none: leave them out unfitted)")
    diag.add_argument("--grid-dir", default="config", metavar="DIR",
                      help="where grids of candidates that need simulations are written (default config)")
    diag.add_argument("--contours-anywhere", action="store_true",
                      help="read contour files outside the measurement file's folder too (by default refused)")
    add_report_option(diag, "a Markdown report (figures beside it)")
    add_json_option(diag, "the verdict (effect / none / unexplained), the strengths with their intervals, G_s "
                    "before and after, the goodness of fit and the capsules left out")
    add_force_option(diag)
    diag.set_defaults(func=cmd_diagnose)
    _add_diagnose_shear(sub)
    mb = sub.add_parser("make-batch", help="synthetic tube batch with an undeclared effect (truth in a separate file)")
    mb.add_argument("--effect", action="append", choices=("contour_offset", "tube_radius", "prestress", "kb", "GH_nu", "SK_C"),
                    help="effect to switch on (repeatable; none: no effect)")
    mb.add_argument("--strength", action="append", type=float, help="its strength (px, relative, alpha, k_b, nu_s, C)")
    mb.add_argument("--out", required=True, metavar="FILE.csv",
                    help="the batch's measurement file (contours in a folder beside it, the truth in <stem>_truth.csv)")
    mb.add_argument("--name", help=argparse.SUPPRESS)
    mb.add_argument("-n", type=int, default=24, help="capsules (default 24)")
    add_base_law_option(mb, "base law key the batch will be fitted with")
    mb.add_argument("--g-s", type=float, default=0.04, help="G_s of the material [N/m] (default 0.04)")
    mb.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    mb.add_argument("--workers", type=int, default=1, help="kernel runs at a time (default 1)")
    add_json_option(mb, "what was written: the files, the effects and their strengths, the capsules")
    add_force_option(mb)
    mb.set_defaults(func=cmd_make_batch)
