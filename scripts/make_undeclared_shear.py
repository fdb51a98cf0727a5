"""Make the synthetic shear batches with an undeclared viscosity ratio in data/examples/undeclared/.

Both batches have the same capsules (one NH material, G_s = 0.04 N/m, Ca_s and radius drawn at
random, see capsmech.diagnosis.undeclared_shear) and differ in lambda and in the noise: shear_batch_A is
simulated at lambda = 1 (the databases' base: no effect), shear_batch_L at lambda = 0.001 (the
paper's Couette cell). Every capsule is one kernel run at level 3, one at a time (lambda = 1:
seconds each; lambda = 0.001: 1-5 minutes each). Runs are kept in --cache, so an interrupted
generation resumes. The measurement files say nothing about lambda; each ``_truth.csv`` does.
The ``_theta`` batches add the measured inclination angle (1 deg error) to the same rows.

    nice -n 10 env PYTHONPATH=analysis/src .venv/bin/python scripts/make_undeclared_shear.py [--only NAME]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from capsmech.diagnosis.undeclared_shear import THETA_ERROR_DEG, cached_simulator, make_shear_batch, write_shear_batch

OUT = Path(__file__).resolve().parents[1] / "data" / "examples" / "undeclared"
#: name -> (viscosity ratio, noise seed, measured theta); the capsules' draw seed is DRAW_SEED
#: for all. The _theta batches are the same measurements with the inclination angle added.
BATCHES: dict[str, tuple[float, int, bool]] = {
    "shear_batch_A": (1.0, 11, False), "shear_batch_L": (0.001, 12, False),
    "shear_batch_A_theta": (1.0, 11, True), "shear_batch_L_theta": (0.001, 12, True)}
DRAW_SEED = 17
N_CAPSULES = 16
G_S = 0.04


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", choices=list(BATCHES), action="append", help="make only this batch (repeatable)")
    parser.add_argument("--out", type=Path, default=OUT, help=f"output folder (default {OUT})")
    parser.add_argument("--cache", type=Path, default=Path("results/undeclared_shear_runs"),
                        help="folder keeping each kernel run's steady state (default results/undeclared_shear_runs)")
    args = parser.parse_args(argv)
    simulate = cached_simulator(args.cache)
    for name in args.only or BATCHES:
        ratio, seed, theta = BATCHES[name]
        batch = make_shear_batch(ratio, n_capsules=N_CAPSULES, g_s=G_S, seed=seed, draw_seed=DRAW_SEED,
                                 simulate=simulate, theta_error_deg=THETA_ERROR_DEG if theta else None)
        csv_path, _ = write_shear_batch(batch, args.out / f"{name}.csv")
        print(f"{csv_path}: {len(batch.rows)} of {N_CAPSULES} capsules steady", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
