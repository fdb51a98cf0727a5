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

import importlib
from typing import TYPE_CHECKING, Any

from capsmech.version import __version__

# The public names, each with the module that defines it. They are imported on first use (PEP
# 562), not with the package: `import capsmech` then costs nothing, and a tool that needs one
# corner of the package (the workflow's case runner, started once per database case) does not
# pay for pandas, scipy and matplotlib (1.2 s of imports measured per process).
_PUBLIC = {
    "Extraction": "capsmech.api",
    "diagnose": "capsmech.api",
    "extract": "capsmech.api",
    "extract_shear": "capsmech.api",
    "fit_shear": "capsmech.api",
    "fit_tube": "capsmech.api",
    "plot_population": "capsmech.api",
    "population": "capsmech.api",
    "population_table": "capsmech.api",
    "read_results": "capsmech.api",
    "diagnose_shear": "capsmech.api",
    "compare_methods": "capsmech.api",
    "make_batch": "capsmech.api",
    "write_batch": "capsmech.api",
    "simulate": "capsmech.api",
    "SimulationRun": "capsmech.api",
    "CapsmechError": "capsmech.errors",
    "CapsmechWarning": "capsmech.errors",
    "InputWarning": "capsmech.errors",
    "OutsideDatabaseWarning": "capsmech.errors",
    "CaseFileError": "capsmech.io.case",
    "CaseResult": "capsmech.io.case",
    "NotSteadyError": "capsmech.io.case",
    "read_case": "capsmech.io.case",
    "load_database": "capsmech.io.database",
    "read_measurements": "capsmech.io.measurements",
    "read_batch": "capsmech.io.measurement_frames",
    "plot_case": "capsmech.plotting",
    "save_figure": "capsmech.plotting",
}

if TYPE_CHECKING:
    from capsmech.api import (
        Extraction,
        SimulationRun,
        compare_methods,
        diagnose,
        diagnose_shear,
        extract,
        extract_shear,
        fit_shear,
        fit_tube,
        make_batch,
        plot_population,
        population,
        population_table,
        read_results,
        simulate,
        write_batch,
    )
    from capsmech.errors import CapsmechError, CapsmechWarning, InputWarning, OutsideDatabaseWarning
    from capsmech.io.case import CaseFileError, CaseResult, NotSteadyError, read_case
    from capsmech.io.database import load_database
    from capsmech.io.measurement_frames import read_batch
    from capsmech.io.measurements import read_measurements
    from capsmech.plotting import plot_case, save_figure


def __getattr__(name: str) -> Any:
    """Import a public name's module on first use (``capsmech.fit_tube``, ``from capsmech import ...``)."""
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'capsmech' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))


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
    "SimulationRun",
    "compare_methods",
    "diagnose",
    "diagnose_shear",
    "extract",
    "extract_shear",
    "fit_shear",
    "fit_tube",
    "load_database",
    "make_batch",
    "plot_case",
    "plot_population",
    "population",
    "population_table",
    "read_batch",
    "read_case",
    "read_measurements",
    "read_results",
    "save_figure",
    "simulate",
    "write_batch",
]
