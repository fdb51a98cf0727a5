"""``capsmech dev ...``: the developers' and the workflow's commands (not a user's job):
``run-case`` (one grid case, as the workflow's case rule runs it), ``run-branch`` (every
Ca_s of one (law, a/l) by continuation, the workflow's branch rule), ``kernel-version`` (check
and record the version the built kernel writes), ``unlock-stale`` (remove the lock a killed
workflow left; on SLURM, first cancel or wait for the jobs it left in the queue), ``check-grid``
(``make database`` names a grid that exists and is valid before Snakemake starts)."""
from __future__ import annotations

import argparse
from pathlib import Path

from capsmech.cli.common import check_output
from capsmech.workflow.grid import GridError
from capsmech.workflow.paths import capsim_executable
from capsmech.workflow.recovery import (
    DEFAULT_ON_OLD_JOBS,
    OnOldJobs,
    clear_lock_of_killed_run,
    main_snakemake_pids,
    recover_old_jobs,
    slurm_profile,
)
from capsmech.workflow.runner import CaseRunError


def cmd_run_case(args: argparse.Namespace) -> int:
    """Run one workflow case (see :mod:`capsmech.workflow.runner` for the exit-code policy)."""
    from capsmech.workflow.runner import run_case

    kernel_args = [a for a in args.kernel_args if a != "--"]
    check_output(args.out, "--out", (".h5",), create_parent=True)
    run_case(args.capsim or capsim_executable(), kernel_args, args.out,
             code_version=args.code_version, threads=args.threads)
    return 0


def cmd_run_branch(args: argparse.Namespace) -> int:
    """Run one workflow branch (see :mod:`capsmech.workflow.runner` for the exit-code policy)."""
    from capsmech.workflow.runner import branch_parts, run_branch

    kernel_args = [a for a in args.kernel_args if a != "--"]
    _, outs, summary = branch_parts(kernel_args)
    check_output(summary, "--branch-summary", (".h5",), create_parent=True)
    for path in outs:
        check_output(path, "--out", (".h5",), create_parent=True)
    run_branch(args.capsim or capsim_executable(), kernel_args, code_version=args.code_version,
               threads=args.threads)
    return 0


def cmd_kernel_version(args: argparse.Namespace) -> int:
    """Check that the built kernel writes the code_version its sources declare; record it."""
    from capsmech.workflow.runner import kernel_code_version

    found = kernel_code_version(args.capsim or capsim_executable())
    if args.expect and found != args.expect:
        raise CaseRunError(f"{args.capsim} writes code_version {found!r} but the kernel sources declare "
                           f"{args.expect!r}: the executable is stale, run `make build`")
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(found + "\n")
    print(found)
    return 0


def cmd_unlock_stale(args: argparse.Namespace) -> int:
    """Remove a Snakemake lock left by a killed workflow (never one of a live workflow).

    With a SLURM profile, the jobs the killed run left in the queue are first cancelled or
    waited for (``--on-old-jobs``), so that the rerun never computes a case a second time while
    an old job still computes it.
    """
    from capsmech.workflow.runner import clear_stale_lock, running_snakemake

    if not slurm_profile(args.profile):
        if clear_stale_lock(args.workdir):
            print(f"removed the stale Snakemake lock of {args.workdir} (left by a killed run)")
        elif running_snakemake(args.workdir):
            print(f"a Snakemake process is running in {args.workdir}: its lock is kept")
        return 0
    live = main_snakemake_pids(args.workdir)
    if live:
        print(f"a Snakemake process is running in {args.workdir} (process {', '.join(map(str, live))}): "
              f"its lock and its SLURM jobs are kept")
        return 0
    recover_old_jobs(args.workdir, OnOldJobs(args.on_old_jobs))
    if clear_lock_of_killed_run(args.workdir):
        print(f"removed the stale Snakemake lock of {args.workdir} (left by a killed run)")
    return 0


def cmd_check_grid(args: argparse.Namespace) -> int:
    """Check the grid ``make database GRID=...`` names: it exists and is valid (one line if not)."""
    from capsmech.workflow.grid import load_grid

    path = Path(args.grid)
    if not path.is_file():
        known = sorted(p.stem for p in path.parent.glob("*.yaml")) if path.parent.is_dir() else []
        raise GridError(f"{path}: no such grid file" + (f"; grids in {path.parent}: {', '.join(known)}" if known else ""))
    grid = load_grid(path)
    print(f"grid {grid['name']!r} ({path}) is valid")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``dev`` group (hidden from the main help's job list: it says 'developer commands')."""
    dev = sub.add_parser("dev", help="developer and workflow commands (run-case, kernel-version, unlock-stale)")
    actions = dev.add_subparsers(dest="action", required=True, metavar="ACTION")
    run = actions.add_parser("run-case", help="run one grid case for the workflow (records non-steady outcomes)")
    run.add_argument("--out", required=True, help="case file to produce")
    run.add_argument("--code-version", required=True, help="code_version the case file must carry")
    run.add_argument("--threads", type=int, default=1, help="OpenMP threads")
    run.add_argument("--capsim", help="kernel executable (default: bin/capsim or $CAPSIM)")
    run.add_argument("kernel_args", nargs=argparse.REMAINDER, help="-- then the kernel's case arguments")
    run.set_defaults(func=cmd_run_case)
    branch = actions.add_parser("run-branch", help="run one steady branch for the workflow (capsim --branch-ca)")
    branch.add_argument("--code-version", required=True, help="code_version every file must carry")
    branch.add_argument("--threads", type=int, default=1, help="OpenMP threads")
    branch.add_argument("--capsim", help="kernel executable (default: bin/capsim or $CAPSIM)")
    branch.add_argument("kernel_args", nargs=argparse.REMAINDER,
                        help="-- then the branch's kernel arguments (--branch-ca, --branch-summary, --out with {ca})")
    branch.set_defaults(func=cmd_run_branch)
    version = actions.add_parser("kernel-version", help="print (and check) the code_version the kernel writes")
    version.add_argument("--capsim", default=None, help="kernel executable (default: bin/capsim)")
    version.add_argument("--expect", help="fail unless the kernel writes this version")
    version.add_argument("--out", help="also write the version to this file")
    version.set_defaults(func=cmd_kernel_version)
    unlock = actions.add_parser("unlock-stale", help="remove the Snakemake lock a killed workflow left")
    unlock.add_argument("workdir", nargs="?", default=".", help="the workflow's working directory")
    unlock.add_argument("--profile", metavar="DIR",
                        help="the run's Snakemake profile folder; with executor: slurm, the jobs a killed "
                             "run left in SLURM's queue are handled first (--on-old-jobs)")
    unlock.add_argument("--on-old-jobs", choices=[mode.value for mode in OnOldJobs],
                        default=DEFAULT_ON_OLD_JOBS.value,
                        help="SLURM jobs of a killed run in this directory: cancel them (the rerun resumes their "
                             "cases from their checkpoints) or wait until they end (default: %(default)s)")
    unlock.set_defaults(func=cmd_unlock_stale)
    check = actions.add_parser("check-grid", help="check that a grid file exists and is valid (make database)")
    check.add_argument("grid", metavar="GRID.yaml", help="the grid file")
    check.set_defaults(func=cmd_check_grid)
