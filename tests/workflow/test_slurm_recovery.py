"""A Snakemake run on SLURM killed by SIGKILL, and the documented command run again.

The killed run's case jobs go on computing in SLURM. The documented command
(``make database PROFILE=slurm``: ``capsmech dev unlock-stale . --profile ... --on-old-jobs
RECOVER`` then Snakemake) must find them in ``squeue`` and cancel them (the default) or wait
for them, so that no case is ever computed by two jobs at once, and the database must be the
one an uninterrupted run writes.

* Without a cluster: :mod:`capsmech.workflow.recovery` against a fake ``squeue``/``scancel``
  (which jobs are the workflow's, what is cancelled, when the wait ends), and the command line
  (a job step's Snakemake does not keep the lock; no ``squeue``: one message, nothing removed).
* On the one-node cluster of ``scripts/slurm_one_node.sh`` (marker ``cluster``; the test is in
  test_slurm_cluster.py, with the cluster's other tests, its steps in slurm_recovery_run.py): a run killed while both case jobs compute, then the documented
  command with ``cancel`` and with ``wait``. A watcher samples ``squeue`` and the kernel
  processes (``/proc``) every 0.2 s from before the kill to the end: at most one job and one
  kernel per case at any time. The databases equal the local profile's bit for bit.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import pytest

from capsmech.workflow.recovery import (
    OnOldJobs,
    RecoveryError,
    main_snakemake_pids,
    parse_squeue,
    recover_old_jobs,
)

from conftest import REPO

LOCAL_PROFILE = REPO / "workflow" / "profiles" / "local"
SLURM_PROFILE = REPO / "workflow" / "profiles" / "slurm"
RUN_ID = "capsmech_c7313459-0d2c-4d33-b2b7-c89c0c89b245"
OTHER_RUN_ID = "0f1e2d3c-4b5a-6978-8796-a5b4c3d2e1f0"


# --- without a cluster -----------------------------------------------------------------------

def squeue_line(job_id: int, state: str, name: str, comment: str, workdir: Path | str) -> str:
    """One line as ``squeue --format=%i|%T|%j|%k|%Z`` prints it."""
    return f"{job_id}|{state}|{name}|{comment}|{workdir}"


class FakeQueue:
    """``squeue`` and ``scancel`` of a cluster that holds ``jobs``.

    A running job ends after ``runs_for`` looks at the queue; a cancelled one shows
    ``COMPLETING`` once, then ends (and stays listed as ``CANCELLED``, as squeue shows an ended
    job for ``MinJobAge``).
    """

    def __init__(self, jobs: dict[int, tuple[str, str, str, str]], runs_for: int = 3) -> None:
        self.jobs = {job_id: list(fields) for job_id, fields in jobs.items()}
        self.runs_for = runs_for
        self.looks = 0
        self.calls: list[list[str]] = []
        self.cancelled: list[int] = []

    def __call__(self, argv: Sequence[str]) -> tuple[int, str, str]:
        argv = list(argv)
        self.calls.append(argv)
        if argv[0] == "scancel":
            for job_id in map(int, argv[1:]):
                self.cancelled.append(job_id)
                self.jobs[job_id][0] = "COMPLETING"
            return 0, "", ""
        assert argv[0] == "squeue" and "--format=%i|%T|%j|%k|%Z" in argv, argv
        self.looks += 1
        text = "\n".join(squeue_line(job_id, *fields) for job_id, fields in self.jobs.items()) + "\n"
        for job_id, fields in self.jobs.items():  # what the next look sees
            if fields[0] == "COMPLETING":
                fields[0] = "CANCELLED" if job_id in self.cancelled else "COMPLETED"
            elif fields[0] in ("RUNNING", "PENDING") and self.looks >= self.runs_for:
                fields[0] = "COMPLETED"
        return 0, text, ""


def _queue(workdir: Path) -> FakeQueue:
    return FakeQueue({
        12: ("RUNNING", RUN_ID, "rule_case_wildcards_shear_NH_Ca0.02", str(workdir)),
        13: ("PENDING", RUN_ID, "rule_case_wildcards_shear_NH_Ca0.025", str(workdir)),
        14: ("RUNNING", OTHER_RUN_ID, "rule_case_wildcards_shear_NH_Ca0.02", "/elsewhere"),
        15: ("RUNNING", "my_own_job", "rule_case_wildcards_shear_NH_Ca0.02", str(workdir)),
    })


def test_squeue_lines_of_this_workflow_are_its_unfinished_plugin_jobs(tmp_path: Path) -> None:
    """Only jobs working in this directory, named as the plugin names them (the run's UUID,
    with or without a prefix) and with a rule comment count; ended ones and others do not."""
    piped = tmp_path / "a|b"
    piped.mkdir()
    text = "\n".join([
        squeue_line(1, "RUNNING", RUN_ID, "rule_case_wildcards_shear_NH_Ca0.02", tmp_path),
        squeue_line(2, "PENDING", OTHER_RUN_ID, "rule_case_wildcards_tube_NH_a0.8_Ca0.1", tmp_path),
        squeue_line(3, "COMPLETING", RUN_ID, "rule_branch_wildcards_x|y", tmp_path),  # '|' in a comment
        squeue_line(4, "COMPLETED", RUN_ID, "rule_case_wildcards_shear_NH_Ca0.03", tmp_path),
        squeue_line(5, "CANCELLED", RUN_ID, "rule_case_wildcards_shear_NH_Ca0.04", tmp_path),
        squeue_line(6, "RUNNING", RUN_ID, "rule_case_wildcards_shear_NH_Ca0.02", tmp_path / "sub"),
        squeue_line(7, "RUNNING", "interactive", "rule_case", tmp_path),
        squeue_line(8, "RUNNING", RUN_ID, "my comment", tmp_path),
        squeue_line(9, "RUNNING", RUN_ID, "rule_case_wildcards_shear_NH_Ca0.05", piped),
        "garbage line",
    ])
    found = parse_squeue(text, tmp_path)
    assert [(job.job_id, job.state) for job in found] == [("1", "RUNNING"), ("2", "PENDING"), ("3", "COMPLETING")]
    assert found[0].describe() == "case shear_NH_Ca0.02 (job 1, RUNNING)"
    assert found[2].comment == "rule_branch_wildcards_x|y" and found[2].case == "branch x|y"
    assert [job.job_id for job in parse_squeue(text, piped)] == ["9"]
    assert parse_squeue(text, tmp_path / ".." / tmp_path.name) == found  # compared resolved


def test_cancel_ends_exactly_the_old_runs_jobs_then_returns_when_the_queue_has_none(tmp_path: Path) -> None:
    queue, said = _queue(tmp_path), []
    found = recover_old_jobs(tmp_path, OnOldJobs.CANCEL, run=queue, sleep=lambda s: None, say=said.append)
    assert [job.job_id for job in found] == ["12", "13"]
    scancels = [call for call in queue.calls if call[0] == "scancel"]
    assert scancels == [["scancel", "12", "13"]]            # not job 14 (elsewhere) nor 15 (not the plugin's)
    assert queue.calls.index(scancels[0]) == 1                # right after the first look
    assert queue.jobs[12][0] == queue.jobs[13][0] == "CANCELLED"
    assert queue.looks == 3                                   # COMPLETING seen, then nothing left
    assert "case shear_NH_Ca0.02 (job 12, RUNNING); case shear_NH_Ca0.025 (job 13, PENDING)" in said[0]
    assert said[1].startswith("Cancelling them (RECOVER=cancel)") and "RECOVER=wait" in said[1]
    assert said[-1].startswith("The earlier run's jobs have ended")


def test_wait_cancels_nothing_and_returns_once_every_old_job_has_ended(tmp_path: Path) -> None:
    queue, said, slept = _queue(tmp_path), [], []
    queue.runs_for = 6
    recover_old_jobs(tmp_path, OnOldJobs.WAIT, run=queue, sleep=slept.append, say=said.append)
    assert not any(call[0] == "scancel" for call in queue.calls)
    assert queue.looks == 7 and queue.jobs[12][0] == queue.jobs[13][0] == "COMPLETED"
    assert said[1].startswith("Waiting until they end (RECOVER=wait)") and "RECOVER=cancel" in said[1]
    assert len(slept) == 6


def test_nothing_in_the_queue_means_nothing_to_do(tmp_path: Path) -> None:
    queue, said = FakeQueue({}), []
    assert recover_old_jobs(tmp_path, OnOldJobs.CANCEL, run=queue, say=said.append) == []
    assert queue.calls == [queue.calls[0]] and queue.calls[0][0] == "squeue" and said == []


def test_a_queue_that_cannot_be_read_stops_the_rerun(tmp_path: Path) -> None:
    def failing(argv: Sequence[str]) -> tuple[int, str, str]:
        return 1, "", "slurm_load_jobs error: Unable to contact slurm controller (connect failure)\n"

    with pytest.raises(RecoveryError, match="Unable to contact slurm controller"):
        recover_old_jobs(tmp_path, run=failing, sleep=lambda s: None)
    with pytest.raises(RecoveryError, match="squeue: command not found"):
        recover_old_jobs(tmp_path, run=lambda argv: (127, "", "squeue: command not found"))


def _fake_snakemake(tmp_path: Path, workdir: Path, *args: str) -> subprocess.Popen:
    """A process that looks like Snakemake (a script named ``snakemake``) working in ``workdir``."""
    script = tmp_path / "snakemake"
    script.write_text("import time\ntime.sleep(60)\n")
    return subprocess.Popen([sys.executable, str(script), *args], cwd=workdir)


def _unlock_stale(workdir: Path, *args: str, path: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "capsmech.cli", "dev", "unlock-stale", str(workdir), *args],
                          cwd=workdir, text=True, capture_output=True, timeout=60,
                          env={**os.environ, "PATH": path})


def test_a_job_steps_snakemake_does_not_keep_the_lock_of_a_killed_run(tmp_path: Path) -> None:
    """The job step of a SLURM job runs ``snakemake ... --mode remote`` in the workflow's
    directory: with the SLURM profile it is not taken for a live run (an empty queue, read
    through a fake squeue); a run without ``--mode remote`` keeps the lock and its jobs."""
    workdir, bin_dir = tmp_path / "work", tmp_path / "bin"
    (workdir / ".snakemake" / "locks").mkdir(parents=True)
    bin_dir.mkdir()
    squeue = bin_dir / "squeue"
    squeue.write_text(f"#!/bin/sh\necho \"$@\" >> {tmp_path / 'squeue.calls'}\nexit 0\n")
    squeue.chmod(0o755)
    path = f"{bin_dir}:{os.environ['PATH']}"
    lock = workdir / ".snakemake" / "locks" / "0.output.lock"
    step = _fake_snakemake(tmp_path, workdir, "--mode", "remote")
    try:
        time.sleep(0.5)
        assert main_snakemake_pids(workdir) == []
        lock.write_text("")
        local = _unlock_stale(workdir, "--profile", str(LOCAL_PROFILE), path=path)
        assert local.returncode == 0 and "its lock is kept" in local.stdout and lock.exists()  # unchanged
        result = _unlock_stale(workdir, "--profile", str(SLURM_PROFILE), path=path)
        assert result.returncode == 0, result.stderr
        assert "removed the stale Snakemake lock" in result.stdout and not lock.exists()
        assert "--format=%i|%T|%j|%k|%Z" in (tmp_path / "squeue.calls").read_text()
    finally:
        step.kill()
        step.wait()
    live = _fake_snakemake(tmp_path, workdir, "--profile", str(SLURM_PROFILE))
    try:
        time.sleep(0.5)
        lock.write_text("")
        (tmp_path / "squeue.calls").unlink()
        result = _unlock_stale(workdir, "--profile", str(SLURM_PROFILE), path=path)
        assert result.returncode == 0 and lock.exists()
        assert f"(process {live.pid}): its lock and its SLURM jobs are kept" in result.stdout
        assert not (tmp_path / "squeue.calls").exists()  # its jobs are not even looked at
    finally:
        live.kill()
        live.wait()


def test_without_squeue_the_slurm_recovery_is_one_message_and_keeps_the_lock(tmp_path: Path) -> None:
    lock = tmp_path / ".snakemake" / "locks" / "0.output.lock"
    lock.parent.mkdir(parents=True)
    lock.write_text("")
    result = _unlock_stale(tmp_path, "--profile", str(SLURM_PROFILE), path=str(tmp_path / "empty"))
    assert result.returncode == 2 and lock.exists()
    assert "cannot list the SLURM jobs of an earlier run" in result.stderr and "squeue" in result.stderr
    assert "Traceback" not in result.stderr and len(result.stderr.strip().splitlines()) == 1
    bad = _unlock_stale(tmp_path, "--profile", str(SLURM_PROFILE), "--on-old-jobs", "ignore",
                        path=os.environ["PATH"])
    assert bad.returncode == 2 and "invalid choice: 'ignore'" in bad.stderr
