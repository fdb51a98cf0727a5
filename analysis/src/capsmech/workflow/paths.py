"""Locations of the repository and of the ``capsim`` kernel executable."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

#: Environment variable that, when set, names the kernel executable to use.
CAPSIM_ENV = "CAPSIM"


def _is_repo_root(path: Path) -> bool:
    """Return True when ``path`` looks like the capsmech repository root.

    Parameters
    ----------
    path : Path
        Candidate directory.

    Returns
    -------
    bool
        True when it holds both ``Makefile`` and ``kernel/``.
    """
    return (path / "Makefile").is_file() and (path / "kernel").is_dir()


def repo_root() -> Path:
    """Return the repository root directory.

    Searched upwards first from this module's location (editable install,
    ``analysis/src/capsmech``), then from the current working directory.

    Returns
    -------
    Path
        Absolute path of the directory holding ``Makefile`` and ``kernel/``.

    Raises
    ------
    FileNotFoundError
        If no such directory is found.
    """
    starts = (Path(__file__).resolve().parent, Path.cwd().resolve())
    for start in starts:
        for candidate in (start, *start.parents):
            if _is_repo_root(candidate):
                return candidate
    raise FileNotFoundError(
        "cannot find the capsmech repository root (a directory with Makefile and kernel/) "
        f"above {starts[0]} or {starts[1]}"
    )


def capsim_executable() -> Path:
    """Return the path of the ``capsim`` kernel executable.

    The environment variable ``CAPSIM`` overrides the default
    ``<repo>/bin/capsim``.

    Returns
    -------
    Path
        Path of an existing, executable file.

    Raises
    ------
    FileNotFoundError
        If the executable does not exist or is not executable; the message
        tells to run ``make build``.
    """
    override = os.environ.get(CAPSIM_ENV)
    if override:
        exe = Path(override)
        origin = f"{CAPSIM_ENV}={override}"
    else:
        exe = repo_root() / "bin" / "capsim"
        origin = "default location"
    if not exe.is_file() or not os.access(exe, os.X_OK):
        raise FileNotFoundError(
            f"capsim executable not found or not executable: {exe} ({origin}); "
            "run `make build` to build the kernel"
        )
    return exe


def kernel_version() -> str:
    """``'capsim 0.3.5 (PATH)'`` for the kernel ``capsim_executable`` finds, or why there is none."""
    try:
        exe = capsim_executable()
    except FileNotFoundError as err:
        return f"capsim not available ({err})"
    try:
        done = subprocess.run([str(exe), "--version"], capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired) as err:
        return f"capsim at {exe} does not run ({err})"
    if done.returncode != 0 or not done.stdout.startswith("capsim "):
        return f"capsim at {exe} gives no version (older than 0.3.5? rebuild it: make build)"
    return f"{done.stdout.strip()} ({exe})"
