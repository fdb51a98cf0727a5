"""capsmech: read, fit and plot the case files written by the ``capsim`` kernel.

The kernel (``bin/capsim``, Fortran + OpenMP) simulates one microcapsule in
Stokes flow and writes one HDF5 case file per run; :func:`read_case` turns such
a file into a validated, immutable :class:`CaseResult`.

The inverse analysis, as the CLI uses it::

    import capsmech
    capsules = capsmech.read_measurements("batch.csv", "tube")
    rows = capsmech.fit_tube(capsules, capsmech.load_database("data/databases/tube.h5"))
    drifts, law = capsmech.inversion.population(rows)
"""

from __future__ import annotations

# Set before the submodules are imported: some of them record it in the files they write.
__version__ = "0.1.0"

from capsmech.inversion.fitting import fit_shear, fit_tube, write_results
from capsmech.inversion.population import population
from capsmech.io.case import CaseFileError, CaseResult, NotSteadyError, read_case
from capsmech.io.database import load_database
from capsmech.io.measurements import read_measurements

__all__ = ["CaseFileError", "CaseResult", "NotSteadyError", "__version__", "fit_shear", "fit_tube", "load_database",
           "population", "read_case", "read_measurements", "write_results"]
