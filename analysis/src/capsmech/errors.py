"""The exceptions and warnings capsmech raises, one hierarchy so that a caller catches them all.

Every error a user can cause (a file, a line, a field, a name) is a :class:`CapsmechError`;
the CLI prints its message on one line and exits with status 2. Everything the analysis
wants a user to know but that does not stop it (a capsule outside the database, a column it
ignores) is a :class:`CapsmechWarning`, issued with :func:`warnings.warn`, so that a
notebook shows what the CLI prints.
"""
from __future__ import annotations


class CapsmechError(Exception):
    """Base class of capsmech's errors: a message that names what is wrong and where."""


class DatabaseError(CapsmechError, ValueError):
    """A database cannot be assembled or loaded; the message names the file and the item."""


class ExtractionError(CapsmechError, ValueError):
    """Frames that cannot be read or measured; the message names the file and the problem
    (``capsmech.imaging``; here so that every reader can raise it without importing another)."""


class CapsmechWarning(UserWarning):
    """Base class of capsmech's warnings."""


class OutsideDatabaseWarning(CapsmechWarning):
    """A capsule (or a requested point) lies outside the database's steady region: no value."""


class InputWarning(CapsmechWarning):
    """An input was accepted with a tolerance the user should know of (e.g. columns ignored)."""
