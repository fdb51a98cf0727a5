"""Static checks at zero (issue 21, item 8): ruff on all the Python, mypy on the package,
Snakemake's linter and snakefmt on the workflow.

Each tool runs from the test's environment (``python -m ruff`` / ``python -m mypy``;
``snakemake`` and ``snakefmt`` from the bin folder beside that Python), from the repository
root, and must exit 0; its output is shown when it does not. A tool that is not installed
skips its test (``pip install -r requirements.txt`` installs them all). The settings:
ruff.toml (ruff) and analysis/pyproject.toml [tool.mypy] (mypy).
"""
from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: What ruff checks: the package, the tests, the scripts, the benchmarks, the docs' hooks.
RUFF_PATHS = ["analysis/src", "tests", "scripts", "bench", "docs/hooks"]
#: Not resolved: a virtual environment's python is a link, its bin folder the one beside the link.
BIN = Path(sys.executable).parent


def run(argv: list[str], timeout: float = 300) -> None:
    """Run a check from the repository root; fail with its output unless it exits 0."""
    proc = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        pytest.fail(f"{' '.join(argv)} exited {proc.returncode}:\n{proc.stdout}\n{proc.stderr}", pytrace=False)


def require_module(name: str) -> None:
    if importlib.util.find_spec(name) is None:
        pytest.skip(f"{name} is not installed in {sys.executable} (pip install -r requirements.txt)")


def require_script(name: str) -> Path:
    path = BIN / name
    if not path.is_file():
        pytest.skip(f"{name} is not installed beside {sys.executable} (pip install -r requirements.txt)")
    return path


def test_ruff() -> None:
    """No ruff finding (rules in ruff.toml) in any of the repository's Python."""
    require_module("ruff")
    run([sys.executable, "-m", "ruff", "check", "--no-cache", *RUFF_PATHS])


def test_mypy(tmp_path: Path) -> None:
    """The package type-checks (analysis/pyproject.toml [tool.mypy]); the cache in a temporary folder."""
    require_module("mypy")
    run([sys.executable, "-m", "mypy", "--config-file", "analysis/pyproject.toml", "--cache-dir",
         str(tmp_path / "mypy_cache"), "analysis/src/capsmech"])


def test_snakemake_lint() -> None:
    """Snakemake's linter finds nothing in the workflow (with the smoke configuration)."""
    snakemake = require_script("snakemake")
    run([str(snakemake), "-s", "workflow/Snakefile", "--configfile", "config/smoke.yaml", "--lint"])


def test_snakefmt() -> None:
    """The Snakefile and rules are formatted as snakefmt formats them."""
    snakefmt = require_script("snakefmt")
    run([str(snakefmt), "--check", "workflow/"])
