"""The law verdict and its G_s interval on repeated batches (issue 19, items 1 and 4):
``fit-tube`` with every law of the paper-grid database, then ``population``, on batches of the
independent generator (``independent_batches``: the kernel's shapes on 96 meridian elements,
its own tracing noise, lengths read off the noisy contour; 12 capsules a batch, a fresh draw and
fresh noise per seed; G_s 0.025 N/m).

Besides the database's laws (GH nu_s 0.5, SK C = 1, NH), batches no law of it describes: two
membranes outside it (SK C = 3, GH nu_s 0.35) and NH capsules whose contours carry a ripple
of 1.5 px (a distortion of the tracing), where the answer must be none.

Per batch a row: the truth, the verdict (``law``, ``cannot_tell``, ``none``) and the law named,
whether it is right, G_s with its 95 % interval and the estimator, whether the interval holds
the truth, and the true law's chi2 per degree of freedom against the noise. ``summarise`` gives
per membrane: the verdicts, the coverage of the G_s interval with its 95 % Wilson interval,
the median error and half-width of G_s (the table of docs/validation/inversion.md)::

    python tests/python/population_coverage.py --batches 50 --workers 2 --out rows.csv
    python tests/python/population_coverage.py --summary docs/validation/runs/population_coverage.csv

About 25 CPU seconds a batch (five laws' contour fits). Not in ``make test``
(tests/python/test_shape_fit.py checks single batches).
"""
from __future__ import annotations

import argparse
import csv
import math
import sys
import tempfile
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from statistics import median

sys.path.insert(0, str(Path(__file__).resolve().parent))
import independent_batches as ib  # noqa: E402
from interval_coverage import wilson  # noqa: E402

#: Batch kind: (pool key, draw_batch keywords, the law of the database that made it; None:
#: none does: a membrane outside the database, or a contour distortion no law describes).
CONFIGS: dict[str, tuple[str, dict, str | None]] = {
    "GH_nu0.5": ("GH_nu0.5", {}, "GH_nu0.5"), "SK_C1": ("SK_C1", {}, "SK_C1"), "NH": ("NH", {}, "NH"),
    "SK_C3": ("SK_C3", {}, None), "GH_nu0.35": ("GH_nu0.35", {}, None),
    "NH+ripple1.5px": ("NH", {"ripple_px": 1.5}, None),
}
TRUTH = {name: truth for name, (_, _, truth) in CONFIGS.items()}
FIELDS = ["membrane", "seed", "truth", "verdict", "law", "right", "g_s", "g_s_low", "g_s_high", "covered",
          "estimator", "truth_chi2_per_dof", "chi2_limit"]


def verdict_row(key: str, seed: int, rows: list[dict]) -> dict:
    """The study's row of one batch from its fit-tube rows."""
    from capsmech.inversion.population import population_verdict

    verdict = population_verdict(rows)
    truth = TRUTH[key]
    named = verdict.best if verdict.kind == "law" else None
    right = (named == truth) if verdict.kind == "law" else (verdict.kind == "none" and truth is None)
    low, high = verdict.g_s_interval if verdict.kind == "law" and verdict.g_s_interval else (math.nan, math.nan)
    noise = verdict.evidence[truth].noise if truth in verdict.evidence else None
    return {"membrane": key, "seed": seed, "truth": truth or "outside", "verdict": verdict.kind, "law": named or "",
            "right": right, "g_s": verdict.g_s if named else math.nan, "g_s_low": low, "g_s_high": high,
            "covered": (low <= ib.G_S <= high) if named else "", "estimator": verdict.estimator,
            "truth_chi2_per_dof": noise.reduced_chi2 if noise else math.nan,
            "chi2_limit": noise.limit if noise else math.nan}


def one_batch(job: tuple[str, int]) -> dict:
    """Draw, fit with every law, and judge one batch."""
    from capsmech.inversion.fitting import fit_tube_rows
    from capsmech.io.database import load_database
    from capsmech.io.measurements import read_measurements

    key, seed = job
    pool_key, keywords, _ = CONFIGS[key]
    with tempfile.TemporaryDirectory() as tmp:
        drawn = ib.draw_batch(ib.load_pool(), pool_key, Path(tmp), f"{pool_key}_{seed}", seed=seed, n=12, **keywords)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rows = fit_tube_rows(read_measurements(drawn.csv, "tube"), load_database("tube-paper"))
    return verdict_row(key, seed, rows)


def run_study(keys: list[str], batches: int, workers: int, out: Path) -> Path:
    jobs = [(key, seed) for key in keys for seed in range(1, batches + 1)]
    with ProcessPoolExecutor(workers) as pool:
        results = list(pool.map(one_batch, jobs))
    with open(out, "w", newline="") as handle:
        writer = csv.DictWriter(handle, FIELDS)
        writer.writeheader()
        writer.writerows(results)
    return out


def summarise(path: Path) -> list[dict]:
    """Per membrane: batches; verdicts (right law, cannot tell, none, wrong law); the G_s
    interval's coverage (hits, batches, Wilson interval) over the batches named right; the
    median error and half-width of G_s relative to the truth; the true law's chi2 per degree
    of freedom (range) against the limit."""
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    out = []
    for key in dict.fromkeys(r["membrane"] for r in rows):
        mine = [r for r in rows if r["membrane"] == key]
        named = [r for r in mine if r["verdict"] == "law" and r["right"] == "True"]
        hits = sum(r["covered"] == "True" for r in named)
        errors = [float(r["g_s"]) / ib.G_S - 1 for r in named]
        halves = [(float(r["g_s_high"]) - float(r["g_s_low"])) / 2 / ib.G_S for r in named]
        chi2 = [float(r["truth_chi2_per_dof"]) for r in mine if r["truth_chi2_per_dof"] not in ("", "nan")]
        chi2 = [c for c in chi2 if math.isfinite(c)]
        out.append({"membrane": key, "batches": len(mine), "right_law": len(named),
                    "cannot_tell": sum(r["verdict"] == "cannot_tell" for r in mine),
                    "none": sum(r["verdict"] == "none" for r in mine),
                    "wrong_law": sum(r["verdict"] == "law" and r["right"] != "True" for r in mine),
                    "covered": (hits, len(named), *wilson(hits, len(named))),
                    "median_error": median(errors) if errors else math.nan,
                    "median_half_width": median(halves) if halves else math.nan,
                    "chi2_range": (min(chi2), max(chi2)) if chi2 else None,
                    "chi2_limit": float(mine[0]["chi2_limit"]) if chi2 else math.nan})
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keys", default=",".join(CONFIGS))
    parser.add_argument("--batches", type=int, default=50)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path)
    parser.add_argument("--summary", type=Path, help="print the summary of a rows file")
    args = parser.parse_args(argv)
    if args.out:
        run_study(args.keys.split(","), args.batches, args.workers, args.out)
    for entry in summarise(args.summary or args.out):
        print(entry)
    return 0


if __name__ == "__main__":
    sys.exit(main())
