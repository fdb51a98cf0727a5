"""Shear databases that state their accuracy (issue 23, item 5): each steady row carries the
kernel's estimate of its time error and, where the grid has a ``mesh_check``, the D12 of the same
case on a finer mesh with the mesh error it implies; the shear fit turns the rows' stated errors
into an error of G_s.

A coarse grid keeps the runs short (level 2 checked by level 3, to t = 10): the numbers are not
accurate, the bookkeeping is what is tested.
"""
from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from capsmech.inversion.fitting import database_d12_error, fit_shear_rows
from capsmech.inversion.inverters import ShearInverter
from capsmech.io.case import read_case
from capsmech.io.database import ACCURACY_COLUMNS, MESH_ERROR_ORDER, load_database
from capsmech.io.measurements import Capsule
from capsmech.workflow.grid import GridError, expand_cases, mesh_check_cases, validate_grid

from conftest import run_grid_databases

GRID = {
    "name": "mesh_check_test",
    "databases_dir": "db",
    "results_dir": "results",
    "profile_points": 16,
    "shear": {"laws": ["NH"], "Ca_s": [0.05, 0.2], "mesh_check": {"level": 3, "Ca_s_min": 0.1},
              "settings": {"level": 2, "t_max": 10}},
}


@pytest.fixture(scope="module")
def checked_run(tmp_path_factory) -> Path:
    """The grid run once through the workflow: its working directory."""
    return run_grid_databases(tmp_path_factory.mktemp("mesh_check"), GRID)


def test_companion_cases_are_the_grid_cases_on_the_finer_level() -> None:
    companions = mesh_check_cases(GRID)
    assert list(companions) == ["shear/NH/Ca0.2.h5"]  # Ca_s_min 0.1 leaves 0.05 out
    (companion,) = companions.values()
    assert companion.relative_path == "shear/NH/Ca0.2_level3.h5"
    (case,) = [c for c in expand_cases(GRID, "shear") if c.Ca_s == 0.2]
    args, finer = case.kernel_args(), companion.kernel_args()
    assert finer[finer.index("--level") + 1] == "3" and args[args.index("--level") + 1] == "2"
    assert [a for a in finer if a != "3"] == [a for a in args if a != "2"]
    with pytest.raises(GridError, match="not finer"):
        validate_grid({**GRID, "shear": {**GRID["shear"], "settings": {"level": 3}, "mesh_check": {"level": 2}}})


def test_database_rows_state_time_and_mesh_error(checked_run: Path) -> None:
    table = load_database(checked_run / "db" / "shear.h5").law("NH")
    cases = checked_run / "results" / "cases" / "shear" / "NH"
    for row, ca in enumerate(table.columns["Ca_s"]):
        case = read_case(cases / f"Ca{ca:g}.h5")
        assert case.is_steady, case.message
        with h5py.File(cases / f"Ca{ca:g}.h5") as f:
            assert table.columns["D12_time_error_rel"][row] == f.attrs["time_error_rel"]
        if ca < 0.1:
            assert np.isnan(table.columns["D12_mesh_check"][row])
            assert np.isnan(table.columns["D12_mesh_error_rel"][row])
            continue
        finer = read_case(cases / f"Ca{ca:g}_level3.h5")
        assert finer.mesh_level == 3 and case.mesh_level == 2
        assert table.columns["D12_mesh_check"][row] == finer.steady_value("D12")
        # Richardson with one level apart (h halved) and order 2: the difference times 4/3.
        gain = 2.0**MESH_ERROR_ORDER
        expected = abs(finer.steady_value("D12") / case.steady_value("D12") - 1) * gain / (gain - 1)
        assert table.columns["D12_mesh_error_rel"][row] == pytest.approx(expected, rel=1e-12)
        # The mesh matters at level 2: the estimate is not a rounding error.
        assert table.columns["D12_mesh_error_rel"][row] > 1e-3


def test_rows_from_the_finer_level(checked_run: Path, tmp_path: Path) -> None:
    """``mesh_check.rows: finer``: the same case files assembled with the finer level's values
    where it is steady; the coarse level's D12 becomes the check, and the stated error is the
    finer value's, the coarse one's divided by r^p (Richardson, one level apart)."""
    from capsmech.workflow.assembly import assemble_database

    grid = {**GRID, "shear": {**GRID["shear"], "mesh_check": {**GRID["shear"]["mesh_check"], "rows": "finer"}}}
    validate_grid(grid)
    cases = checked_run / "results" / "cases"
    out = assemble_database(grid, "shear", cases, tmp_path / "finer.h5")
    table, coarse_table = load_database(out).law("NH"), load_database(checked_run / "db" / "shear.h5").law("NH")
    gain = 2.0**MESH_ERROR_ORDER
    for row, ca in enumerate(table.columns["Ca_s"]):
        if ca < 0.1:  # no companion: the row is the case's own level, as before
            assert table.columns["mesh_level"][row] == 2
            assert table.columns["D12"][row] == coarse_table.columns["D12"][row]
            continue
        finer = read_case(cases / "shear" / "NH" / f"Ca{ca:g}_level3.h5")
        assert table.columns["mesh_level"][row] == 3 and coarse_table.columns["mesh_level"][row] == 2
        assert table.columns["D12"][row] == finer.steady_value("D12")
        assert table.columns["L1_over_a"][row] == finer.steady_value("L1")
        assert table.columns["D12_time_error_rel"][row] == finer.time_error_rel
        assert table.columns["D12_mesh_check"][row] == coarse_table.columns["D12"][row]
        assert table.columns["D12_mesh_error_rel"][row] == pytest.approx(
            coarse_table.columns["D12_mesh_error_rel"][row] * table.columns["D12_mesh_check"][row]
            / table.columns["D12"][row] / gain, rel=1e-12)
    with pytest.raises(GridError, match="mesh_check.rows"):
        validate_grid({**GRID, "shear": {**GRID["shear"], "mesh_check": {"level": 3, "rows": "best"}}})


def test_bending_stiffness_as_a_model_setting() -> None:
    """``shear.settings.k_b`` reaches the kernel as --kb and is the case's (and so the database
    group's) bending stiffness; a law key's +kb overrides it."""
    grid = {**GRID, "shear": {**GRID["shear"], "settings": {**GRID["shear"]["settings"], "k_b": 0.0003}}}
    validate_grid(grid)
    for case in expand_cases(grid, "shear"):
        args = case.kernel_args()
        assert args[args.index("--kb") + 1] == "0.0003"
        assert case.effects == {"kb": 0.0003}
    (companion,) = mesh_check_cases(grid).values()
    assert companion.effects == {"kb": 0.0003}
    keyed = {**grid, "shear": {**grid["shear"], "laws": ["NH+kb0.001"]}}
    (keyed_case, _) = expand_cases(keyed, "shear")
    assert keyed_case.effects == {"kb": 0.001}
    args = keyed_case.kernel_args()
    assert args.count("--kb") == 1 and args[args.index("--kb") + 1] == "0.001"


def test_a_database_without_accuracy_columns_reads_them_as_nan(checked_run: Path, tmp_path: Path) -> None:
    old = tmp_path / "old.h5"
    old.write_bytes((checked_run / "db" / "shear.h5").read_bytes())
    with h5py.File(old, "a") as f:
        for name in ACCURACY_COLUMNS["shear"]:
            del f["NH"][name]
    table = load_database(old).law("NH")
    for name in ACCURACY_COLUMNS["shear"]:
        assert np.isnan(table.columns[name]).all()
    assert np.isnan(database_d12_error(table.steady_rows())).all()


def test_g_s_error_is_what_shifting_the_rows_by_their_error_does() -> None:
    """The fit's database error equals the change of G_s when every row's D12 is moved by its
    stated error (first order: a 1e-3 error, the finite difference to 2 % of itself)."""
    ca = np.array([0.1, 0.2, 0.3, 0.5, 0.8])
    d12 = np.array([0.18, 0.32, 0.40, 0.49, 0.57])
    l3 = np.full(5, 1.1)
    err = np.full(5, 1e-3)
    measured = 0.44
    fit = ShearInverter(ca, d12, l3, D12_error_rel=err).fit(D12=measured)
    shifted = ShearInverter(ca, d12 * (1 + err), l3).fit(D12=measured)
    assert fit.database_error_rel == pytest.approx(abs(shifted.Ca_s / fit.Ca_s - 1), rel=0.02)
    # Rows that state no error give none (NaN), never zero.
    assert np.isnan(ShearInverter(ca, d12, l3).fit(D12=measured).database_error_rel)


def test_fit_shear_reports_the_database_error(checked_run: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import capsmech.inversion.fitting as fitting

    database = load_database(checked_run / "db" / "shear.h5")
    table = database.law("NH")
    d12 = float(np.nanmean(table.columns["D12"]))
    # The coarse rows lie partly below the D12 the fit accepts (0.35): accept every D12 here.
    original = fitting.shear_inverter

    def accept_all(db, law):
        inverter = original(db, law)
        inverter.min_D12 = 0.0
        return inverter

    monkeypatch.setattr(fitting, "shear_inverter", accept_all)
    expected = fitting.shear_inverter(database, "NH").fit(D12=d12).database_error_rel
    assert np.isfinite(expected) and expected > 0
    l1 = 1.1e-5
    capsule = Capsule(id="c1", values={"L1": l1, "L2": l1 * (1 - d12) / (1 + d12), "shear_rate": 100.0, "mu": 0.1},
                      line=2)
    (row,) = fit_shear_rows([capsule], database, ["NH"])
    assert row["G_s_database_error"] == pytest.approx(row["G_s"] * expected, rel=1e-9)
