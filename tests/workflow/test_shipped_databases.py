"""The database files shipped with capsmech (package data, capsmech.io.catalog) agree with the
kernel: a few of their cases, run again now, reproduce their rows to 1e-6."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from capsmech.io.case import read_case
from capsmech.io.catalog import CATALOG, database_path
from capsmech.io.database import RESULTS, load_database
from capsmech.workflow.grid import expand_cases, mesh_check_cases
from capsmech.workflow.runner import reproduces_results, run_case, source_code_version

from conftest import REPO

#: The shipped capsmech databases, by name (the catalog also ships other tables, e.g. the
#: off-centre one, tested with their module).
SHIPPED = [name for name, entry in CATALOG.items() if entry.kind == "database"]
#: A row whose case took longer than this (as recorded; the device machine that refilled most
#: of them is 2-3 times faster than a CI machine) is checked by `make validate`, not `make test`:
#: a steady row (seconds) almost always qualifies, a max_time shear row (run to t = 60) not.
QUICK_CASE_S = {True: 30.0, False: 10.0}


def _cheapest_row(database, steady: bool) -> int | None:
    """The first law's cheapest steady (or not steady) row; None when it has none. Failure
    records have no wall time: the kernel did not finish them, there is nothing to redo."""
    table = database.law(expand_cases(database.grid, database.flow)[0].law.key)
    wall = table.columns["wall_time_s"]
    rows = (table.steady if steady else ~table.steady) & np.isfinite(wall)
    return int(np.argmin(np.where(rows, wall, np.inf))) if rows.any() else None


def _shipped_params(steady: bool) -> list:
    params = []
    for name in SHIPPED:
        database = load_database(database_path(name))
        row = _cheapest_row(database, steady)
        first = database.law(expand_cases(database.grid, database.flow)[0].law.key)
        slow = row is not None and first.columns["wall_time_s"][row] > QUICK_CASE_S[steady]
        params.append(pytest.param(database_path(name), id=name, marks=[pytest.mark.validate] if slow else []))
    return params


def _check_row(path: Path, tmp_path: Path, steady: bool, finer: bool = False) -> None:
    """Run the first law's cheapest (un)steady case again: same status, same values to 1e-6.
    A row whose values come from the finer level of its grid's mesh check (``mesh_level``) is
    checked on the cases' own level against the D12 it stores from there (``D12_mesh_check``),
    or with ``finer`` on the finer level against the row itself (minutes: `make validate`)."""
    database = load_database(path)
    if not reproduces_results(source_code_version(REPO), database.provenance["code_version"], database.flow):
        pytest.skip(f"{path} was made by kernel {database.provenance['code_version']}: refill it")
    row = _cheapest_row(database, steady)
    if row is None:
        pytest.skip(f"{path}: its first law has no {'steady' if steady else 'non-steady'} row with a wall time")
    cases = expand_cases(database.grid, database.flow)
    first = database.law(cases[0].law.key)
    case = [c for c in cases if c.law.key == first.key][row]
    companion = mesh_check_cases(database.grid).get(case.relative_path)
    row_level = first.columns["mesh_level"][row] if "mesh_level" in first.columns else np.nan
    from_finer = companion is not None and row_level == dict(companion.settings)["level"]
    if finer and not from_finer:
        pytest.skip(f"{path}: its rows are not from a finer mesh level")
    if finer:
        case = companion
    out = tmp_path / case.relative_path
    run_case(REPO / "bin" / "capsim", case.kernel_args(), out, code_version=source_code_version(REPO))
    fresh = read_case(out)
    if from_finer and not finer:
        # The row is the finer level's; this level's steady D12 is what the row stores of it.
        assert fresh.is_steady
        np.testing.assert_allclose(fresh.steady_value("D12"), first.columns["D12_mesh_check"][row],
                                   rtol=1e-6, atol=1e-9, err_msg=f"{path}: {case.case_id} D12 (level of the cases)")
        return
    assert fresh.status == first.status[row]
    for column, (source, _, _) in RESULTS[database.flow].items():
        if fresh.is_steady:
            np.testing.assert_allclose(fresh.steady_value(source), first.columns[column][row],
                                       rtol=1e-6, atol=1e-9, err_msg=f"{path}: {case.case_id} {column}")


@pytest.mark.skipif(not SHIPPED, reason="no database file shipped yet")
@pytest.mark.parametrize("path", _shipped_params(steady=True))
def test_shipped_database_steady_row_is_reproduced(path: Path, tmp_path: Path) -> None:
    _check_row(path, tmp_path, steady=True)


@pytest.mark.skipif(not SHIPPED, reason="no database file shipped yet")
@pytest.mark.parametrize("path", _shipped_params(steady=False))
def test_shipped_database_row_that_is_not_steady_is_reproduced(path: Path, tmp_path: Path) -> None:
    _check_row(path, tmp_path, steady=False)


@pytest.mark.validate
@pytest.mark.parametrize("path", [pytest.param(database_path(name), id=name) for name in SHIPPED])
def test_shipped_database_row_from_the_finer_level_is_reproduced(path: Path, tmp_path: Path) -> None:
    _check_row(path, tmp_path, steady=True, finer=True)
