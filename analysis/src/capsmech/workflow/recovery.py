"""After a Snakemake run on SLURM was killed: its case jobs, found in the queue, waited for or cancelled.

A Snakemake process killed by SIGKILL (a lost login session, the out-of-memory killer) leaves
its SLURM jobs running: each job runs a Snakemake of its own (``--mode remote``) that computes
one case from its checkpoint. Rerunning the workflow then would submit the unfinished cases
again, and two jobs would compute one case from the same checkpoint. So before a rerun,
:func:`recover_old_jobs` finds the jobs the killed run submitted and either cancels them (the
rerun resumes each case from its checkpoint) or waits until they have ended; either way it
returns only when none of them is pending, running or completing.

A job of the workflow is recognised by what the SLURM executor plugin gives every job it
submits: the job name is the run's ID (a UUID, after the profile's ``slurm-jobname-prefix``),
the comment names the rule and wildcards (``rule_case_wildcards_shear_NH_Ca0.02``), and the
working directory (``sbatch -D``) is the workflow's. Only jobs of this user whose working
directory is the workflow's are considered.

Nothing is touched while a Snakemake process that is not a job step (no ``--mode remote``)
works in the directory on this machine: that run is alive and owns its jobs.
"""

from __future__ import annotations

import os
import pwd
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

import yaml

from capsmech.errors import CapsmechError
from capsmech.workflow.runner import clear_stale_lock, running_snakemake
from capsmech.workflow.slurm import Runner, run_command

#: A job name the SLURM executor plugin gives: the run's UUID, after an optional prefix.
PLUGIN_JOB_NAME = re.compile(r"^(?:[A-Za-z0-9_-]{1,50}_)?[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}$")

#: squeue states of a job that has ended (squeue shows such a job for ``MinJobAge`` seconds).
ENDED_STATES = frozenset({"COMPLETED", "CANCELLED", "FAILED", "TIMEOUT", "NODE_FAIL", "PREEMPTED",
                          "BOOT_FAIL", "DEADLINE", "OUT_OF_MEMORY", "SPECIAL_EXIT", "REVOKED"})

#: squeue's output format: fields separated by ``|``; the working directory last, so that a
#: ``|`` in a comment cannot shift it.
SQUEUE_FORMAT = "%i|%T|%j|%k|%Z"

#: Seconds between two looks at the queue while old jobs end.
POLL_S = 5.0

#: Seconds between two progress lines while waiting (a line is also printed whenever a job ends).
REPORT_EVERY_S = 300.0


class OnOldJobs(str, Enum):
    """What to do with the jobs of a killed run that are still in SLURM's queue."""

    #: Cancel them (``scancel``); the rerun resumes each case from its checkpoint.
    CANCEL = "cancel"
    #: Wait until they have ended; the rerun keeps the cases they finished.
    WAIT = "wait"


#: What ``make database PROFILE=slurm`` does when no ``RECOVER=`` is given.
DEFAULT_ON_OLD_JOBS = OnOldJobs.CANCEL


class RecoveryError(CapsmechError, RuntimeError):
    """The jobs of an earlier run cannot be listed or ended; the rerun must not start."""


@dataclass(frozen=True)
class OldJob:
    """One job of the workflow in SLURM's queue, as ``squeue`` shows it."""

    job_id: str
    state: str
    name: str
    comment: str

    @property
    def case(self) -> str:
        """What the job computes, from the plugin's comment: ``case shear_NH_Ca0.02``."""
        match = re.match(r"^rule_(.+?)(?:_wildcards_(.+))?$", self.comment)
        if match is None:
            return self.comment or f"job {self.job_id}"
        return f"{match.group(1)} {match.group(2)}" if match.group(2) else match.group(1)

    def describe(self) -> str:
        """``case shear_NH_Ca0.02 (job 12, RUNNING)``."""
        return f"{self.case} (job {self.job_id}, {self.state})"


def parse_squeue(text: str, workdir: str | Path) -> list[OldJob]:
    """The workflow's jobs in ``squeue --format`` output (:data:`SQUEUE_FORMAT`) that work in ``workdir``.

    Parameters
    ----------
    text : str
        What ``squeue --noheader --format=%i|%T|%j|%k|%Z`` printed.
    workdir : str or Path
        The workflow's working directory (compared once resolved).

    Returns
    -------
    list of OldJob
        The jobs whose working directory is ``workdir``, whose name is one the SLURM executor
        plugin gives (the run's UUID) and whose comment names a rule, in squeue's order, the
        ended ones (a finished job squeue still shows) left out.
    """
    target = str(Path(workdir).resolve())
    jobs = []
    for line in text.splitlines():
        if not line.endswith("|" + target):
            continue
        fields = line[:-len(target) - 1].split("|", 3)
        if len(fields) != 4:
            continue
        job_id, state, name, comment = (field.strip() for field in fields)
        if PLUGIN_JOB_NAME.match(name) and comment.startswith("rule_") and state not in ENDED_STATES:
            jobs.append(OldJob(job_id=job_id, state=state, name=name, comment=comment))
    return jobs


def squeue_argv(user: str | None = None) -> list[str]:
    """The ``squeue`` command listing this user's jobs in :data:`SQUEUE_FORMAT`."""
    user = user or pwd.getpwuid(os.getuid()).pw_name
    return ["squeue", "--noheader", f"--user={user}", f"--format={SQUEUE_FORMAT}"]


def list_old_jobs(workdir: str | Path, run: Runner = run_command, attempts: int = 3,
                  sleep: Callable[[float], None] = time.sleep) -> list[OldJob]:
    """The workflow's jobs in SLURM's queue that work in ``workdir`` (:func:`parse_squeue`).

    Parameters
    ----------
    workdir : str or Path
        The workflow's working directory.
    run : callable
        Command runner (tests pass a fake one).
    attempts : int
        Tries before a failing ``squeue`` (a busy controller) is an error.
    sleep : callable
        Pause between tries [s].

    Raises
    ------
    RecoveryError
        ``squeue`` is missing or keeps failing: nobody can tell whether old jobs still run.
    """
    argv = squeue_argv()
    why = ""
    for attempt in range(attempts):
        status, out, err = run(argv)
        if status == 0:
            return parse_squeue(out, workdir)
        why = " ".join((err or out).split()) or f"exit status {status}"
        if status == 127:
            break
        if attempt + 1 < attempts:
            sleep(POLL_S)
    raise RecoveryError(f"cannot list the SLURM jobs of an earlier run in {workdir} ({' '.join(argv)}: {why}); "
                        f"the rerun would not know whether old jobs still compute its cases. Run it where "
                        f"SLURM's commands work, or check with squeue yourself and remove the lock with "
                        f"snakemake --unlock")


def main_snakemake_pids(workdir: str | Path) -> list[int]:
    """Ids of Snakemake processes on this machine that run a workflow in ``workdir`` (not a job's step).

    A job step of the SLURM executor runs a Snakemake of its own in the workflow's directory,
    with ``--mode remote``: it holds no lock and is not the run that owns the jobs.
    """
    pids = []
    for pid in running_snakemake(workdir):
        try:
            argv = Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").split("\0")
        except OSError:  # ended meanwhile
            continue
        modes = [argv[k + 1] for k, arg in enumerate(argv[:-1]) if arg == "--mode"]
        modes += [arg.split("=", 1)[1] for arg in argv if arg.startswith("--mode=")]
        if not any(mode in ("remote", "subprocess") for mode in modes):
            pids.append(pid)
    return pids


def clear_lock_of_killed_run(workdir: str | Path) -> bool:
    """Remove Snakemake's lock in ``workdir`` unless a run (not a job step) works there.

    Returns
    -------
    bool
        True when a lock was removed.
    """
    return clear_stale_lock(workdir, main_snakemake_pids)


def slurm_profile(profile: str | Path | None) -> bool:
    """Whether the Snakemake profile folder ``profile`` runs the jobs on SLURM (``executor: slurm``).

    Raises
    ------
    RecoveryError
        The profile has no readable ``config.yaml``.
    """
    if profile is None:
        return False
    config = Path(profile) / "config.yaml"
    try:
        settings = yaml.safe_load(config.read_text())
    except (OSError, yaml.YAMLError) as error:
        raise RecoveryError(f"{config}: cannot read the Snakemake profile ({error})") from None
    return isinstance(settings, dict) and settings.get("executor") == "slurm"


def _names(jobs: Sequence[OldJob]) -> str:
    return "; ".join(job.describe() for job in jobs)


def recover_old_jobs(workdir: str | Path, on_old_jobs: OnOldJobs = DEFAULT_ON_OLD_JOBS, *,
                     run: Runner = run_command, sleep: Callable[[float], None] = time.sleep,
                     clock: Callable[[], float] = time.monotonic,
                     say: Callable[[str], None] = print) -> list[OldJob]:
    """Cancel, or wait for, the jobs an earlier run left in SLURM's queue; return when none is left.

    Parameters
    ----------
    workdir : str or Path
        The workflow's working directory.
    on_old_jobs : OnOldJobs
        Cancel the jobs (then wait until SLURM has ended them), or wait until they end.
    run : callable
        Command runner (tests pass a fake one).
    sleep, clock : callable
        Pause [s] and monotonic clock [s] (tests pass fake ones).
    say : callable
        Where the lines for the user go.

    Returns
    -------
    list of OldJob
        The jobs found (empty: nothing to do).

    Raises
    ------
    RecoveryError
        ``squeue`` or ``scancel`` fails.
    """
    found = list_old_jobs(workdir, run, sleep=sleep)
    if not found:
        return found
    other = OnOldJobs.WAIT if on_old_jobs is OnOldJobs.CANCEL else OnOldJobs.CANCEL
    say(f"{len(found)} SLURM job(s) of an earlier Snakemake run in {workdir} are still in the queue: "
        f"{_names(found)}.")
    if on_old_jobs is OnOldJobs.CANCEL:
        say(f"Cancelling them (RECOVER={on_old_jobs.value}); the rerun resumes their cases from their "
            f"checkpoints. RECOVER={other.value} (--on-old-jobs {other.value}) waits for them instead.")
        status, out, err = run(["scancel", *(job.job_id for job in found)])
        if status != 0:
            raise RecoveryError(f"scancel {' '.join(job.job_id for job in found)} failed: "
                                f"{' '.join((err or out).split())}")
    else:
        say(f"Waiting until they end (RECOVER={on_old_jobs.value}); the rerun keeps the cases they "
            f"finish. RECOVER={other.value} (--on-old-jobs {other.value}) cancels them instead.")
    started = last_report = clock()
    remaining = found
    while True:
        sleep(POLL_S)
        now_left = list_old_jobs(workdir, run, sleep=sleep)
        if not now_left:
            break
        if {job.job_id for job in now_left} != {job.job_id for job in remaining} or \
                clock() - last_report >= REPORT_EVERY_S:
            say(f"{len(now_left)} job(s) of the earlier run left after {clock() - started:.0f} s: "
                f"{_names(now_left)}")
            last_report = clock()
        remaining = now_left
    say(f"The earlier run's jobs have ended ({clock() - started:.0f} s); no case is computed twice.")
    return found
