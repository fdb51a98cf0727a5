"""Run one grid case with the ``capsim`` kernel, as the workflow's case rule does.

What happens to each kernel outcome (the workflow's fault policy):

exit 0
    The kernel wrote its case file, whatever the status (steady, continuous_elongation,
    max_time, failed): the case is done and becomes a database row. The file's
    ``code_version`` must be the one the kernel sources declare, otherwise ``bin/capsim``
    is stale and the job fails (run ``make build``).
exit 2
    Invalid parameters: a grid error, not a property of the case. The job fails loudly.
killed by a signal (or exit > 128)
    The run was interrupted (SIGKILL, out of memory, cluster pre-emption): the job fails,
    and running the workflow again resumes the case from the kernel's checkpoint.
any other exit code
    The kernel ran and reported an error of its own (one line on stderr). A *failure
    record* is written in place of the case file: root attributes ``record =
    'capsim_failure'``, ``status = 'failed'``, ``message`` (exit code and stderr),
    ``exit_code``, ``code_version``, ``kernel_args``. It becomes a database row with
    status ``failed``; it is not retried (delete the file to retry).
"""

from __future__ import annotations

import os
import re
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path

import h5py

from capsmech.errors import CapsmechError
from capsmech.io.case import CaseFileError, CaseResult, decode_str, read_case, require_hdf5_file

#: Root attribute value that marks a failure record written by :func:`run_case`.
FAILURE_RECORD = "capsim_failure"

_CODE_VERSION = re.compile(r"code_version\s*=\s*'([^']*)'")


class CaseRunError(CapsmechError, RuntimeError):
    """The case could not be run or recorded; the workflow job must fail."""


def source_code_version(repo: str | Path) -> str:
    """Return the kernel's ``code_version`` as declared in ``kernel/src/capsim_kinds.f90``.

    This is the version every case file written by a kernel built from these sources
    carries; :func:`run_case` checks the two agree.

    Raises
    ------
    CaseRunError
        If the declaration is not found.
    """
    source = Path(repo) / "kernel" / "src" / "capsim_kinds.f90"
    match = _CODE_VERSION.search(source.read_text())
    if match is None:
        raise CaseRunError(f"{source}: no `code_version = '...'` declaration")
    return match.group(1)


def kernel_code_version(capsim: str | Path) -> str:
    """Return the ``code_version`` the built kernel writes, from a tiny throw-away run.

    Raises
    ------
    CaseRunError
        If the kernel cannot run that case.
    """
    with tempfile.TemporaryDirectory(prefix="capsim-version-") as tmp:
        out = Path(tmp) / "version.h5"
        argv = [str(capsim), "--flow", "shear", "--law", "NH", "--ca", "0.1", "--level", "1",
                "--t-max", "0.01", "--threads", "1", "--quiet", "--out", str(out)]
        proc = subprocess.run(argv, capture_output=True, text=True)
        if proc.returncode != 0:
            raise CaseRunError(f"{capsim} failed a one-step run (exit {proc.returncode}): {proc.stderr.strip()}")
        with h5py.File(out, "r") as f:
            return decode_str(f.attrs["code_version"])


def write_failure_record(out: Path, *, exit_code: int, stderr: str, code_version: str,
                         kernel_args: Sequence[str]) -> None:
    """Write a failure record for a kernel run that exited with an error (tmp, then rename)."""
    lines = [line for line in stderr.strip().splitlines() if line.strip()]
    reason = lines[-1] if lines else "no message on stderr"
    tmp = out.with_name(out.name + ".record.tmp")
    with h5py.File(tmp, "w") as f:
        f.attrs["record"] = FAILURE_RECORD
        f.attrs["status"] = "failed"
        f.attrs["message"] = f"capsim exited with code {exit_code}: {reason}"
        f.attrs["exit_code"] = exit_code
        f.attrs["code_version"] = code_version
        f.attrs["kernel_args"] = " ".join(kernel_args)
    os.replace(tmp, out)


def is_failure_record(path: str | Path) -> bool:
    """Return True when ``path`` is a failure record rather than a kernel case file.

    Raises
    ------
    CaseFileError
        If the file is not HDF5, or is truncated or damaged (the message names it).
    """
    where = require_hdf5_file(Path(path), "case file", CaseFileError)
    try:
        with h5py.File(path, "r") as f:
            return "record" in f.attrs and decode_str(f.attrs["record"]) == FAILURE_RECORD
    except (OSError, TypeError) as exc:
        raise CaseFileError(f"{where}: cannot read HDF5 case file (truncated or damaged?): {exc}") from None


def read_outcome(path: str | Path) -> tuple[str, str, str, CaseResult | None]:
    """Return ``(status, message, code_version, case)`` of a case file or failure record.

    ``case`` is the validated :class:`~capsmech.io.case.CaseResult`, or None for a failure record.
    """
    if is_failure_record(path):
        with h5py.File(path, "r") as f:
            return ("failed", decode_str(f.attrs["message"]), decode_str(f.attrs["code_version"]), None)
    case = read_case(path)
    return case.status, case.message, case.code_version, case


def run_case(capsim: str | Path, kernel_args: Sequence[str], out: str | Path, *,
             code_version: str, threads: int = 1) -> str:
    """Run one case and leave its case file (or failure record) at ``out``.

    Parameters
    ----------
    capsim : str or Path
        The kernel executable.
    kernel_args : sequence of str
        The case's arguments (from :meth:`capsmech.workflow.grid.Case.kernel_args`).
    out : str or Path
        Case file to produce.
    code_version : str
        The version the case file must carry.
    threads : int
        OpenMP threads.

    Returns
    -------
    str
        The recorded status.

    Raises
    ------
    CaseRunError
        On invalid parameters (exit 2), an interrupted run (signal) or a stale kernel;
        the message carries the kernel's stderr.
    """
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    argv = [str(capsim), *kernel_args, "--threads", str(threads), "--out", str(out)]
    print("running:", " ".join(argv), flush=True)
    proc = subprocess.run(argv, capture_output=True, text=True)
    print(proc.stdout, end="", flush=True)
    if proc.returncode == 0:
        status, message, written_version, _ = read_outcome(out)
        if written_version != code_version:
            out.unlink()
            raise CaseRunError(
                f"{capsim} wrote code_version {written_version!r} but the kernel sources declare "
                f"{code_version!r}: the executable is stale, run `make build`"
            )
        print(f"case {out}: {status}: {message}")
        return status
    if proc.returncode == 2:
        raise CaseRunError(f"capsim refused the parameters (exit 2): {proc.stderr.strip()}")
    if proc.returncode < 0 or proc.returncode > 128:
        raise CaseRunError(
            f"capsim was interrupted (exit {proc.returncode}); run the workflow again to resume "
            f"from its checkpoint. stderr: {proc.stderr.strip()}"
        )
    write_failure_record(out, exit_code=proc.returncode, stderr=proc.stderr,
                         code_version=code_version, kernel_args=kernel_args)
    print(f"case {out}: failed: capsim exited with code {proc.returncode}: {proc.stderr.strip()}")
    return "failed"


def running_snakemake(workdir: str | Path) -> list[int]:
    """Return the ids of live Snakemake processes working in ``workdir`` (Linux ``/proc``)."""
    target = Path(workdir).resolve()
    pids = []
    for proc in Path("/proc").glob("[0-9]*"):
        try:
            cmdline = (proc / "cmdline").read_bytes().split(b"\0")
            if any(Path(part.decode(errors="replace")).name == "snakemake" for part in cmdline[:3]) \
                    or b"snakemake" in cmdline[1:3]:
                if (proc / "cwd").resolve() == target:
                    pids.append(int(proc.name))
        except OSError:  # the process ended meanwhile, or is not ours to inspect
            continue
    return pids


def clear_stale_lock(workdir: str | Path) -> bool:
    """Remove Snakemake's lock in ``workdir`` if no Snakemake process is working there.

    A workflow killed by SIGKILL leaves ``.snakemake/locks`` behind, and the next run
    refuses to start. The lock is only removed when no live Snakemake process has
    ``workdir`` as its working directory, so a workflow that really runs keeps it.

    Returns
    -------
    bool
        True when a stale lock was removed.
    """
    locks = sorted((Path(workdir) / ".snakemake" / "locks").glob("*.lock"))
    if not locks or running_snakemake(workdir):
        return False
    for lock in locks:
        lock.unlink()
    return True
