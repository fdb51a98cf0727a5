"""``capsmech population``: which law describes the batch (contours of every capsule, and a G_s
that does not drift with the deformation), with the evidence per law."""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from capsmech.api import fits_above_fold, plot_population, population, population_table, read_results
from capsmech.cli.common import (
    FIGURE_SUFFIXES,
    TABLE_SUFFIXES,
    add_force_option,
    add_json_option,
    format_table,
    plan_output,
    records,
    write_json,
)
from capsmech.inversion.fitting import write_results
from capsmech.inversion.population import FAIL_SCORE
from capsmech.inversion.population_report import verdict_dict
from capsmech.io.results import read_results_file
from capsmech.plotting import save_figure

#: Columns printed and their units (--out writes every column of the table, separately).
PRINTED = {"law": "", "fitted": "", "H_median": "1", "p_contours": "1", "G_s_mean": "N/m", "G_s_std": "N/m",
           "G_s_95": "N/m", "drift": "1/Delta", "drift_95": "1/Delta", "drift_p": "1", "drift_database": "1/Delta",
           "chi2_dof": "1", "status": ""}


def _interval(low: float, high: float) -> str:
    return "n/a" if low != low or high != high else f"{low:.3g}..{high:.3g}"


def _printed(table: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The table's rows as printed: fitted/used, the intervals as 'low..high'."""
    return [{"law": r["law"], "fitted": f"{int(r['fitted'])}/{int(r['used'])}", "H_median": r["score_median"],
             "p_contours": r["p_vs_reference"], "G_s_mean": r["G_s_mean"], "G_s_std": r["G_s_std"],
             "G_s_95": _interval(r["G_s_low"], r["G_s_high"]), "drift": r["drift"],
             "drift_95": _interval(r["drift_ci_low"], r["drift_ci_high"]), "drift_p": r["drift_p"],
             "drift_database": r["drift_database"], "chi2_dof": r["chi2_per_dof"], "status": r["status"]} for r in table]


def _rows(paths: list[str]) -> list[dict[str, Any]]:
    """The result rows of every file; where several files use the same capsule id, each id is
    qualified by its file's name (``file:id``) so that capsules of different batches stay apart."""
    for path in paths:
        # fit-tube's results (CSV or HDF5), or a ResultsFileError naming file, line and field.
        read_results_file(path)
    per_file = [(Path(path), records(read_results(path))) for path in paths]
    ids = [{(str(row["id"]), str(row["law"])) for row in rows} for _, rows in per_file]
    clash = len(per_file) > 1 and sum(len(i) for i in ids) > len(set().union(*ids))
    if not clash:
        return [row for _, rows in per_file for row in rows]
    return [{**row, "id": f"{path.stem}:{row['id']}"} for path, rows in per_file for row in rows]


def cmd_population(args: argparse.Namespace) -> int:
    """The law the batch supports, with the evidence per law (see capsmech.inversion.population)."""
    outs = [plan_output(out, "--out", TABLE_SUFFIXES, args.force) for out in args.out or []]
    plot = plan_output(args.plot, "--plot", FIGURE_SUFFIXES, args.force, create_parent=True) if args.plot else None
    json_out = plan_output(args.json, "--json", (".json",), args.force) if args.json else None
    results = _rows(args.results)
    verdict = population(results)
    table = population_table(verdict)
    units = table.attrs["units"]
    print(f"capsules: {verdict.measured} measured, {verdict.used} used"
          + (f", {len(verdict.left_out)} left out for every law" if verdict.left_out else ""))
    for cid, why in verdict.left_out:
        print(f"  left out {cid}: {why}")
    for law, ids in fits_above_fold(results).items():
        print(f"  {law}: {len(ids)} fitted above the law's critical Ca_s (no steady shape there, a failure of the "
              f"law): {', '.join(ids)}")
    print(format_table(_printed(records(table)), list(PRINTED), PRINTED, digits=3))
    print(f"fitted: capsules the law reproduces of those used; H_median: median contour misfit H/a, {FAIL_SCORE:g} "
          f"for a capsule the law cannot fit; p_contours: paired signed-rank p that {verdict.reference} fits the "
          f"contours no better (one-sided); G_s by {verdict.estimator}; G_s_95: 95 % interval of the mean G_s (with "
          "the database's accuracy); drift: slope of G_s/mean per unit Delta, with its 95 % interval and the p-value "
          "of no drift beyond drift_database, the steepest slope the database's own error can make; chi2_dof: the best shapes' chi2 per degree of freedom against the tracing noise (misfits "
          "noise above the limit that noise reaches at p = 0.01, 1.5-1.7 for 10-12 capsules)")
    print(verdict.line())
    if verdict.heterogeneity is not None and verdict.kind != "not_one_material":
        # The groups open a two-material verdict's line; otherwise the test is said here.
        print(verdict.heterogeneity.line())
    if plot is not None:
        print(plot.wrote(save_figure(plot_population(results, verdict), plot.path)))
    for out in outs:
        print(out.wrote(write_results(records(table), units, out.path)))
    if json_out is not None:
        print(json_out.wrote(write_json(json_out.path, "population", verdict_dict(verdict))))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``population``."""
    pop = sub.add_parser("population", help="which law describes the batch, with its G_s and the evidence per law")
    pop.add_argument("results", nargs="+", metavar="RESULTS", help="fit-tube results (.csv or .h5, as fit-tube --out writes them)")
    pop.add_argument("--plot", metavar="FIG.png", help="draw G_s against Delta (paper figure 10)")
    pop.add_argument("--out", action="append", metavar="FILE", help="write the per-law table (.csv or .h5; repeatable)")
    add_json_option(pop, "the verdict and its evidence")
    add_force_option(pop)
    pop.set_defaults(func=cmd_population)
