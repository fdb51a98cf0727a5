"""Interval coverage of the diagnosis (issue 19, item 4): how often does an interval hold the truth?

Each configuration is one effect at one strength, switched on in batches drawn from the
independent pool (``independent_batches``: capsules simulated once, each batch a fresh draw of
16 capsules with fresh tracing noise and measured lengths). Each batch is diagnosed with the
true effect's candidate alone (the question is the interval, not the choice), and the record
says whether

- the strength's interval holds the true strength;
- G_s after the effect, by lengths (``length_g_s``: each capsule's lengths, measured on its
  contour, inverted) with its interval (``capsmech.diagnosis.record.g_s_interval``: the
  Student-t half-width of the capsules' mean and the systematic part, the databases' accuracy
  and the strength's interval carried into G_s, in quadrature), holds the true G_s; likewise
  by the contour fits;
- (configuration ``none``) G_s of the base law holds the truth when there is no effect.

``python tests/python/interval_coverage.py --batches 25 --workers 16 --out FILE.csv`` runs the
study (about 10 core-minutes per 25 batches of a configuration); ``summarise`` turns its rows
into the table of docs/validation (coverage with its 95 % Wilson interval). ``make validate``
runs it at a reduced size; the figures in the docs (strengths and G_s) come from 50 batches per
effect and strength on the 2-core machine (seeds 0-49, every configuration; two processes, one
with ``--first 35 --batches 15``, their rows merged; docs/validation/diagnosis.md says which
code).
"""
from __future__ import annotations

import argparse
import csv
import math
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import independent_batches as ib  # noqa: E402

#: (name, effect candidate, pool key, draw_batch keywords, true strength)
CONFIGS: list[tuple[str, str, str, dict, float]] = [
    ("offset 1.0 px", "contour_offset", "NH", {"contour_offset_px": 1.0}, 1.0),
    ("offset 2.2 px", "contour_offset", "NH", {"contour_offset_px": 2.2}, 2.2),
    ("tube radius +0.02", "tube_radius", "NH", {"tube_radius_rel": 0.02}, 0.02),
    ("tube radius -0.035", "tube_radius", "NH", {"tube_radius_rel": -0.035}, -0.035),
    ("pre-stress 0.045", "prestress", "NH+prestress0.045", {}, 0.045),
    ("pre-stress 0.07", "prestress", "NH+prestress0.07", {}, 0.07),
    ("bending 0.003", "kb", "NH+kb0.003", {}, 0.003),
    ("bending 0.007", "kb", "NH+kb0.007", {}, 0.007),
    ("no effect", "none", "NH", {}, math.nan),
    # Below the lowest shipped level (0.04), between it and the base law: the strength pool's.
    ("pre-stress 0.03", "prestress", "NH+prestress0.03", {}, 0.03),
]
FIELDS = ["config", "seed", "capsules", "strength", "low", "high", "covered", "supported",
          "g_s_lengths", "g_s_lengths_low", "g_s_lengths_high", "g_s_lengths_covered",
          "g_s_contours", "g_s_contours_low", "g_s_contours_high", "g_s_contours_covered"]

_DATABASES = None


def _databases():
    global _DATABASES
    if _DATABASES is None:
        from capsmech.diagnosis.candidates import DatabaseSet
        from capsmech.io.catalog import database_path
        from capsmech.io.database import load_database

        _DATABASES = DatabaseSet([load_database(database_path(n)) for n in ("tube-paper", "tube-prestress", "tube-kb")])
    return _DATABASES


def _candidate(name: str):
    from capsmech.diagnosis import candidates

    return {"contour_offset": candidates.contour_offset_candidate, "tube_radius": candidates.tube_radius_candidate,
            "prestress": candidates.prestress_candidate, "kb": candidates.bending_candidate}[name]("NH")


def one_batch(config: int, seed: int, n: int = 16) -> dict:
    """Draw and diagnose one batch of configuration ``config``; its row of ``FIELDS``."""
    from capsmech.diagnosis.diagnose import diagnose
    from capsmech.diagnosis.record import g_s_interval
    from capsmech.diagnosis.scoring import length_g_s_with_systematic, lengths_inverter
    from capsmech.io.measurements import read_measurements

    name, effect, key, keywords, truth = CONFIGS[config]
    with tempfile.TemporaryDirectory() as tmp:
        pool = ib.load_pool(ib.STRENGTH_POOL if key in ib.STRENGTH_KEYS else ib.POOL)
        batch = ib.draw_batch(pool, key, Path(tmp), "b", seed=seed, n=n, **keywords)
        capsules = read_measurements(batch.csv, "tube")
    row: dict = {"config": name, "seed": seed, "capsules": len(capsules)}
    g_s = ib.G_S
    if effect == "none":
        summary, floor = length_g_s_with_systematic(capsules, lengths_inverter(_databases(), "NH"))
        lengths, contours = (*summary, floor), (math.nan, math.nan, 0)
    else:
        result = diagnose(capsules, _databases(), "NH", [_candidate(effect)], screen=False).results[0]
        row.update(strength=result.theta, low=result.interval[0], high=result.interval[1],
                   covered=bool(result.interval[0] <= truth <= result.interval[1]), supported=result.supported)
        lengths = (*result.g_s_lengths_after, result.g_s_lengths_systematic[1])
        contours = (*result.g_s_after, result.capsules, result.g_s_systematic[1])
    for label, summary in (("lengths", lengths), ("contours", contours)):
        interval = g_s_interval(*summary)
        if interval["value"] is not None:
            low, high = interval["interval"]
            row.update({f"g_s_{label}": interval["value"], f"g_s_{label}_low": low, f"g_s_{label}_high": high,
                        f"g_s_{label}_covered": bool(low <= g_s <= high)})
    return row


def _run(job: tuple[int, int, int]) -> dict:
    try:
        return one_batch(*job)
    except Exception as err:  # a failed batch is a row that says so, not a lost study
        return {"config": CONFIGS[job[0]][0], "seed": job[1], "capsules": f"error: {err}"}


def run_study(batches: int, workers: int, out: Path, configs: list[int] | None = None, capsules: int = 16,
              first: int = 0) -> Path:
    """Run the study; each row is written as soon as its batch is done (a study stopped early
    keeps what it measured). Batches are interleaved across configurations for the same reason."""
    chosen = configs if configs is not None else range(len(CONFIGS))
    jobs = [(c, 1000 * c + k, capsules) for k in range(first, first + batches) for c in chosen]
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w", newline="") as f, ProcessPoolExecutor(workers) as pool:
        writer = csv.DictWriter(f, FIELDS)
        writer.writeheader()
        for row in pool.map(_run, jobs):
            writer.writerow(row)
            f.flush()
    return out


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson interval of a proportion k/n."""
    if n == 0:
        return (math.nan, math.nan)
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (centre - half, centre + half)


def summarise(path: Path) -> list[dict]:
    """Per configuration: batches, coverage of each interval (with its Wilson interval), the
    median relative width of the strength's interval and the strength's median error."""
    with path.open() as f:
        rows = list(csv.DictReader(f))
    table = []
    for name, _, _, _, truth in CONFIGS:
        mine = [r for r in rows if r["config"] == name and not r["capsules"].startswith("error")]
        entry: dict = {"config": name, "batches": len(mine),
                       "errors": sum(1 for r in rows if r["config"] == name and r["capsules"].startswith("error"))}
        for column in ("covered", "g_s_lengths_covered", "g_s_contours_covered"):
            values = [r[column] == "True" for r in mine if r.get(column) not in ("", None)]
            entry[column] = (sum(values), len(values), *wilson(sum(values), len(values)))
        for label in ("lengths", "contours"):
            # G_s: the median error and the median interval width, both relative to the truth.
            known = [r for r in mine if r.get(f"g_s_{label}") not in ("", None)]
            if known:
                value = np.array([float(r[f"g_s_{label}"]) for r in known])
                width = np.array([float(r[f"g_s_{label}_high"]) - float(r[f"g_s_{label}_low"]) for r in known])
                entry[f"g_s_{label}_median_error"] = float(np.median(value / ib.G_S - 1))
                entry[f"g_s_{label}_median_width"] = float(np.median(width / ib.G_S))
        if math.isfinite(truth) and mine:
            strengths = np.array([float(r["strength"]) for r in mine])
            widths = np.array([float(r["high"]) - float(r["low"]) for r in mine])
            entry["median_error"] = float(np.median(strengths - truth))
            entry["median_width"] = float(np.median(widths))
        table.append(entry)
    return table


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, default=25, help="batches per configuration")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--capsules", type=int, default=16, help="capsules per batch")
    parser.add_argument("--config", type=int, action="append", help="only these configurations (indices)")
    parser.add_argument("--first", type=int, default=0, help="first batch number (seeds follow from it)")
    args = parser.parse_args(argv)
    run_study(args.batches, args.workers, args.out, args.config, args.capsules, args.first)
    for entry in summarise(args.out):
        print(entry)
    return 0


if __name__ == "__main__":
    sys.exit(main())
