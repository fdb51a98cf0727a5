"""The kernel's reproducers of the second outside fault campaign, run as a user runs them.

``test_kernel_faults.py`` pins each fault on one form; these are the campaign's own command
lines and the forms it left untested: the tube case of the thread-count crash, both thread
counts in a namelist, the huge checkpoint in a tube run, and the warning that a checkpoint of
other options was kept aside, which must be on stderr before the run is killed mid-work.
"""
from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path

import pytest

#: The campaign's reproducer (exit 139 with --threads 100000 before the bound).
TUBE = ["--flow", "tube", "--law", "NH", "--ca", "0.1", "--a-over-l", "0.8", "--t-max", "0.01"]


def run(capsim: Path, *args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([str(capsim), *args], capture_output=True, text=True, timeout=timeout)


def one_error_line(result: subprocess.CompletedProcess) -> str:
    """Exit 2, one stderr line starting 'capsim: error: ', no backtrace."""
    assert result.returncode == 2, (result.returncode, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("capsim: error: "), result.stderr
    assert "Backtrace" not in result.stderr and "Error allocating" not in result.stderr
    return lines[0]


@pytest.mark.parametrize("threads", ["100000", "2147483647"])
def test_the_tube_reproducers_thread_count_is_refused_in_a_namelist(capsim, tmp_path, threads):
    out = tmp_path / "x.h5"
    nml = tmp_path / "run.nml"
    nml.write_text("&capsim\n flow='tube', law='NH', ca=0.1, a_over_l=0.8, t_max=0.01,\n"
                   f" out='{out}', threads={threads}\n/\n")
    line = one_error_line(run(capsim, "--namelist", str(nml)))
    assert "--threads" in line and threads in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.nml"]


def test_a_group_of_another_name_after_capsim_is_refused(capsim, tmp_path):
    """Fortran's reader stops at the end of &capsim: whatever follows was silently ignored."""
    nml = tmp_path / "run.nml"
    nml.write_text(f"&capsim\n flow='tube', law='NH', ca=0.1, a_over_l=0.8, t_max=0.01, out='{tmp_path / 'x.h5'}'\n/\n"
                   "&other\n ca=0.3\n/\n")
    line = one_error_line(run(capsim, "--namelist", str(nml)))
    assert "run.nml" in line and "line 4" in line and "second group" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.nml"]


def test_the_tube_reproducer_with_a_6_gb_checkpoint_runs_without_reading_it(capsim, tmp_path):
    """A file of 6 GB with the checkpoint's header (magic and a CRC) in the checkpoint's place."""
    out = tmp_path / "x.h5"
    with open(Path(str(out) + ".ckpt"), "wb") as f:       # sparse: no disk space used
        f.write(b"CAPSCKP3" + bytes(4))
        f.truncate(6 * 2**30)
    result = subprocess.run(["/usr/bin/time", "-f", "%M", str(capsim), *TUBE, "--threads", "1", "--quiet",
                             "--out", str(out)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    lines = result.stderr.strip().splitlines()
    assert lines[0].startswith("capsim: warning: ") and "larger than any checkpoint" in lines[0], result.stderr
    assert int(lines[-1]) < 200_000                       # peak RSS [kB]: 6 GB before
    assert out.exists()


def test_the_kept_aside_warning_is_on_stderr_before_the_run_is_killed(capsim, tmp_path):
    """A run killed with its checkpoint on disk, rerun with Ca changed and killed again while it
    works: the old checkpoint is kept whole and the line saying so reached stderr (a buffered
    warning was lost with the process)."""
    out = tmp_path / "case.h5"
    checkpoint, kept = Path(str(out) + ".ckpt"), Path(str(out) + ".ckpt.other-options")
    common = ["--flow", "shear", "--law", "NH", "--level", "2", "--threads", "1", "--quiet",
              "--checkpoint-every", "0.05", "--out", str(out)]
    first = subprocess.Popen([str(capsim), *common, "--ca", "0.02"])
    _wait_for(checkpoint, first)
    time.sleep(0.2)
    first.send_signal(signal.SIGKILL)
    first.wait()
    saved = checkpoint.read_bytes()
    stderr = tmp_path / "stderr.txt"
    with open(stderr, "wb") as err:
        second = subprocess.Popen([str(capsim), *common, "--ca", "0.25"], stderr=err)
        _wait_for(kept, second)
        _wait_for(checkpoint, second)                    # its own first checkpoint: it is at work
        second.send_signal(signal.SIGKILL)
        second.wait()
    assert second.returncode == -signal.SIGKILL          # killed at work, not ended by itself
    assert kept.read_bytes() == saved
    text = stderr.read_text()
    assert "capsim: warning:" in text and "signature differs" in text and str(kept) in text, text


def _wait_for(path: Path, proc: subprocess.Popen, limit: float = 60) -> None:
    deadline = time.time() + limit
    while not path.exists() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.01)
    assert path.exists() and proc.poll() is None, "the run ended before it could be killed"


def test_a_huge_t_max_is_printed_as_a_number_the_progress_bar_reads(capsim, tmp_path):
    # Fixed notation wrote t_max = 1e300 with 300 digits; the progress relay must parse the line.
    # Level 3 at Ca_s 0.05 steps for longer than the 2 s between progress lines.
    from capsmech.workflow.simulate import _KERNEL_PROGRESS

    proc = subprocess.Popen([str(capsim), "--flow", "shear", "--law", "NH", "--ca", "0.05", "--level", "3",
                             "--integrator", "rk2", "--kb", "0", "--t-max", "1e300", "--threads", "1",
                             "--out", str(tmp_path / "x.h5")], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        line = next(text for text in proc.stdout if text.startswith("capsim: t ="))
    finally:
        proc.kill()
        proc.wait()
    match = _KERNEL_PROGRESS.match(line.strip())
    assert match is not None, line
    assert float(match["t_max"]) == pytest.approx(1e300) and 0 < float(match["t"]) < 1e3
    assert len(line) < 120
