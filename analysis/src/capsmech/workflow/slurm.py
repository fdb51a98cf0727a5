"""Checks a run on SLURM needs before its first job is submitted (the workflow's onstart hook).

Two things make a workflow on SLURM wait for ever instead of failing, and neither is visible
to Snakemake or to its SLURM executor plugin:

* a job that no node can run (more CPUs, memory or wall time than any node of its partition
  offers) is accepted by ``sbatch`` and pends for ever with reason ``PartitionConfig``;
* Snakemake learns that a job ended from ``sacct`` or ``squeue``: ``sacct`` cannot answer on a
  cluster without accounting storage ("Slurm accounting storage is disabled"), and ``squeue``
  forgets a job ``MinJobAge`` seconds after it ended, possibly before Snakemake asks again.

:func:`check_slurm_run` finds both before anything is submitted: it asks ``sbatch --test-only``
whether each distinct request of the jobs to run fits the cluster, and checks that the status
command the plugin will use can answer, then raises :class:`SlurmCheckError` naming the request,
the nodes and the setting to change. The workflow calls it from its ``onstart`` hook (a no-op
unless the executor is ``slurm``; ``--no-hooks`` skips it).
"""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from capsmech.errors import CapsmechError

#: Longest wait of snakemake-executor-plugin-slurm (2.6.0) between two status checks, in
#: seconds: a job that ends and is forgotten by ``squeue`` within this time may never be seen.
MAX_STATUS_INTERVAL_S = 180

#: Where a user changes what a case job asks for.
PROFILE_HINT = ("set-threads / set-resources of the case rule in workflow/profiles/slurm/config.yaml "
                "(or --set-threads case=N, --set-resources case:mem_mb=M on the command line)")

#: A command runner: argv in, (exit status, stdout, stderr) out.
Runner = Callable[[Sequence[str]], tuple[int, str, str]]


class SlurmCheckError(CapsmechError, RuntimeError):
    """The run cannot work on this SLURM cluster; nothing was submitted."""


def run_command(argv: Sequence[str]) -> tuple[int, str, str]:
    """Run ``argv`` and return ``(exit status, stdout, stderr)``; 127 when it is not found.

    Parameters
    ----------
    argv : sequence of str
        The command line.

    Returns
    -------
    tuple of (int, str, str)
        Exit status, standard output and standard error.
    """
    if shutil.which(argv[0]) is None:
        return 127, "", f"{argv[0]}: command not found"
    try:
        proc = subprocess.run(list(argv), capture_output=True, text=True, timeout=60)
    except subprocess.TimeoutExpired:
        return 124, "", f"{argv[0]} did not answer within 60 s"
    return proc.returncode, proc.stdout, proc.stderr


@dataclass(frozen=True)
class JobRequest:
    """What one SLURM job of a rule asks for, as the executor plugin passes it to ``sbatch``."""

    #: The rule whose jobs ask for it.
    rule: str
    #: CPUs per task (the rule's threads, or its ``cpus_per_task`` resource).
    cpus: int
    #: Memory per job [MB] (``--mem``), or None.
    mem_mb: int | None = None
    #: Memory per CPU [MB] (``--mem-per-cpu``), or None.
    mem_mb_per_cpu: int | None = None
    #: Wall time [min] (``-t``), or None.
    runtime: int | None = None
    #: Partition (``-p``), or None for the cluster's default partition.
    partition: str | None = None
    #: Account (``-A``), or None.
    account: str | None = None
    #: Quality of service (``--qos``), or None.
    qos: str | None = None
    #: Node features (``-C``), or None.
    constraint: str | None = None
    #: More sbatch options, verbatim (the ``slurm_extra`` resource), or None.
    extra: str | None = None

    @classmethod
    def of_job(cls, job: Any) -> JobRequest:
        """The request of a Snakemake job (its rule name, threads and resources).

        Parameters
        ----------
        job : snakemake.jobs.Job
            A job of the DAG (anything with ``rule.name``, ``threads`` and ``resources.get``).

        Returns
        -------
        JobRequest
        """
        res = job.resources

        def number(name: str) -> int | None:
            value = res.get(name)
            return int(value) if isinstance(value, (int, float)) and value > 0 else None

        def text(name: str) -> str | None:
            value = res.get(name)
            return str(value) if value not in (None, "") else None

        cpus = res.get("cpus_per_task")
        return cls(rule=job.rule.name,
                   cpus=max(1, int(cpus)) if isinstance(cpus, int) and cpus > 0 else max(1, int(job.threads)),
                   mem_mb=number("mem_mb"), mem_mb_per_cpu=number("mem_mb_per_cpu"),
                   runtime=number("runtime"), partition=text("slurm_partition"),
                   account=text("slurm_account"), qos=text("qos"), constraint=text("constraint"),
                   extra=text("slurm_extra"))

    def sbatch_args(self) -> list[str]:
        """The ``sbatch`` options of this request (as the plugin sets them), without the script."""
        args = ["--ntasks=1", f"--cpus-per-task={self.cpus}"]
        if self.partition:
            args.append(f"--partition={self.partition}")
        if self.account:
            args.append(f"--account={self.account}")
        if self.runtime:
            args.append(f"--time={self.runtime}")
        if self.mem_mb_per_cpu:
            args.append(f"--mem-per-cpu={self.mem_mb_per_cpu}")
        elif self.mem_mb:
            args.append(f"--mem={self.mem_mb}")
        if self.qos:
            args.append(f"--qos={self.qos}")
        if self.constraint:
            args.append(f"--constraint={self.constraint}")
        if self.extra:
            args.extend(shlex.split(self.extra))
        return args

    def describe(self) -> str:
        """One line: ``rule case asks for 4 CPUs, 4000 MB, 240 min (default partition) per job``."""
        parts = [f"{self.cpus} CPU{'s' if self.cpus != 1 else ''}"]
        if self.mem_mb_per_cpu:
            parts.append(f"{self.mem_mb_per_cpu} MB per CPU")
        elif self.mem_mb:
            parts.append(f"{self.mem_mb} MB")
        if self.runtime:
            parts.append(f"{self.runtime} min")
        where = [f"partition {self.partition}" if self.partition else "default partition"]
        for name in ("account", "qos", "constraint", "extra"):
            value = getattr(self, name)
            if value:
                where.append(f"{name} {value}")
        return f"rule {self.rule} asks for {', '.join(parts)} ({', '.join(where)}) per job"


def job_requests(jobs: Iterable[Any]) -> list[JobRequest]:
    """The distinct requests of the jobs that go to the cluster (local jobs left out), in order.

    Parameters
    ----------
    jobs : iterable of snakemake.jobs.Job
        The jobs to run (``workflow.dag.needrun_jobs()``).

    Returns
    -------
    list of JobRequest
    """
    requests: dict[JobRequest, None] = {}
    for job in jobs:
        if not job.is_local:
            requests.setdefault(JobRequest.of_job(job), None)
    return list(requests)


def try_request(request: JobRequest, run: Runner = run_command) -> str | None:
    """Ask ``sbatch --test-only`` whether SLURM could ever run ``request``.

    Parameters
    ----------
    request : JobRequest
        The request.
    run : callable
        Command runner (tests pass a fake one).

    Returns
    -------
    str or None
        None when SLURM would accept and schedule it (some time), else sbatch's message.
    """
    status, out, err = run(["sbatch", "--test-only", *request.sbatch_args(), "--wrap=true"])
    if status == 0:
        return None
    return " ".join((err or out).split()) or f"sbatch --test-only exited with status {status}"


def describe_nodes(run: Runner = run_command) -> str:
    """The cluster's partitions and their nodes, one line each (``sinfo``), for error messages."""
    status, out, err = run(["sinfo", "--noheader", "--format=%P|%D|%c|%m|%l"])
    if status != 0:
        return f"(sinfo failed: {' '.join(err.split())})"
    lines = []
    for row in out.splitlines():
        fields = row.strip().split("|")
        if len(fields) == 5:
            partition, count, cpus, mem, limit = fields
            lines.append(f"  partition {partition}: {count} node(s) of {cpus} CPUs, {mem} MB, "
                         f"time limit {limit}")
    return "\n".join(lines) or "  (sinfo lists no node)"


def parse_min_job_age(config_text: str) -> int | None:
    """``MinJobAge`` in seconds from the output of ``scontrol show config``, or None.

    Parameters
    ----------
    config_text : str
        What ``scontrol show config`` printed (``MinJobAge = 300 sec``).

    Returns
    -------
    int or None
    """
    match = re.search(r"^\s*MinJobAge\s*=\s*(\d+)\s*([A-Za-z]*)", config_text, re.M)
    if match is None:
        return None
    value, unit = int(match.group(1)), match.group(2).lower()
    return value * 3600 if unit in ("h", "hour", "hours") else value


def effective_status_command(configured: str | None, min_job_age: int | None, init_seconds: int,
                             sacct_installed: bool) -> str:
    """The status command the SLURM executor plugin (2.6.0) will really use.

    The plugin takes ``squeue`` only when ``MinJobAge`` is at least three times its first
    status-check interval, and otherwise falls back to ``sacct`` when that is installed; it
    takes ``squeue`` when ``sacct`` is not installed.

    Parameters
    ----------
    configured : str or None
        ``slurm-status-command`` (None: the plugin's default, ``sacct`` when installed).
    min_job_age : int or None
        The cluster's ``MinJobAge`` [s], None when unknown.
    init_seconds : int
        ``slurm-init-seconds-before-status-checks`` [s].
    sacct_installed : bool
        Whether a ``sacct`` command exists.

    Returns
    -------
    str
        ``"sacct"`` or ``"squeue"``.
    """
    command = configured or ("sacct" if sacct_installed else "squeue")
    if command == "squeue" and sacct_installed and (min_job_age is None or min_job_age < 3 * init_seconds):
        command = "sacct"
    if command == "sacct" and not sacct_installed:
        command = "squeue"
    return command


def status_problem(configured: str | None, init_seconds: int, run: Runner = run_command) -> str | None:
    """Why Snakemake could not see the cluster's jobs end, or None when it can.

    Parameters
    ----------
    configured : str or None
        ``slurm-status-command`` as set (None: the plugin's default).
    init_seconds : int
        ``slurm-init-seconds-before-status-checks`` [s].
    run : callable
        Command runner (tests pass a fake one).

    Returns
    -------
    str or None
        A message naming the command, the cluster setting and what to change.
    """
    status, out, _ = run(["scontrol", "show", "config"])
    min_job_age = parse_min_job_age(out) if status == 0 else None
    sacct_installed = run(["sacct", "--version"])[0] != 127
    command = effective_status_command(configured, min_job_age, init_seconds, sacct_installed)
    age = f"{min_job_age} s" if min_job_age is not None else "unknown"
    if command == "sacct":
        status, out, err = run(["sacct", "-X", "--parsable2", "--noheader", "--format=JobIdRaw,State",
                                "--name=capsmech-status-check"])
        if status == 0:
            return None
        why = " ".join((err or out).split())
        needed = max(3 * init_seconds, MAX_STATUS_INTERVAL_S + init_seconds)
        if min_job_age is not None and min_job_age >= needed:
            remedy = f"this cluster's MinJobAge ({age}) is long enough for it"
        else:
            remedy = (f"squeue needs MinJobAge >= {needed} s (this cluster: {age}): ask the "
                      f"administrators for it, or for accounting storage")
        return (f"job status: the plugin would ask sacct, which cannot answer here ({why}), so Snakemake "
                f"would never see a job end. Set slurm-status-command: squeue in the profile; {remedy}.")
    if min_job_age is None or min_job_age < MAX_STATUS_INTERVAL_S + init_seconds:
        return (f"job status: squeue forgets a job MinJobAge = {age} after it ends, and Snakemake may "
                f"wait up to {MAX_STATUS_INTERVAL_S} s between two checks: a job that ends unseen would "
                f"be waited for for ever. Use slurm-status-command: sacct if this cluster has "
                f"accounting storage, else ask for MinJobAge >= {MAX_STATUS_INTERVAL_S + init_seconds} s.")
    return None


def check_requests(requests: Sequence[JobRequest], configured_status: str | None, init_seconds: int,
                   run: Runner = run_command) -> None:
    """Raise :class:`SlurmCheckError` when a request can never run or job status cannot be read.

    Parameters
    ----------
    requests : sequence of JobRequest
        The distinct requests of the jobs to submit.
    configured_status : str or None
        ``slurm-status-command`` as set.
    init_seconds : int
        ``slurm-init-seconds-before-status-checks`` [s].
    run : callable
        Command runner (tests pass a fake one).

    Raises
    ------
    SlurmCheckError
        Every problem found, with what to change; nothing has been submitted.
    """
    if not requests:
        return
    if run(["sbatch", "--version"])[0] == 127:
        raise SlurmCheckError("SLURM check: sbatch is not installed here: run the workflow with "
                              "--profile workflow/profiles/slurm on a machine that submits SLURM jobs")
    problems = []
    for request in requests:
        refusal = try_request(request, run)
        if refusal is not None:
            problems.append(f"{request.describe()}, and no node of the cluster can run that "
                            f"(sbatch --test-only: {refusal}). Change {PROFILE_HINT}, or choose another "
                            f"slurm_partition.\n{describe_nodes(run)}")
    status = status_problem(configured_status, init_seconds, run)
    if status is not None:
        problems.append(status)
    if problems:
        raise SlurmCheckError("SLURM check before the first submission (nothing was submitted):\n- "
                              + "\n- ".join(problems))


def check_slurm_run(workflow: Any) -> None:
    """The workflow's ``onstart`` check: on SLURM, fail now rather than wait for ever.

    Does nothing unless the executor is ``slurm``. Otherwise checks every distinct request of the
    jobs to run that go to the cluster, and the status command, with :func:`check_requests`.

    Parameters
    ----------
    workflow : snakemake.workflow.Workflow
        The running workflow (the ``workflow`` object of a Snakefile).

    Raises
    ------
    SlurmCheckError
        As :func:`check_requests`.
    """
    plugin = getattr(workflow, "executor_plugin", None)
    if plugin is None or plugin.name != "slurm":
        return
    settings = workflow.executor_settings
    check_requests(job_requests(workflow.dag.needrun_jobs()),
                   getattr(settings, "status_command", None),
                   int(getattr(settings, "init_seconds_before_status_checks", None) or 40))
