"""Time the lengths-only tube inversion of 10^5 capsules: the committed
``tube_batch.fit_batch`` (``git show <rev>:.../tube_batch.py``, loaded as a module of its own,
over the working tree's ``inverters``) against the working tree's
``capsmech.inversion.tube_batch.fit_batch``, each on one thread and on every core, in one
run, so that the ratios hold on a shared machine.

The capsules are those of ``bench_inverse.py`` (uniform in the NH steady region of the paper
database, 2 % noise on the lengths). Prints, for each path, the wall and CPU seconds (the
best of ``--repeats`` runs each, the paths taking turns), the ratios before/after on as many
threads, whether the flags are the same and the largest relative difference of a/l, Ca_s,
v_c/V against the committed one-thread result; nothing asserted. With ``--laws N``, the same
comparison (flags, largest relative differences) for N capsules of each law of the database,
drawn the same way in each law's region, the working tree on every core.
On a loaded machine the wall time of the threaded path says little: its CPU time, and its
wall time against its own one-thread run, do.

    .venv/bin/python bench/bench_lengths_inversion.py [--capsules 100000] [--rev HEAD] [--repeats 2] [--laws 20000]
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_inverse import DATABASE, capsules, inverter  # noqa: E402

from capsmech.inversion.fitting import tube_inverter  # noqa: E402
from capsmech.inversion.inverters import TubeFits  # noqa: E402
from capsmech.inversion.tube_batch import default_workers, fit_batch  # noqa: E402
from capsmech.io.database import load_database  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
MODULE = "analysis/src/capsmech/inversion/tube_batch.py"


def committed_module(rev: str) -> ModuleType:
    """tube_batch.py as committed at rev, imported under a name of its own."""
    source = subprocess.run(["git", "show", f"{rev}:{MODULE}"], cwd=REPO, check=True, capture_output=True,
                            text=True).stdout
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as handle:
        handle.write(source)
    spec = importlib.util.spec_from_file_location("tube_batch_before", handle.name)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    os.unlink(handle.name)
    return module


def timed(run: Callable[[], TubeFits]) -> tuple[TubeFits, float, float]:
    start, cpu = time.perf_counter(), time.process_time()
    result = run()
    return result, time.perf_counter() - start, time.process_time() - cpu


def differences(new: TubeFits, old: TubeFits) -> str:
    with np.errstate(invalid="ignore", divide="ignore"):
        gaps = [np.nanmax(np.abs(getattr(new, k) / getattr(old, k) - 1)) for k in ("a_over_l", "Ca_s", "vc_over_V")]
    return (f"same flags: {old.flag == new.flag}; largest relative difference (a/l, Ca_s, v_c/V): "
            + ", ".join(f"{g:.1e}" for g in gaps))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--capsules", type=int, default=100_000)
    parser.add_argument("--rev", default="HEAD", help="the committed version to compare with")
    parser.add_argument("--repeats", type=int, default=2, help="runs of each path (the best is kept)")
    parser.add_argument("--laws", type=int, default=0, metavar="N",
                        help="also compare the results on N capsules of each law of the database")
    args = parser.parse_args()
    inv = inverter()
    fit_batch_before = committed_module(args.rev).fit_batch
    l_z, l_p = capsules(inv, args.capsules)
    n, workers = len(l_z), default_workers()
    paths: dict[str, Callable[[], TubeFits]] = {
        f"before ({args.rev}), 1 thread": lambda: fit_batch_before(inv, l_z, l_p, workers=1),
        "after, 1 thread": lambda: fit_batch(inv, l_z, l_p, workers=1),
        f"before ({args.rev}), {workers} threads": lambda: fit_batch_before(inv, l_z, l_p, workers=workers),
        f"after, {workers} threads": lambda: fit_batch(inv, l_z, l_p, workers=workers),
    }
    print(f"machine: {os.cpu_count()} cores, {workers} usable; load average {os.getloadavg()[0]:.1f} "
          "(shared: compare ratios)")
    best: dict[str, tuple[float, float]] = {}
    results: dict[str, TubeFits] = {}
    for _ in range(args.repeats):
        for name, run in paths.items():
            results[name], wall, cpu = timed(run)
            previous = best.get(name, (np.inf, np.inf))
            best[name] = (min(wall, previous[0]), min(cpu, previous[1]))
    names = list(paths)
    for name in names:
        wall, cpu = best[name]
        line = f"{name}: {n} capsules in {wall:.2f} s wall, {cpu:.2f} s CPU"
        if name.startswith("after"):
            # Against the committed version on as many threads.
            before = names[names.index(name) - 1]
            line += f"; before/after {best[before][0] / wall:.2f} wall, {best[before][1] / cpu:.2f} CPU"
        print(line)
    print(f"after: 1 thread / {workers} threads, wall {best[names[1]][0] / best[names[3]][0]:.2f}")
    print(f"load average after: {os.getloadavg()[0]:.1f}")
    for name in names[1:]:
        print(f"{name} against {names[0]}: {differences(results[name], results[names[0]])}; "
              f"{int(results[name].ok.sum())} valid")
    if args.laws:
        database = load_database(DATABASE)
        for law in database.laws:
            law_inverter = tube_inverter(database, law)
            l_z, l_p = capsules(law_inverter, args.laws, seed=1)
            before = fit_batch_before(law_inverter, l_z, l_p, workers=1)
            after = fit_batch(law_inverter, l_z, l_p, workers=workers)
            print(f"{law}, {args.laws} capsules, after ({workers} threads) against before (1 thread): "
                  f"{differences(after, before)}; {int(after.ok.sum())} valid")


if __name__ == "__main__":
    main()
