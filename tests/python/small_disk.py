"""A command run with its output folder on a real full (or read-only) file system: a tmpfs of
one page mounted in a private mount namespace (``unshare -rm``), its one page taken first."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

#: Mounts a tmpfs of one page at $D (read-only if $RO), fills it, runs the command, lists $D.
ON_A_SMALL_DISK = r"""
mount -t tmpfs -o size=4k tmpfs "$D" || exit 77
head -c 4096 /dev/zero > "$D/filler" 2>/dev/null
if [ -n "$RO" ]; then mount -o remount,ro "$D" || exit 77; fi
"$@" >"$W/stdout" 2>"$W/stderr"
echo $? >"$W/rc"
ls -A "$D" >"$W/listing"
"""


def on_a_small_disk(tmp_path: Path, *command: str, read_only: bool = False, timeout: float = 300,
                    cwd: Path | None = None) -> tuple[int, str, list[str]]:
    """``command`` run with ``tmp_path / "disk"`` a full one-page tmpfs (remounted read-only
    where ``read_only``): (its exit status, its stderr, what it left on the disk). Skips the
    test where ``unshare`` is missing or no private tmpfs can be mounted."""
    disk, work = tmp_path / "disk", tmp_path / "w"
    disk.mkdir()
    work.mkdir()
    env = {**os.environ, "D": str(disk), "W": str(work), "RO": "1" if read_only else ""}
    try:
        subprocess.run(["unshare", "-rm", "sh", "-c", ON_A_SMALL_DISK, "sh", *command], env=env,
                       capture_output=True, text=True, timeout=timeout, cwd=cwd)
    except FileNotFoundError:
        pytest.skip("unshare is not installed")
    if not (work / "rc").exists():
        pytest.skip("cannot mount a private tmpfs here")
    left = [name for name in (work / "listing").read_text().split() if name != "filler"]
    return int((work / "rc").read_text()), (work / "stderr").read_text(), left
