"""The workflow on a real SLURM cluster: a one-node cluster on this machine (issue 24).

``scripts/slurm_one_node.sh`` installs slurm-wlm and munge when missing and starts munged,
slurmctld and slurmd on this machine's host name, everything under a temporary folder (node CPUs
and memory read by ``slurmd -C``; no accounting storage, so ``sacct`` cannot answer). The tests
marked ``cluster`` then run the workflow through ``--profile workflow/profiles/slurm`` as shipped
(only the status-check interval shortened):

* the smoke grid, whose databases must equal the local profile's value for value;
* a grid of two longer cases, one cancelled (``scancel``) and one killed (SIGKILL of its kernel)
  once each has written a checkpoint: both are retried, resume from their checkpoints, and the
  database equals the local one;
* requests no node can run, and a status command the cluster cannot answer: the run stops
  before the first submission, with a message, instead of waiting for ever.

The daemons are stopped by their process ids whatever happens (the fixture's finalizer). The
tests are skipped, with the reason, only where the cluster cannot run: not root, or slurm-wlm
missing and no apt-get (or no network) to install it. ``pytest -m cluster`` selects them,
``-m "not cluster"`` leaves them out. The other tests here check capsmech.workflow.slurm
without a cluster.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import pytest
import yaml
from slurm_recovery_run import Watcher, local_kill_grid, rerun_after_a_killed_snakemake

from capsmech.workflow.grid import expand_cases, load_grid
from capsmech.workflow.slurm import (
    JobRequest,
    SlurmCheckError,
    check_requests,
    effective_status_command,
    parse_min_job_age,
)

from conftest import REPO, SMOKE, SNAKEFILE, assert_same_database, run_snakemake

SCRIPT = REPO / "scripts" / "slurm_one_node.sh"
SLURM_PROFILE = REPO / "workflow" / "profiles" / "slurm"
#: The only departure from the shipped profile: status checks every 2 s rather than 40 s (the
#: one-node cluster keeps finished jobs for MinJobAge = 300 s, so squeue still sees them all).
FAST_STATUS = ("--slurm-init-seconds-before-status-checks", "2", "--seconds-between-status-checks", "2")
#: Two shear cases of ~30 s of one core each (level 3, small Ca_s: many steps): long enough to
#: write a checkpoint (every 10 s of wall time) before they are cancelled or killed.
#: Two shear cases that outlive the kernel's 10 s checkpoint interval on an idle machine (t_max
#: 10: 23-28 s on one thread; with t_max 4 the second finished in 9 s, before its first
#: checkpoint, and the test had nothing to kill).
FAULT_GRID = {
    "name": "faults", "databases_dir": "db", "results_dir": "results",
    "shear": {"laws": ["NH"], "Ca_s": [0.02, 0.025], "settings": {"level": 3, "t_max": 10}},
}
CANCELLED, KILLED = "shear/NH/Ca0.02", "shear/NH/Ca0.025"


# --- capsmech.workflow.slurm without a cluster ------------------------------------------------

class FakeSlurm:
    """A command runner that answers as a cluster of ``cpus``-CPU nodes would."""

    def __init__(self, cpus: int = 2, sacct_error: str | None = "Slurm accounting storage is disabled",
                 min_job_age: int = 300) -> None:
        self.cpus, self.sacct_error, self.min_job_age = cpus, sacct_error, min_job_age
        self.calls: list[list[str]] = []

    def __call__(self, argv: Sequence[str]) -> tuple[int, str, str]:
        argv = list(argv)
        self.calls.append(argv)
        if argv[1:] == ["--version"]:
            return 0, "slurm 22.05.8\n", ""
        if argv[0] == "sbatch":
            cpus = int(next(a for a in argv if a.startswith("--cpus-per-task=")).split("=")[1])
            if cpus > self.cpus:
                return 1, "", "allocation failure: Requested node configuration is not available\n"
            return 0, "", "sbatch: Job 4 to start at 2026-11-26T00:00:00 using 1 processors on nodes vm\n"
        if argv[0] == "sinfo":
            return 0, f"main*|1|{self.cpus}|24105|infinite\n", ""
        if argv[0] == "scontrol":
            return 0, f"MaxJobCount             = 10000\nMinJobAge               = {self.min_job_age} sec\n", ""
        if argv[0] == "sacct":
            return (1, "", self.sacct_error + "\n") if self.sacct_error else (0, "", "")
        raise AssertionError(f"unexpected command {argv}")


def test_request_is_what_the_plugin_submits() -> None:
    """Threads are the CPUs per task (one setting); memory, time, partition, account follow."""
    request = JobRequest(rule="case", cpus=4, mem_mb=4000, runtime=240, partition="compute", account="lab")
    assert request.sbatch_args() == ["--ntasks=1", "--cpus-per-task=4", "--partition=compute", "--account=lab",
                                     "--time=240", "--mem=4000"]
    assert request.describe() == "rule case asks for 4 CPUs, 4000 MB, 240 min (partition compute, account lab) per job"

    class Job:
        is_local = False
        threads = 3
        rule = type("Rule", (), {"name": "case"})
        resources = {"mem_mb": 1000, "runtime": 60, "slurm_partition": "short"}

    assert JobRequest.of_job(Job()) == JobRequest(rule="case", cpus=3, mem_mb=1000, runtime=60, partition="short")


def test_status_command_choice_follows_the_plugin() -> None:
    assert parse_min_job_age("MinJobAge               = 300 sec\n") == 300
    assert parse_min_job_age("MinJobAge = 1h\n") == 3600
    assert parse_min_job_age("nothing\n") is None
    assert effective_status_command("squeue", 300, 40, sacct_installed=True) == "squeue"
    assert effective_status_command("squeue", 60, 40, sacct_installed=True) == "sacct"   # plugin's fallback
    assert effective_status_command(None, 300, 40, sacct_installed=True) == "sacct"      # plugin's default
    assert effective_status_command("sacct", 300, 40, sacct_installed=False) == "squeue"


def test_check_stops_a_request_beyond_every_node_and_an_unreadable_status() -> None:
    fits = [JobRequest(rule="case", cpus=1, mem_mb=1000, runtime=240)]
    check_requests(fits, "squeue", 40, FakeSlurm())                       # no accounting, squeue: fine
    check_requests(fits, "sacct", 40, FakeSlurm(sacct_error=None))        # accounting, sacct: fine
    with pytest.raises(SlurmCheckError) as error:
        check_requests([JobRequest(rule="case", cpus=4, mem_mb=4000, runtime=240)], "sacct", 40, FakeSlurm())
    message = str(error.value)
    assert "rule case asks for 4 CPUs, 4000 MB, 240 min (default partition) per job" in message
    assert "Requested node configuration is not available" in message
    assert "partition main*: 1 node(s) of 2 CPUs, 24105 MB" in message
    assert "Slurm accounting storage is disabled" in message and "slurm-status-command: squeue" in message
    with pytest.raises(SlurmCheckError, match="MinJobAge = 60 s"):  # squeue would forget finished jobs
        check_requests(fits, "squeue", 10, FakeSlurm(min_job_age=60))


def test_shipped_profile_sets_cpus_from_threads_and_reads_status_with_squeue() -> None:
    profile = yaml.safe_load((SLURM_PROFILE / "config.yaml").read_text())
    assert profile["executor"] == "slurm" and profile["slurm-status-command"] == "squeue"
    assert "cpus_per_task" not in profile["set-resources"]["case"]  # CPUs per task = threads
    assert profile["set-threads"]["case"] == 1 and profile["retries"] >= 1


# --- a one-node cluster -------------------------------------------------------------------------

def _why_no_cluster() -> str | None:
    """The reason the one-node cluster cannot run here, or None."""
    if not sys.platform.startswith("linux"):
        return "the one-node SLURM cluster needs Linux"
    if os.geteuid() != 0:
        return "the one-node SLURM cluster needs root (slurmd starts the jobs)"
    if shutil.which("slurmctld") is None and shutil.which("apt-get") is None:
        return "slurm-wlm is not installed and there is no apt-get to install it"
    conf = Path("/etc/slurm/slurm.conf")
    if (conf.exists() or conf.is_symlink()) and not (
            conf.is_symlink() and (not conf.exists() or "slurm_one_node.sh" in conf.read_text())):
        return "this machine has a SLURM configuration of its own (/etc/slurm/slurm.conf): not starting another"
    return None


def _kill_by_pid_files(directory: Path) -> None:
    """Last resort of the finalizer: SIGKILL each daemon of ``directory/run/*.pid`` still alive."""
    for pid_file in (directory / "run").glob("*.pid"):
        try:
            pid = int(pid_file.read_text().split()[0])
            name = pid_file.name.split(".")[0]
            if name.encode() in Path(f"/proc/{pid}/cmdline").read_bytes():
                os.kill(pid, signal.SIGKILL)
        except (OSError, ValueError, IndexError):
            continue


@pytest.fixture(scope="module")
def slurm_cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    """A running one-node cluster: its folder and node; stopped afterwards whatever happens."""
    reason = _why_no_cluster()
    if reason:
        pytest.skip(reason)
    started = time.monotonic()
    install = subprocess.run(["bash", str(SCRIPT), "install"], text=True, stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, timeout=600)
    if install.returncode != 0:
        pytest.skip(f"slurm-wlm and munge could not be installed (no network?): {install.stdout[-1500:]}")
    installed = time.monotonic() - started
    directory = tmp_path_factory.mktemp("slurm")
    try:
        start = subprocess.run(["bash", str(SCRIPT), "start", str(directory)], text=True,
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=120)
        assert start.returncode == 0, start.stdout
        node = subprocess.run(["sinfo", "-h", "-N", "-o", "%N %c %m"], text=True, capture_output=True,
                              check=True).stdout.split()
        print(f"one-node cluster: install {installed:.0f} s, {start.stdout.strip()}")
        yield {"dir": directory, "node": node[0], "cpus": int(node[1]), "mem_mb": int(node[2])}
    finally:
        subprocess.run(["bash", str(SCRIPT), "stop", str(directory)], timeout=120)
        _kill_by_pid_files(directory)


def slurm_argv(workdir: Path, configfile: Path, *extra: str) -> list[str]:
    """The workflow on ``configfile`` through the shipped SLURM profile, in ``workdir``."""
    return [sys.executable, "-m", "snakemake", "-s", str(SNAKEFILE), "--configfile", str(configfile),
            "--profile", str(SLURM_PROFILE), "--directory", str(workdir), *FAST_STATUS, *extra]


def run_on_slurm(workdir: Path, configfile: Path, *extra: str, timeout: float = 1200) -> subprocess.CompletedProcess:
    workdir.mkdir(parents=True, exist_ok=True)
    return subprocess.run(slurm_argv(workdir, configfile, *extra), cwd=workdir, text=True,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=timeout)


def _our_jobs() -> list[str]:
    return subprocess.run(["squeue", "-h", "-t", "PD,R,CG", "-o", "%i"], text=True,
                          capture_output=True).stdout.split()


@pytest.mark.cluster
def test_smoke_grid_on_slurm_equals_local(slurm_cluster: dict, smoke_run: dict, tmp_path: Path) -> None:
    """The smoke grid through the shipped profile: every case a SLURM job, job states from squeue
    (no accounting storage), all steps done, both databases equal to the local profile's."""
    grid = load_grid(SMOKE)
    cases = sum(len(expand_cases(grid, flow)) for flow in ("tube", "shear"))
    started = time.monotonic()
    result = run_on_slurm(tmp_path, SMOKE)
    elapsed = time.monotonic() - started
    assert result.returncode == 0, result.stdout[-6000:]
    steps = cases + 7  # kernel_version, grid_record, 2 databases, 2 figures, all
    assert f"{steps} of {steps} steps (100%) done" in result.stdout
    submitted = re.findall(r"has been submitted with SLURM jobid (\d+)", result.stdout)
    assert len(submitted) == cases
    assert "Falling back to 'sacct'" not in result.stdout
    for flow in ("tube", "shear"):
        assert_same_database(tmp_path / grid["databases_dir"] / f"{flow}.h5",
                      smoke_run["workdir"] / grid["databases_dir"] / f"{flow}.h5")
    assert _our_jobs() == []
    print(f"smoke grid on a {slurm_cluster['cpus']}-CPU SLURM node: {steps} of {steps} steps, {cases} jobs, "
          f"{elapsed:.0f} s (local profile: {smoke_run['seconds']:.0f} s)")


def _wait_for(predicate, what: str, proc: subprocess.Popen, timeout: float = 600):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        if proc.poll() is not None:
            pytest.fail(f"the workflow ended (exit {proc.returncode}) before {what}")
        time.sleep(0.5)
    pytest.fail(f"no {what} after {timeout:.0f} s")


def _kernel_pid(workdir: Path, out: Path) -> int | None:
    """The capsim process writing ``out`` (relative to ``workdir``, its working directory)."""
    for proc in Path("/proc").glob("[0-9]*"):
        try:
            argv = (proc / "cmdline").read_bytes().split(b"\0")
            if argv[0].endswith(b"capsim") and str(out).encode() in argv and (proc / "cwd").resolve() == workdir:
                return int(proc.name)
        except OSError:
            continue
    return None


@pytest.mark.cluster
def test_cancelled_and_killed_cases_resume_from_their_checkpoints(slurm_cluster: dict, tmp_path: Path) -> None:
    """One case job scancel'd, the kernel of another SIGKILLed, each after its first checkpoint:
    the profile's retry runs them again, the kernel resumes from the checkpoint, and the database
    equals that of an uninterrupted local run."""
    grid_file = tmp_path / "faults.yaml"
    grid_file.write_text(yaml.safe_dump(FAULT_GRID))
    local = run_snakemake(tmp_path / "local", grid_file, timeout=900)
    assert local.returncode == 0, local.stdout[-4000:]

    workdir = tmp_path / "slurm"
    workdir.mkdir()
    cases = workdir / "results" / "cases"
    started = time.monotonic()
    with open(tmp_path / "slurm.log", "w") as log:
        proc = subprocess.Popen(slurm_argv(workdir, grid_file), cwd=workdir, stdout=log, stderr=subprocess.STDOUT)
    try:
        # Case 1: once its checkpoint exists, cancel its SLURM job (found by its comment).
        ckpt = cases / f"{CANCELLED}.h5.ckpt"
        _wait_for(ckpt.exists, f"checkpoint {ckpt.name}", proc)
        wildcards = CANCELLED.replace("/", "_")
        jobs = subprocess.run(["squeue", "-h", "-o", "%i %k"], text=True, capture_output=True).stdout
        (job_id,) = [line.split()[0] for line in jobs.splitlines() if line.endswith(f"_wildcards_{wildcards}")]
        subprocess.run(["scancel", job_id], check=True)
        # Case 2: once its checkpoint exists, SIGKILL its kernel (as the out-of-memory killer would).
        out = Path("results") / "cases" / f"{KILLED}.h5"
        _wait_for((workdir / f"{out}.ckpt").exists, f"checkpoint of {KILLED}", proc)
        os.kill(_wait_for(lambda: _kernel_pid(workdir, out), f"kernel of {KILLED}", proc), signal.SIGKILL)
        proc.wait(timeout=1200)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)  # snakemake cancels its SLURM jobs
            proc.wait(timeout=120)
    elapsed = time.monotonic() - started
    output = (tmp_path / "slurm.log").read_text()
    assert proc.returncode == 0, output[-6000:]
    assert f"SLURM-job '{job_id}' failed, SLURM status is: 'CANCELLED'" in output
    assert re.search(r"SLURM-job '\d+' failed, SLURM status is: 'FAILED'", output)
    assert len(re.findall(r"has been submitted with SLURM jobid", output)) == 4  # 2 cases, each twice
    resumed = {}
    for case in (CANCELLED, KILLED):
        log_text = (workdir / "results" / "logs" / "cases" / f"{case}.log").read_text()
        match = re.search(r"capsim: resumed from checkpoint at t = (\S+)", log_text)
        assert match, f"{case} did not resume from its checkpoint:\n{log_text[-2000:]}"
        resumed[case] = float(match.group(1))
        assert resumed[case] > 0
    assert_same_database(workdir / "db" / "shear.h5", tmp_path / "local" / "db" / "shear.h5")
    assert _our_jobs() == []
    print(f"faults on SLURM: {CANCELLED} cancelled (job {job_id}), {KILLED} killed; resumed at t = "
          f"{resumed[CANCELLED]:g} and {resumed[KILLED]:g}; database equal to the local one; {elapsed:.0f} s")


@pytest.mark.cluster
def test_requests_the_cluster_cannot_serve_stop_the_run(slurm_cluster: dict, tmp_path: Path) -> None:
    """A case asking for more CPUs than the node has, and a status command (sacct) that cannot
    answer without accounting storage: the run stops before any submission and says why."""
    cpus = slurm_cluster["cpus"] + 1
    started = time.monotonic()
    result = run_on_slurm(tmp_path, SMOKE, "--set-threads", f"case={cpus}", "--slurm-status-command", "sacct",
                          timeout=300)
    elapsed = time.monotonic() - started
    assert result.returncode != 0
    assert "nothing was submitted" in result.stdout, result.stdout[-4000:]
    assert f"rule case asks for {cpus} CPUs, 1000 MB, 240 min (default partition) per job" in result.stdout
    assert "Requested node configuration is not available" in result.stdout
    assert f"1 node(s) of {slurm_cluster['cpus']} CPUs" in result.stdout
    assert "Slurm accounting storage is disabled" in result.stdout
    assert "has been submitted" not in result.stdout and _our_jobs() == []
    print(f"unschedulable request and unreadable status reported in {elapsed:.0f} s")


@pytest.mark.cluster
def test_simulations_on_demand_run_on_the_cluster(slurm_cluster: dict, tmp_path: Path) -> None:
    """Issue 22, item 5: the on-demand path (``diagnose --simulate``, ``database simulate``) with
    the SLURM profile: every case a SLURM job, the database equal to the local profile's."""
    from test_simulate_on_demand import TINY

    from capsmech.io.database import load_database
    from capsmech.workflow.simulate import simulate_grid

    local = simulate_grid(TINY, root=tmp_path / "local", cores=2)
    on_slurm = simulate_grid(TINY, root=tmp_path / "slurm", profile=SLURM_PROFILE, snakemake_args=FAST_STATUS)
    log = (on_slurm.parent / "workflow.log").read_text()
    assert len(re.findall(r"has been submitted with SLURM jobid (\d+)", log)) == 4, log[-3000:]
    # The two caches place their files differently (recorded in the provenance): compare the
    # law's rows, bit for bit.
    a, b = load_database(on_slurm).law("SK_C4"), load_database(local).law("SK_C4")
    assert list(a.status) == list(b.status)
    for column in ("a_over_l", "Ca_s", "L_z", "L_p", "vc_over_V"):
        assert np.array_equal(a.column(column, steady_only=False), b.column(column, steady_only=False)), column
    assert _our_jobs() == []


# --- recovery after a killed Snakemake (steps in slurm_recovery_run.py) ------------------------

@pytest.fixture(scope="module")
def kill_grid(tmp_path_factory: pytest.TempPathFactory) -> dict:
    return local_kill_grid(tmp_path_factory.mktemp("recovery"))


@pytest.fixture
def watcher(tmp_path: Path) -> Iterator[Watcher]:
    w = Watcher(tmp_path / "slurm")
    yield w
    w.stop()


@pytest.mark.cluster
@pytest.mark.parametrize("recover", ["cancel", "wait"])
def test_rerun_after_a_killed_snakemake_computes_no_case_twice(slurm_cluster: dict, kill_grid: dict, recover: str,
                                                                tmp_path: Path, watcher: Watcher) -> None:
    """SIGKILL of Snakemake while both case jobs compute; the documented command then cancels
    the old jobs (the cases are submitted again) or waits for them (the rerun submits no case):
    never two jobs or two kernels on one case, and the database of an uninterrupted run."""
    rerun_after_a_killed_snakemake(kill_grid, recover, tmp_path, watcher)
