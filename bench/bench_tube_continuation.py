"""Steady tube branches by continuation (capsim --branch-ca) against one case at a time by time
stepping, in one run: cases per second of each, their agreement, and the time of a whole law
group of the paper grid (config/paper.yaml: 9 a/l x 22 Ca_s) with one branch per a/l on
--workers processes of one thread each (issue 22's target: under 2 minutes on 2 cores).

The time-stepping side runs a sample of the same cases (--sample-a a/l values x --sample-ca
Ca_s; `all` for the grid's, so that both sides of the law group are measured), one thread each,
on the same workers. Run after `make build`; prints figures only (the machines are
shared: compare the two columns of one run, not runs of different days).

    python bench/bench_tube_continuation.py [--law NH] [--workers 2] [--n-meridian 64] [--capsim PATH]

--capsim runs another build (e.g. an older kernel kept aside) against the same grid.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import h5py
import yaml

REPO = Path(__file__).resolve().parents[1]
CAPSIM = REPO / "bin" / "capsim"
LAW_FLAGS = {"NH": ["--law", "NH"], "SK_C1": ["--law", "SK", "--C", "1"],
             "GH_nu0.5": ["--law", "GH", "--nu-s", "0.5"], "GH_nu0.2": ["--law", "GH", "--nu-s", "0.2"],
             "GH_nu0": ["--law", "GH", "--nu-s", "0"]}
MEASURES = ("L_z", "L_p", "v_c")


def paper_grid() -> tuple[list[float], list[float]]:
    tube = yaml.safe_load((REPO / "config" / "paper.yaml").read_text())["tube"]
    return tube["a_over_l"], tube["Ca_s"]


def read(path: Path) -> dict:
    with h5py.File(path) as f:
        status = f.attrs["status"]
        out = {"status": status.decode() if isinstance(status, bytes) else str(status)}
        for name in MEASURES:
            out[name] = float(f["steady/" + name][()]) if "steady" in f else float("nan")
        out["message"] = str(f.attrs["message"])
    return out


def cpu_seconds(argv: list[str]) -> float:
    """Run argv; its CPU time [s] (user + system), which the shared machine's load does not
    inflate as it does the wall time."""
    proc = subprocess.Popen(argv)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise subprocess.CalledProcessError(proc.returncode, argv)
    return usage.ru_utime + usage.ru_stime


def run_branch(capsim: Path, law: str, a_over_l: float, cas: list[float], n_meridian: int, root: Path) -> tuple[float, Path]:
    """CPU time [s] of one branch (one thread) and its directory."""
    directory = root / f"branch_{a_over_l:g}"
    directory.mkdir()
    cpu = cpu_seconds([str(capsim), "--flow", "tube", *LAW_FLAGS[law], "--a-over-l", repr(a_over_l),
                       "--n-meridian", str(n_meridian), "--threads", "1", "--quiet",
                       "--branch-ca", ",".join(f"{c:g}" for c in cas), "--branch-summary", str(directory / "branch.h5"),
                       "--out", str(directory / "Ca{ca}.h5")])
    return cpu, directory


def run_single(capsim: Path, law: str, a_over_l: float, ca: float, n_meridian: int, root: Path) -> tuple[float, dict]:
    """CPU time [s] of one time-stepped case and its results."""
    out = root / f"single_{a_over_l:g}_{ca:g}.h5"
    cpu = cpu_seconds([str(capsim), "--flow", "tube", *LAW_FLAGS[law], "--a-over-l", repr(a_over_l), "--ca", repr(ca),
                       "--n-meridian", str(n_meridian), "--threads", "1", "--quiet", "--out", str(out)])
    return cpu, read(out)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--law", default="NH", choices=sorted(LAW_FLAGS))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--n-meridian", type=int, default=64)
    parser.add_argument("--a-values", default="", help="a/l of the branches (default: the paper grid's)")
    parser.add_argument("--sample-a", default="0.7,0.9,1.1", help="a/l of the time-stepped sample ('all': the grid's)")
    parser.add_argument("--sample-ca", default="0.02,0.07,0.15", help="Ca_s of the time-stepped sample ('all': the grid's)")
    parser.add_argument("--capsim", type=Path, default=CAPSIM, help="the kernel to run (default bin/capsim)")
    args = parser.parse_args()
    if not args.capsim.exists():
        print(f"{args.capsim} is missing: run `make build` first", file=sys.stderr)
        return 2
    a_values, ca_values = paper_grid()
    if args.a_values:
        a_values = [float(a) for a in args.a_values.split(",")]
    n_cases = len(a_values) * len(ca_values)
    print(f"law {args.law}, {args.n_meridian} meridian elements, {len(a_values)} a/l x {len(ca_values)} Ca_s = "
          f"{n_cases} cases; {args.workers} workers of one thread ({os.cpu_count()} cores, shared)")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        start = time.perf_counter()
        with ThreadPoolExecutor(args.workers) as pool:
            branches = list(pool.map(lambda a: run_branch(args.capsim, args.law, a, ca_values, args.n_meridian, root), a_values))
        group_wall = time.perf_counter() - start
        branch_cpu = sum(t for t, _ in branches)
        print(f"\ncontinuation: law group in {group_wall:.1f} s wall on {args.workers} workers "
              f"({n_cases / group_wall:.2f} cases/s); {branch_cpu:.1f} CPU s in all "
              f"({n_cases / branch_cpu:.2f} cases per CPU second)")
        print(f"{'a/l':>5} {'CPU [s]':>9} {'steady':>7} {'continued':>9} {'stepped':>8} {'critical Ca_s':>14} kind")
        for a_over_l, (wall, directory) in zip(a_values, branches):
            cases = [read(directory / f"Ca{c:g}.h5") for c in ca_values]
            continued = sum("by continuation" in c["message"] for c in cases)
            stepped = sum("implicit steps" in c["message"] or "Newton residual" in c["message"] for c in cases)
            steady = sum(c["status"] == "steady" for c in cases)
            with h5py.File(directory / "branch.h5") as f:
                kind = f.attrs["critical_kind"]
                kind = kind.decode() if isinstance(kind, bytes) else str(kind)
                critical = float(f.attrs["critical_Ca_s"])
            print(f"{a_over_l:>5g} {wall:>9.1f} {steady:>7} {continued:>9} {stepped:>8} {critical:>14.4g} {kind}")

        sample_a = a_values if args.sample_a == "all" else [float(a) for a in args.sample_a.split(",")]
        sample_ca = ca_values if args.sample_ca == "all" else [float(c) for c in args.sample_ca.split(",")]
        sample = [(a, c) for a in sample_a for c in sample_ca]
        whole = len(sample) == n_cases
        print(f"\ntime stepping, one case at a time ({'the whole group' if whole else f'sample of {len(sample)}'}"
              f" on {args.workers} workers), against the branch's case:")
        print(f"{'a/l':>5} {'Ca_s':>6} {'CPU [s]':>9} {'stepped':>34} {'branch':>34} "
              f"{'max rel diff L_z, L_p, v_c':>27}")
        single_total = 0.0
        worst = 0.0
        start = time.perf_counter()
        with ThreadPoolExecutor(args.workers) as pool:
            singles = list(pool.map(lambda ac: run_single(args.capsim, args.law, ac[0], ac[1], args.n_meridian, root),
                                    sample))
        single_wall = time.perf_counter() - start
        for (a_over_l, ca), (wall, single) in zip(sample, singles):
            single_total += wall
            branch_case = read(root / f"branch_{a_over_l:g}" / f"Ca{ca:g}.h5")
            how = "continued" if "by continuation" in branch_case["message"] else "stepped"
            diff = float("nan")
            if single["status"] == branch_case["status"] == "steady":
                # L_p is 0 for a convex rear: its difference is then taken as absolute.
                diff = max(abs(branch_case[m] - single[m]) / (abs(single[m]) or 1.0) for m in MEASURES)
                if how == "continued":
                    worst = max(worst, diff)
            polish = "polished" if "Newton polish: residual" in single["message"] else "unpolished"
            print(f"{a_over_l:>5g} {ca:>6g} {wall:>9.2f} {single['status'] + ' (' + polish + ')':>34} "
                  f"{branch_case['status'] + ' (' + how + ')':>34} {diff:>27.2e}")
        per_case = single_total / len(sample)
        if whole:
            print(f"\ntime stepping: {1 / per_case:.2f} cases per CPU second ({per_case:.2f} CPU s a case); "
                  f"law group case by case {single_total:.1f} CPU s, {single_wall:.0f} s wall measured")
        else:
            print(f"\ntime stepping: {1 / per_case:.2f} cases per CPU second ({per_case:.2f} CPU s a case); "
                  f"law group extrapolated from {len(sample)} sampled cases to {n_cases * per_case / args.workers:.0f} s "
                  f"on {args.workers} idle cores (not measured: `--sample-a all --sample-ca all` runs the group)")
        print(f"continuation: {n_cases / branch_cpu:.2f} cases per CPU second; law group "
              f"{branch_cpu / args.workers:.0f} s on {args.workers} idle cores (CPU / workers; target 120 s), "
              f"{group_wall:.0f} s wall measured on this machine's load; "
              f"speed-up x{per_case * n_cases / branch_cpu:.1f}")
        print(f"largest relative difference of a continued case from its time-stepped run: {worst:.2e} "
              "(time-stepped shapes whose Newton polish was discarded are ~1e-3 from the root)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
