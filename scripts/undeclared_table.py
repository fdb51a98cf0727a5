"""Run capsmech diagnose on every batch of data/examples/undeclared blind, and tabulate what it
finds against the truth (the README's before/after table, issue 7).

For each batch: the effect library of ``capsmech diagnose`` (contour offset, tube radius,
pre-stress and bending stiffness from the shipped tube-prestress and tube-kb, every other law of
the tube database), base law NH, diagnosed sequentially (``diagnose_sequential``: a second
effect after fixing the first). Columns: the truth, the first chosen candidate and its value
with the interval, the second effect found (or none), the relative error of the batch's mean
G_s against the truth before (base fit) and after (every effect found), and chi2 before and
after the first. Reports (first round) with figures go to --reports.

    PYTHONPATH=analysis/src .venv/bin/python scripts/undeclared_table.py [--readme]  (--readme: into docs/validation/diagnosis.md) [--only batch_A]
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

from capsmech.diagnosis.candidates import DatabaseSet, candidate_library
from capsmech.diagnosis.report import write_report
from capsmech.diagnosis.sequential import diagnose_sequential
from capsmech.diagnosis.undeclared_tube import expected_candidates, read_truth
from capsmech.io.catalog import database_path, effect_database_paths
from capsmech.io.database import load_database
from capsmech.io.measurements import read_measurements

ROOT = Path(__file__).resolve().parents[1]
BATCHES = ROOT / "data" / "examples" / "undeclared"
DATABASES = [database_path("tube-paper"), *effect_database_paths()]
BEGIN, END = "<!-- undeclared-table: scripts/undeclared_table.py -->", "<!-- /undeclared-table -->"


def truth_text(truth: dict) -> str:
    parts = [f"{name} {value:g}" for name, value in expected_candidates(truth).items() if not name.startswith("law")]
    law = str(truth["law"]).split("+")[0]
    if law != "NH":
        parts.append(f"law {law}")
    return ", ".join(parts) or "none"


def analyse(name: str, databases: DatabaseSet, reports: Path) -> dict:
    truth = read_truth(BATCHES / f"{name}_truth.csv")
    capsules = read_measurements(BATCHES / f"{name}.csv", "tube")
    start = time.perf_counter()
    laws = databases.databases[0].laws
    sequence = diagnose_sequential(capsules, databases, "NH", lambda law: candidate_library(law, laws))
    result = sequence.rounds[0]
    seconds = time.perf_counter() - start
    reports.mkdir(parents=True, exist_ok=True)
    write_report(result, reports / f"{name}.md", name)
    g_s = float(truth["G_s"])
    row = {"batch": name, "truth": truth_text(truth), "seconds": seconds,
           "supported": [r.name for r in result.results if r.supported],
           "expected": expected_candidates(truth), "effects": sequence.effects, "note": sequence.note}
    chosen = result.chosen
    if chosen is None:
        base = result.base.g_s[[math.isfinite(x) for x in result.base.g_s]]
        row.update(found="no candidate supported", error_before=(base.mean() - g_s) / g_s)
        return row
    second = (f"{sequence.effects[1][0]}: {sequence.effects[1][1]:.3g}" if len(sequence.effects) > 1
              else "none supported")
    row.update(found=f"{chosen.name}: {chosen.parameter} = {chosen.theta:.3g}", interval=list(chosen.interval),
               second=second, error_before=(sequence.g_s[0][0] - g_s) / g_s,
               error_after=(sequence.g_s[-1][0] - g_s) / g_s,
               chi2_before=chosen.chi2_base, chi2_after=chosen.chi2, bic_drop=chosen.bic_drop,
               rivals=[r.name for r in result.rivals])
    joint = sequence.joint
    if joint is not None:
        # Both strengths fitted together: the row shows them, and chi2 after is the pair's.
        (lo, hi), (lo_2, hi_2) = joint.intervals
        row.update(found=f"{chosen.name}: {chosen.parameter} = {joint.values[0]:.3g} (with the second, jointly)",
                   interval=[lo, hi], second=f"{joint.names[1]}: {joint.values[1]:.3g} [{lo_2:.3g}, {hi_2:.3g}]",
                   chi2_after=joint.chi2, joint_capsules=joint.capsules)
    return row


def markdown(rows: list[dict]) -> str:
    lines = ["| batch | truth (undeclared) | diagnose finds | interval | then (effect fixed) | "
             "G_s error before -> after | chi2 before -> after | other supported |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error_after" in r:
            interval = f"[{r['interval'][0]:.3g}, {r['interval'][1]:.3g}]"
            error = f"{100 * r['error_before']:+.1f} % -> {100 * r['error_after']:+.1f} %"
            chi2 = f"{r['chi2_before']:.0f} -> {r['chi2_after']:.0f}"
            second = r["second"]
        else:
            interval, chi2, second = "", "", ""
            error = f"{100 * r['error_before']:+.1f} %"
        found = r["found"].split(":")[0]
        others = ", ".join(s for s in r["supported"] if s != found) or "-"
        lines.append(f"| {r['batch']} | {r['truth']} | {r['found']} | {interval} | {second} | {error} | {chi2} | {others} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", action="append",
                        help="batch name (repeatable; default all); the other rows are kept from the last run's table.json")
    parser.add_argument("--readme", action="store_true", help="write the table into docs/validation/diagnosis.md between its markers")
    parser.add_argument("--reports", type=Path, default=ROOT / "results" / "undeclared", help="report folder")
    args = parser.parse_args(argv)
    databases = DatabaseSet([load_database(path) for path in DATABASES if path.is_file()])
    # batch_O (capsules off the axis, each its own offset) has its own table: scripts/offcentre_fit_table.py.
    names = args.only or sorted(p.stem for p in BATCHES.glob("batch_?.csv") if p.stem != "batch_O")
    rows = []
    for name in names:
        rows.append(analyse(name, databases, args.reports))
        print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    saved = args.reports / "table.json"
    if args.only and saved.is_file():
        # Rows of the batches not analysed now are kept from the last run (same folder).
        fresh = {r["batch"]: r for r in rows}
        rows = [fresh.pop(r["batch"], r) for r in json.loads(saved.read_text())] + list(fresh.values())
    table = markdown(rows)
    print(table)
    saved.write_text(json.dumps(rows, indent=1))
    if args.readme:
        readme = ROOT / "docs" / "validation" / "diagnosis.md"
        text = readme.read_text(encoding="utf-8")
        if BEGIN not in text or END not in text:
            raise SystemExit(f"{readme}: no table markers {BEGIN} ... {END}")
        head, rest = text.split(BEGIN, 1)
        tail = rest.split(END, 1)[1]
        readme.write_text(f"{head}{BEGIN}\n{table}\n{END}{tail}", encoding="utf-8")
        print(f"wrote the table into {readme}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
