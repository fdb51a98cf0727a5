"""Kernel inputs that crashed, hung, misread or lost work, each now a clear refusal or a kept file.

Each reproducer failed before its fix: a thread count of 1e5 crashed (exit 139) and 2^31-1
ended in libgomp's raw "out of memory"; --dt 1e-300 ran until killed; a repeated name or a
second group in the namelist was read silently (the last value, the first group); a 6 GB file
with a checkpoint's header was read whole into memory ("Error allocating ... bytes" and a
backtrace); a checkpoint of other options was overwritten by the rerun's first checkpoint.
"""
from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from conftest import datasets

SHEAR = ["--flow", "shear", "--law", "NH", "--ca", "0.1", "--level", "1"]


def run(capsim: Path, *args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([str(capsim), *args], capture_output=True, text=True, timeout=timeout)


def assert_refused(result: subprocess.CompletedProcess, *names: str) -> str:
    """Exit 2, one stderr line naming each of `names`, no backtrace."""
    assert result.returncode == 2, (result.returncode, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("capsim: error: "), result.stderr
    for name in names:
        assert name in lines[0], lines[0]
    return lines[0]


@pytest.mark.parametrize("threads", ["100000", "2147483647", str(4 * (os.cpu_count() or 1) + 1000)])
def test_a_thread_count_beyond_the_machine_is_refused(capsim, tmp_path, threads):
    out = tmp_path / "x.h5"
    tube = ["--flow", "tube", "--law", "NH", "--ca", "0.1", "--a-over-l", "0.8", "--t-max", "0.01"]
    line = assert_refused(run(capsim, *tube, "--out", str(out), "--threads", threads), "--threads", threads)
    assert "processor" in line and not out.exists()


def test_a_thread_count_beyond_the_machine_is_refused_in_the_namelist(capsim, tmp_path):
    nml = tmp_path / "run.nml"
    nml.write_text(f"&capsim\n flow='shear', law='NH', ca=0.1, threads=100000, out='{tmp_path / 'x.h5'}' /\n")
    assert_refused(run(capsim, "--namelist", str(nml)), "--threads")


def test_a_few_threads_more_than_processors_still_run(capsim, tmp_path):
    # Oversubscription is allowed (a shared node's OpenMP may see fewer processors than exist).
    out = tmp_path / "x.h5"
    result = run(capsim, *SHEAR, "--t-max", "0.05", "--threads", str(2 * (os.cpu_count() or 1)), "--quiet",
                 "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert out.exists()


@pytest.mark.parametrize("option,value", [("--dt", "1e-300"), ("--dt", "1e-9"), ("--dt-factor", "1e-300")])
def test_a_time_step_that_cannot_get_anywhere_is_refused_at_once(capsim, tmp_path, option, value):
    out = tmp_path / "x.h5"
    started = time.perf_counter()
    line = assert_refused(run(capsim, *SHEAR, option, value, "--out", str(out), timeout=30), option)
    assert time.perf_counter() - started < 20            # refused up front, not after a bounded run
    assert "steps" in line and not out.exists()


def test_a_small_time_step_over_a_short_t_max_is_not_refused(capsim, tmp_path):
    # 1e-6 over t_max 1e-3: a thousand steps, a legitimate short run.
    out = tmp_path / "x.h5"
    result = run(capsim, *SHEAR, "--dt", "1e-6", "--t-max", "1e-3", "--threads", "1", "--quiet", "--out", str(out))
    assert result.returncode == 0, result.stderr


@pytest.mark.parametrize("body,line_no,words", [
    ("ca=0.1 ca=0.2\n", 3, ["ca", "twice"]),
    ("ca=0.1,\n CA = 0.2\n", 4, ["ca", "twice", "first on line 3"]),
    ("ca=0.1 /\n&capsim ca=0.3\n", 4, ["second group"]),
])
def test_an_ambiguous_namelist_is_refused(capsim, tmp_path, body, line_no, words):
    nml = tmp_path / "run.nml"
    nml.write_text(f"&capsim\n flow='shear', law='NH', out='{tmp_path / 'x.h5'}',\n {body}" + ("/\n" if "/" not in body
                                                                                                  else ""))
    line = assert_refused(run(capsim, "--namelist", str(nml)), "--namelist", f"line {line_no}", *words)
    assert str(nml.name) in line


def test_names_in_comments_and_quoted_values_are_not_repeats(capsim, tmp_path):
    # What Fortran's namelist reader skips is skipped here too: a comment and a quoted path.
    out = tmp_path / "a ca=1 !b.h5"
    nml = tmp_path / "run.nml"
    nml.write_text(f"! ca=0.5 in a comment\n&capsim\n flow='shear', law='NH', ca=0.1, level=1, t_max=0.05, "
                   f"out=\"{out}\" ! ca=0.7\n/\n")
    result = run(capsim, "--namelist", str(nml), "--quiet")
    assert result.returncode == 0, result.stderr
    assert out.exists()


def test_a_huge_file_with_a_checkpoint_header_is_not_read_into_memory(capsim, tmp_path):
    out = tmp_path / "case.h5"
    checkpoint = Path(str(out) + ".ckpt")
    with open(checkpoint, "wb") as f:                    # sparse: 6 GB on no disk space
        f.write(b"CAPSCKP3" + bytes(4))
        f.truncate(6 * 2**30)
    result = subprocess.run(["/usr/bin/time", "-f", "%M", str(capsim), *SHEAR, "--t-max", "0.05", "--quiet",
                             "--out", str(out)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    lines = result.stderr.strip().splitlines()
    assert "not used: larger than any checkpoint" in lines[0] and "Error allocating" not in result.stderr
    assert int(lines[-1]) < 200_000                      # peak RSS [kB]: the file was never read whole
    assert out.exists()


def _killed_with_checkpoint(capsim: Path, args: list[str], out: Path) -> bytes:
    checkpoint = Path(str(out) + ".ckpt")
    proc = subprocess.Popen([str(capsim), *args, "--quiet", "--checkpoint-every", "0.05", "--out", str(out)])
    deadline = time.time() + 60
    while not checkpoint.exists() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.02)
    time.sleep(0.2)
    assert proc.poll() is None, "the run ended before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    return checkpoint.read_bytes()


def test_a_checkpoint_of_other_options_is_kept_and_resumed_by_its_own_options(capsim, tmp_path):
    """Killed at Ca 0.02, rerun by mistake at Ca 0.25, then rerun at Ca 0.02: the third run
    resumes the first's work and ends as an uninterrupted run, to the bit."""
    first = ["--flow", "shear", "--law", "NH", "--ca", "0.02", "--level", "2", "--threads", "1"]
    reference = tmp_path / "reference.h5"
    assert run(capsim, *first, "--quiet", "--out", str(reference), timeout=300).returncode == 0
    out = tmp_path / "case.h5"
    saved = _killed_with_checkpoint(capsim, first, out)
    mistaken = [a if a != "0.02" else "0.25" for a in first]
    result = run(capsim, *mistaken, "--t-max", "0.2", "--out", str(out), timeout=300)
    assert result.returncode == 0, result.stderr
    kept = Path(str(out) + ".ckpt.other-options")
    assert "signature differs" in result.stderr and str(kept) in result.stderr
    assert kept.read_bytes() == saved
    out.unlink()
    kept.rename(Path(str(out) + ".ckpt"))
    result = run(capsim, *first, "--out", str(out), timeout=300)
    assert result.returncode == 0 and "resumed from checkpoint" in result.stdout, result.stderr
    found, expected = datasets(out), datasets(reference)
    assert found.keys() == expected.keys()
    for name in expected:
        assert (found[name] == expected[name]).all(), name


def test_a_second_foreign_checkpoint_does_not_replace_the_first_kept(capsim, tmp_path):
    out = tmp_path / "case.h5"
    checkpoint = Path(str(out) + ".ckpt")
    first = ["--flow", "shear", "--law", "NH", "--ca", "0.02", "--level", "2", "--threads", "1"]
    saved = _killed_with_checkpoint(capsim, first, out)
    Path(str(out) + ".ckpt.other-options").write_bytes(b"an earlier one")
    result = run(capsim, *SHEAR, "--t-max", "0.05", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert Path(str(out) + ".ckpt.other-options").read_bytes() == b"an earlier one"
    assert Path(str(out) + ".ckpt.other-options-2").read_bytes() == saved
    assert not checkpoint.exists()
