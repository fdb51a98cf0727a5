"""``capsmech population``: which law gives a G_s that does not drift with the deformation."""
from __future__ import annotations

import argparse

from capsmech.api import plot_population, population, population_table, read_results
from capsmech.cli.common import format_table, records
from capsmech.inversion.fitting import write_results
from capsmech.plotting import save_figure


def cmd_population(args: argparse.Namespace) -> int:
    """Drift of G_s with Delta per law from fit-tube results; the law that fits."""
    results = [row for path in args.results for row in records(read_results(path))]
    verdict = population(results)
    table = population_table(verdict)
    units = table.attrs["units"]
    print(format_table(records(table),
                       ["law", "n", "G_s_mean", "G_s_std", "drift", "drift_ci_low", "drift_ci_high", "p_value"],
                       {**units, "drift": "1/Delta", "drift_ci_low": "1/Delta", "drift_ci_high": "1/Delta"}))
    if verdict.shape is not None:
        shape = verdict.shape
        print(f"contour misfit H/a over the {shape.n} capsules every law fits: "
              + ", ".join(f"{law} median {m:.4f}" for law, m in shape.median.items())
              + "; paired signed-rank p: " + ", ".join(f"{a}/{b} {p:.2g}" for (a, b), p in shape.p_values.items()))
    drifts, best = verdict.drifts, verdict.best
    if best is None:
        print(f"verdict: no law fits the batch ({verdict.reason})")
    else:
        print(f"verdict: {best}, G_s = {drifts[best].mean:.4g} +- {drifts[best].std:.2g} N/m ({verdict.reason})")
    if args.plot:
        print(f"wrote {save_figure(plot_population(results, verdict), args.plot)}")
    for out in args.out or []:
        print(f"wrote {write_results(records(table), units, out)}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``population``."""
    pop = sub.add_parser("population", help="which law gives a G_s that does not drift with deformation")
    pop.add_argument("results", nargs="+", metavar="RESULTS.csv", help="fit-tube results")
    pop.add_argument("--plot", metavar="FIG.png", help="draw G_s against Delta (paper figure 10)")
    pop.add_argument("--out", action="append", metavar="FILE", help="write the per-law table (.csv or .h5; repeatable)")
    pop.set_defaults(func=cmd_population)
