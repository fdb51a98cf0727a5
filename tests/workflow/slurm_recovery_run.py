"""The one-node cluster's half of the recovery test (tests/workflow/test_slurm_recovery.py):
a Snakemake run on SLURM killed by SIGKILL while both case jobs compute, then the documented
command. Its test lives in test_slurm_cluster.py, beside the other cluster tests, so that one
pytest worker holds the one cluster this machine can run (two modules on two workers each
started one, and the second was refused).
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from types import ModuleType

import pytest
import yaml

from capsmech.workflow.recovery import OldJob, parse_squeue

from conftest import assert_same_database, run_snakemake


def cluster_module() -> ModuleType:
    """test_slurm_cluster (its profile and argv), imported when used: it imports this module."""
    import test_slurm_cluster

    return test_slurm_cluster


#: Two shear cases of ~10 s of one core each on an idle machine: both jobs run at once on the
#: 2-CPU node, long enough to be killed mid-run, short enough for a test. The integrator and
#: k_b are given, so that the kernel's flow-dependent defaults play no part.
KILL_GRID = {
    "name": "recovery", "databases_dir": "db", "results_dir": "results",
    "shear": {"laws": ["NH"], "Ca_s": [0.02, 0.025],
              "settings": {"level": 3, "t_max": 4, "integrator": "rk2", "k_b": 0.0}},
}
CASES = ("shear_NH_Ca0.02", "shear_NH_Ca0.025")


class Watcher(threading.Thread):
    """Samples, every ``period`` s, the workflow's unfinished SLURM jobs (``squeue``) and the
    kernel processes (``/proc``) of each case in ``workdir``; keeps the most seen at once."""

    def __init__(self, workdir: Path, period: float = 0.2) -> None:
        super().__init__(daemon=True)
        self.workdir, self.period = workdir.resolve(), period
        self.most_jobs: Counter[str] = Counter()
        self.most_kernels: Counter[str] = Counter()
        self.samples = 0
        self.halt = threading.Event()

    def unfinished_jobs(self) -> list[OldJob]:
        text = subprocess.run(["squeue", "--noheader", "--format=%i|%T|%j|%k|%Z"], text=True,
                              capture_output=True).stdout
        return parse_squeue(text, self.workdir)

    def jobs_per_case(self) -> Counter[str]:
        return Counter(job.case for job in self.unfinished_jobs())

    def kernels_per_case(self) -> Counter[str]:
        found: Counter[str] = Counter()
        for proc in Path("/proc").glob("[0-9]*"):
            try:
                argv = (proc / "cmdline").read_bytes().decode(errors="replace").split("\0")
                if Path(argv[0]).name == "capsim" and (proc / "cwd").resolve() == self.workdir:
                    out = argv[argv.index("--out") + 1]
                    if "/cases/" in f"/{out}":  # a case, not the kernel-version step's run
                        found[Path(out).with_suffix("").as_posix().split("cases/")[-1].replace("/", "_")] += 1
            except (OSError, ValueError, IndexError):
                continue
        return found

    def run(self) -> None:
        while not self.halt.is_set():
            for seen, most in ((self.jobs_per_case(), self.most_jobs), (self.kernels_per_case(), self.most_kernels)):
                for case, count in seen.items():
                    most[case] = max(most[case], count)
            self.samples += 1
            time.sleep(self.period)

    def stop(self) -> None:
        self.halt.set()
        self.join(timeout=30)


def _wait_for(predicate, what: str, timeout: float = 300):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.2)
    pytest.fail(f"no {what} after {timeout:.0f} s")


def _kill_mid_run(workdir: Path, grid_file: Path, watcher: Watcher) -> list[OldJob]:
    """Start the workflow on SLURM, SIGKILL Snakemake once both case jobs run and a kernel
    computes; the jobs it left (the first case may end before the kill on a fast machine:
    the second job starts at least 5 s after the first, the plugin's pause between submissions)."""
    workdir.mkdir()
    with open(workdir / "killed.log", "w") as log:
        proc = subprocess.Popen(cluster_module().slurm_argv(workdir, grid_file, "databases"), cwd=workdir, stdout=log,
                                stderr=subprocess.STDOUT, start_new_session=True)
    try:
        watcher.start()
        _wait_for(lambda: proc.poll() is not None or (
            [job.state for job in watcher.unfinished_jobs()] == ["RUNNING", "RUNNING"]
            and watcher.kernels_per_case()), "both case jobs running and a kernel computing")
        assert proc.poll() is None, (workdir / "killed.log").read_text()[-4000:]
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    left = subprocess.run(["squeue", "--noheader", "--format=%i|%T|%j|%k|%Z"], text=True,
                          capture_output=True, check=True).stdout
    jobs = parse_squeue(left, workdir)
    assert jobs and {job.case for job in jobs} <= {f"case {case}" for case in CASES}, left
    return jobs


def _documented_rerun(workdir: Path, grid_file: Path, recover: str) -> tuple[str, str]:
    """What ``make database PROFILE=slurm RECOVER=...`` runs after check-grid, in ``workdir``."""
    unlock = subprocess.run([sys.executable, "-m", "capsmech.cli", "dev", "unlock-stale", ".", "--profile",
                             str(cluster_module().SLURM_PROFILE), "--on-old-jobs", recover], cwd=workdir, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=600)
    assert unlock.returncode == 0, unlock.stdout
    rerun = subprocess.run(cluster_module().slurm_argv(workdir, grid_file, "databases"), cwd=workdir, text=True,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=900)
    assert rerun.returncode == 0, rerun.stdout[-6000:]
    return unlock.stdout, rerun.stdout


def local_kill_grid(root: Path) -> dict:
    """The grid file and its databases from an uninterrupted run of the local profile, in ``root``."""
    grid_file = root / "grid.yaml"
    grid_file.write_text(yaml.safe_dump(KILL_GRID))
    local = run_snakemake(root / "local", grid_file, "databases", timeout=600)
    assert local.returncode == 0, local.stdout[-4000:]
    return {"grid": grid_file, "database": root / "local" / "db" / "shear.h5"}


def rerun_after_a_killed_snakemake(kill_grid: dict, recover: str, tmp_path: Path, watcher: Watcher) -> None:
    """SIGKILL of Snakemake while both case jobs compute; the documented command then cancels
    the old jobs (the cases are submitted again) or waits for them (the rerun submits no case):
    never two jobs or two kernels on one case, and the database of an uninterrupted run."""
    workdir = tmp_path / "slurm"
    started = time.monotonic()
    old = _kill_mid_run(workdir, kill_grid["grid"], watcher)
    killed_at = time.monotonic() - started
    unlock, rerun = _documented_rerun(workdir, kill_grid["grid"], recover)
    watcher.stop()
    elapsed = time.monotonic() - started
    found = re.search(r"(\d+) SLURM job\(s\) of an earlier Snakemake run in \. are still in the queue: (.*)\.", unlock)
    assert found, unlock
    assert {job.describe().split(" (")[0] for job in old} == set(re.findall(r"(case \S+) \(job", found.group(2)))
    assert ("Cancelling them" if recover == "cancel" else "Waiting until they end") in unlock
    assert "removed the stale Snakemake lock" in unlock
    submitted = dict(re.findall(r"has been submitted with SLURM jobid (\d+) \(log: \S+/rule_case/(\S+)/\d+\.log\)",
                                rerun))
    assert not set(submitted) & {job.job_id for job in old}
    # cancel: exactly the cancelled cases again; wait: the old jobs finished them, nothing again
    assert sorted(submitted.values()) == (sorted(job.case.split()[1] for job in old) if recover == "cancel" else []), \
        rerun[-4000:]
    assert watcher.samples > 20
    assert dict(watcher.most_jobs) == {f"case {case}": 1 for case in CASES}, watcher.most_jobs
    assert dict(watcher.most_kernels) == {case: 1 for case in CASES}, watcher.most_kernels
    assert_same_database(workdir / "db" / "shear.h5", kill_grid["database"])
    assert watcher.jobs_per_case() == Counter()
    print(f"recovery '{recover}': Snakemake killed after {killed_at:.0f} s with {'; '.join(map(OldJob.describe, old))} "
          f"computing; rerun submitted {len(submitted)} case job(s); at most one job and one kernel per case "
          f"in {watcher.samples} samples; database equal to the local one; {elapsed:.0f} s")
