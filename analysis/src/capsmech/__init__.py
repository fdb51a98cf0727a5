"""capsmech: the shear modulus of microcapsules' membranes from images of capsules flowing in a
capillary (or sheared in a Couette rheometer), compared with simulations of the ``capsim`` kernel.

The public API (every function documented in ``capsmech.api``)::

    import capsmech

    db = capsmech.load_database("tube-paper")           # a shipped database by name, or a file
    capsules = capsmech.read_measurements("batch.csv")  # flow inferred from the columns
    results = capsmech.fit_tube(capsules, db, laws=["NH", "GH_nu0.5"])   # a DataFrame
    verdict = capsmech.population(results)              # which law: verdict.best, verdict.reason
    figure = capsmech.plot_population(results)          # a matplotlib Figure
    diagnosis = capsmech.diagnose(capsules, db, law="NH")   # which effect the model lacks
    found = capsmech.extract("film.tif", pixel_size="0.5um")  # frames -> found.capsules (DataFrame)

Errors a user can cause are ``CapsmechError``; warnings are ``CapsmechWarning``.
"""

from __future__ import annotations

from capsmech.api import (
    Extraction,
    diagnose,
    extract,
    fit_shear,
    fit_tube,
    plot_population,
    population,
    population_table,
    read_results,
)
from capsmech.errors import CapsmechError, CapsmechWarning, InputWarning, OutsideDatabaseWarning
from capsmech.io.case import CaseFileError, CaseResult, NotSteadyError, read_case
from capsmech.io.database import load_database
from capsmech.io.measurements import read_measurements
from capsmech.plotting import plot_case, save_figure
from capsmech.version import __version__

__all__ = [
    "CapsmechError",
    "CapsmechWarning",
    "CaseFileError",
    "CaseResult",
    "InputWarning",
    "NotSteadyError",
    "OutsideDatabaseWarning",
    "__version__",
    "Extraction",
    "diagnose",
    "extract",
    "fit_shear",
    "fit_tube",
    "load_database",
    "plot_case",
    "plot_population",
    "population",
    "population_table",
    "read_case",
    "read_measurements",
    "read_results",
    "save_figure",
]
