"""A tube grid computed by continuation (``tube.settings.branch``) through Snakemake: one kernel
run per (law, a/l) writes the grid's own case files, the database holds the same rows the case
files hold and, per law and a/l, the critical Ca_s where the steady branch ends; a branch the
kernel gives up still yields every row (its cases run one by one).

Coarse meridians (32 elements, as tests/kernel/test_tube_continuation.py): NH at a/l 0.9 folds
between Ca_s 0.12 and 0.2 there; GH (nu_s 0.5) stays steady to 0.2.
"""
from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from capsmech.io.case import read_case
from capsmech.io.database import RESULTS, load_database
from capsmech.workflow.grid import GridError, expand_branches, expand_cases, validate_grid
from capsmech.workflow.runner import FAILURE_RECORD, is_failure_record, run_branch

from conftest import run_grid_databases, run_snakemake

GRID = {
    "name": "branch_test",
    "databases_dir": "db",
    "results_dir": "results",
    "profile_points": 32,
    "tube": {"laws": ["NH", "GH_nu0.5"], "a_over_l": [0.9], "Ca_s": [0.05, 0.12, 0.2],
             "settings": {"n_meridian": 32, "branch": True}},
}


@pytest.fixture(scope="module")
def branch_run(tmp_path_factory) -> Path:
    """The grid run once through the workflow: its working directory."""
    return run_grid_databases(tmp_path_factory.mktemp("branch_grid"), GRID)


@pytest.mark.slow
def test_branch_grid_writes_the_cases_rows_and_critical_ca(branch_run: Path) -> None:
    database = load_database(branch_run / "db" / "tube.h5")
    cases = expand_cases(GRID, "tube")
    assert database.provenance["case_count"] == len(cases)
    for case in cases:
        written = read_case(branch_run / "results" / "cases" / case.relative_path)
        table = database.law(case.law.key)
        (row,) = np.flatnonzero(table.columns["Ca_s"] == case.Ca_s)
        assert table.status[row] == written.status
        for column, (source, _, _) in RESULTS["tube"].items():
            if written.is_steady:
                assert table.columns[column][row] == written.steady_value(source)
    ends = database.critical_Ca_s().set_index("law")
    # NH: the steady branch ends at a fold between the last steady and the first elongating row.
    nh = database.law("NH")
    last_steady = nh.columns["Ca_s"][nh.steady].max()
    first_elongating = nh.columns["Ca_s"][nh.status == "continuous_elongation"].min()
    assert ends.loc["NH", "kind"] == "fold"
    assert last_steady < ends.loc["NH", "critical_Ca_s"] < first_elongating
    # The database's value is the branch file's, the kernel's record of the fold.
    with h5py.File(branch_run / "results" / "branches" / "tube" / "NH" / "a0.9.h5") as f:
        assert ends.loc["NH", "critical_Ca_s"] == float(f.attrs["critical_Ca_s"])
    # GH nu_s 0.5 is steady on the whole grid: no end inside it, said so.
    assert database.law("GH_nu0.5").steady.all()
    assert np.isnan(ends.loc["GH_nu0.5", "critical_Ca_s"])
    assert ends.loc["GH_nu0.5", "kind"].startswith("none")
    # `capsmech database show` says where each branch ends.
    shown = subprocess.run([sys.executable, "-m", "capsmech.cli", "database", "show", str(branch_run / "db" / "tube.h5")],
                           capture_output=True, text=True, check=True).stdout
    assert f"a/l 0.9: {ends.loc['NH', 'critical_Ca_s']:.4g} (fold)" in shown
    assert "nowhere inside the grid" in shown


@pytest.mark.slow
def test_branch_grid_rerun_has_nothing_to_do(branch_run: Path) -> None:
    result = run_snakemake(branch_run, branch_run / "grid.yaml", "databases")
    assert result.returncode == 0, result.stdout[-4000:]
    assert "Nothing to be done" in result.stdout, result.stdout[-2000:]


def test_branches_are_one_per_law_and_size_with_the_cases_of_the_grid() -> None:
    branches = expand_branches(GRID)
    assert [(b.law.key, b.a_over_l) for b in branches] == [("NH", 0.9), ("GH_nu0.5", 0.9)]
    assert [c.relative_path for b in branches for c in b.cases] == \
        [c.relative_path for c in expand_cases(GRID, "tube")]
    args = branches[0].kernel_args("cases", "b.h5")
    assert args[args.index("--branch-ca") + 1] == "0.05,0.12,0.2"
    assert args[args.index("--out") + 1] == str(Path("cases/tube/NH/a0.9_Ca{ca}.h5"))
    assert "--ca" not in args and "--branch" not in args
    # A grid without the setting has no branches; the setting is not a kernel argument.
    plain = {**GRID, "tube": {**GRID["tube"], "settings": {"n_meridian": 32}}}
    assert expand_branches(plain) == []
    assert [c.kernel_args() for c in expand_cases(plain, "tube")] == \
        [c.kernel_args() for c in expand_cases(GRID, "tube")]


@pytest.mark.parametrize("settings,needle", [({"branch": True, "model": "3d"}, "axisymmetric model only"),
                                             ({"branch": True, "integrator": "rk2"}, "contradicts")])
def test_branch_grid_refuses_what_continuation_cannot_do(settings: dict, needle: str) -> None:
    grid = {**GRID, "tube": {**GRID["tube"], "settings": settings}}
    with pytest.raises(GridError, match=needle):
        validate_grid(grid)


def test_a_branch_the_kernel_gives_up_runs_its_cases_one_by_one(tmp_path: Path) -> None:
    """A kernel error of its own (exit 3) in the branch: each case is run alone under the case
    policy (here the stand-in kernel fails those too, so each becomes a failure record) and the
    branch file says the branch failed, with no critical Ca_s."""
    fake = tmp_path / "capsim"
    fake.write_text("#!/bin/sh\necho 'capsim: error: the stand-in kernel always fails' >&2\nexit 3\n")
    fake.chmod(fake.stat().st_mode | stat.S_IXUSR)
    (branch,) = [b for b in expand_branches(GRID) if b.law.key == "NH"]
    summary = tmp_path / "branches" / "a0.9.h5"
    kind = run_branch(fake, branch.kernel_args(tmp_path / "cases", summary), code_version="0.0.0")
    assert kind.startswith("failed: capsim exited with code 3")
    for case in branch.cases:
        path = tmp_path / "cases" / case.relative_path
        assert is_failure_record(path)
        with h5py.File(path) as f:
            assert f.attrs["kernel_args"].endswith(f"--ca {case.Ca_s:g}")
    with h5py.File(summary) as f:
        assert f.attrs["record"] == FAILURE_RECORD
        assert np.isnan(f.attrs["critical_Ca_s"])
    assert not any(p.name.endswith(".tmp") for p in tmp_path.rglob("*")), os.listdir(tmp_path)
