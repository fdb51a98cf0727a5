"""Fixtures that locate and run the kernel executables built by `make build`."""
from __future__ import annotations

import subprocess
from pathlib import Path

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
