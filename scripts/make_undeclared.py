"""Make the synthetic batches with an undeclared effect in data/examples/undeclared/.

Every batch has the same 24 capsules (one material, G_s = 0.04 N/m, (a/l, Ca_s) drawn at random
between the database nodes) and differs in the effect switched on and in the noise; the kernel
runs once per capsule and simulated law (120 runs, about 20 minutes on one core). The
measurement files say nothing about the effect; each ``<name>_truth.csv`` holds it.

    PYTHONPATH=analysis/src .venv/bin/python scripts/make_undeclared.py [--only NAME] [--out DIR]
"""
from __future__ import annotations

import argparse
import sys
import threading
from pathlib import Path

from capsmech.diagnosis.synthetic import SimulatedCapsule, simulate_tube
from capsmech.diagnosis.undeclared_tube import make_batch, write_batch

OUT = Path(__file__).resolve().parents[1] / "data" / "examples" / "undeclared"
#: name -> (effects, noise seed). The capsules' draw seed is DRAW_SEED for all. The names say
#: nothing about the effect (only the _truth files do).
BATCHES: dict[str, tuple[dict[str, float], int]] = {
    "batch_A": ({}, 1),
    "batch_B": ({"contour_offset": 1.5}, 2),
    "batch_C": ({"tube_radius": 0.03}, 3),
    "batch_D": ({"prestress": 0.05}, 4),
    "batch_E": ({"GH_nu": 0.5}, 5),
    "batch_F": ({"prestress": 0.05, "contour_offset": 1.5}, 6),
    # k_b = K_B/(G_s a^2) ~ (h/a)^2/3 for a shell of thickness h: 0.004 is h ~ 0.11 a.
    "batch_G": ({"kb": 0.004}, 8),
    "batch_H": ({"SK_C": 1.0}, 9),
}
DRAW_SEED = 7
N_CAPSULES = 24


def cached_simulator():
    """simulate_tube with its runs kept, so that batches sharing capsules run the kernel once."""
    cache: dict[tuple[float, float, str], SimulatedCapsule] = {}
    lock = threading.Lock()

    def simulate(a: float, ca: float, key: str) -> SimulatedCapsule:
        with lock:
            hit = cache.get((a, ca, key))
        if hit is None:
            hit = simulate_tube(a, ca, key)
            with lock:
                cache[(a, ca, key)] = hit
        return hit
    return simulate


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", choices=list(BATCHES), action="append", help="make only this batch (repeatable)")
    parser.add_argument("--out", type=Path, default=OUT, help=f"output folder (default {OUT})")
    parser.add_argument("--workers", type=int, default=1, help="kernel runs at a time (one thread each)")
    args = parser.parse_args(argv)
    simulate = cached_simulator()
    for name in args.only or BATCHES:
        effects, seed = BATCHES[name]
        batch = make_batch(effects, n_capsules=N_CAPSULES, seed=seed, draw_seed=DRAW_SEED, simulate=simulate,
                           workers=args.workers)
        csv_path, _ = write_batch(batch, args.out / f"{name}.csv")
        print(f"{csv_path}: {len(batch.rows)} of {N_CAPSULES} capsules steady", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
