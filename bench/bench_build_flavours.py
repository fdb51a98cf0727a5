"""Portable against native build: the same sources built both ways (`make PORTABLE=1` and the
default `make`), timed interleaved in one run, printed as the ratio portable/native.

Each flavour is built into its own bin directory (build/bench-portable/bin,
build/bench-native/bin; the objects live in build/portable and build/native). Measured: the
level-4 velocity evaluation of a sheared capsule (`kernel_probe bench 4`, one thread, CPU time) and one
axisymmetric tube case to steady state (NH, a/l = 0.9, Ca_s = 0.1, one thread, CPU time of the
process). The two binaries alternate, ROUNDS times; the ratio of the medians is printed. The
machines are shared and noisy: the ratio is the figure, not the absolute times, and nothing
here is a test. Run through `make bench` or on its own: python bench/bench_build_flavours.py
"""
from __future__ import annotations

import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py

REPO = Path(__file__).resolve().parents[1]
FLAVOURS = {"portable": ["PORTABLE=1"], "native": []}
ROUNDS = 5
VELOCITY_REPEATS = 10
TUBE_ARGS = ["--flow", "tube", "--law", "NH", "--a-over-l", "0.9", "--ca", "0.1"]
ONE_THREAD = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")


def bin_dir(flavour: str) -> Path:
    return REPO / "build" / f"bench-{flavour}" / "bin"


def build(flavour: str) -> None:
    subprocess.run(["make", "-C", str(REPO), "--no-print-directory", "-s", "build",
                    f"BIN={bin_dir(flavour).relative_to(REPO)}", *FLAVOURS[flavour]], check=True)


def velocity_s(flavour: str) -> float:
    out = subprocess.run([str(bin_dir(flavour) / "kernel_probe"), "bench", "4", str(VELOCITY_REPEATS)],
                         env=ONE_THREAD, capture_output=True, text=True, check=True).stdout
    return float(dict(line.split() for line in out.splitlines())["velocity_cpu_s"])


def tube_cpu_s(flavour: str) -> tuple[float, float]:
    """CPU seconds of one tube case, and its steady L_z (to show both builds agree)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "case.h5"
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run([str(bin_dir(flavour) / "capsim"), *TUBE_ARGS, "--threads", "1", "--quiet",
                        "--out", str(out)], env=ONE_THREAD, check=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        with h5py.File(out) as f:
            l_z = float(f["steady/L_z"][()]) if "steady" in f else float("nan")
    return after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, l_z


def main() -> int:
    for flavour in FLAVOURS:
        build(flavour)
        print((bin_dir(flavour) / ".flavour").read_text().split(" -fopenmp")[0])
    times: dict[str, dict[str, list[float]]] = {f: {"velocity": [], "tube": []} for f in FLAVOURS}
    l_z = {}
    for _ in range(ROUNDS):
        for flavour in FLAVOURS:
            times[flavour]["velocity"].append(velocity_s(flavour))
            cpu, l_z[flavour] = tube_cpu_s(flavour)
            times[flavour]["tube"].append(cpu)
    print(f"one thread, {ROUNDS} interleaved rounds, medians ({os.cpu_count()} cores on this machine)")
    print(f"{'measure':>40} {'portable':>10} {'native':>10} {'portable/native':>16}")
    for key, label, scale, unit in [("velocity", "level-4 velocity evaluation (CPU)", 1e3, "ms"),
                                    ("tube", "tube NH a/l=0.9 Ca_s=0.1 (CPU)", 1.0, "s")]:
        p, n = (statistics.median(times[f][key]) for f in FLAVOURS)
        spread = [a / b for a, b in zip(times["portable"][key], times["native"][key])]
        print(f"{label:>40} {scale * p:>8.2f}{unit:<2} {scale * n:>8.2f}{unit:<2} {p / n:>10.2f} "
              f"(rounds {min(spread):.2f}-{max(spread):.2f})")
    print(f"steady L_z/l: portable {l_z['portable']:.15f}, native {l_z['native']:.15f}, "
          f"relative difference {abs(l_z['portable'] / l_z['native'] - 1):.1e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
