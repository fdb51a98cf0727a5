"""The ring kernel's complete elliptic integrals: the fast form (polynomials and one logarithm,
kernel/src/elliptic_integrals.f90) against Bulirsch's AGM that it replaced, in one run.

1. Per call, both algorithms in the same binary on the same arguments (`axi_probe
   ellip-bench`: m1 log-uniform on [1e-12, 1]), alternated ROUNDS times: ratio of medians.
2. With --baseline DIR (the bin/ directory of a build of the AGM version, e.g. the previous
   commit built with `make build BIN=...`): axisymmetric tube cases to steady state, baseline
   and this build alternated ROUNDS times on one thread, CPU time of the process, ratio of
   medians; and the relative change of the steady results (L_z, L_p, v_c).

Prints figures only (shared, noisy machines): `python bench/bench_elliptic.py [--baseline DIR]`
after `make build`.
"""
from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py

REPO = Path(__file__).resolve().parents[1]
ROUNDS = 5
ONE_THREAD = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
CASES = [["--law", "NH", "--a-over-l", "0.9", "--ca", "0.1"],
         ["--law", "NH", "--a-over-l", "0.8", "--ca", "0.03"]]
RESULTS = ["L_z", "L_p", "v_c"]


def per_call(bin_dir: Path) -> tuple[float, float]:
    out = subprocess.run([str(bin_dir / "axi_probe"), "ellip-bench", "200000", str(ROUNDS)], env=ONE_THREAD,
                         capture_output=True, text=True, check=True).stdout
    values = dict(line.split() for line in out.splitlines())
    fast = [float(v) for k, v in values.items() if k.startswith("fast_s_")]
    agm = [float(v) for k, v in values.items() if k.startswith("agm_s_")]
    return statistics.median(fast), statistics.median(agm)


def tube_case(bin_dir: Path, args: list[str]) -> tuple[float, dict[str, float]]:
    """CPU seconds of one case and its steady results."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "case.h5"
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run([str(bin_dir / "capsim"), "--flow", "tube", *args, "--threads", "1", "--quiet",
                        "--out", str(out)], env=ONE_THREAD, check=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        with h5py.File(out) as f:
            steady = {name: float(f[f"steady/{name}"][()]) for name in RESULTS} if "steady" in f else {}
    return after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, steady


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, help="bin/ directory of a build with the AGM")
    args = parser.parse_args()
    this = REPO / "bin"
    fast, agm = per_call(this)
    print(f"per call (m1 log-uniform on [1e-12, 1], median of {ROUNDS}): fast {1e9 * fast:.1f} ns, "
          f"AGM {1e9 * agm:.1f} ns, AGM/fast {agm / fast:.2f}")
    if args.baseline is None:
        return 0
    print(f"tube cases, one thread, {ROUNDS} interleaved rounds, CPU s (median), baseline = {args.baseline}")
    print(f"{'case':>24} {'baseline':>9} {'this':>9} {'base/this':>10}   relative change " + ", ".join(RESULTS))
    for case in CASES:
        times: dict[str, list[float]] = {"baseline": [], "this": []}
        results = {}
        for _ in range(ROUNDS):
            for name, bin_dir in (("baseline", args.baseline), ("this", this)):
                cpu, results[name] = tube_case(bin_dir, case)
                times[name].append(cpu)
        base, new = statistics.median(times["baseline"]), statistics.median(times["this"])
        change = ", ".join(f"{results['this'][k] / results['baseline'][k] - 1:+.1e}" for k in RESULTS) \
            if results["this"] and results["baseline"] else "not steady"
        label = " ".join(case[1::2])
        print(f"{label:>24} {base:>9.2f} {new:>9.2f} {base / new:>10.2f}   {change}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
