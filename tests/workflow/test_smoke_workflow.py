"""The smoke grid end to end through Snakemake: databases, statuses, kill and rerun, staleness, lint."""

from __future__ import annotations

import base64
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from capsmech.io.case import read_case
from capsmech.io.database import RESULTS, expected_units, load_database
from capsmech.workflow.grid import expand_cases, load_grid
from capsmech.workflow.runner import clear_stale_lock, source_code_version

from conftest import LOCAL_PROFILE, REPO, SMOKE, SNAKEFILE, assert_same_database, run_snakemake, snakemake_argv

GRID = load_grid(SMOKE)


def databases(workdir: Path) -> dict[str, Path]:
    return {flow: workdir / GRID["databases_dir"] / f"{flow}.h5" for flow in ("tube", "shear")}


def test_smoke_grid_end_to_end(smoke_run: dict) -> None:
    """Both databases have the grid's laws as groups, every column with its units, one row per
    case, and the status, message and values the kernel wrote in each case file."""
    workdir = smoke_run["workdir"]
    cases_dir = workdir / GRID["results_dir"] / "cases"
    for flow, path in databases(workdir).items():
        database = load_database(path)
        assert database.flow == flow
        assert list(database.laws) == GRID[flow]["laws"]
        assert database.provenance["grid_name"] == "smoke"
        assert database.provenance["case_count"] == len(expand_cases(GRID, flow))
        assert database.grid == GRID
        for case in expand_cases(GRID, flow):
            table = database.law(case.law.key)
            assert table.units == expected_units(flow)
            rows = table.columns["Ca_s"] == case.Ca_s
            if case.a_over_l is not None:
                rows &= table.columns["a_over_l"] == case.a_over_l
            (row,) = np.flatnonzero(rows)
            written = read_case(cases_dir / case.relative_path)
            assert table.status[row] == written.status
            assert table.message[row] == written.message
            assert database.provenance["code_version"] == written.code_version
            for column, (source, _, _) in RESULTS[flow].items():
                if written.is_steady:
                    assert table.columns[column][row] == written.steady_value(source)
                else:
                    assert np.isnan(table.columns[column][row])
    shear = load_database(databases(workdir)["shear"])
    # The non-steady cases the smoke grid was designed to contain are rows, not gaps.
    assert dict(zip(shear.law("NH").columns["Ca_s"], shear.law("NH").status)) == {
        0.05: "steady", 0.2: "steady", 3.0: "continuous_elongation"}
    assert dict(zip(shear.law("GH_nu0").columns["Ca_s"], shear.law("GH_nu0").status)) == {
        0.05: "steady", 0.2: "steady", 3.0: "failed"}
    tube = load_database(databases(workdir)["tube"])
    assert all(tube.law(k).steady.all() for k in tube.laws)
    assert tube.law("NH").profiles["profile_r"].shape == (6, GRID["profile_points"])
    figures = sorted(p.name for p in (workdir / GRID["results_dir"] / "figures").rglob("*.p*"))
    assert len(figures) == 12 and "figure6_shear_D12_L3.pdf" in figures and "tube_steady_range.pdf" in figures
    print(f"smoke grid end to end: {smoke_run['seconds']:.1f} s")


def test_kill_and_rerun_recomputes_only_missing_cases(smoke_run: dict, tmp_path: Path) -> None:
    """SIGKILL the whole workflow while cases run; the rerun keeps the finished case files,
    computes the rest (a case killed after its first checkpoint resumes from it), and gives the
    database of the uninterrupted run bit for bit (issue 25, item 1: resume is exact for every
    integrator; measured before it was: 6.5e-6 in D12 and 2.5e-2 in a profile)."""
    workdir = tmp_path / "killed"
    workdir.mkdir()
    cases_dir = workdir / GRID["results_dir"] / "cases"
    proc = subprocess.Popen(snakemake_argv(workdir), cwd=workdir, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while len(list(cases_dir.rglob("*.h5"))) < 4 and time.monotonic() < deadline:
            time.sleep(0.2)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    finished = {p: p.stat().st_mtime_ns for p in cases_dir.rglob("*.h5")}
    total = len(expand_cases(GRID, "tube")) + len(expand_cases(GRID, "shear"))
    assert 4 <= len(finished) < total, "the kill must fall while cases are still to run"
    assert not any(p.exists() for p in databases(workdir).values())

    # A case whose kernel had renamed its file but whose job had not ended when the kill
    # came is marked incomplete by Snakemake and is legitimately computed again.
    markers = workdir / ".snakemake" / "incomplete"
    incomplete = {base64.urlsafe_b64decode(p.name).decode() for p in markers.glob("*")}
    missing = {p.relative_to(workdir).as_posix() for p in (cases_dir / f"{c.relative_path}"
               for flow in ("tube", "shear") for c in expand_cases(GRID, flow)) if not p.exists()}

    assert clear_stale_lock(workdir)  # the killed run left its lock; no snakemake runs here
    result = run_snakemake(workdir)
    assert result.returncode == 0, result.stdout[-4000:]
    recomputed = set(re.findall(r"output: (\S+/cases/\S+\.h5)", result.stdout))
    assert missing <= recomputed and recomputed - missing <= incomplete
    kept = {p: mtime for p, mtime in finished.items() if p.relative_to(workdir).as_posix() not in recomputed}
    assert len(kept) >= 2 and all(p.stat().st_mtime_ns == mtime for p, mtime in kept.items())
    for flow, path in databases(workdir).items():
        assert_same_database(path, databases(smoke_run["workdir"])[flow])


def _cases_to_run(workdir: Path, configfile: Path) -> set[str]:
    """The case files a dry run would compute."""
    result = run_snakemake(workdir, configfile, "--dry-run")
    assert result.returncode == 0, result.stdout[-4000:]
    return {Path(p).relative_to(Path(GRID["results_dir"]) / "cases").as_posix()
            for p in re.findall(r"output: (\S+/cases/\S+\.h5)", result.stdout)}


def test_grid_change_marks_exactly_the_affected_cases_stale(smoke_run: dict, tmp_path: Path) -> None:
    """A new tube mesh setting makes every tube case stale and no shear case; a new Ca_s value
    adds its cases only; an unchanged grid, even with a rebuilt kernel, has no case to run."""
    workdir = smoke_run["workdir"]
    assert _cases_to_run(workdir, SMOKE) == set()
    # A rebuilt kernel (newer executable, same code_version) makes no case stale.
    kernel = REPO / "bin" / "capsim"
    os.utime(kernel)
    assert _cases_to_run(workdir, SMOKE) == set()
    changed = yaml.safe_load(SMOKE.read_text())
    changed["tube"]["settings"]["n_meridian"] = 26
    changed["shear"]["Ca_s"].append(0.1)
    grid_file = tmp_path / "changed.yaml"
    grid_file.write_text(yaml.safe_dump(changed))
    expected = {c.relative_path for c in expand_cases(changed, "tube")} | {
        f"shear/{law}/Ca0.1.h5" for law in changed["shear"]["laws"]}
    assert _cases_to_run(workdir, grid_file) == expected


def test_snakemake_lint_is_clean() -> None:
    result = subprocess.run(
        [*snakemake_argv(REPO)[:5], "--lint"], cwd=REPO, text=True,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=120)
    assert result.returncode == 0, result.stdout
    assert "Congratulations, your workflow is in a good condition!" in result.stdout
    assert "Lints for" not in result.stdout


def test_snakefmt_is_clean() -> None:
    result = subprocess.run([sys.executable, "-m", "snakefmt", "--check", str(REPO / "workflow")],
                            text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=120)
    assert result.returncode == 0, result.stdout


def test_new_code_version_marks_every_case_stale(smoke_run: dict, tmp_path: Path) -> None:
    """The same workflow beside kernel sources that declare another code_version (a copy of
    workflow/ next to a kernel/src/capsim_kinds.f90 that says so) finds every case stale."""
    repo = tmp_path / "repo"
    shutil.copytree(REPO / "workflow", repo / "workflow")
    (repo / "kernel" / "src").mkdir(parents=True)
    source = (REPO / "kernel" / "src" / "capsim_kinds.f90").read_text()
    version = source_code_version(REPO)
    (repo / "kernel" / "src" / "capsim_kinds.f90").write_text(
        source.replace(f"code_version = '{version}'", f"code_version = '{version}-next'"))
    (repo / "bin").mkdir()
    (repo / "bin" / "capsim").symlink_to(REPO / "bin" / "capsim")
    argv = snakemake_argv(smoke_run["workdir"], SMOKE, "--dry-run")
    argv[argv.index(str(SNAKEFILE))] = str(repo / "workflow" / "Snakefile")
    argv[argv.index(str(LOCAL_PROFILE))] = str(repo / "workflow" / "profiles" / "local")
    result = subprocess.run(argv, cwd=smoke_run["workdir"], text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, timeout=120)
    assert result.returncode == 0, result.stdout[-4000:]
    stale = set(re.findall(r"output: \S+/cases/(\S+\.h5)", result.stdout))
    assert stale == {c.relative_path for flow in ("tube", "shear") for c in expand_cases(GRID, flow)}
    assert f"before: '{version}' now: '{version}-next'" in result.stdout


def test_shear_only_grid_with_effects_runs_exactly_its_cases(tmp_path: Path) -> None:
    """A grid with one flow and law keys that carry an effect (NH+lambda0.2) plans exactly its
    own cases: no case of the default (smoke) grid's other flow, and every effect case."""
    grid = {"name": "effects", "databases_dir": "db", "results_dir": "results",
            "shear": {"laws": ["NH+lambda0.2", "GH_nu0.5+prestress0.05"], "Ca_s": [0.1, 0.3],
                      "settings": {"level": 2, "t_max": 2}}}
    grid_file = tmp_path / "effects.yaml"
    grid_file.write_text(yaml.safe_dump(grid))
    result = run_snakemake(tmp_path / "work", grid_file, "--dry-run")
    assert result.returncode == 0, result.stdout[-4000:]
    planned = {Path(p).relative_to("results/cases").as_posix()
               for p in re.findall(r"output: (\S+/cases/\S+\.h5)", result.stdout)}
    assert planned == {c.relative_path for c in expand_cases(grid, "shear")}
    assert len(planned) == 4
