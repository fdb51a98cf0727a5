#!/usr/bin/env python3
"""The validation tables that are computed from the shipped data, not pasted (issue 21, item 6).

Each table is a function of the files capsmech ships (its databases, the example batches and
film) and takes seconds. The documentation's hook (docs/hooks/validation_tables.py) puts each
one where a page holds its marker ``<!-- generated-table NAME -->``, at every ``make docs``;
this script prints them::

    .venv/bin/python scripts/validation_tables.py            # every table
    .venv/bin/python scripts/validation_tables.py databases  # one

Tables measured by long runs (kernel convergence, refill times, diagnoses over many batches)
stay on their pages as records of a run, each naming the test or script that measured it.
"""
from __future__ import annotations

import math
import sys
import warnings
from collections.abc import Callable

import numpy as np


def _markdown(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def databases() -> str:
    """Every shipped database: flow, law groups, cases and steady cases, range, kernel, accuracy."""
    from capsmech.io.catalog import shipped_databases
    from capsmech.io.database import load_database

    rows = []
    for entry in shipped_databases():
        if entry.kind != "database":
            continue
        db = load_database(entry.name)
        cases = sum(len(table) for table in db.laws.values())
        steady = sum(int((table.status == "steady").sum()) for table in db.laws.values())
        ca = np.concatenate([np.asarray(table.column("Ca_s", steady_only=False)) for table in db.laws.values()])
        span = f"Ca_s {ca.min():g}-{ca.max():g}"
        if db.flow == "tube":
            al = np.concatenate([np.asarray(table.column("a_over_l", steady_only=False)) for table in db.laws.values()])
            span = f"a/l {al.min():.2f}-{al.max():.2f}, " + span
        rows.append([f"`{entry.name}`", db.flow, ", ".join(db.laws), str(cases), str(steady), span,
                     str(db.code_version), db.accuracy or "—"])
    return _markdown(["name", "flow", "law groups", "cases", "steady", "range", "kernel", "accuracy"], rows)


def tube_steady_range() -> str:
    """The largest steady Ca_s per a/l and law of the paper-grid tube database."""
    from capsmech.io.database import load_database

    db = load_database("tube-paper")
    sizes = sorted({float(v) for table in db.laws.values() for v in table.column("a_over_l", steady_only=False)})
    rows = []
    for law, table in db.laws.items():
        a = np.asarray(table.column("a_over_l", steady_only=False), dtype=float)
        ca = np.asarray(table.column("Ca_s", steady_only=False), dtype=float)
        steady = np.asarray(table.status) == "steady"
        cells = []
        for size in sizes:
            here = steady & np.isclose(a, size)
            cells.append(f"{ca[here].max():g}" if here.any() else "—")
        rows.append([law, *cells])
    return _markdown(["law \\ a/l", *(f"{s:.2f}" for s in sizes)], rows)


def tube_folds() -> str:
    """Where each law's steady branch ends (critical Ca_s) per a/l, in every shipped tube
    database that records it (scripts/add_folds.py), beside the database's own time-stepped
    bracket: its last steady and first continuously elongating Ca_s."""
    from capsmech.io.catalog import shipped_databases
    from capsmech.io.database import load_database

    rows = []
    for entry in shipped_databases():
        if entry.kind != "database":
            continue
        db = load_database(entry.name)
        if db.flow != "tube":
            continue
        for law, table in db.laws.items():
            if table.critical is None:
                continue
            a = np.asarray(table.columns["a_over_l"])
            for size, critical, kind in zip(table.critical["a_over_l"], table.critical["Ca_s"], table.critical["kind"]):
                here = np.isclose(a, size)
                ca, status = table.columns["Ca_s"][here], table.status[here]
                steady, elongating = ca[status == "steady"], ca[status == "continuous_elongation"]
                bracket = (f"{steady.max():g}" if steady.size else "—") + " – " + \
                          (f"{elongating.min():g}" if elongating.size else "—")
                value = "—" if math.isnan(critical) else f"{critical:.4f}"
                rows.append([f"`{entry.name}`", law, f"{size:.2f}", value, str(kind).split(":")[0], bracket])
    return _markdown(["database", "law", "a/l", "critical Ca_s", "kind", "rows: last steady – first elongating"], rows)


def compare_methods() -> str:
    """``capsmech compare-methods`` on the shipped shear databases (the paper's three laws)."""
    from capsmech.inversion.microrheometry import compare_methods as compare
    from capsmech.inversion.microrheometry import comparison_table
    from capsmech.io.database import ShearDatabase, load_database

    base, with_lambda = load_database("shear-paper"), load_database("shear-microrheometry")
    assert isinstance(base, ShearDatabase) and isinstance(with_lambda, ShearDatabase)
    return comparison_table(compare(base, with_lambda, "+lambda0.001", ("NH", "GH_nu0.5", "GH_nu0.2")))


def example_fits() -> str:
    """Every law of the paper grid on the two shipped example batches: capsules fitted / measured,
    median contour misfit H/a, mean G_s and its spread, against the batch's true law and G_s."""
    import csv
    from pathlib import Path

    import capsmech

    root = Path(__file__).resolve().parents[1] / "data" / "examples"
    rows = []
    for batch in ("tube_batch_NH", "tube_batch_GH_nu0.5"):
        with (root / f"{batch}_truth.csv").open(encoding="utf-8") as stream:
            truth = list(csv.DictReader(line for line in stream if not line.startswith("#")))
        g_true = np.median([float(t["G_s [N/m]"]) for t in truth])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", capsmech.OutsideDatabaseWarning)
            results = capsmech.fit_tube(root / f"{batch}.csv", "tube-paper")
        for law, fits in results.groupby("law", sort=False):
            fitted = fits[fits["flag"] == ""]
            g = fitted["G_s"].to_numpy(dtype=float)
            g_text = f"{g.mean():.4f} ± {g.std(ddof=1):.4f}" if len(g) > 1 else "—"
            misfit = float(np.nanmedian(fitted["H_over_a"])) if len(fitted) else math.nan
            rows.append([f"`{batch}`", law, f"{len(fitted)}/{len(fits)}",
                         "—" if math.isnan(misfit) else f"{misfit:.4f}", g_text, f"{g_true:g}"])
    return _markdown(["batch", "law", "fitted", "median H/a", "G_s [N/m]", "true G_s [N/m]"], rows)


RUNS = __import__("pathlib").Path(__file__).resolve().parents[1] / "docs" / "validation" / "runs"


def diagnosis_confusion() -> str:
    """The confusion study of the diagnosis (issue 19, item 6), from the rows its run wrote
    (``docs/validation/runs/confusion.csv``, by ``tests/python/confusion_study.py``)."""
    import csv

    with (RUNS / "confusion.csv").open(encoding="utf-8") as stream:
        rows = list(csv.DictReader(stream))

    def number(text: str, digits: str) -> str:
        return "—" if text in ("", "None") else format(float(text), digits)

    table = [[f"`{r['batch']}`", r["membrane"], r["expected"], r["verdict"], r["named"] or "—", r["closest"] or "—",
              number(r["reduced_chi2"], ".2f"), number(r["g_s_before"], ".4f"), number(r["g_s_after"], ".4f"),
              "yes" if r["right"] == "True" else "**no**", "**yes**" if r["wrong_effect_named"] == "True" else "no"]
             for r in rows]
    right = sum(r["right"] == "True" for r in rows)
    wrong = sum(r["wrong_effect_named"] == "True" for r in rows)
    return (_markdown(["batch", "membrane", "right answer", "verdict", "named", "closest", "χ²/dof left",
                       "G_s before [N/m]", "G_s after [N/m]", "right", "wrong effect named"], table)
            + f"\n\n{right} of {len(rows)} right; a wrong effect named in {wrong}. True G_s 0.025 N/m; G_s by "
            "fit-tube's estimator (lengths), after only where the verdict supports it.")


def _coverage_cell(entry: tuple) -> str:
    """A coverage (hits, batches, Wilson interval) as a table cell."""
    k, n, low, high = entry
    return "—" if n == 0 else f"{k}/{n} = {100 * k / n:.0f} % [{100 * low:.0f}, {100 * high:.0f}]"


def interval_coverage(name: str = "interval_coverage.csv") -> str:
    """Measured coverage of the diagnosis' intervals (issue 19, item 4), from the rows its run
    wrote (``docs/validation/runs/interval_coverage.csv``, by ``tests/python/interval_coverage.py``)."""
    sys.path.insert(0, str(RUNS.parents[2] / "tests" / "python"))
    from interval_coverage import summarise

    rows = []
    for e in summarise(RUNS / name):
        rows.append([e["config"], str(e["batches"]), _coverage_cell(e["covered"]),
                     _coverage_cell(e["g_s_lengths_covered"]), _coverage_cell(e["g_s_contours_covered"]),
                     f"{e['median_error']:+.3g}" if "median_error" in e else "—",
                     f"{e['median_width']:.3g}" if "median_width" in e else "—"])
    return _markdown(["effect, true strength", "batches", "strength interval holds the truth",
                      "G_s interval (lengths) holds it", "G_s interval (contour fits) holds it",
                      "median error of the strength", "median interval width"], rows)


def g_s_interval_coverage(name: str = "interval_coverage.csv") -> str:
    """Measured coverage of the G_s intervals (issue 19, item 4) by each estimator, with the
    median error and interval width relative to the truth (``interval_coverage.py``'s rows)."""
    sys.path.insert(0, str(RUNS.parents[2] / "tests" / "python"))
    from interval_coverage import summarise

    def percent(entry: dict, key: str) -> str:
        return f"{100 * entry[key]:+.1f} %" if key in entry else "—"

    rows = []
    for e in summarise(RUNS / name):
        rows.append([e["config"], str(e["batches"]),
                     _coverage_cell(e["g_s_lengths_covered"]), percent(e, "g_s_lengths_median_error"),
                     percent(e, "g_s_lengths_median_width").lstrip("+"),
                     _coverage_cell(e["g_s_contours_covered"]), percent(e, "g_s_contours_median_error"),
                     percent(e, "g_s_contours_median_width").lstrip("+")])
    return _markdown(["effect, true strength", "batches", "G_s by lengths: interval holds the truth", "median error",
                      "median width", "G_s by contour fits: interval holds the truth", "median error",
                      "median width"], rows)


def population_coverage(name: str = "population_coverage.csv") -> str:
    """The law verdict and its G_s interval on batches of the independent generator (issue 19,
    items 1 and 4), from the rows its run wrote (``docs/validation/runs/population_coverage.csv``,
    by ``tests/python/population_coverage.py``)."""
    sys.path.insert(0, str(RUNS.parents[2] / "tests" / "python"))
    from population_coverage import summarise

    rows = []
    for e in summarise(RUNS / name):
        chi2 = (f"{e['chi2_range'][0]:.2f}–{e['chi2_range'][1]:.2f} (limit {e['chi2_limit']:.2f})"
                if e["chi2_range"] else "—")
        named = e["covered"][1] > 0
        rows.append([e["membrane"], str(e["batches"]), str(e["right_law"]), str(e["cannot_tell"]), str(e["none"]),
                     f"**{e['wrong_law']}**" if e["wrong_law"] else "0",
                     _coverage_cell(e["covered"]) if named else "—",
                     f"{100 * e['median_error']:+.1f} %" if named else "—",
                     f"{100 * e['median_half_width']:.1f} %" if named else "—", chi2])
    return _markdown(["membrane (batches of 12)", "batches", "right law", "cannot tell", "none", "wrong law",
                      "G_s interval holds the truth", "median error of G_s", "median half-width",
                      "true law's χ²/dof"], rows)


def shear_rows() -> str:
    """Each row of the paper-grid shear database: D12 from the row's mesh level, the other
    level's, the stated mesh and time errors, and D12/Ca_s against the small-deformation limit
    where Ca_s <= 0.02."""
    from capsmech.inversion.small_deformation import law_d12_slope
    from capsmech.io.database import load_database

    db = load_database("shear-paper")
    rows = []
    for law, table in db.laws.items():
        c = table.columns
        limit = law_d12_slope(law)
        for i, ca in enumerate(c["Ca_s"]):
            if table.status[i] != "steady":
                rows.append([law, f"{ca:g}", table.status[i], "", "", "", "", ""])
                continue
            small = f"{(c['D12'][i] / ca / limit - 1) * 100:+.2f} %" if ca <= 0.02 else ""
            rows.append([law, f"{ca:g}", f"{c['D12'][i]:.4f}", f"{c['mesh_level'][i]:.0f}",
                         f"{c['D12_mesh_check'][i]:.4f}", f"{c['D12_mesh_error_rel'][i] * 100:.2f} %",
                         f"{c['D12_time_error_rel'][i] * 100:.3f} %", small])
    return _markdown(["law", "Ca_s", "D12", "level", "D12, other level", "mesh error", "time error",
                      "D12/Ca_s vs small-deformation limit"], rows)


def duct_rows() -> str:
    """The square-duct database per law and a/w: its rows, the steady ones, those of them whose
    level-2 companion is steady too (a mesh error), those that are not steady (status and Ca_s),
    and the largest mesh error its steady rows state (levels 2 and 3)."""
    from capsmech.io.database import load_database

    db = load_database("duct-dev")
    rows = []
    for law, table in db.laws.items():
        c = table.columns
        for size in np.unique(c["a_over_l"]):
            here = c["a_over_l"] == size
            steady = here & table.steady
            others = "; ".join(f"{c['Ca_s'][i]:g} {table.status[i]}" for i in np.flatnonzero(here & ~table.steady))
            stated = [c[f"{name}_mesh_error_rel"][steady] for name in ("L_z", "L_p", "vc_over_V")]
            errors = [100 * float(np.max(e[np.isfinite(e)])) if np.isfinite(e).any() else math.nan for e in stated]
            checked = int(np.isfinite(c["L_z_mesh_error_rel"][steady]).sum())
            rows.append([law, f"{size:g}", str(int(here.sum())), str(int(steady.sum())), str(checked), others or "—",
                         f"{c['Ca_s'][steady].max():g}" if steady.any() else "—",
                         " / ".join("—" if math.isnan(e) else f"{e:.2f} %" for e in errors)])
    return _markdown(["law", "a/w", "rows", "steady", "with a mesh error", "not steady (Ca_s status)", "last steady Ca_s",
                      "largest mesh error L_z / L_p / v_c"], rows)


TABLES: dict[str, Callable[[], str]] = {"databases": databases, "tube-steady-range": tube_steady_range,
                                        "tube-folds": tube_folds,
                                        "shear-rows": shear_rows, "duct-rows": duct_rows,
                                        "compare-methods": compare_methods, "example-fits": example_fits,
                                        "diagnosis-confusion": diagnosis_confusion,
                                        "interval-coverage": interval_coverage,
                                        "interval-coverage-statistical-only":
                                            lambda: interval_coverage("interval_coverage_statistical_only.csv"),
                                        "g-s-interval-coverage": g_s_interval_coverage,
                                        "population-coverage": population_coverage}


def main(argv: list[str]) -> int:
    names = argv or list(TABLES)
    unknown = [n for n in names if n not in TABLES]
    if unknown:
        print(f"unknown table(s) {', '.join(unknown)}; known: {', '.join(TABLES)}", file=sys.stderr)
        return 2
    for name in names:
        print(f"## {name}\n\n{TABLES[name]()}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
