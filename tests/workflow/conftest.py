"""Run the Snakemake workflow on the smoke grid in temporary working directories.

Every run uses ``--directory TMP``: the grid's relative paths (results_dir, databases_dir)
land below TMP, never in the repository's data/ or results/.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SNAKEFILE = REPO / "workflow" / "Snakefile"
SMOKE = REPO / "config" / "smoke.yaml"
LOCAL_PROFILE = REPO / "workflow" / "profiles" / "local"


def snakemake_argv(workdir: Path, configfile: Path = SMOKE, *extra: str) -> list[str]:
    """Return the command line of a workflow run on ``configfile`` in ``workdir``."""
    return [sys.executable, "-m", "snakemake", "-s", str(SNAKEFILE), "--configfile", str(configfile),
            "--profile", str(LOCAL_PROFILE), "--directory", str(workdir), *extra]


def run_snakemake(workdir: Path, configfile: Path = SMOKE, *extra: str,
                  timeout: float = 300) -> subprocess.CompletedProcess[str]:
    """Run the workflow to completion; stdout and stderr together in ``.stdout``."""
    workdir.mkdir(parents=True, exist_ok=True)
    return subprocess.run(snakemake_argv(workdir, configfile, *extra), cwd=workdir, text=True,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=timeout)


def run_grid_databases(workdir: Path, grid: dict) -> Path:
    """Write ``grid`` as ``workdir/grid.yaml`` and run the workflow's databases there (asserting
    it succeeds): the working directory."""
    import yaml

    config = workdir / "grid.yaml"
    config.write_text(yaml.safe_dump(grid))
    result = run_snakemake(workdir, config, "databases")
    assert result.returncode == 0, result.stdout[-4000:]
    return workdir


@pytest.fixture(scope="session")
def smoke_run(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The smoke grid run once, uninterrupted: its working directory and wall time."""
    if not (REPO / "bin" / "capsim").exists():
        pytest.fail(f"{REPO / 'bin' / 'capsim'} is missing: run `make build` first")
    workdir = tmp_path_factory.mktemp("smoke")
    started = time.monotonic()
    result = run_snakemake(workdir)
    elapsed = time.monotonic() - started
    assert result.returncode == 0, result.stdout[-4000:]
    return {"workdir": workdir, "seconds": elapsed, "output": result.stdout}


def assert_same_database(a: Path, b: Path, rtol: float = 0.0) -> None:
    """Two databases equal value for value (``rtol`` 0: bit for bit; NaN equals NaN): the same
    laws, provenance (creation date aside), statuses and messages, every column (wall times
    aside) and profile."""
    import numpy as np

    from capsmech.io.database import load_database

    da, db = load_database(a), load_database(b)
    assert list(da.laws) == list(db.laws)
    assert {k: v for k, v in da.provenance.items() if k != "created"} == \
        {k: v for k, v in db.provenance.items() if k != "created"}
    for key, ta in da.laws.items():
        tb = db.law(key)
        assert list(ta.status) == list(tb.status) and list(ta.message) == list(tb.message)
        for name in ta.columns:
            if name != "wall_time_s":
                np.testing.assert_allclose(ta.columns[name], tb.columns[name], rtol=rtol, atol=rtol,
                                           err_msg=f"{key} {name}")
        for name in ta.profiles:
            np.testing.assert_allclose(ta.profiles[name], tb.profiles[name], rtol=rtol, atol=rtol,
                                       err_msg=f"{key} {name}")
