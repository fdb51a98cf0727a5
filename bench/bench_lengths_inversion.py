"""Time the lengths-only tube inversion of 10^5 capsules: ``TubeInverter.fit_many`` of the
working tree against the committed one (``git show <rev>:.../inverters.py``, loaded as a
module of its own), in one run, so that the ratio holds on a shared machine.

The capsules are those of ``bench_inverse.py`` (uniform in the NH steady region of the paper
database, 2 % noise on the lengths). Prints the times (wall and CPU; the before side is the
best of two runs), the ratio before/after, whether the flags are the same and the largest
relative difference of a/l, Ca_s, v_c/V; nothing asserted.

    .venv/bin/python bench/bench_lengths_inversion.py [--capsules 100000] [--rev HEAD]
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_inverse import capsules, inverter  # noqa: E402

from capsmech.inversion.inverters import TubeFits, TubeInverter  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
MODULE = "analysis/src/capsmech/inversion/inverters.py"


def committed_module(rev: str) -> ModuleType:
    """inverters.py as committed at rev, imported under a name of its own."""
    source = subprocess.run(["git", "show", f"{rev}:{MODULE}"], cwd=REPO, check=True, capture_output=True,
                            text=True).stdout
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as handle:
        handle.write(source)
    spec = importlib.util.spec_from_file_location("inverters_before", handle.name)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    os.unlink(handle.name)
    return module


def timed(inv: TubeInverter, l_z: np.ndarray, l_p: np.ndarray) -> tuple[TubeFits, float, float]:
    start, cpu = time.perf_counter(), time.process_time()
    result = inv.fit_many(l_z, l_p)
    return result, time.perf_counter() - start, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--capsules", type=int, default=100_000)
    parser.add_argument("--rev", default="HEAD", help="the committed version to compare with")
    args = parser.parse_args()
    new_inv = inverter()
    old_inv = committed_module(args.rev).TubeInverter(new_inv.table)
    l_z, l_p = capsules(new_inv, args.capsules)
    n = len(l_z)
    print(f"machine: {os.cpu_count()} cores; load average {os.getloadavg()[0]:.1f} (shared: compare ratios)")
    old, old_wall, old_cpu = timed(old_inv, l_z, l_p)
    new, new_wall, new_cpu = timed(new_inv, l_z, l_p)
    _, old_wall2, old_cpu2 = timed(old_inv, l_z, l_p)
    old_wall, old_cpu = min(old_wall, old_wall2), min(old_cpu, old_cpu2)
    print(f"before ({args.rev}): {n} capsules in {old_wall:.2f} s wall, {old_cpu:.2f} s CPU")
    print(f"after (working tree): {n} capsules in {new_wall:.2f} s wall, {new_cpu:.2f} s CPU")
    print(f"ratio before/after: {old_wall / new_wall:.2f} wall, {old_cpu / new_cpu:.2f} CPU")
    with np.errstate(invalid="ignore", divide="ignore"):
        gaps = [np.nanmax(np.abs(getattr(new, k) / getattr(old, k) - 1)) for k in ("a_over_l", "Ca_s", "vc_over_V")]
    print(f"same flags: {old.flag == new.flag}; largest relative difference (a/l, Ca_s, v_c/V): "
          + ", ".join(f"{g:.1e}" for g in gaps) + f"; {int(new.ok.sum())} valid")


if __name__ == "__main__":
    main()
