"""Fixtures that locate and run the kernel executables built by `make build`."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]


def _executable(name: str) -> Path:
    path = REPO / "bin" / name
    if not path.exists():
        pytest.fail(f"{path} is missing: run `make build` in {REPO} first")
    return path


def run_probe(*args: object) -> dict[str, float]:
    """Run `bin/kernel_probe ARGS` and parse its "key value" lines."""
    result = subprocess.run(
        [str(_executable("kernel_probe")), *map(str, args)],
        capture_output=True, text=True, check=True,
    )
    values: dict[str, float] = {}
    for line in result.stdout.splitlines():
        key, value = line.split()
        values[key] = float(value)
    return values


def run_keyed_probe(name: str, *args: object, check: bool = True, timeout: float = 120) -> dict[str, float | str]:
    """Run ``bin/NAME ARGS`` and parse its "key value" lines (numbers as float, other values as
    text), with its exit status and stderr under "returncode" and "stderr"; ``check``: a
    non-zero exit fails the test with the probe's output."""
    result = subprocess.run([str(_executable(name)), *map(str, args)], capture_output=True, text=True,
                            check=False, timeout=timeout)
    if check and result.returncode != 0:
        pytest.fail(f"{name} {args} failed ({result.returncode}):\n{result.stdout}\n{result.stderr}")
    values: dict[str, float | str] = {"returncode": result.returncode, "stderr": result.stderr}
    for line in result.stdout.splitlines():
        key, _, value = line.strip().partition(" ")
        value = value.strip()
        try:
            values[key] = float(value)
        except ValueError:
            values[key] = value
    return values


def axi(*args: object) -> dict[str, float]:
    """Run `bin/axi_probe ARGS` on one thread and parse its "key value" lines; repr() keeps
    all 17 digits of a float, so the probe sees exactly the caller's point."""
    result = subprocess.run([str(_executable("axi_probe")), *(repr(a) if isinstance(a, float) else str(a) for a in args)],
                            capture_output=True, text=True, check=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    return {key: float(value) for key, value in (line.split() for line in result.stdout.splitlines())}


def run_quiet(capsim: Path, out: Path, *args: object, timeout: float = 1800) -> Path:
    """Run capsim with ARGS, quietly, on one thread, writing ``out``; return ``out``."""
    subprocess.run([str(capsim), *map(str, args), "--threads", "1", "--quiet", "--out", str(out)],
                   check=True, timeout=timeout)
    return out


def datasets(path: Path) -> dict[str, object]:
    """Every dataset of an HDF5 file by name (for bit-for-bit comparisons of case files)."""
    found: dict[str, object] = {}
    with h5py.File(path) as f:
        f.visititems(lambda name, obj: found.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None)
    return found


#: Short runs of both flows for the "neutral value of an effect = base model" checks.
NEUTRAL_FLOW_ARGS = [("--flow", "shear", "--ca", 0.2, "--level", 2, "--t-max", 0.5),
                     ("--flow", "tube", "--a-over-l", 0.6, "--ca", 0.1)]


def assert_neutral_effect_is_base(capsim: Path, tmp_path: Path, flow_args: tuple, flag: str, attr: str) -> None:
    """The effect ``flag`` at 0 gives every dataset of the base model's case file bit for bit,
    and the file records the attribute ``attr`` = 0."""
    base = datasets(run_quiet(capsim, tmp_path / "base.h5", "--law", "NH", *flow_args))
    zero = datasets(run_quiet(capsim, tmp_path / "zero.h5", "--law", "NH", *flow_args, flag, 0))
    assert base.keys() == zero.keys()
    for name in base:
        assert np.array_equal(base[name], zero[name]), name
    with h5py.File(tmp_path / "zero.h5") as f:
        assert f.attrs[attr] == 0.0


@pytest.fixture(scope="session")
def probe():
    return run_probe


@pytest.fixture(scope="session")
def capsim() -> Path:
    return _executable("capsim")


def assert_usage_error(capsim: Path, base: dict[str, str], override: list[str], field: str, out: Path) -> None:
    """Run capsim with `base` options updated by `override` (flag, value pairs) and assert the
    edge behaviour for bad input: exit code 2, one stderr line naming `field`, no output file."""
    args = dict(base)
    args.update(dict(zip(override[::2], override[1::2])))
    argv = [str(capsim)] + [a for kv in args.items() for a in kv]
    result = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("capsim: error: " + field), result.stderr
    assert not out.exists()


def run_killed_and_resumed(capsim: Path, args: list[str], out: Path, timeout: float = 600) -> str:
    """Start capsim ARGS --out OUT with frequent checkpoints, SIGKILL it once a checkpoint
    exists, check that nothing half-written is left, run it again and return its stdout
    (which must report the resume). `args` ends with --quiet, dropped for the second run.

    Also checks the case's wall time: the checkpoint's last field is the wall time spent so
    far (positive, at most the time the killed run lived), and the resumed file's
    ``wall_time_s`` is that plus the second run's own, not the second run's alone."""
    import signal
    import struct
    import time

    import h5py

    checkpoint = Path(str(out) + ".ckpt")
    started = time.perf_counter()
    proc = subprocess.Popen([str(capsim), *args, "--checkpoint-every", "0.2", "--out", str(out)])
    deadline = time.time() + 60
    while not checkpoint.exists() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    time.sleep(0.3)
    assert proc.poll() is None, "run finished before it could be killed: make the case longer"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    first_lived = time.perf_counter() - started
    assert not out.exists() and checkpoint.exists()      # nothing half-written
    (spent_before,) = struct.unpack("<d", checkpoint.read_bytes()[-8:])
    assert 0.0 < spent_before <= first_lived
    started = time.perf_counter()
    result = subprocess.run([str(capsim), *args[:-1], "--out", str(out)],
                            capture_output=True, text=True, check=True, timeout=timeout)
    second_lived = time.perf_counter() - started
    assert "resumed from checkpoint" in result.stdout
    assert not checkpoint.exists()
    with h5py.File(out, "r") as f:
        wall_time = float(f.attrs["wall_time_s"])
    assert spent_before < wall_time <= spent_before + second_lived
    return result.stdout


def uninterrupted_and_resumed(capsim: Path, args: list[str], tmp_path: Path, timeout: float = 600):
    """Run capsim ARGS once to the end and once killed and resumed (run_killed_and_resumed);
    return both case files read (``capsmech.io.case.read_case``): (uninterrupted, resumed)."""
    from capsmech.io.case import read_case

    reference = tmp_path / "ref.h5"
    subprocess.run([str(capsim), *args, "--out", str(reference)], check=True, timeout=timeout)
    resumed = tmp_path / "resumed.h5"
    run_killed_and_resumed(capsim, args, resumed)
    return read_case(reference), read_case(resumed)


def cached_capsim(capsim: Path, root: Path, *fixed: str, timeout: float = 900, env: dict | None = None):
    """A function that runs ``capsim FIXED... ARGS... --quiet --out FILE`` once per distinct
    ARGS (later calls return the same file) and returns the case file's path."""
    cache: dict[tuple[str, ...], Path] = {}

    def run(*args: str) -> Path:
        key = tuple(args)
        if key not in cache:
            out = root / f"case{len(cache)}.h5"
            subprocess.run([str(capsim), *fixed, *args, "--quiet", "--out", str(out)], check=True, timeout=timeout,
                           env=env)
            cache[key] = out
        return cache[key]

    return run


def run_killed_repeatedly(capsim: Path, args: list[str], out: Path, kills: int, seed: int,
                          within: float, timeout: float = 600) -> str:
    """Run capsim ARGS --out OUT with checkpoints every 0.1 s, SIGKILL it ``kills`` times (the
    first run once its first checkpoint exists, each at a random moment up to ``within``
    seconds later; every later run resumes from the last checkpoint), then let it finish and
    return the last run's stdout, which must report the resume. `args` ends with --quiet,
    dropped for the last run. ``within`` must leave the case unfinished at every kill: the
    caller takes a fraction of the uninterrupted run's wall time, divided among the kills."""
    import random
    import signal
    import time

    rng = random.Random(seed)
    checkpoint = Path(str(out) + ".ckpt")
    for kill in range(kills):
        proc = subprocess.Popen([str(capsim), *args, "--checkpoint-every", "0.1", "--out", str(out)])
        deadline = time.time() + 120
        while not checkpoint.exists() and time.time() < deadline and proc.poll() is None:
            time.sleep(0.02)
        time.sleep(rng.uniform(0.05, within))
        assert proc.poll() is None, f"the run finished before kill {kill + 1}: make the case longer"
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        assert not out.exists() and checkpoint.exists()      # nothing half-written
    result = subprocess.run([str(capsim), *args[:-1], "--checkpoint-every", "0.1", "--out", str(out)],
                            capture_output=True, text=True, check=True, timeout=timeout)
    assert "resumed from checkpoint" in result.stdout
    assert not checkpoint.exists()
    return result.stdout


def assert_same_case_file(reference: Path, other: Path) -> None:
    """Every dataset bit for bit, and every attribute equal but those of the run's own
    circumstances: wall times and whether the 3D wall's LU came from the cache."""
    own = {"wall_time_s", "wall_setup_s", "wall_from_cache"}
    a, b = datasets(reference), datasets(other)
    assert a.keys() == b.keys()
    for name in a:
        assert np.array_equal(a[name], b[name]), f"{name} differs"
    with h5py.File(reference) as f, h5py.File(other) as g:
        keys = set(f.attrs) - own
        assert keys == set(g.attrs) - own
        for key in keys:
            assert np.array_equal(f.attrs[key], g.attrs[key]), f"attribute {key}: {f.attrs[key]!r} != {g.attrs[key]!r}"
