"""Locations of the project files (the ``capsim`` kernel, the workflow, the grids).

Two layouts hold them, the same relative paths in both (``bin/capsim``,
``kernel/src/capsim_kinds.f90``, ``workflow/Snakefile``, ``config/<grid>.yaml``):

- an installed package (a wheel, or ``pip install ./analysis``) carries its own copy in
  ``capsmech/_project/``, the kernel compiled by the build (``analysis/CMakeLists.txt``);
- a repository checkout (an editable install, ``make venv``) uses the repository itself, its
  kernel built by ``make build``.

The installed copy comes first: it is the one built for the package that runs.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

#: Environment variable that, when set, names the kernel executable to use.
CAPSIM_ENV = "CAPSIM"

#: The project files an installed package carries (created by the wheel build, absent in a checkout).
INSTALLED_PROJECT = Path(__file__).resolve().parent.parent / "_project"


def installed_project() -> Path | None:
    """The package's own project files (``capsmech/_project``), or None in a checkout."""
    if (INSTALLED_PROJECT / "workflow" / "Snakefile").is_file():
        return INSTALLED_PROJECT
    return None


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


def checkout_root() -> Path | None:
    """The repository checkout above this module (an editable install, ``analysis/src/capsmech``)
    or above the current working directory, or None."""
    for start in (Path(__file__).resolve().parent, Path.cwd().resolve()):
        for candidate in (start, *start.parents):
            if _is_repo_root(candidate):
                return candidate
    return None


def repo_root() -> Path:
    """Return the folder of the project files: the installed package's own
    (``capsmech/_project``), else the repository checkout.

    The checkout is searched upwards first from this module's location (editable install,
    ``analysis/src/capsmech``), then from the current working directory.

    Returns
    -------
    Path
        Absolute path of the folder holding ``bin/``, ``kernel/src/``, ``workflow/`` and ``config/``.

    Raises
    ------
    FileNotFoundError
        If neither is found.
    """
    installed = installed_project()
    if installed is not None:
        return installed
    checkout = checkout_root()
    if checkout is not None:
        return checkout
    raise FileNotFoundError(
        f"this capsmech has no kernel: neither its own ({INSTALLED_PROJECT}: install capsmech from a wheel "
        "or an sdist, which build it) nor a repository checkout (a directory with Makefile and kernel/) "
        f"above {Path(__file__).resolve().parent} or {Path.cwd().resolve()}"
    )


def capsim_executable() -> Path:
    """Return the path of the ``capsim`` kernel executable.

    The environment variable ``CAPSIM`` overrides the default ``bin/capsim`` of
    :func:`repo_root` (the installed package's kernel, else the checkout's).

    Returns
    -------
    Path
        Path of an existing, executable file.

    Raises
    ------
    FileNotFoundError
        If the executable does not exist or is not executable; the message
        tells how to build it (``make build`` in a checkout, a reinstall otherwise).
    """
    override = os.environ.get(CAPSIM_ENV)
    packaged = installed_project() is not None
    if override:
        exe = Path(override)
        origin = f"{CAPSIM_ENV}={override}"
    else:
        exe = repo_root() / "bin" / "capsim"
        origin = "installed with the package" if packaged else "default location"
    if not exe.is_file() or not os.access(exe, os.X_OK):
        cure = ("reinstall capsmech (pip install --force-reinstall) to rebuild it" if packaged and not override
                else "run `make build` to build the kernel")
        raise FileNotFoundError(f"capsim executable not found or not executable: {exe} ({origin}); {cure}")
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
