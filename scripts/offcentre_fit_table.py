"""Fit the offsets of batch_O (capsules caught off the axis) and of its centred control
batch_O0, and print the README's per-capsule table (``capsmech.diagnosis.offcentre``).

    PYTHONPATH=analysis/src .venv/bin/python scripts/offcentre_fit_table.py
"""
from __future__ import annotations

import csv
import math
import sys
from pathlib import Path

import numpy as np

from capsmech.diagnosis.offcentre import OffcentreTable, fit_offcentre_capsule
from capsmech.inversion.fitting import tube_inverter
from capsmech.io.catalog import database_path
from capsmech.io.database import load_database
from capsmech.io.measurements import read_measurements

ROOT = Path(__file__).resolve().parents[1]
BATCHES = ROOT / "data" / "examples" / "undeclared"


def main() -> int:
    table = OffcentreTable.read(database_path("offcentre"))
    inverter = tube_inverter(load_database(database_path("tube-paper")), "NH")
    print("| capsule | truth a/l, Ca_s | truth r_c [l] | fitted b [l] (interval) | G_s error as centred | G_s error with b |")
    print("|---|---|---|---|---|---|")
    for name in ("batch_O", "batch_O0"):
        with open(BATCHES / f"{name}_truth.csv", newline="", encoding="utf-8") as stream:
            truth = {row["id"]: row for row in csv.DictReader(stream)}
        errors = []
        for capsule in read_measurements(BATCHES / f"{name}.csv", "tube"):
            fit = fit_offcentre_capsule(capsule, inverter, table)
            row = truth[capsule.id]
            g_s = float(row["G_s"])
            before, after = fit.centred[2] / g_s - 1, fit.corrected[2] / g_s - 1
            errors.append((before, after))
            fitted = (f"{fit.offset.offset:+.4f} [{fit.interval[0]:+.4f}, {fit.interval[1]:+.4f}]" if not fit.flag
                      else f"flag: {fit.flag}")
            print(f"| {capsule.id} | {float(row['a_over_l']):g}, {float(row['Ca_s']):g} | {float(row['r_c']):.4f} | "
                  f"{fitted} | " + (f"{before:+.1%}" if math.isfinite(before) else "no fit") + " | "
                  + (f"{after:+.1%}" if math.isfinite(after) else "-") + " |")
        before, after = np.array(errors).T
        print(f"| {name} mean | | | | {np.nanmean(before):+.1%} ({np.isfinite(before).sum()} fitted) | "
              f"{np.nanmean(after):+.1%} ({np.isfinite(after).sum()} fitted) |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
