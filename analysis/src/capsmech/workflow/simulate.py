"""Simulations on demand: a grid run through the workflow into a
cache, so that ``capsmech diagnose --simulate`` closes the loop in one command and
``capsmech database simulate`` makes a database of a new law in one command.

A candidate that needs law groups no database holds carries the grid of exactly those cases
(``capsmech.diagnosis.effect_grid.needed_grid``). ``simulate_grid`` runs that grid with the
project's Snakemake workflow (the local profile by default, any profile the user gives: a
SLURM profile sends the cases to a cluster) into a cache folder under the user's data
directory, keyed by the grid's science (laws, nodes, mesh and time settings) and the kernel's
``code_version``: the same request made again is read from the cache, a new kernel makes new
cases. The workflow writes case files whole and resumes a killed run, so an interrupted
``--simulate`` repeated goes on where it stopped.

Why the workflow and not a loop over ``capsim``: it already assembles checked databases, runs
the cases in parallel or on a cluster, and resumes; a second path would duplicate all three.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import subprocess
import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, TextIO

import yaml

from capsmech.errors import CapsmechError
from capsmech.workflow.grid import by_continuation, expand_cases, validate_grid
from capsmech.workflow.paths import repo_root
from capsmech.workflow.runner import clear_stale_lock, source_code_version

#: Environment variable naming the cache folder (default: the user's data directory).
DATA_DIR_ENV = "CAPSMECH_DATA_DIR"

#: Grid keys that say where things go, not what is computed: not part of the cache key.
_PLACEMENT_KEYS = ("name", "description", "databases_dir", "results_dir")

#: Snakemake's progress line, "12 of 40 steps (30%) done".
_PROGRESS = re.compile(r"(\d+) of (\d+) steps \(\d+%\) done")

#: The kernel's progress line (every 2 s of wall time), "capsim: t =     1.430 / 60.0  D12 =  0.02067 ...".
_KERNEL_PROGRESS = re.compile(r"^capsim: t =\s*(?P<t>\S+)\s*/\s*(?P<t_max>\S+)\s*(?P<measures>.*)$")


def case_count(grid: dict[str, Any]) -> int:
    """Cases of the grid's tube section."""
    return len(expand_cases(grid, "tube"))


class SimulationError(CapsmechError, RuntimeError):
    """The workflow could not compute a grid the diagnosis needs (the log says why)."""


def cache_root() -> Path:
    """The folder of simulated databases: ``$CAPSMECH_DATA_DIR`` if set, else
    ``<user data dir>/capsmech/simulated`` (platformdirs: ``~/.local/share`` on Linux)."""
    override = os.environ.get(DATA_DIR_ENV)
    if override:
        return Path(override).expanduser()
    try:
        from platformdirs import user_data_dir
    except ImportError:  # platformdirs comes with snakemake; without it, the XDG default
        return Path.home() / ".local" / "share" / "capsmech" / "simulated"
    return Path(user_data_dir("capsmech")) / "simulated"


def grid_key(grid: dict[str, Any], code_version: str) -> str:
    """12 hex digits identifying what a grid computes with a kernel version (its placement
    aside): equal keys, equal databases."""
    science = {k: v for k, v in grid.items() if k not in _PLACEMENT_KEYS}
    text = json.dumps(science, sort_keys=True, default=str) + "|" + code_version
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def cached_grid(grid: dict[str, Any], code_version: str | None = None, root: Path | None = None
                ) -> tuple[dict[str, Any], Path]:
    """The grid placed in its cache folder (databases and results there), and that folder."""
    version = code_version or source_code_version(repo_root())
    folder = (root or cache_root()) / f"{grid['name']}-{grid_key(grid, version)}"
    placed = dict(grid, databases_dir=str(folder), results_dir=str(folder / "results"))
    validate_grid(placed, f"{grid['name']} (simulated)")
    return placed, folder


def law_grid(grid: dict[str, Any], laws: Sequence[str], accuracy: str = "") -> dict[str, Any]:
    """The grid of new law groups over the tube nodes and settings of an existing grid (a
    database's ``grid``): ``law_grid(load_database("tube-paper").grid, ["SK_C5"])`` is the
    paper grid for Skalak's law with C = 5."""
    if "tube" not in grid:
        raise SimulationError(f"grid {grid.get('name', '?')!r} has no tube section to simulate new laws on")
    tube = grid["tube"]
    tag = "_".join(re.sub(r"[^A-Za-z0-9_-]", "_", key.replace(".", "p")) for key in laws)
    name = f"{grid.get('name', 'grid')}_{tag}"
    new: dict[str, Any] = {"name": name, "description": f"{', '.join(laws)} over the tube nodes of grid {grid.get('name', '?')!r}",
                           "databases_dir": "unplaced", "results_dir": "unplaced",
                           "profile_points": int(grid.get("profile_points", 64)),
                           "tube": {"laws": list(laws), "a_over_l": list(tube["a_over_l"]), "Ca_s": list(tube["Ca_s"]),
                                    "database": {"name": f"tube-{name}", "version": 1,
                                                 "accuracy": accuracy or f"the mesh of grid {grid.get('name', '?')!r}"}}}
    # By continuation where the model allows it: the same cases, a law group in minutes.
    new["tube"]["settings"] = by_continuation(tube.get("settings"))
    validate_grid(new, f"new laws {', '.join(laws)}")
    return new


def simulate_grid(grid: dict[str, Any], *, profile: str | Path | None = None, cores: int | None = None,
                  progress: Callable[[int, int], None] | None = None, root: Path | None = None,
                  snakemake_args: Sequence[str] = ()) -> Path:
    """Compute the grid's tube database through the workflow (or find it in the cache).

    Parameters
    ----------
    grid : dict
        A workflow grid with a ``tube`` section (``needed_grid``'s).
    profile : str or Path, optional
        Snakemake profile folder (default the project's ``workflow/profiles/local``).
    cores : int, optional
        Cores for the local run (default the profile's).
    progress : callable, optional
        Called with (steps done, steps in all) as the workflow reports them.
    root : Path, optional
        Cache folder (default ``cache_root()``).
    snakemake_args : sequence of str
        More Snakemake options (e.g. a cluster's status-check interval).

    Returns
    -------
    Path
        The database file (``tube.h5`` in the grid's cache folder).

    Raises
    ------
    SimulationError
        The workflow failed; the message names its log.
    """
    repo = repo_root()
    placed, folder = cached_grid(grid, root=root)
    database = folder / "tube.h5"
    if database.is_file():
        return database
    folder.mkdir(parents=True, exist_ok=True)
    config = folder / "grid.yaml"
    config.write_text(f"# capsmech: {case_count(placed)} cases simulated on demand, cached by their grid and "
                      "kernel version\n" + yaml.safe_dump(placed, sort_keys=False), encoding="utf-8")
    profile_dir = Path(profile) if profile else repo / "workflow" / "profiles" / "local"
    if not (profile_dir / "config.yaml").is_file():
        raise SimulationError(f"--profile {profile_dir}: no Snakemake profile there (a folder with config.yaml)")
    clear_stale_lock(folder)
    command = [sys.executable, "-m", "snakemake", "-s", str(repo / "workflow" / "Snakefile"),
               "--configfile", str(config), "--profile", str(profile_dir.resolve()), "--directory", str(folder),
               *snakemake_args, str(database)]
    if cores:
        command += ["--cores", str(cores)]
    log = folder / "workflow.log"
    with open(log, "w", encoding="utf-8") as sink:
        # The kernel must be built: the workflow checks it and says so, in the log.
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                   cwd=folder)
        assert process.stdout is not None
        for line in process.stdout:
            sink.write(line)
            match = _PROGRESS.search(line)
            if match and progress is not None:
                progress(int(match[1]), int(match[2]))
        code = process.wait()
    if code != 0 or not database.is_file():
        tail = [line.strip() for line in log.read_text(encoding="utf-8", errors="replace").splitlines()
                if "Error" in line or "error" in line][-3:]
        raise SimulationError(f"the workflow stopped (exit {code}) computing {case_count(placed)} cases of "
                              f"{grid['name']}: see {log}" + (f" ({'; '.join(tail)})" if tail else ""))
    return database


def relay_kernel_output(lines: Iterable[str], stream: TextIO, *, bar: bool | None = None) -> None:
    """Write the kernel's output ``lines`` to ``stream``, its progress lines as one progress bar.

    The kernel prints a progress line ("capsim: t = 1.4 / 60.0  D12 = ...") every 2 s of wall
    time: hundreds for a long run. With a bar (tqdm, over t / t_max, the last shape measures
    beside it) they update it in place; the bar stays at the time the run ended, which for a
    steady case is well before t_max. Every other line (degrees of freedom, warnings, the
    status, the file written) is written as it comes, below the bar.

    Parameters
    ----------
    lines : iterable of str
        The kernel's output, line by line (a ``Popen`` stdout), newlines kept.
    stream : text stream
        Where the output goes.
    bar : bool, optional
        Draw the bar; the default draws it when ``stream`` is a terminal, and otherwise writes
        the progress lines as they are (a log keeps them).
    """
    from tqdm import tqdm

    draw = stream.isatty() if bar is None else bar
    progress: Any = None
    try:
        for line in lines:
            match = _KERNEL_PROGRESS.match(line.rstrip("\n")) if draw else None
            if match is None:
                if progress is not None:
                    # The bar stays as the run left it, the status line under it; a later
                    # stretch of time steps (the next case of a branch) has a bar of its own.
                    progress.close()
                    progress = None
                stream.write(line)
                stream.flush()
                continue
            t, t_max = float(match["t"]), float(match["t_max"])
            if progress is None:
                progress = tqdm(total=t_max, desc="capsim t", file=stream, dynamic_ncols=True,
                                bar_format="{desc}: {n:.2f}/{total:g} |{bar}| {elapsed}{postfix}")
            progress.n = min(t, t_max)
            progress.set_postfix_str(" ".join(match["measures"].split()), refresh=True)
    finally:
        if progress is not None:
            progress.close()
