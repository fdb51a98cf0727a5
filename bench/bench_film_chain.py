"""Time the film chain: 12 capillary films -> ``capsmech extract`` -> one batch -> ``fit-tube`` -> ``population``.

The front end's target: 12 films to the population's verdict in under 60 s on 2 cores. The films
are drawn (not timed) by the tests' own generator, apart from the package's renderer
(tests/python/capillary_films.py: the independent pool's steady NH capsules in a glass capillary
of radius 30 um at 0.5 um a pixel, 480 x 160 px, 22 frames each; thin and thick wall bands,
tilt, illumination gradient, dirt and noise as tests/python/test_film_chain.py draws them). The
timed part is what a user runs: ``extract`` on each film (pixel size, frame rate, viscosity),
the measurement files put together, ``fit-tube --law NH --law GH_nu0.5 --law SK_C1`` and
``population --json``, each through the command line in this process.

It prints each stage's wall and CPU seconds (this process and its children: the CPU time is
what the stages cost on a machine shared with other work, where the wall clock is not), the
verdict (law and G_s interval, truth 0.04 N/m), and the ratio to the target of the time on 2
cores, estimated from the CPU: the films are independent (two ``extract`` processes share them),
the fit and the population follow on the batch: extract CPU / 2 + fit and population CPU.

    .venv/bin/python bench/bench_film_chain.py [--films 12]
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "python"))

from capillary_films import PIXEL_SIZE_UM, film_batch, passage, pool_capsules  # noqa: E402
from glass_walls import Glass  # noqa: E402

from capsmech.cli.main import main  # noqa: E402

TARGET_S = 60.0
CORES = 2
LAWS = ["NH", "GH_nu0.5", "SK_C1"]
TEST_CAPSULES = [1, 7, 9, 10, 11, 14, 19, 20, 22, 12, 23]


def films(count: int, seed: int = 40) -> list[tuple[int, Glass, bool]]:
    """``count`` films as the film-chain test draws its batch (``capillary_films.film_batch``):
    pool capsules taken in turn, every third film a thick (15 px) band, the others thin bands."""
    # The film-chain test's capsules (its batch and its held-out pair) first, then the pool's others.
    pool = [c.index for c in pool_capsules("NH")]
    return film_batch((TEST_CAPSULES + [i for i in pool if i not in TEST_CAPSULES])[:count], seed)


def _cpu() -> float:
    """CPU seconds of this process and its finished children."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def _run(argv: list[str], may_fail: bool = False) -> bool:
    """The command line as a user runs it; False where it measured nothing (``may_fail``)."""
    with contextlib.redirect_stdout(io.StringIO()) as printed, contextlib.redirect_stderr(io.StringIO()) as said:
        code = main(argv)
    if code != 0 and not may_fail:
        raise SystemExit(f"capsmech {argv[0]} exited {code}:\n{printed.getvalue()}{said.getvalue()}")
    return code == 0


def chain(count: int) -> None:
    import pandas as pd
    import tifffile

    capsules = {c.index: c for c in pool_capsules("NH")}
    start = time.perf_counter()
    drawn = [(n, passage(capsules[index], glass, seed=100 + n, flip=flip))
             for n, (index, glass, flip) in enumerate(films(count))]
    draw_s = time.perf_counter() - start
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for n, film in drawn:
            tifffile.imwrite(folder / f"film{n}.tif", film.frames)
        stages: dict[str, tuple[float, float]] = {}
        wall, cpu = time.perf_counter(), _cpu()
        written = [n for n, film in drawn
                   if _run(["extract", str(folder / f"film{n}.tif"), "--pixel-size", f"{PIXEL_SIZE_UM}um",
                            "--frame-rate", str(film.frame_rate), "--mu", "1", "--id", f"film{n}", "--out",
                            str(folder / f"film{n}.csv")], may_fail=True)]
        measured = pd.concat([pd.read_csv(folder / f"film{n}.csv", comment="#") for n in written])
        measured.to_csv(folder / "batch.csv", index=False)
        stages["extract"] = (time.perf_counter() - wall, _cpu() - cpu)
        wall, cpu = time.perf_counter(), _cpu()
        _run(["fit-tube", str(folder / "batch.csv"), *[a for law in LAWS for a in ("--law", law)],
              "--out", str(folder / "results.csv")])
        stages["fit-tube"] = (time.perf_counter() - wall, _cpu() - cpu)
        wall, cpu = time.perf_counter(), _cpu()
        _run(["population", str(folder / "results.csv"), "--json", str(folder / "population.json")])
        stages["population"] = (time.perf_counter() - wall, _cpu() - cpu)
        verdict = json.loads((folder / "population.json").read_text())
    frames = sum(len(film.frames) for _, film in drawn)
    print(f"machine: {os.cpu_count()} cores; load average {os.getloadavg()[0]:.1f}")
    print(f"drew {count} films ({frames} frames of {drawn[0][1].frames.shape[2]}x{drawn[0][1].frames.shape[1]} px) "
          f"in {draw_s:.1f} s (not timed); {len(measured)} capsules measured"
          + (f" (films {', '.join(str(n) for n, _ in drawn if n not in written)}: nothing measured)"
             if len(written) < len(drawn) else ""))
    for name, (w, c) in stages.items():
        print(f"  {name:<11} {w:6.2f} s wall, {c:6.2f} s CPU")
    total_wall = sum(w for w, _ in stages.values())
    total_cpu = sum(c for _, c in stages.values())
    on_cores = stages["extract"][1] / CORES + stages["fit-tube"][1] + stages["population"][1]
    print(f"  total       {total_wall:6.2f} s wall, {total_cpu:6.2f} s CPU ({1e3 * stages['extract'][1] / frames:.1f} ms "
          f"of extract CPU a frame)")
    print(f"on {CORES} cores (the films split over two extract processes): ~{on_cores:.1f} s; target {TARGET_S:.0f} s: "
          f"ratio {TARGET_S / on_cores:.2f} (above 1: met)")
    print(f"verdict: {_verdict_line(verdict)}")


def _verdict_line(verdict: dict) -> str:
    """The population's verdict in one line: the law named and its G_s interval, or the reason."""
    if verdict.get("verdict") == "law":
        low, high = verdict["G_s_interval"]
        return f"law {verdict['law']}, G_s in [{low:.4f}, {high:.4f}] N/m (truth 0.04)"
    return f"{verdict.get('verdict')}: {verdict.get('reason', '')}"


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--films", type=int, default=12)
    chain(parser.parse_args().films)
