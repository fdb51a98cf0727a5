"""Make the synthetic example batches in data/examples/ with the kernel (documented there).

Each batch: one material (G_s = 0.04 N/m) whose capsules, of random sizes, flowed at random
rates, so that (a/l, Ca_s) fall at random off the database grid; simulated with one law,
measured with 2 % Gaussian noise on L_z, L_p and v_c, in a 100 um capillary (l = 50 um),
mu = 1 Pa s. The truth goes to a separate file, never into the measurements.

    .venv/bin/python scripts/make_examples.py          # about 3 minutes on 2 cores
"""
from __future__ import annotations

import csv
import sys
from concurrent.futures import ThreadPoolExecutor
from itertools import repeat
from pathlib import Path

import numpy as np

from capsmech.diagnosis.synthetic import simulate_tube, tube_batch, write_tube_csv

OUT = Path(__file__).resolve().parents[1] / "data" / "examples"
BATCHES = {"NH": 0, "GH_nu0.5": 1}
N_CAPSULES = 12
G_S = 0.04
#: Image scale of the traced contours (a 100 um capillary is 200 pixels wide).
PIXEL_SIZE_UM = 0.5


def main() -> int:
    OUT.mkdir(parents=True, exist_ok=True)
    for law, seed in BATCHES.items():
        rng = np.random.default_rng(100 + seed)
        a = rng.uniform(0.88, 1.02, N_CAPSULES)
        ca = np.exp(rng.uniform(np.log(0.03), np.log(0.10), N_CAPSULES))
        with ThreadPoolExecutor(max_workers=2) as pool:
            # The law goes in as an argument (not through a closure over the loop variable).
            capsules = list(pool.map(simulate_tube, a, ca, repeat(law, N_CAPSULES)))
        rows = tube_batch(capsules, g_s=G_S, seed=seed, pixel_size_um=PIXEL_SIZE_UM)
        name = f"tube_batch_{law}"
        write_tube_csv(rows, OUT / f"{name}.csv",
                       comment=f"synthetic batch made by scripts/make_examples.py with the kernel ({law}),\n"
                               "2 % noise on lengths and velocity, contours traced to +-1 pixel; the truth is in the _truth file")
        with open(OUT / f"{name}_truth.csv", "w", newline="", encoding="utf-8") as stream:
            writer = csv.writer(stream)
            writer.writerow(["id", "law", "a_over_l", "Ca_s", "G_s [N/m]", "status"])
            k = 0
            for j, capsule in enumerate(capsules):
                writer.writerow([f"s{j + 1:03d}", law, f"{capsule.a_over_l:.6g}", f"{capsule.Ca_s:.6g}",
                                 f"{G_S:.6g}", capsule.status])
                k += capsule.status == "steady"
        print(f"{name}: {k} of {N_CAPSULES} capsules steady")
    return 0


if __name__ == "__main__":
    sys.exit(main())
