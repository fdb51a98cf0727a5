"""Locations of the repository and of the ``capsim`` kernel executable."""

from __future__ import annotations

import os
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
