"""Reading a text file from outside: bounded in size, decoded whatever a lab's tools wrote.

Every reader of user files (measurement CSV, contour files, results files) reads through
:func:`read_text`, so that each behaves alike on the files a careless user or a failing disk
gives it:

* at most ``limit`` bytes are read (a path such as ``/dev/zero`` or a file of gigabytes is
  refused once the limit is passed, never read whole into memory);
* a file with NUL bytes is binary, not text, and is refused naming its line;
* text is UTF-8 (a byte-order mark dropped), else Windows-1252 (Excel's plain "CSV"), else
  Latin-1 (ISO 8859-1), which decodes any byte: a file is never refused for its encoding.

Errors are raised as the caller's error class (a :class:`capsmech.errors.CapsmechError`), with
a message that names the file (and the line, where there is one).
"""
from __future__ import annotations

from pathlib import Path

from capsmech.errors import CapsmechError

#: Encodings tried in turn; Latin-1 decodes every byte, so the last always succeeds.
ENCODINGS = ("utf-8-sig", "cp1252", "latin-1")


def _mebibytes(size: int) -> str:
    return f"{size / 2**20:g} MiB"


def read_bytes(path: Path, limit: int, what: str, error: type[CapsmechError]) -> bytes:
    """The bytes of a user's file, at most ``limit`` of them in memory (``read_text``'s
    parameters); ``error`` when it cannot be read or is larger than ``limit``, naming the file."""
    try:
        with open(path, "rb") as stream:
            data = stream.read(limit + 1)
    except (OSError, ValueError) as err:      # ValueError: a NUL character in the path
        reason = err.strerror if isinstance(err, OSError) and err.strerror else str(err)
        raise error(f"{path}: cannot read the {what}: {reason}") from None
    if len(data) > limit:
        raise error(f"{path}: larger than {_mebibytes(limit)}, the most a {what} may hold "
                    "(is it the right file?)")
    return data


def read_text(path: Path, limit: int, what: str, error: type[CapsmechError]) -> str:
    """The text of a user's file, read with at most ``limit`` bytes in memory.

    Parameters
    ----------
    path : Path
        The file (any readable path: a regular file, a pipe, a device).
    limit : int
        Largest size accepted [bytes]; a larger file is refused after reading ``limit + 1``.
    what : str
        What the file is, for the messages (e.g. ``'measurement file'``).
    error : type of CapsmechError
        The exception raised, constructed with the message.

    Returns
    -------
    str
        The decoded text (see the module for the encodings).

    Raises
    ------
    CapsmechError
        ``error``, when the path cannot be opened or read (a directory, no permission, no
        such file), is larger than ``limit``, or holds NUL bytes (binary); the message names
        the file, and for a binary file its first line with a NUL byte.
    """
    data = read_bytes(path, limit, what, error)
    nul = data.find(b"\x00")
    if nul >= 0:
        line = data[:nul].count(b"\n") + 1
        raise error(f"{path}:{line}: a NUL byte: a binary file, not a {what} (text)")
    for encoding in ENCODINGS:
        try:
            return data.decode(encoding)
        except UnicodeDecodeError:
            continue
    raise AssertionError("latin-1 decodes every byte")  # pragma: no cover


def split_lines(text: str) -> list[str]:
    """The lines of ``text``, broken at LF, CRLF and CR only (as an editor numbers them).

    ``str.splitlines`` also breaks at form feeds, NEL (``\\x85``, a byte Latin-1 text may hold)
    and other separators, which would shift the line numbers that messages name.
    """
    return text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
