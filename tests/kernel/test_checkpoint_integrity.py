"""Checkpoints that are checked (issue 25, item 2): a CRC-32 over the checkpoint's bytes and a
signature holding every option that changes the result, t_max and the kernel's code_version.
A damaged or foreign checkpoint is reported on one line (stderr) and the run starts afresh,
ending exactly as an uninterrupted run; a checkpoint that cannot be written leaves the previous
one in place, no temporary file, and exits 1 with one line.

Layout (case_output.f90, write_checkpoint): 'CAPSCKP3', CRC-32 (int32) of every byte after it,
len(signature) (int32), signature, step (int32), t, size(x) (int32), x, rows (int32), n_rec
(int32), history, wall_time_s; little-endian on the machines the tests run on."""
from __future__ import annotations

import signal
import struct
import subprocess
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

from conftest import datasets

#: ~4 s on one core, steady at t = 2 (shear, level 2, RK2).
ARGS = ["--flow", "shear", "--law", "NH", "--ca", "0.02", "--level", "2", "--threads", "1"]
MAGIC = b"CAPSCKP3"


def killed_checkpoint(capsim: Path, out: Path, *extra: str) -> bytes:
    """Run ARGS EXTRA with a checkpoint at nearly every step, SIGKILL it once a checkpoint
    exists, and return the checkpoint's bytes (left at OUT.ckpt)."""
    checkpoint = Path(str(out) + ".ckpt")
    proc = subprocess.Popen([str(capsim), *ARGS, *extra, "--quiet", "--checkpoint-every", "0.05", "--out", str(out)])
    deadline = time.time() + 60

    def records() -> int:
        try:
            data = checkpoint.read_bytes()
            at = offsets(data)
            return struct.unpack("<i", data[at["n_rec"]:at["n_rec"] + 4])[0]
        except (OSError, struct.error):
            return 0

    # At least 5 records, so that every corruption below has a field to change.
    while records() < 5 and time.time() < deadline and proc.poll() is None:
        time.sleep(0.02)
    assert proc.poll() is None, "the run ended before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert checkpoint.exists() and not out.exists()
    return checkpoint.read_bytes()


@pytest.fixture(scope="module")
def reference(capsim, tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("reference") / "ref.h5"
    subprocess.run([str(capsim), *ARGS, "--quiet", "--out", str(out)], check=True, timeout=300)
    return datasets(out)


@pytest.fixture(scope="module")
def checkpoint(capsim, tmp_path_factory) -> bytes:
    data = killed_checkpoint(capsim, tmp_path_factory.mktemp("killed") / "killed.h5")
    assert data[:8] == MAGIC
    (crc,) = struct.unpack("<i", data[8:12])
    assert crc == struct.unpack("<i", struct.pack("<I", zlib.crc32(data[12:])))[0]   # the CRC-32 of zlib
    return data


def offsets(data: bytes) -> dict[str, int]:
    """Byte offsets of the fields of a checkpoint."""
    (sig_len,) = struct.unpack("<i", data[12:16])
    at = {"signature": 16, "step": 16 + sig_len, "t": 20 + sig_len, "n_state": 28 + sig_len, "x": 32 + sig_len}
    (n_state,) = struct.unpack("<i", data[at["n_state"]:at["n_state"] + 4])
    at["rows"] = at["x"] + 8 * n_state
    at["n_rec"] = at["rows"] + 4
    at["history"] = at["n_rec"] + 4
    at["sig_len"] = sig_len
    return at


def with_crc(data: bytes) -> bytes:
    """`data` with its CRC recomputed (a forged but whole checkpoint)."""
    return data[:8] + struct.pack("<I", zlib.crc32(data[12:])) + data[12:]


def resume_from(capsim: Path, tmp_path: Path, data: bytes, *extra: str) -> tuple[subprocess.CompletedProcess, Path]:
    """Put `data` as the checkpoint of a new case and run it (not quiet: the resume is reported)."""
    out = tmp_path / "case.h5"
    Path(str(out) + ".ckpt").write_bytes(data)
    result = subprocess.run([str(capsim), *ARGS, *extra, "--out", str(out)], capture_output=True, text=True,
                            timeout=300)
    return result, out


def assert_fresh_and_exact(result: subprocess.CompletedProcess, out: Path, reference: dict, reason: str) -> None:
    assert result.returncode == 0, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "checkpoint" in lines[0] and "not used" in lines[0] and reason in lines[0], \
        result.stderr
    assert "resumed" not in result.stdout
    assert not Path(str(out) + ".ckpt").exists() and not Path(str(out) + ".ckpt.tmp").exists()
    found = datasets(out)
    assert found.keys() == reference.keys()
    for name in reference:
        assert np.array_equal(found[name], reference[name]), name


def test_an_intact_checkpoint_is_resumed_exactly(capsim, tmp_path, reference, checkpoint):
    result, out = resume_from(capsim, tmp_path, checkpoint)
    assert result.returncode == 0 and result.stderr == "", result.stderr
    assert "resumed from checkpoint" in result.stdout
    found = datasets(out)
    for name in reference:
        assert np.array_equal(found[name], reference[name]), name


def flip(data: bytes, offset: int, bit: int) -> bytes:
    b = bytearray(data)
    b[offset] ^= 1 << bit
    return bytes(b)


def put(data: bytes, offset: int, raw: bytes) -> bytes:
    return data[:offset] + raw + data[offset + len(raw):]


#: Corruptions of a whole checkpoint; each was resumed silently (exit 0) before the checksum
#: (issue 25: 10 of 18 structurally valid corruptions).
CORRUPTIONS = {
    "t exponent bit": lambda d, at: flip(d, at["t"] + 7, 4),
    "t mantissa bit": lambda d, at: flip(d, at["t"] + 1, 0),
    "t NaN": lambda d, at: put(d, at["t"], struct.pack("<d", float("nan"))),
    "node NaN": lambda d, at: put(d, at["x"] + 8 * 17, struct.pack("<d", float("nan"))),
    "node mantissa bit": lambda d, at: flip(d, at["x"] + 8 * 40 + 2, 3),
    "history bit": lambda d, at: flip(d, at["history"] + 8 * 12 + 6, 1),
    "negative record count": lambda d, at: put(d, at["n_rec"], struct.pack("<i", -3)),
    "smaller record count": lambda d, at: put(d, at["n_rec"], struct.pack("<i", struct.unpack(
        "<i", d[at["n_rec"]:at["n_rec"] + 4])[0] - 1)),
    "step count": lambda d, at: put(d, at["step"], struct.pack("<i", struct.unpack(
        "<i", d[at["step"]:at["step"] + 4])[0] + 1)),
    "signature byte": lambda d, at: flip(d, at["signature"] + 3, 0),
    "wall time": lambda d, at: put(d, len(d) - 8, struct.pack("<d", -1.0)),
    "checksum bit": lambda d, at: flip(d, 9, 5),
    "truncated to half": lambda d, at: d[:len(d) // 2],
    "last byte missing": lambda d, at: d[:-1],
    "a byte too many": lambda d, at: d + b"\0",
    "header only": lambda d, at: d[:12],
    "empty": lambda d, at: b"",
    "other file": lambda d, at: b"\x89HDF\r\n\x1a\n" + bytes(200),
}


@pytest.mark.parametrize("name", list(CORRUPTIONS))
def test_a_damaged_checkpoint_is_reported_and_the_run_starts_afresh(capsim, tmp_path, reference, checkpoint, name):
    damaged = CORRUPTIONS[name](checkpoint, offsets(checkpoint))
    assert damaged != checkpoint
    result, out = resume_from(capsim, tmp_path, damaged)
    assert_fresh_and_exact(result, out, reference, "not used")


def test_a_checkpoint_of_another_code_version_is_not_used(capsim, tmp_path, reference, checkpoint):
    # A whole checkpoint (valid CRC) whose signature names another kernel version, as an
    # older or newer build would have written it.
    at = offsets(checkpoint)
    signature = checkpoint[at["signature"]:at["signature"] + at["sig_len"]].decode()
    assert " code_version " in signature
    version = signature.split(" code_version ")[1].split()[0]
    other = version[:-1] + ("1" if version[-1] != "1" else "2")
    forged = with_crc(checkpoint.replace(f" code_version {version}".encode(), f" code_version {other}".encode()))
    result, out = resume_from(capsim, tmp_path, forged)
    assert_fresh_and_exact(result, out, reference, "signature differs")


def test_a_checkpoint_of_another_t_max_is_not_used(capsim, tmp_path, reference):
    # Killed with --t-max 50, run again with the default 60: the checkpoint is not resumed
    # (a shorter t_max resumed into a history longer than t_max).
    data = killed_checkpoint(capsim, tmp_path / "short.h5", "--t-max", "50")
    result, out = resume_from(capsim, tmp_path, data)
    assert_fresh_and_exact(result, out, reference, "signature differs")


def test_a_forged_checkpoint_with_a_valid_checksum_but_nan_is_not_used(capsim, tmp_path, reference, checkpoint):
    at = offsets(checkpoint)
    forged = with_crc(put(checkpoint, at["x"], struct.pack("<d", float("nan"))))
    result, out = resume_from(capsim, tmp_path, forged)
    assert_fresh_and_exact(result, out, reference, "non-finite")


#: Runs capsim on a tmpfs of SIZE bytes mounted at D in a private mount namespace (a full
#: disk, seen by write(2) as ENOSPC), with the checkpoint PREV (if any) put there first; what is
#: left in D is listed in W/listing and its checkpoint copied to W/after.ckpt.
FULL_DISK = r"""
mount -t tmpfs -o size="$SIZE" tmpfs "$D" || exit 77
if [ -n "$PREV" ]; then cp "$PREV" "$D/case.h5.ckpt"; fi
"$CAPSIM" "$@" --out "$D/case.h5" >"$W/stdout" 2>"$W/stderr"
rc=$?
ls -A "$D" >"$W/listing"
if [ -f "$D/case.h5.ckpt" ]; then cp "$D/case.h5.ckpt" "$W/after.ckpt"; fi
exit $rc
"""


def on_full_disk(capsim: Path, tmp_path: Path, size: int, previous: bytes | None, *args: str):
    """Run capsim ARGS on a disk of `size` bytes; returns (exit code, stdout, stderr, files
    left, checkpoint left or None). Skips where no private tmpfs can be mounted."""
    import os

    disk, work = tmp_path / "disk", tmp_path / "w"
    disk.mkdir()
    work.mkdir()
    prev = ""
    if previous is not None:
        (work / "prev.ckpt").write_bytes(previous)
        prev = str(work / "prev.ckpt")
    env = {**os.environ, "SIZE": str(size), "D": str(disk), "W": str(work), "PREV": prev, "CAPSIM": str(capsim)}
    try:
        result = subprocess.run(["unshare", "-rm", "sh", "-c", FULL_DISK, "sh", *args], env=env,
                                capture_output=True, text=True, timeout=300)
    except FileNotFoundError:
        pytest.skip("unshare is not installed")
    if result.returncode == 77 or not (work / "listing").exists():
        pytest.skip(f"cannot mount a private tmpfs here: {result.stderr.strip()}")
    after = work / "after.ckpt"
    return (result.returncode, (work / "stdout").read_text(), (work / "stderr").read_text(),
            (work / "listing").read_text().split(), after.read_bytes() if after.exists() else None)


def test_a_checkpoint_that_cannot_be_written_exits_1_and_leaves_nothing(capsim, tmp_path):
    # A disk of one page: the first checkpoint (~5 kB) does not fit. Before, the failed write
    # was not checked (a runtime error, or a 0-byte checkpoint in place of a good one).
    rc, _, stderr, left, _ = on_full_disk(capsim, tmp_path, 4096, None, *ARGS, "--quiet", "--checkpoint-every", "0.05")
    assert rc == 1, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("capsim: error: ") and "checkpoint" in lines[0], stderr
    assert left == []                                   # no case.h5.tmp, no case.h5.ckpt.tmp


def test_a_failed_checkpoint_write_keeps_the_previous_checkpoint(capsim, tmp_path, checkpoint):
    # Room for the previous checkpoint and one page more: the next one (at least as long) fails.
    pages = -(-len(checkpoint) // 4096)
    rc, stdout, stderr, left, after = on_full_disk(capsim, tmp_path, 4096 * (pages + 1), checkpoint, *ARGS,
                                                   "--checkpoint-every", "0.05")
    assert rc == 1, stderr
    assert "resumed from checkpoint" in stdout
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("capsim: error: ") and "checkpoint" in lines[0], stderr
    assert after == checkpoint
    assert left == ["case.h5.ckpt"]


def test_a_full_disk_at_the_final_write_exits_1_and_leaves_no_temporary(capsim, tmp_path):
    # Was: the error printed, then a segfault in HDF5's exit handler (exit 139), OUT.tmp left.
    rc, _, stderr, left, _ = on_full_disk(capsim, tmp_path, 12288, None, "--flow", "shear", "--law", "NH", "--ca", "0.2",
                                          "--level", "2", "--t-max", "1", "--threads", "1", "--quiet")
    assert rc == 1, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("capsim: error: writing the case file"), stderr
    assert left == []
