"""The database files shipped with capsmech (package data, capsmech.io.catalog) agree with the
kernel: a few of their cases, run again now, reproduce their rows to 1e-6."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from capsmech.io.case import read_case
from capsmech.io.catalog import CATALOG, database_path
from capsmech.io.database import RESULTS, load_database
from capsmech.workflow.grid import expand_cases
from capsmech.workflow.runner import run_case, source_code_version

from conftest import REPO

#: The shipped capsmech databases, by name (the catalog also ships other tables, e.g. the
#: off-centre one, tested with their module).
SHIPPED = [name for name, entry in CATALOG.items() if entry.kind == "database"]
#: A database whose cheapest steady case took longer than this is checked by `make validate`.
QUICK_CASE_S = 30.0


def _cheapest_steady_case_s(path: Path) -> float:
    database = load_database(path)
    table = database.law(expand_cases(database.grid, database.flow)[0].law.key)
    return float(np.min(np.where(table.steady, table.columns["wall_time_s"], np.inf)))


def _shipped_params() -> list:
    return [pytest.param(database_path(name), id=name,
                         marks=[pytest.mark.validate] if _cheapest_steady_case_s(database_path(name)) > QUICK_CASE_S
                         else [])
            for name in SHIPPED]


@pytest.mark.skipif(not SHIPPED, reason="no database file shipped yet")
@pytest.mark.parametrize("path", _shipped_params())
def test_shipped_database_rows_are_reproduced(path: Path, tmp_path: Path) -> None:
    database = load_database(path)
    if database.provenance["code_version"] != source_code_version(REPO):
        pytest.skip(f"{path} was made by kernel {database.provenance['code_version']}: refill it")
    cases = expand_cases(database.grid, database.flow)
    # The cheapest steady case of the first law, and its cheapest case that is not steady.
    first = database.law(cases[0].law.key)
    # (Failure records have no wall time: the kernel did not finish them, there is nothing to redo.)
    wall = first.columns["wall_time_s"]
    picks = [int(np.argmin(np.where(first.steady, wall, np.inf)))]
    unsteady = ~first.steady & np.isfinite(wall)
    if unsteady.any():
        picks.append(int(np.argmin(np.where(unsteady, wall, np.inf))))
    law_cases = [c for c in cases if c.law.key == first.key]
    for row in picks:
        case = law_cases[row]
        out = tmp_path / case.relative_path
        run_case(REPO / "bin" / "capsim", case.kernel_args(), out, code_version=source_code_version(REPO))
        fresh = read_case(out)
        assert fresh.status == first.status[row]
        for column, (source, _, _) in RESULTS[database.flow].items():
            if fresh.is_steady:
                np.testing.assert_allclose(fresh.steady_value(source), first.columns[column][row],
                                           rtol=1e-6, atol=1e-9, err_msg=f"{path}: {case.case_id} {column}")
