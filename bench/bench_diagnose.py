"""CPU seconds of ``capsmech diagnose BATCH --database tube-paper --law NH`` (the command's
defaults: every candidate the shipped databases allow, up to two effects, no simulation) on
14-capsule batches of the project's independent generator, the committed code against the
working tree's in one run, with the largest change of every number of the JSON record.

The batches (``--make``, seed 11, 14 capsules each) are drawn from the independent pool
(``tests/python/independent_batches.py``): NH without an effect, NH with pre-stress 0.045,
NH traced 1 px outside the membrane. Each diagnosis runs in a process of its own whose
``capsmech`` is either the working tree's ``analysis/src`` or a copy of it with the paths of
``--old-paths`` (default: the diagnosis and the contour fits) taken from ``--rev`` (``git
show``, nothing in the repository changed); the two paths take turns at going first, so
that a shared machine's load falls on both alike. CPU seconds are the child's own
(``time.process_time``), the JSON records are compared leaf by leaf: "identical", or each
number's largest change, absolute and against the width of the interval it sits in (a
strength's, a G_s's), nothing asserted.

    .venv/bin/python bench/bench_diagnose.py --make /tmp/diag_batches
    .venv/bin/python bench/bench_diagnose.py /tmp/diag_batches/*.csv [--rev HEAD] [--new-only]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "analysis" / "src"
#: What the old path takes from ``--rev`` (the rest is the working tree's).
OLD_PATHS = ("analysis/src/capsmech/diagnosis", "analysis/src/capsmech/inversion/shape_fit.py",
             "analysis/src/capsmech/inversion/residuals.py")
#: name -> (pool key, draw_batch keywords).
BATCHES = {"nh": ("NH", {}), "prestress": ("NH+prestress0.045", {}), "offset": ("NH", {"contour_offset_px": 1.0})}


def make_batches(folder: Path, capsules: int = 14, seed: int = 11) -> None:
    sys.path.insert(0, str(REPO / "tests" / "python"))
    from independent_batches import draw_batch, load_pool

    pool = load_pool()
    folder.mkdir(parents=True, exist_ok=True)
    for name, (key, keywords) in BATCHES.items():
        drawn = draw_batch(pool, key, folder, name, seed=seed, n=capsules, **keywords)
        print(f"wrote {drawn.csv}")


def old_source(rev: str, paths: list[str], into: Path) -> Path:
    """A copy of the working tree's ``analysis/src`` with ``paths`` as committed at ``rev``."""
    target = into / "src"
    shutil.copytree(SRC, target, ignore=shutil.ignore_patterns("__pycache__"))
    for path in paths:
        inside = Path(path).relative_to("analysis/src")
        listed = subprocess.run(["git", "ls-tree", "-r", "--name-only", rev, path], cwd=REPO, check=True,
                                capture_output=True, text=True).stdout.split()
        if (target / inside).is_dir():
            for stale in (target / inside).glob("*.py"):
                stale.unlink()
        for file in listed:
            text = subprocess.run(["git", "show", f"{rev}:{file}"], cwd=REPO, check=True, capture_output=True,
                                  text=True).stdout
            (target / Path(file).relative_to("analysis/src")).write_text(text)
    return target


CHILD = """
import sys, time
sys.meta_path[:] = [f for f in sys.meta_path if 'editable' not in type(f).__module__]
sys.path.insert(0, sys.argv[1])
import capsmech
assert capsmech.__file__.startswith(sys.argv[1]), capsmech.__file__
from capsmech.cli.main import main
start = time.process_time()
code = main(['diagnose', sys.argv[2], '--database', 'tube-paper', '--law', 'NH', '--json', sys.argv[3], '--force'])
print('CPU_SECONDS', time.process_time() - start, code)
"""


def run_diagnose(src: Path, batch: Path, out: Path) -> float:
    """CPU seconds of one diagnosis in a child process importing capsmech from ``src``."""
    done = subprocess.run([sys.executable, "-c", CHILD, str(src), str(batch), str(out)], cwd=REPO,
                          capture_output=True, text=True, env={**os.environ, "PYTHONWARNINGS": "ignore"})
    line = next((l for l in done.stdout.splitlines() if l.startswith("CPU_SECONDS")), None)
    if done.returncode != 0 or line is None:
        raise RuntimeError(f"diagnose of {batch} failed:\n{done.stdout[-2000:]}\n{done.stderr[-4000:]}")
    return float(line.split()[1])


def _leaves(record, path: str = ""):
    if isinstance(record, dict):
        for key, value in record.items():
            yield from _leaves(value, f"{path}.{key}" if path else key)
    elif isinstance(record, list):
        for k, value in enumerate(record):
            yield from _leaves(value, f"{path}[{k}]")
    else:
        yield path, record


#: The numbers an interval describes (an estimate, the interval's ends, its parts): only these
#: are measured against its width (a chi2 or a p-value beside a strength's interval is not).
INTERVAL_PARTS = ("strength", "value", "interval", "interval_systematic", "systematic", "sd")


def _width_of(record: dict, path: str) -> float:
    """The width of the interval the number at ``path`` belongs to: the ``interval`` beside it
    (or the one it is an end of), NaN when there is none or the number is not one of
    ``INTERVAL_PARTS``."""
    parts = path.replace("]", "").replace("[", ".").split(".")
    named = [part for part in parts if not part.isdigit()]
    if not named or named[-1] not in INTERVAL_PARTS:
        return math.nan
    for cut in range(len(parts), 0, -1):
        node = record
        try:
            for part in parts[:cut]:
                node = node[int(part)] if isinstance(node, list) else node[part]
        except (KeyError, IndexError, ValueError, TypeError):
            continue
        if isinstance(node, dict) and isinstance(node.get("interval"), list) and len(node["interval"]) == 2:
            low, high = node["interval"]
            if isinstance(low, (int, float)) and isinstance(high, (int, float)):
                return abs(float(high) - float(low))
    return math.nan


def compare(old: dict, new: dict) -> list[str]:
    """Lines: the numbers that changed (largest first by the share of their interval's width),
    the other leaves that changed, or "identical"."""
    if old == new:
        return ["identical JSON records"]
    old_leaves, new_leaves = dict(_leaves(old)), dict(_leaves(new))
    numbers, others = [], []
    for path in sorted(set(old_leaves) | set(new_leaves)):
        a, b = old_leaves.get(path, "<absent>"), new_leaves.get(path, "<absent>")
        if a == b:
            continue
        if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
            change = abs(float(b) - float(a))
            width = _width_of(new, path)
            relative = change / max(abs(float(a)), 1e-300)
            numbers.append((change / width if width > 0 else math.nan, path, a, b, change, relative))
        else:
            others.append(f"  changed: {path}: {str(a)[:120]!s} -> {str(b)[:120]!s}")
    numbers.sort(key=lambda n: (-n[0] if math.isfinite(n[0]) else 1.0, -n[5]))
    lines = [f"  {len(numbers)} numbers changed; the largest against their interval's width, then the rest "
             "by relative change:"]
    for share, path, a, b, change, relative in numbers[:25]:
        width = f"{100 * share:.3g} % of its interval's width" if math.isfinite(share) else "no interval"
        lines.append(f"  {path}: {a!r} -> {b!r} (|change| {change:.3g}, relative {relative:.3g}, {width})")
    return lines + others


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("batches", nargs="*", type=Path, help="batch CSV files (with their contours)")
    parser.add_argument("--make", type=Path, metavar="DIR", help="draw the benchmark's batches into DIR and stop")
    parser.add_argument("--rev", default="HEAD", help="revision of the old path (default HEAD)")
    parser.add_argument("--old-paths", nargs="+", default=list(OLD_PATHS),
                        help="paths the old path takes from --rev (default: the diagnosis and the contour fits)")
    parser.add_argument("--new-only", action="store_true", help="time the working tree only")
    parser.add_argument("--keep", type=Path, metavar="DIR", help="keep the JSON records in DIR")
    args = parser.parse_args(argv)
    if args.make:
        make_batches(args.make)
        return 0
    if not args.batches:
        parser.error("no batch given (draw them with --make DIR)")
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} (shared: compare ratios)")
    with tempfile.TemporaryDirectory() as scratch:
        folder = args.keep or Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        old_src = None if args.new_only else old_source(args.rev, args.old_paths, Path(scratch))
        for k, batch in enumerate(args.batches):
            started = time.perf_counter()
            new_json, old_json = folder / f"{batch.stem}_new.json", folder / f"{batch.stem}_old.json"
            if old_src is None:
                print(f"{batch.name}: {run_diagnose(SRC, batch, new_json):.1f} s CPU", flush=True)
                continue
            # (the two paths take turns at going first: a load that changes during a batch
            # falls on both alike over the batches)
            if k % 2 == 0:
                old_cpu = run_diagnose(old_src, batch, old_json)
                new_cpu = run_diagnose(SRC, batch, new_json)
            else:
                new_cpu = run_diagnose(SRC, batch, new_json)
                old_cpu = run_diagnose(old_src, batch, old_json)
            print(f"{batch.name}: {args.rev} {old_cpu:.1f} s CPU -> working tree {new_cpu:.1f} s CPU "
                  f"(x{old_cpu / new_cpu:.2f}; {time.perf_counter() - started:.0f} s wall for both)", flush=True)
            for line in compare(json.loads(old_json.read_text()), json.loads(new_json.read_text())):
                print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
