"""Time the 3D tube model (`--model 3d`): the wall's assembly and LU factorisation, the load
of the cached LU, one membrane velocity evaluation and one RK2 step, at capsule levels 3 and
4 on 1 and 2 OpenMP threads, and where a velocity evaluation spends its time (the membrane's
own single layer, capsule single layer at the wall nodes, the membrane's near-field self
correction, wall solve, wall single layer at the membrane nodes).

Run through `make bench` or directly after `make build`:

    .venv/bin/python bench/bench_tube_3d.py [--wall H_FAR H_CENTRE LENGTH] [--steps N]
        [--repeats N] [--baseline OTHER/bin/tube3d_probe] [--self vertex near full ...]
        [--threads 1 2 ...]

`--self` times the membrane's own single layer's rules in the same run (vertex: the vertex
rule beyond the second ring, `--self-quadrature vertex`; near: that plus the near-field
self correction within 0.5 l, `tube_capsule_t%self_near_field`; full: the 7-point rule on
every triangle, `--self-quadrature full`, the default), alternating case by case, and prints
each rule's time over the vertex rule's when vertex is among them.

`--baseline` times a second build (e.g. a worktree of an earlier commit) in the same run,
alternating the two binaries case by case, and prints this build's time over the
baseline's per column: on a shared machine only such ratios are meaningful. Each figure is
the smallest of `--repeats` runs (the load only ever adds time).

The default wall (0.2 / 0.1 l over 6 l, 2772 nodes) is the one of the level-3 validation;
`--wall 0.14 0.07 10` is the paper's (7138 nodes: a 3.7 GB LU, minutes to factorise).
`--steady` instead times the steady solver (`capsim --integrator newton`, Newton-Krylov) on
the level-3 case to its steady shape, per thread count, and compares it with time stepping
by velocity evaluations: the time-stepped run (RK2, 2 evaluations per step, 1 per record)
reached its steady state at t = 3.25 l/V (docs/validation/kernel-tube.md, "Cost"), so it
needs 2 t / dt + t / 0.05 evaluations; at the CPU seconds per evaluation of the Newton run
(its CPU time over its evaluations, the preconditioner's set-up included) that gives the
time-stepped run's CPU time on this machine now, without running it.

Prints figures only: machines are shared and noisy, so nothing here is a test.
"""
from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PROBE = REPO / "bin" / "tube3d_probe"
SIZE_RATIO, CA = 0.8, 0.05


CAPSIM = REPO / "bin" / "capsim"
# The time-stepped level-3 case (wall 0.2 / 0.1 l over 6 l) reached its steady state at this time (l/V).
STEPPED_T_STEADY, RECORD_EVERY = 3.25, 0.05

SELF_MODES = {"vertex": 0, "near": 1, "full": 2}
TIMED = ("velocity_s", "capsule_self_s", "capsule_at_wall_s", "capsule_self_near_s", "wall_solve_s", "wall_at_capsule_s", "rk2_step_s",
         "velocity_cpu_s")


def run_probe(probe: Path, level: int, threads: int, wall: list[str], cache: Path, steps: int,
              mode: str | None = None) -> dict[str, float]:
    """One probe run (`mode`: the self quadrature, None for the probe's default); its CPU
    time (user + system, all threads) as cpu_s."""
    env = dict(os.environ, OMP_NUM_THREADS=str(threads), OMP_PROC_BIND="close")
    args = [str(probe), "timing", str(level), str(SIZE_RATIO), str(CA), wall[2], wall[0], wall[1], str(cache), str(steps)]
    if mode is not None:
        args.append(str(SELF_MODES[mode]))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    out = subprocess.run(args, env=env, capture_output=True, text=True, check=True).stdout
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    r = {k: float(v) for k, v in (line.split() for line in out.splitlines())}
    r["cpu_s"] = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return r


def measure(probe: Path, level: int, threads: int, wall: list[str], cache: Path, steps: int,
            mode: str | None = None) -> dict[str, float]:
    """The probe's wall-clock figures, and the CPU time of one velocity evaluation: the CPU
    time of a run with `steps` RK2 steps less that of a run with none, over 2 x steps
    evaluations. CPU time is what a loaded machine disturbs least (no waiting for a core)."""
    r = run_probe(probe, level, threads, wall, cache, steps, mode)
    r["velocity_cpu_s"] = (r["cpu_s"] - run_probe(probe, level, threads, wall, cache, 0, mode)["cpu_s"]) / (2 * steps)
    return r


def fastest(runs: list[dict[str, float]]) -> dict[str, float]:
    """The first run's record with each timed figure replaced by its minimum over the runs."""
    best = dict(runs[0])
    for key in TIMED:
        # A build from before the membrane's near-field self correction has no such figure.
        best[key] = min(r.get(key, 0.0) for r in runs)
    return best


def steady_newton(threads: int, wall: list[str], cache: Path, out: Path) -> dict[str, float]:
    """One `capsim --integrator newton` run of the level-3 case: its wall and CPU seconds,
    the solver's counts, the steady measures and the automatic time step."""
    import h5py

    args = [str(CAPSIM), "--flow", "tube", "--model", "3d", "--integrator", "newton", "--law", "NH",
            "--a-over-l", str(SIZE_RATIO), "--ca", str(CA), "--level", "3", "--wall-h-far", wall[0],
            "--wall-h-centre", wall[1], "--tube-length", wall[2], "--wall-cache", str(cache),
            "--threads", str(threads), "--out", str(out)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    stdout = subprocess.run(args, capture_output=True, text=True, check=True).stdout
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    dt = float(stdout.split("dt =")[1].split(",")[0])
    with h5py.File(out) as f:
        r = {k: float(f.attrs[k]) for k in ("wall_time_s", "velocity_evaluations", "newton_iterations",
                                             "gmres_products", "newton_residual", "growth_rate", "stable")}
        r.update({k: float(f["steady"][k][()]) for k in ("L_z", "L_p", "v_c")})
    r["cpu_s"] = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    r["dt"] = dt
    return r


def bench_steady(wall: list[str], thread_counts: list[int]) -> int:
    """Newton-Krylov on the level-3 case against time stepping, by velocity evaluations."""
    if not CAPSIM.exists() or not PROBE.exists():
        print(f"{CAPSIM} or {PROBE} is missing: run `make build` first", file=sys.stderr)
        return 2
    print(f"3D steady solver, level 3, NH a/l = {SIZE_RATIO}, Ca_s = {CA}, wall h {wall[0]} / {wall[1]} l over "
          f"{wall[2]} l; {os.cpu_count() or 1} cores, load {os.getloadavg()[0]:.1f}")
    print(f"{'threads':>7} {'wall [s]':>9} {'CPU [s]':>8} {'evals':>6} {'Newton':>7} {'GMRES':>6} {'residual':>9} "
          f"{'growth':>8} {'L_z':>7} {'L_p':>7} {'v_c':>7} {'stepping evals':>15} {'stepping CPU [s]':>17} {'load':>5}")
    with tempfile.TemporaryDirectory() as tmp:
        cache = Path(tmp)
        # The wall LU first (the probe writes it), so that the timed runs load it from the cache.
        run_probe(PROBE, 3, 1, wall, cache, 0)
        for threads in thread_counts:
            r = steady_newton(threads, wall, cache, Path(tmp) / f"steady{threads}.h5")
            stepped = 2 * STEPPED_T_STEADY / r["dt"] + STEPPED_T_STEADY / RECORD_EVERY
            per_eval = r["cpu_s"] / r["velocity_evaluations"]
            print(f"{threads:>7} {r['wall_time_s']:>9.1f} {r['cpu_s']:>8.1f} {int(r['velocity_evaluations']):>6} "
                  f"{int(r['newton_iterations']):>7} {int(r['gmres_products']):>6} {r['newton_residual']:>9.1e} "
                  f"{r['growth_rate']:>8.1e} {r['L_z']:>7.4f} {r['L_p']:>7.4f} {r['v_c']:>7.4f} {stepped:>15.0f} "
                  f"{stepped * per_eval:>17.0f} {os.getloadavg()[0]:>5.1f}")
    print("wall, CPU: the case's (wall LU loaded from the cache); stepping: the time-stepped run's evaluations "
          "to t = 3.25 and their CPU time at this run's CPU seconds per evaluation")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--wall", nargs=3, default=["0.2", "0.1", "6"], metavar=("H_FAR", "H_CENTRE", "LENGTH"))
    parser.add_argument("--steps", type=int, default=3, help="RK2 steps timed per case (at least 1)")
    parser.add_argument("--repeats", type=int, default=1, help="runs per case; the fastest is reported")
    parser.add_argument("--baseline", type=Path, help="a tube3d_probe of another build, timed alternately")
    parser.add_argument("--self", nargs="+", choices=sorted(SELF_MODES), default=None,
                        help="self quadratures to time in this run (default: the model's default only)")
    parser.add_argument("--threads", nargs="+", type=int, default=[1, 2], help="OpenMP thread counts")
    parser.add_argument("--steady", action="store_true", help="time the steady solver (Newton-Krylov) instead")
    args = parser.parse_args()
    if args.steady:
        return bench_steady(args.wall, args.threads)
    if not PROBE.exists():
        print(f"{PROBE} is missing: run `make build` first", file=sys.stderr)
        return 2
    if args.baseline is not None and not args.baseline.exists():
        print(f"{args.baseline} is missing", file=sys.stderr)
        return 2
    print(f"3D tube model, NH a/l = {SIZE_RATIO}, Ca_s = {CA}, wall h {args.wall[0]} / {args.wall[1]} l over "
          f"{args.wall[2]} l; {os.cpu_count() or 1} cores on this machine, load {os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory() as tmp:
        cache = Path(tmp)
        # The wall LU first, so that every timed run loads it from the cache.
        w = run_probe(PROBE, 3, 1, args.wall, cache, 0)
        print(f"wall of {int(w['n_wall_nodes'])} nodes: assembly {w['wall_assembly_s']:.2f} s, "
              f"LU {w['wall_factor_s']:.2f} s (1 thread), written to the cache")
        modes = args.self if args.self is not None else [None]
        print(f"{'level':>5} {'nodes':>6} {'threads':>7} {'self':>6} {'wall setup [s]':>15} {'velocity [s]':>13} "
              f"{'own SL':>7} {'caps->wall':>11} {'caps self':>10} {'solve':>7} {'wall->caps':>11} {'RK2 step [s]':>13} "
              f"{'velocity CPU [s]':>17}")
        ratios, mode_ratios = [], []
        for level in (3, 4):
            for threads in args.threads:
                mode_runs: dict[str | None, list[dict[str, float]]] = {m: [] for m in modes}
                base_runs = []
                for _ in range(args.repeats):
                    for m in modes:
                        mode_runs[m].append(measure(PROBE, level, threads, args.wall, cache, args.steps, m))
                    if args.baseline is not None:
                        base_runs.append(measure(args.baseline, level, threads, args.wall, cache, args.steps))
                best = {m: fastest(runs) for m, runs in mode_runs.items()}
                for m, r in best.items():
                    setup = f"{r['wall_setup_s']:.2f} (cache)" if r["from_cache"] else f"{r['wall_setup_s']:.2f}"
                    print(f"{level:>5} {int(r['n_nodes']):>6} {threads:>7} {m or 'dflt':>6} {setup:>15} "
                          f"{r['velocity_s']:>13.3f} {r['capsule_self_s']:>7.3f} "
                          f"{r['capsule_at_wall_s']:>11.3f} {r['capsule_self_near_s']:>10.3f} {r['wall_solve_s']:>7.3f} "
                          f"{r['wall_at_capsule_s']:>11.3f} "
                          f"{r['rk2_step_s']:>13.3f} {r['velocity_cpu_s']:>17.3f}")
                if "vertex" in best:
                    v = best["vertex"]
                    for m, r in best.items():
                        if m != "vertex":
                            mode_ratios.append((level, threads, m, {k: r[k] / v[k] for k in TIMED if v[k] > 0}))
                r = best[modes[0]]
                if base_runs:
                    b = fastest(base_runs)
                    print(f"{'':>5} {'':>6} {'base':>7} {'':>6} {'':>15} {b['velocity_s']:>13.3f} "
                          f"{b.get('capsule_self_s', 0.0):>7.3f} {b['capsule_at_wall_s']:>11.3f} "
                          f"{b['capsule_self_near_s']:>10.3f} {b['wall_solve_s']:>7.3f} {b['wall_at_capsule_s']:>11.3f} "
                          f"{b['rk2_step_s']:>13.3f} {b['velocity_cpu_s']:>17.3f}")
                    ratios.append((level, threads, {k: r[k] / b[k] for k in TIMED if b[k] > 0}))
        print("velocity CPU: CPU seconds (all threads) of one evaluation, from runs with and without RK2 steps; "
              "own SL: the membrane's own single layer (vertex, near: single_layer; full: self_single_layer)")
        if mode_ratios:
            print("self quadrature / vertex rule (same run, fastest of each):")
            print(f"{'level':>5} {'threads':>7} {'self':>6} {'velocity':>9} {'RK2 step':>9} {'velocity CPU':>13}")
            for level, threads, m, q in mode_ratios:
                print(f"{level:>5} {threads:>7} {m:>6} {q['velocity_s']:>9.2f} {q['rk2_step_s']:>9.2f} "
                      f"{q['velocity_cpu_s']:>13.2f}")
        if ratios:
            print("this build / baseline (same run, fastest of each):")
            print(f"{'level':>5} {'threads':>7} {'velocity':>9} {'caps->wall':>11} {'wall->caps':>11} {'RK2 step':>9} "
                  f"{'velocity CPU':>13}")
            for level, threads, q in ratios:
                print(f"{level:>5} {threads:>7} {q['velocity_s']:>9.2f} {q['capsule_at_wall_s']:>11.2f} "
                      f"{q['wall_at_capsule_s']:>11.2f} {q['rk2_step_s']:>9.2f} {q['velocity_cpu_s']:>13.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
