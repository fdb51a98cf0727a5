"""Time the batch tube inversion (issue 5: 10^5 capsules, lengths only, under 10 s on 2 cores).

The capsules are drawn uniformly in the NH steady region of the paper database
(tube-paper) in (a/l, ln Ca_s), their lengths linear in the database's Delaunay
triangles, with 2 % Gaussian noise on L_z and L_p. Timed: ``TubeInverter.fit_many`` on all
of them in one process, then split into 2 chunks on 2 processes (ProcessPoolExecutor, forked
after the inverter is built; the pool's start is included), and the scalar reference
``TubeInverter.fit`` on a subsample in the same run, for the speed-up. Prints figures and
ratios measured in this one run; not a test, nothing asserted.

    .venv/bin/python bench/bench_inverse.py [--capsules 100000] [--scalar 500]
"""
from __future__ import annotations

import argparse
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from scipy.interpolate import LinearNDInterpolator

from capsmech.inversion.fitting import tube_inverter
from capsmech.inversion.inverters import TubeInverter
from capsmech.io.catalog import database_path
from capsmech.io.database import load_database

REPO = Path(__file__).resolve().parents[1]
DATABASE = database_path("tube-paper")
LAW = "NH"


def inverter() -> TubeInverter:
    return tube_inverter(load_database(DATABASE), LAW)


def capsules(inv: TubeInverter, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """n noisy (L_z, L_p) [l] in the law's steady region (see the module docstring)."""
    rng = np.random.default_rng(seed)
    p = np.column_stack([inv.table.a_over_l, np.log(inv.table.Ca_s)])
    scale = inv._p_scale
    points = np.empty((0, 2))
    while len(points) < n:
        draw = rng.uniform(p.min(axis=0), p.max(axis=0), size=(2 * n, 2))
        points = np.vstack([points, draw[inv._hull.find_simplex(draw / scale) >= 0]])
    scaled = points[:n] / scale
    l_z = LinearNDInterpolator(inv._hull, inv.table.L_z)(scaled) * (1 + 0.02 * rng.standard_normal(n))
    l_p = LinearNDInterpolator(inv._hull, inv.table.L_p)(scaled) * (1 + 0.02 * rng.standard_normal(n))
    return l_z, l_p


_INVERTER: TubeInverter | None = None


def _fit_chunk(chunk: tuple[np.ndarray, np.ndarray]) -> int:
    """Worker: fit one chunk with the inverter the parent built (forked); the number of valid fits."""
    assert _INVERTER is not None
    return int(_INVERTER.fit_many(*chunk).ok.sum())


def run(n: int, n_scalar: int) -> None:
    global _INVERTER
    inv = _INVERTER = inverter()
    l_z, l_p = capsules(inv, n)
    print(f"machine: {os.cpu_count()} cores; load average {os.getloadavg()[0]:.1f} (shared: timings are noisy)")

    start, cpu = time.perf_counter(), time.process_time()
    for a, b in zip(l_z[:n_scalar], l_p[:n_scalar]):
        inv.fit(float(a), float(b))
    scalar_s = (time.perf_counter() - start) / n_scalar
    scalar_cpu = (time.process_time() - cpu) / n_scalar
    print(f"fit (scalar reference), {n_scalar} capsules: {1e3 * scalar_s:.2f} ms a capsule "
          f"({1e3 * scalar_cpu:.2f} ms CPU), "
          f"{1 / scalar_s:.0f} capsules/s; {n} would take {n * scalar_s:.0f} s")

    start, cpu = time.perf_counter(), time.process_time()
    result = inv.fit_many(l_z, l_p)
    one_s, one_cpu = time.perf_counter() - start, time.process_time() - cpu
    print(f"fit_many, 1 process: {n} capsules in {one_s:.2f} s ({one_cpu:.2f} s CPU), {n / one_s:.0f} capsules/s, "
          f"{int(result.ok.sum())} valid; speed-up against fit {n * scalar_s / one_s:.1f}x")

    children = os.times()
    start = time.perf_counter()
    halves = [(l_z[: n // 2], l_p[: n // 2]), (l_z[n // 2:], l_p[n // 2:])]
    with ProcessPoolExecutor(max_workers=2, mp_context=multiprocessing.get_context("fork")) as pool:
        valid = sum(pool.map(_fit_chunk, halves))
    two_s = time.perf_counter() - start
    after = os.times()
    two_cpu = (after.children_user + after.children_system) - (children.children_user + children.children_system)
    print(f"fit_many, 2 processes: {n} capsules in {two_s:.2f} s ({two_cpu:.2f} s CPU in the workers), "
          f"{n / two_s:.0f} capsules/s, {valid} valid; "
          f"{one_s / two_s:.2f}x the 1-process rate, {n * scalar_s / two_s:.1f}x fit (target: 1e5 < 10 s on 2 cores)")
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--capsules", type=int, default=100_000)
    parser.add_argument("--scalar", type=int, default=500)
    args = parser.parse_args()
    run(args.capsules, args.scalar)
