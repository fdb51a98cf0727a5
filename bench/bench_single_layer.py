"""Time the kernel's hot path: one velocity evaluation and one RK2 step, levels 3 and 4,
on 1 and 2 OpenMP threads, with the speed-up measured in the same run.

Run through `make bench` (which builds with -O3 -march=native first) or directly after
`make build`. Prints figures only: machines are shared and noisy, so nothing here is a test.
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
    bench_tube()
    return 0


def bench_tube() -> None:
    """Wall time of axisymmetric tube cases to steady state, on one thread (DESIGN target: < 10 s)."""
    import tempfile

    import h5py

    capsim = REPO / "bin" / "capsim"
    print("\naxisymmetric tube, one thread, to steady state")
    print(f"{'case':>28} {'status':>10} {'wall [s]':>9}")
    for law, size_ratio, ca in [("NH", 0.4, 0.001), ("NH", 0.85, 0.05)]:
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "case.h5"
            subprocess.run([str(capsim), "--flow", "tube", "--law", law, "--a-over-l", str(size_ratio),
                            "--ca", str(ca), "--threads", "1", "--quiet", "--out", str(out)], check=True)
            with h5py.File(out) as f:
                status = f.attrs["status"].decode() if isinstance(f.attrs["status"], bytes) else f.attrs["status"]
                wall = float(f.attrs["wall_time_s"])
        print(f"{law + f' a/l={size_ratio} Ca={ca}':>28} {status:>10} {wall:>9.1f}")


if __name__ == "__main__":
    sys.exit(main())
