"""Wall time of axisymmetric tube cases to steady state on one thread (DESIGN.md target: under
10 s a case), with the linearly implicit solver (the default) against explicit RK2 measured
in the same run, and the projected time of the paper's tube grid.

Run through `make bench` or after `make build` (the default build, -O3 -march=native).
Prints figures only: the machines are shared and noisy, so nothing here is a test.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py

REPO = Path(__file__).resolve().parents[1]
CAPSIM = REPO / "bin" / "capsim"
TARGET_S = 10.0

# (law flags, a/l, Ca_s, compare with RK2?)
CASES = [
    (["--law", "NH"], 0.4, 0.001, False),
    (["--law", "NH"], 0.7, 0.05, False),
    (["--law", "NH"], 0.85, 0.05, True),
    (["--law", "NH"], 0.9, 0.1, False),
    (["--law", "GH", "--nu-s", "0.5"], 1.0, 0.2, False),
]


def run_case(law: list[str], size_ratio: float, ca: float, integrator: str) -> tuple[str, float, float]:
    """Status, wall time [s] and steady L_z [l] (NaN when not steady) of one case."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "case.h5"
        subprocess.run([str(CAPSIM), "--flow", "tube", *law, "--a-over-l", str(size_ratio), "--ca", str(ca),
                        "--integrator", integrator, "--threads", "1", "--quiet", "--out", str(out)], check=True)
        with h5py.File(out) as f:
            status = f.attrs["status"]
            status = status.decode() if isinstance(status, bytes) else str(status)
            l_z = float(f["steady/L_z"][()]) if "steady" in f else float("nan")
            return status, float(f.attrs["wall_time_s"]), l_z


def main() -> int:
    if not CAPSIM.exists():
        print(f"{CAPSIM} is missing: run `make build` first", file=sys.stderr)
        return 2
    print(f"axisymmetric tube to steady state, one thread ({os.cpu_count()} cores on this machine)")
    print(f"{'case':>30} {'solver':>9} {'status':>8} {'L_z/l':>8} {'wall [s]':>9} {'RK2/auto':>9}")
    times = []
    for law, size_ratio, ca, compare in CASES:
        name = f"{' '.join(law[1::2])} a/l={size_ratio} Ca={ca}"
        status, wall, l_z = run_case(law, size_ratio, ca, "auto")
        times.append(wall)
        print(f"{name:>30} {'auto':>9} {status:>8} {l_z:>8.4f} {wall:>9.2f}")
        if compare:
            status_rk2, wall_rk2, l_z_rk2 = run_case(law, size_ratio, ca, "rk2")
            print(f"{name:>30} {'rk2':>9} {status_rk2:>8} {l_z_rk2:>8.4f} {wall_rk2:>9.2f} {wall_rk2 / wall:>9.1f}")
    mean = sum(times) / len(times)
    verdict = "meets" if max(times) < TARGET_S else "misses"
    print(f"slowest case {max(times):.1f} s: {verdict} the {TARGET_S:.0f} s target; mean {mean:.1f} s")
    # Paper grid (config/paper.yaml): 9 a/l x 12 Ca_s x 5 laws, two cases at a time on 2 cores.
    n_cases = 9 * 12 * 5
    print(f"projected tube database ({n_cases} cases, 2 at a time): {n_cases * mean / 2 / 60:.0f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
