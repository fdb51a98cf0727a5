"""A full disk is one clear line and no partial file (an outside campaign found "internal error:
OSError" and a 0-byte ``*.tmp`` left behind). The outputs are written on a real full file
system: a tmpfs of one page mounted in a private mount namespace, its one page taken first."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from small_disk import on_a_small_disk

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "data" / "examples" / "tube_batch_NH.csv"

@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("fit") / "results.csv"
    done = subprocess.run([sys.executable, "-m", "capsmech.cli", "fit-tube", str(EXAMPLE), "--law", "NH",
                           "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return out


@pytest.mark.parametrize("what", ["population --json", "population --out"])
def test_a_full_disk_is_one_line_and_leaves_nothing(tmp_path: Path, results: Path, what: str) -> None:
    option = what.split()[1]
    target = tmp_path / "disk" / ("verdict.json" if option == "--json" else "verdict.csv")
    rc, stderr, left = on_a_small_disk(tmp_path, sys.executable, "-m", "capsmech.cli", "population", str(results),
                                       option, str(target))
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert rc == 2, stderr
    assert lines[-1].startswith("capsmech: error: ") and str(target) in lines[-1], stderr
    assert "internal error" not in stderr and "Traceback" not in stderr
    assert left == []                                   # neither the file nor its .tmp
