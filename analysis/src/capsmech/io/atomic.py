"""Files written whole or not at all, and a failed write said in one line.

Every output goes to ``NAME.tmp`` beside its place and is renamed over ``NAME`` only once it is
complete: a reader never sees half a file, and a run killed mid-write leaves the previous file.
A write that fails (a full disk, a folder that turned read-only, a quota) removes the temporary
file and raises an :class:`OutputError` naming the file and the system's reason, which the CLI
prints as one line, instead of an internal error and a 0-byte ``.tmp`` left behind.
"""
from __future__ import annotations

import contextlib
import os
import re
from collections.abc import Iterator
from pathlib import Path

from capsmech.errors import CapsmechError


class OutputError(CapsmechError, OSError):
    """An output file that could not be written; nothing of it is left."""


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """The temporary path to write ``path``'s content to; renamed over ``path`` when the block
    ends, removed if it fails. An ``OSError`` in the block or the rename becomes an OutputError."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as err:
        raise OutputError(f"{path}: cannot write: {_reason(err)}") from None
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)


def _reason(err: OSError) -> str:
    """The system's reason in a few words, from the error number: h5py's errors carry HDF5's
    multi-line report as their text, with the number in it ("... errno = 28, ...")."""
    errno = err.errno or next((int(n) for n in re.findall(r"errno = (\d+)", str(err))), 0)
    if errno:
        return os.strerror(errno)
    return " ".join(str(err.strerror or err).split())


def write_text_atomically(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` whole or not at all; returns ``path``."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)
