"""capsim gives the BLAS library its own thread count (kernel module blas_threads).

OpenBLAS starts one thread per core when loaded, whatever --threads says, and its idle
threads spin between calls: a --threads 1 tube branch used 87 CPU s for 46 s of work, and a
workflow running one single-threaded case per core ran twice as many busy threads as cores.
Contract checked here with the probe bin/blas_threads_probe: after the rule, OpenBLAS runs the
kernel's thread count; a user's OPENBLAS_NUM_THREADS is left alone. Skipped where the BLAS
library is not OpenBLAS (the rule then does nothing)."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

PROBE = Path(__file__).resolve().parents[2] / "bin" / "blas_threads_probe"


def probe(*threads: int, env: dict[str, str] | None = None) -> list[tuple[str, ...]]:
    if not PROBE.exists():
        pytest.fail(f"{PROBE} is missing: run `make build` first")
    base = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    out = subprocess.run([str(PROBE), *map(str, threads)], capture_output=True, text=True, check=True,
                         env={**base, **(env or {})}).stdout
    return [tuple(line.split()) for line in out.splitlines()]


def test_openblas_runs_the_kernels_thread_count() -> None:
    lines = probe(1, 3, 1)
    if lines[0] == ("before", "-1"):
        pytest.skip("the BLAS library is not OpenBLAS: capsim leaves its threads alone")
    assert lines[1:] == [("threads", "1", "1"), ("threads", "3", "3"), ("threads", "1", "1")]


def test_a_users_openblas_num_threads_is_honoured() -> None:
    lines = probe(1, env={"OPENBLAS_NUM_THREADS": "2"})
    if lines[0] == ("before", "-1"):
        pytest.skip("the BLAS library is not OpenBLAS")
    assert lines == [("before", "2"), ("threads", "1", "2")]
