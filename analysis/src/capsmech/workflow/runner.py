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

A steady tube case whose Newton polish was discarded (the kernel's message ends "... and was
discarded": time stepping declared the shape steady at its drift rule, but Newton's method from
there stalled or found an unstable shape) is **run again with a steady rule 100 times
stricter, then, while its polish is still discarded, 1000 times** (:data:`RETRY_STEADY_TOL_FACTORS`),
up to :data:`RETRY_T_MAX`: the rule's area part, the binding one (``--steady-tol``), is
tightened, its shape part (``--shape-tol``) left as it is; the same time steps, continued until
the area drifts 100 (1000) times less, and polished again from there (the paper grid: 14 of its
26 such rows reach a root of the steady equations at 100 times, 6 more at 1000). A rerun's case
file replaces the case before when it is steady too, its message prefixed with why it was
rerun; otherwise the case before stays.

A branch (:func:`run_branch`, one run for every Ca_s of a (law, a/l)) follows the same policy
for its kernel run; when the kernel reports an error of its own, the cases it did not write are
run one by one (each under the policy above) and the branch file becomes a failure record
(no critical Ca_s, the reason in ``critical_kind``): a branch that breaks costs time, not rows.
"""

from __future__ import annotations

import os
import re
import subprocess
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

import h5py

from capsmech.errors import CapsmechError
from capsmech.io.case import CaseFileError, CaseResult, decode_str, polish_discarded, read_case, require_hdf5_file

#: Root attribute value that marks a failure record written by :func:`run_case`.
FAILURE_RECORD = "capsim_failure"

_CODE_VERSION = re.compile(r"code_version\s*=\s*'([^']*)'")


#: A steady tube case whose Newton polish was discarded is rerun with the steady rule's area
#: part (the kernel's --steady-tol, default 1e-3 per time unit) this many times smaller, the
#: next factor only while the polish is still discarded ...
RETRY_STEADY_TOL_FACTORS = (1e-2, 1e-3)
#: ... and up to this time (l/V; the grids' 60 is too short for the stricter rule at Ca_s 0.01:
#: the paper grid's reruns ended steady by t = 113).
RETRY_T_MAX = 400.0
#: The kernel's default steady rule (capsim --steady-tol).
KERNEL_STEADY_TOL = 1.0e-3


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


#: Earlier kernels whose results of a flow a kernel version reproduces unchanged, by (version,
#: flow): a database of that flow made by one of them is still this kernel's (the shipped
#: databases' check, tests/workflow/test_shipped_databases.py). Kernel 0.3.3 changed the
#: axisymmetric tube's implicit steps and branches, not the shear flow's code; 0.3.4 only when a
#: tube branch searches for its fold; 0.3.5 only where an implicit tube step would change an
#: element's stretch by more than 30 % (at large Ca_s); 0.3.6 only the 3D model's growth-rate
#: estimate and where a 3D branch ends (a shape not stable ends it): its steady shapes agree with
#: 0.3.5's to 3e-10, the axisymmetric model's are the same.
RESULTS_UNCHANGED_SINCE: dict[tuple[str, str], tuple[str, ...]] = {("0.3.3", "shear"): ("0.3.2",),
                                                                    ("0.3.4", "shear"): ("0.3.3", "0.3.2"),
                                                                    ("0.3.5", "shear"): ("0.3.4", "0.3.3", "0.3.2"),
                                                                    ("0.3.6", "shear"): ("0.3.5", "0.3.4", "0.3.3",
                                                                                         "0.3.2"),
                                                                    ("0.3.6", "tube"): ("0.3.5",)}


def reproduces_results(kernel_version: str, made_by: str, flow: str) -> bool:
    """Whether kernel ``kernel_version`` reproduces the ``flow`` results of kernel ``made_by``
    (the same version, or one listed in :data:`RESULTS_UNCHANGED_SINCE`)."""
    return made_by == kernel_version or made_by in RESULTS_UNCHANGED_SINCE.get((kernel_version, flow), ())


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


def _raise_if_refused_or_interrupted(proc: subprocess.CompletedProcess[str], what: str) -> None:
    """Fail the job on the exits that are not a property of the run: the kernel refused the
    parameters (exit 2, a grid error), or a signal stopped it (run again: it resumes)."""
    if proc.returncode == 2:
        raise CaseRunError(f"capsim refused the parameters of {what} (exit 2): {proc.stderr.strip()}")
    if proc.returncode < 0 or proc.returncode > 128:
        raise CaseRunError(
            f"capsim was interrupted (exit {proc.returncode}); run the workflow again to resume {what} "
            f"from its checkpoint. stderr: {proc.stderr.strip()}"
        )


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
    """Run one case and leave its case file (or failure record) at ``out``; a steady tube case
    whose Newton polish was discarded is run again with a stricter steady rule (module docstring).

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
    status, message = _run_once(capsim, kernel_args, out, code_version=code_version, threads=threads)
    if status != "steady" or _option(kernel_args, "--flow") != "tube" or not polish_discarded(message):
        return status
    retry = out.with_name(out.name + ".retry.h5")
    for factor in RETRY_STEADY_TOL_FACTORS:
        stricter = retry_args(kernel_args, factor)
        retry.unlink(missing_ok=True)       # a rerun finished but not moved in place by a killed job
        retry_status, retry_message = _run_once(capsim, stricter, retry, code_version=code_version, threads=threads)
        if retry_status != "steady":
            retry.unlink(missing_ok=True)
            print(f"case {out}: the rerun {' '.join(stricter[-4:])} ended {retry_status}: the last steady case stays")
            break
        changed = " ".join(stricter[-4:])
        with h5py.File(retry, "r+") as f:
            f.attrs["message"] = (f"rerun with a steady rule {1 / factor:g} times stricter ({changed}) "
                                  f"after the Newton polish was discarded: {retry_message}")
        # Closer to the steady shape than the run before, a root or not: it replaces it.
        os.replace(retry, out)
        print(f"case {out}: steady, rerun with {changed}")
        if not polish_discarded(retry_message):
            break
    return "steady"


def _run_once(capsim: str | Path, kernel_args: Sequence[str], out: Path, *, code_version: str,
              threads: int) -> tuple[str, str]:
    """One kernel run under the fault policy (module docstring); the recorded status and message."""
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
        return status, message
    _raise_if_refused_or_interrupted(proc, "the case")
    write_failure_record(out, exit_code=proc.returncode, stderr=proc.stderr,
                         code_version=code_version, kernel_args=kernel_args)
    print(f"case {out}: failed: capsim exited with code {proc.returncode}: {proc.stderr.strip()}")
    return "failed", proc.stderr.strip()


def _option(kernel_args: Sequence[str], name: str) -> str | None:
    """The value of ``name`` in a kernel argument list (the last one given), or None."""
    values = [kernel_args[k + 1] for k, arg in enumerate(kernel_args[:-1]) if arg == name]
    return values[-1] if values else None


def retry_args(kernel_args: Sequence[str], factor: float = RETRY_STEADY_TOL_FACTORS[0]) -> list[str]:
    """The kernel arguments of a stricter rerun: the case's own with ``--steady-tol`` (the
    case's rule times ``factor``) and ``--t-max`` (at least :data:`RETRY_T_MAX`) set (the
    kernel refuses an option given twice), those two last."""
    tol = float(_option(kernel_args, "--steady-tol") or KERNEL_STEADY_TOL) * factor
    t_max = max(float(_option(kernel_args, "--t-max") or 0.0), RETRY_T_MAX)
    kept: list[str] = []
    k = 0
    while k < len(kernel_args):
        if kernel_args[k] in ("--steady-tol", "--t-max") and k + 1 < len(kernel_args):
            k += 2
            continue
        kept.append(kernel_args[k])
        k += 1
    return [*kept, "--steady-tol", f"{tol:g}", "--t-max", f"{t_max:g}"]


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


def clear_stale_lock(workdir: str | Path, holders: Callable[[str | Path], list[int]] | None = None) -> bool:
    """Remove Snakemake's lock in ``workdir`` if no Snakemake process is working there.

    A workflow killed by SIGKILL leaves ``.snakemake/locks`` behind, and the next run
    refuses to start. The lock is only removed when no live Snakemake process has
    ``workdir`` as its working directory, so a workflow that really runs keeps it.
    ``holders`` narrows which of them keep it (default: ``running_snakemake``, every one).

    Returns
    -------
    bool
        True when a stale lock was removed.
    """
    locks = sorted((Path(workdir) / ".snakemake" / "locks").glob("*.lock"))
    if not locks or (holders or running_snakemake)(workdir):
        return False
    for lock in locks:
        lock.unlink()
    return True


def _check_version(path: Path, code_version: str, capsim: str | Path) -> None:
    """Remove ``path`` and fail when the kernel that wrote it is not the sources' version."""
    with h5py.File(path, "r") as f:
        written = decode_str(f.attrs["code_version"])
    if written != code_version:
        path.unlink()
        raise CaseRunError(f"{capsim} wrote code_version {written!r} in {path} but the kernel sources declare "
                           f"{code_version!r}: the executable is stale, run `make build`")


def write_branch_failure(summary: Path, *, message: str, code_version: str, kernel_args: Sequence[str]) -> None:
    """Write the branch file of a branch whose kernel run failed: no critical Ca_s, and why."""
    tmp = summary.with_name(summary.name + ".record.tmp")
    with h5py.File(tmp, "w") as f:
        f.attrs["record"] = FAILURE_RECORD
        f.attrs["critical_Ca_s"] = float("nan")
        f.attrs["critical_kind"] = f"failed: {message}"
        f.attrs["code_version"] = code_version
        f.attrs["kernel_args"] = " ".join(kernel_args)
    os.replace(tmp, summary)


def branch_parts(branch_args: Sequence[str]) -> tuple[list[list[str]], list[Path], Path]:
    """Split a branch's kernel arguments into its cases: each case's own arguments (the branch's
    with ``--ca <value>`` instead of the branch options), each case file (``--out`` with
    ``{ca}`` replaced by the value as written in ``--branch-ca``), and the branch file.

    Raises
    ------
    CaseRunError
        If ``--branch-ca``, ``--branch-summary`` or ``--out`` is missing.
    """
    args = list(branch_args)
    options: dict[str, str] = {}
    common: list[str] = []
    i = 0
    while i < len(args):
        if args[i] in ("--branch-ca", "--branch-summary", "--out") and i + 1 < len(args):
            options[args[i]] = args[i + 1]
            i += 2
        else:
            common.append(args[i])
            i += 1
    missing = [name for name in ("--branch-ca", "--branch-summary", "--out") if name not in options]
    if missing:
        raise CaseRunError(f"branch arguments without {', '.join(missing)}: {' '.join(args)}")
    values = options["--branch-ca"].split(",")
    outs = [Path(options["--out"].replace("{ca}", value)) for value in values]
    return [[*common, "--ca", value] for value in values], outs, Path(options["--branch-summary"])


def run_branch(capsim: str | Path, branch_args: Sequence[str], *, code_version: str, threads: int = 1) -> str:
    """Run one steady branch (``capsim --branch-ca``) and leave its case files and branch file.

    Parameters
    ----------
    capsim : str or Path
        The kernel executable.
    branch_args : sequence of str
        The branch's arguments (from :meth:`capsmech.workflow.grid.Branch.kernel_args`), which
        name its case files and branch file (see :func:`branch_parts`).
    code_version : str
        The version every file must carry.
    threads : int
        OpenMP threads.

    Returns
    -------
    str
        The branch's end as the kernel records it (``critical_kind``).

    Raises
    ------
    CaseRunError
        On invalid parameters (exit 2), an interrupted run (signal: run again to resume from
        the branch's checkpoint) or a stale kernel.
    """
    case_args, outs, summary = branch_parts(branch_args)
    for path in [summary, *outs]:
        path.parent.mkdir(parents=True, exist_ok=True)
    argv = [str(capsim), *branch_args, "--threads", str(threads)]
    print("running:", " ".join(argv), flush=True)
    proc = subprocess.run(argv, capture_output=True, text=True)
    print(proc.stdout, end="", flush=True)
    if proc.returncode == 0:
        for path in [summary, *outs]:
            if not path.is_file():
                raise CaseRunError(f"{capsim} ended the branch without writing {path}")
            _check_version(path, code_version, capsim)
        with h5py.File(summary, "r") as f:
            kind = decode_str(f.attrs["critical_kind"])
        print(f"branch {summary}: {kind}")
        return kind
    _raise_if_refused_or_interrupted(proc, "the branch")
    lines = [line for line in proc.stderr.strip().splitlines() if line.strip()]
    reason = f"capsim exited with code {proc.returncode}: {lines[-1] if lines else 'no message on stderr'}"
    print(f"branch {summary}: {reason}; the cases it did not write run one by one", flush=True)
    for args, out in zip(case_args, outs):
        if not out.is_file():
            run_case(capsim, args, out, code_version=code_version, threads=threads)
    write_branch_failure(summary, message=reason, code_version=code_version, kernel_args=branch_args)
    return f"failed: {reason}"
