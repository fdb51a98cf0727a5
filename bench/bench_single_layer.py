"""Time the kernel's hot path: one velocity evaluation and one RK2 step, levels 3 and 4,
on 1 and 2 OpenMP threads, with the speed-up measured in the same run.

Run through `make bench` or directly after `make build` (the default, native build). Prints
figures only: machines are shared and noisy, so nothing here is a test.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PROBE = REPO / "bin" / "kernel_probe"
TARGET_VELOCITY_S = 0.050   # DESIGN.md: level 4, 2 cores, "well under 50 ms"


def measure(level: int, threads: int, repeats: int) -> dict[str, float]:
    env = dict(os.environ, OMP_NUM_THREADS=str(threads), OMP_PROC_BIND="close")
    out = subprocess.run([str(PROBE), "bench", str(level), str(repeats)], env=env,
                         capture_output=True, text=True, check=True).stdout
    return {k: float(v) for k, v in (line.split() for line in out.splitlines())}


def main() -> int:
    if not PROBE.exists():
        print(f"{PROBE} is missing: run `make build` first", file=sys.stderr)
        return 2
    cores = os.cpu_count() or 1
    print(f"capsim hot path, {cores} cores on this machine")
    print(f"{'level':>5} {'nodes':>6} {'threads':>7} {'velocity [ms]':>14} {'RK2 step [ms]':>14} {'speed-up':>9}")
    for level, repeats in [(3, 40), (4, 10)]:
        base = None
        for threads in (1, 2):
            r = measure(level, threads, repeats)
            base = base or r["velocity_s"]
            print(f"{level:>5} {int(r['n_nodes']):>6} {threads:>7} {1e3 * r['velocity_s']:>14.2f} "
                  f"{1e3 * r['rk2_step_s']:>14.2f} {base / r['velocity_s']:>9.2f}")
            if level == 4 and threads == 2:
                verdict = "meets" if r["velocity_s"] < TARGET_VELOCITY_S else "misses"
                print(f"      level-4 velocity on 2 threads {verdict} the {1e3 * TARGET_VELOCITY_S:.0f} ms target")
    return 0


if __name__ == "__main__":
    sys.exit(main())
