"""Wall time to steady state of the 3D shear kernel, RK2 against --integrator implicit (issue 2/4).

Runs ``bin/capsim --flow shear --law NH`` at each Ca_s with both integrators, one after the
other, on one thread (``--threads 1``, OPENBLAS_NUM_THREADS=1) under ``nice``, and prints one
table: the steady time, the velocity evaluations (RK2: 2 per step; implicit: counted, plus its
Jacobians and LU factorisations), the wall and CPU time of each, their ratios RK2/implicit and
how far the implicit steady D12 and theta are from RK2's. The times are of a shared machine: the
load average is printed with the table; the CPU time (one thread) suffers less from the load than
the wall time, and only the ratios of one run mean much.

    .venv/bin/python bench/bench_shear_implicit.py [--level 3] [--ca 0.01 0.05 0.2 1] [--capsim bin/capsim]
"""
from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import tempfile
from pathlib import Path

import h5py

from capsmech.io.case import read_case

REPO = Path(__file__).resolve().parents[1]
ONE_THREAD = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


def run_case(capsim: Path, level: int, ca: float, integrator: str, out: Path) -> dict[str, object]:
    """One capsim run; its status, steady time, wall and CPU time and counts."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(["nice", str(capsim), "--flow", "shear", "--law", "NH", "--ca", repr(ca),
                    "--level", str(level), "--integrator", integrator, "--threads", "1", "--quiet",
                    "--out", str(out)], check=True, env=ONE_THREAD)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    case = read_case(out)
    with h5py.File(out) as f:
        wall = float(f.attrs["wall_time_s"])
        dt = float(f.attrs["dt"])
    t_end = float(case.history["t"][-1])
    found = re.search(r"(\d+) velocity evaluations, (\d+) Jacobians, (\d+) factorisations", case.message)
    if found:
        evaluations, jacobians, lus = (int(g) for g in found.groups())
    else:
        evaluations, jacobians, lus = 2 * round(t_end / dt), 0, 0
    steady = case.status == "steady"
    return {"status": case.status, "t": t_end, "wall": wall, "cpu": cpu, "evals": evaluations, "jac": jacobians, "lu": lus,
            "D12": case.steady_value("D12") if steady else float("nan"),
            "theta": case.steady_value("theta") if steady else float("nan")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--level", type=int, default=3)
    parser.add_argument("--ca", type=float, nargs="+", default=[0.01, 0.05, 0.2, 1.0])
    parser.add_argument("--capsim", type=Path, default=REPO / "bin" / "capsim")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for ca in args.ca:
            rk2 = run_case(args.capsim, args.level, ca, "rk2", Path(tmp) / f"rk2_{ca}.h5")
            imp = run_case(args.capsim, args.level, ca, "implicit", Path(tmp) / f"implicit_{ca}.h5")
            rows.append((ca, rk2, imp))
            print(f"  done Ca_s = {ca}: rk2 {rk2['wall']:.1f} s, implicit {imp['wall']:.1f} s (wall)", flush=True)
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the end; "
          f"level {args.level}, NH, --threads 1, nice")
    print("| Ca_s | status (rk2 / implicit) | t_end | RK2 evals | implicit evals (Jacobians, LUs) | "
          "wall s (rk2 / implicit) | wall ratio | CPU s (rk2 / implicit) | CPU ratio | dD12/D12 | dtheta/theta |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for ca, rk2, imp in rows:
        print(f"| {ca:g} | {rk2['status']} / {imp['status']} | {rk2['t']:.2f} / {imp['t']:.2f} | {rk2['evals']} | "
              f"{imp['evals']} ({imp['jac']}, {imp['lu']}) | {rk2['wall']:.1f} / {imp['wall']:.1f} | "
              f"{rk2['wall'] / imp['wall']:.2f} | {rk2['cpu']:.1f} / {imp['cpu']:.1f} | {rk2['cpu'] / imp['cpu']:.2f} | "
              f"{imp['D12'] / rk2['D12'] - 1:+.1e} | "
              f"{imp['theta'] / rk2['theta'] - 1:+.1e} |")


if __name__ == "__main__":
    main()
