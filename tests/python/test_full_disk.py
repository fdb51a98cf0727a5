"""A full disk is one clear line and no partial file (an outside campaign found "internal error:
OSError" and a 0-byte ``*.tmp`` left behind). The outputs are written on a real full file
system: a tmpfs of one page mounted in a private mount namespace, its one page taken first."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "data" / "examples" / "tube_batch_NH.csv"

#: Mounts a tmpfs of one page at $D, fills it, runs the command, lists what is left in $D.
FULL_DISK = r"""
mount -t tmpfs -o size=4k tmpfs "$D" || exit 77
head -c 4096 /dev/zero > "$D/filler" 2>/dev/null
"$@" >"$W/stdout" 2>"$W/stderr"
echo $? >"$W/rc"
ls -A "$D" >"$W/listing"
"""


def on_full_disk(tmp_path: Path, *command: str) -> tuple[int, str, list[str]]:
    disk, work = tmp_path / "disk", tmp_path / "w"
    disk.mkdir()
    work.mkdir()
    env = {**os.environ, "D": str(disk), "W": str(work)}
    try:
        subprocess.run(["unshare", "-rm", "sh", "-c", FULL_DISK, "sh", *command], env=env, capture_output=True,
                       text=True, timeout=300)
    except FileNotFoundError:
        pytest.skip("unshare is not installed")
    if not (work / "rc").exists():
        pytest.skip("cannot mount a private tmpfs here")
    left = [name for name in (work / "listing").read_text().split() if name != "filler"]
    return int((work / "rc").read_text()), (work / "stderr").read_text(), left


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
    rc, stderr, left = on_full_disk(tmp_path, sys.executable, "-m", "capsmech.cli", "population", str(results),
                                    option, str(target))
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert rc == 2, stderr
    assert lines[-1].startswith("capsmech: error: ") and str(target) in lines[-1], stderr
    assert "internal error" not in stderr and "Traceback" not in stderr
    assert left == []                                   # neither the file nor its .tmp
