"""Start-up cost of the process the workflow runs once per database case
(`capsmech dev run-case`), against a process that builds the whole command line.

Why: a steady tube case takes 0.2-7 s in the kernel (kernel 0.3.5); importing every user job's
modules (pandas, scipy, matplotlib) took 1.2 s more per case before `capsmech dev ...` parsed
its own commands alone, a third of a paper-grid refill on 2 cores. Prints the ratio of the two
from one run (median of --repeat starts each, interleaved).

    python bench/bench_cli_startup.py [--repeat 5]
"""
from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time

COMMANDS = {
    "dev run-case (workflow, per case)": [sys.executable, "-m", "capsmech.cli", "dev", "run-case", "--help"],
    "every job's parser": [sys.executable, "-c", "from capsmech.cli.main import build_parser; build_parser()"],
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    times: dict[str, list[float]] = {name: [] for name in COMMANDS}
    for _ in range(args.repeat):
        for name, command in COMMANDS.items():
            start = time.perf_counter()
            subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
            times[name].append(time.perf_counter() - start)
    medians = {name: statistics.median(values) for name, values in times.items()}
    for name, value in medians.items():
        print(f"{name:<36} {value:6.2f} s (median of {args.repeat})")
    slow, fast = medians["every job's parser"], medians["dev run-case (workflow, per case)"]
    print(f"per-case start-up: {slow / fast:.1f} times cheaper than the whole command line")
    return 0


if __name__ == "__main__":
    sys.exit(main())
