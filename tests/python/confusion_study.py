"""The confusion study of issue 19, item 6: capsmech's diagnosis, as a user runs it (``capsmech.diagnose``
with its defaults: the whole candidate library, up to two effects), on the batches of the
independent generator (``independent_batches.CONFUSION_BATCHES``): every library effect at two
strengths other than those of ``data/examples/undeclared``, a control, and three effects outside
the library. The right answer is the effect, "none" for the control, and "unexplained" for the
effects outside the library; a wrongly *named* effect is the failure that must not happen.

``python tests/python/confusion_study.py OUT_DIR --workers 14`` writes ``confusion.csv`` (one row
per batch: expected, verdict, effects named, G_s) and ``raw.pkl`` (each batch's ``--json``
record and its fits as plain arrays, so that the goodness-of-fit tests can be re-evaluated
without rerunning the diagnosis); the batches themselves are drawn in a temporary folder.
"""
from __future__ import annotations

import argparse
import csv
import pickle
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import independent_batches as ib  # noqa: E402

SEED = 7


def _score(score) -> dict | None:
    if score is None:
        return None
    return {"chi2": score.chi2, "residual": score.residual, "g_s": score.g_s, "delta": score.delta}


def diagnose_batch(name: str, folder: Path, seed: int = SEED, capsules: int = 16) -> tuple[dict, dict]:
    """Draw batch ``name`` and diagnose it with capsmech's defaults; (table row, raw fits)."""
    import capsmech
    from capsmech.diagnosis.record import diagnosis_record
    from capsmech.io.measurements import read_measurements

    key, keywords, expected = ib.CONFUSION_BATCHES[name]
    batch = ib.draw_batch(ib.load_pool(), key, folder, name, seed=seed, n=capsules, **keywords)
    start = time.time()
    outcome = capsmech.diagnose(str(batch.csv))
    record = diagnosis_record(outcome, name)
    named = [e["name"] for e in record["effects"]]
    tied = record["cannot_tell"]
    answer = record["verdict"] if record["verdict"] != "effect" else " + ".join(named)
    # Right: the effect alone, "none" for the control, "unexplained" outside the library, or
    # (partly right: reported apart) a tie between candidates that holds the true one.
    right = (answer == "none" if expected is None else answer == expected
             or (expected == "unexplained" and record["verdict"] == "unexplained")
             or (record["verdict"] == "cannot_tell" and expected in tied))
    wrong_named = ((record["verdict"] == "effect" and (expected is None or expected == "unexplained"
                                                       or expected not in named))
                   or (record["verdict"] == "cannot_tell" and expected not in tied))
    lengths = record["g_s"]["lengths"]
    row = {"batch": name, "membrane": key, "expected": expected or "none", "verdict": record["verdict"],
           "named": " + ".join(named) or " / ".join(tied), "right": right, "wrong_effect_named": wrong_named,
           "closest": (record["closest"] or {}).get("name", ""),
           "reduced_chi2": (record["goodness_of_fit"] or {}).get("reduced_chi2"),
           "g_s_before": (lengths["before"] or {}).get("value"), "g_s_after": (lengths["after"] or {}).get("value"),
           "seconds": round(time.time() - start)}
    rounds = outcome.rounds if hasattr(outcome, "rounds") else [outcome]
    capsules = [c for c in read_measurements(batch.csv, "tube") if c.contour is not None]
    raw = {"name": name, "expected": expected, "lengths_px": [c["L_z"] / c["pixel_size"] for c in capsules],
           "rounds": [{"base": _score(r.base), "chosen": r.chosen.name if r.chosen else None,
                       "results": [{"name": x.name, "supported": x.supported, "bic_drop": x.bic_drop,
                                    "theta": x.theta, "interval": x.interval, "after": _score(x.after)}
                                   for x in r.results]} for r in rounds],
           "final": _score(getattr(outcome, "final", None)), "record": record}
    return row, raw


def _run(job: tuple[str, str, int]) -> tuple[dict, dict]:
    name, folder, capsules = job
    try:
        with tempfile.TemporaryDirectory(dir=folder) as tmp:
            return diagnose_batch(name, Path(tmp), capsules=capsules)
    except Exception as err:  # one failed batch is a row that says so
        return {"batch": name, "verdict": f"error: {err!r}"}, {"name": name}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--batch", action="append", help="only these batches")
    parser.add_argument("--capsules", type=int, default=16, help="capsules per batch")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    names = args.batch or list(ib.CONFUSION_BATCHES)
    fields = ["batch", "membrane", "expected", "verdict", "named", "right", "wrong_effect_named", "closest",
              "reduced_chi2", "g_s_before", "g_s_after", "seconds"]
    raws = []
    # Each batch's row and raw fits are written as soon as it is done (a study stopped early
    # keeps what it measured).
    with (args.out / "confusion.csv").open("w", newline="") as f, ProcessPoolExecutor(args.workers) as pool:
        writer = csv.DictWriter(f, fields)
        writer.writeheader()
        futures = [pool.submit(_run, (n, str(args.out), args.capsules)) for n in names]
        for future in as_completed(futures):
            row, raw = future.result()
            writer.writerow(row)
            f.flush()
            raws.append(raw)
            with (args.out / "raw.pkl").open("wb") as out:
                pickle.dump(raws, out)
            print(row, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
