"""capsmech: read, fit and plot the case files written by the ``capsim`` kernel.

The kernel (``bin/capsim``, Fortran + OpenMP) simulates one microcapsule in
Stokes flow and writes one HDF5 case file per run; :func:`read_case` turns such
a file into a validated, immutable :class:`CaseResult`.
"""

from __future__ import annotations

from capsmech.io import CaseFileError, CaseResult, NotSteadyError, read_case

__version__ = "0.1.0"

__all__ = ["CaseFileError", "CaseResult", "NotSteadyError", "__version__", "read_case"]
