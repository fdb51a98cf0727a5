"""The square-duct database (``config/duct-dev.yaml``, shipped as ``duct-dev``): its grid gives the
kernel exactly the duct cases (3D model, square channel, Newton-Krylov, level 3) and their level-2
companions; assembly turns real case files of the kernel (``tests/data/duct_cases``) into rows
with each row's mesh error; the shipped database states its channel and its rows obey the flow's
physics."""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

from capsmech.io.database import DatabaseError, load_database
from capsmech.workflow.assembly import assemble_database
from capsmech.workflow.grid import GridError, expand_cases, load_grid, mesh_check_cases, validate_grid

from conftest import REPO

DUCT_GRID = REPO / "config" / "duct-dev.yaml"
#: Real case files of the duct-dev grid (kernel 0.3.5), with their level-2 companions.
DATA = REPO / "tests" / "data" / "duct_cases"
#: The duct-dev cases' kernel settings, as the grid's documentation states them.
SETTINGS = ["--channel", "square", "--integrator", "newton", "--level", "3", "--model", "3d",
            "--tube-length", "6", "--wall-h-centre", "0.1", "--wall-h-far", "0.2"]
LAW_ARGS = {"NH": ["--law", "NH"], "GH_nu0.5": ["--law", "GH", "--nu-s", "0.5"]}
SIZES = ("0.6", "0.7", "0.8", "0.9")
CAPILLARY = ("0.02", "0.04", "0.06", "0.08", "0.1", "0.12", "0.15")
#: Observed orders of mesh convergence of the duct (levels 2-4, a/w 0.8, Ca_s 0.05): from
#: docs/validation/runs/duct_convergence.csv, where the level-2, 3 and 4 values give
#: p = log2((X3 - X2) / (X4 - X3)): L_z 3.46, L_p 1.64, v_c 2.42.
ORDERS = {"L_z": 3.4, "L_p": 1.6, "v_c": 2.4}
#: The square duct's centreline velocity over the mean (series solution, docs/theory/duct.md).
DUCT_U_MAX = 2.0963


def test_grid_expands_to_the_duct_cases_and_their_level_2_companions() -> None:
    grid = load_grid(DUCT_GRID)
    cases = {case.relative_path: case.kernel_args() for case in expand_cases(grid, "tube")}
    expected = {f"tube/{key}/a{a}_Ca{ca}.h5": ["--flow", "tube", *law, "--ca", ca, "--a-over-l", a, *SETTINGS]
                for key, law in LAW_ARGS.items() for a in SIZES for ca in CAPILLARY}
    assert cases == expected
    companions = mesh_check_cases(grid)
    assert set(companions) == set(expected)
    level2 = [arg if arg != "3" else "2" for arg in SETTINGS]
    for path, companion in companions.items():
        assert companion.relative_path == path.replace(".h5", "_level2.h5")
        assert companion.kernel_args() == expected[path][:-len(SETTINGS)] + level2


def _duct(**settings: object) -> dict:
    grid = yaml.safe_load(DUCT_GRID.read_text())
    grid["tube"]["settings"].update(settings)
    return grid


@pytest.mark.parametrize(("grid", "message"), [
    (_duct(model="axi", level=None), "tube.settings.channel: a square duct needs tube.settings.model: 3d"),
    (_duct(aspect=0.5), "tube.settings.aspect: only for tube.settings.channel: rect"),
    (_duct(channel="circle"), "tube.settings.channel: 'circle' is not one of"),
    (_duct(level=2), "tube.mesh_check.level: 2 is the cases' own level"),
], ids=["duct without the 3D model", "aspect of a square", "unknown channel", "mesh check on the cases' level"])
def test_grid_refuses_what_the_kernel_would(grid: dict, message: str) -> None:
    grid["tube"]["settings"] = {k: v for k, v in grid["tube"]["settings"].items() if v is not None}
    with pytest.raises(GridError, match=message.replace("(", r"\(").replace(")", r"\)")):
        validate_grid(grid)


def test_a_rect_duct_passes_its_aspect_to_the_kernel() -> None:
    grid = _duct(channel="rect", aspect=2)
    validate_grid(grid)
    args = expand_cases(grid, "tube")[0].kernel_args()
    assert args[args.index("--channel") + 1] == "rect" and args[args.index("--aspect") + 1] == "2"
    # The kernel's rule: the capsule fits the duct's smaller half-side, a/w <= 0.9 min(1, aspect).
    with pytest.raises(GridError, match=r"tube.a_over_l: \[0.6, 0.7, 0.8, 0.9\] do not fit the duct"):
        validate_grid(_duct(channel="rect", aspect=0.5))


def _small_grid() -> dict:
    """The duct-dev grid cut to the case files in DATA."""
    grid = yaml.safe_load(DUCT_GRID.read_text())
    grid["tube"].update(laws=["NH"], a_over_l=[0.6], Ca_s=[0.02, 0.04])  # Ca_s 0.02: a failed row
    return grid


def _steady(path: Path, name: str) -> float:
    """A case file's steady value, read with h5py (NaN unless steady)."""
    with h5py.File(path, "r") as f:
        return float(f[f"steady/{name}"][()]) if f.attrs["status"] == b"steady" else np.nan


def test_assembly_of_real_duct_cases(tmp_path: Path) -> None:
    grid = _small_grid()
    database = load_database(assemble_database(grid, "tube", DATA, tmp_path / "tube.h5"))
    assert (database.channel, database.aspect) == ("square", 1.0)
    assert database.provenance["length_scale"] == "w (duct half-width)"
    assert "square duct" in repr(database)
    table = database.law("NH")
    for row, case in enumerate(expand_cases(grid, "tube")):
        path, companion = DATA / case.relative_path, DATA / case.relative_path.replace(".h5", "_level2.h5")
        with h5py.File(path, "r") as f:
            assert table.status[row] == f.attrs["status"].decode()
            end = (f["profile/r"][0], f["profile/z"][0])
        assert table.columns["mesh_level"][row] == 3
        for column, source in (("L_z", "L_z"), ("L_p", "L_p"), ("vc_over_V", "v_c")):
            value, coarse = _steady(path, source), _steady(companion, source)
            assert table.columns[column][row] == value or np.isnan(value)
            assert table.columns[f"{column}_mesh_check"][row] == coarse or np.isnan(coarse)
            # Richardson: the error of the finer (row's) value is its gap to the coarser one over 2^p - 1.
            expected = abs(value - coarse) / abs(value) / (2.0 ** ORDERS[source] - 1.0)
            np.testing.assert_allclose(table.columns[f"{column}_mesh_error_rel"][row], expected, rtol=1e-12)
        if table.steady[row]:
            # The outline (the mesh's section by y = 0) starts on the axis at the front pole,
            # where the kernel's own outline starts when it keeps its pole (these cases do: r ~1e-9).
            assert table.profiles["profile_r"][row][0] == 0.0 and abs(end[0]) < 1e-6
            assert abs(table.profiles["profile_z"][row][0] - end[1]) < 1e-6


def test_rows_beyond_the_mesh_check_have_no_companion(tmp_path: Path) -> None:
    grid = _small_grid()
    grid["tube"]["mesh_check"]["Ca_s_max"] = 0.02
    assert list(mesh_check_cases(grid)) == ["tube/NH/a0.6_Ca0.02.h5"]
    table = load_database(assemble_database(grid, "tube", DATA, tmp_path / "tube.h5")).law("NH")
    assert table.steady.tolist() == [False, True]
    # The steady row at Ca_s 0.04 has its values and level, and no companion to estimate its error.
    assert table.columns["L_z"][1] == _steady(DATA / "tube/NH/a0.6_Ca0.04.h5", "L_z")
    assert table.columns["mesh_level"][1] == 3
    assert all(np.isnan(table.columns[f"{c}_mesh_{k}"][1]) for c in ("L_z", "L_p", "vc_over_V")
               for k in ("check", "error_rel"))


def test_assembly_refuses_a_case_of_another_channel(tmp_path: Path) -> None:
    cases = tmp_path / "cases"
    shutil.copytree(DATA, cases)
    with h5py.File(cases / "tube" / "NH" / "a0.6_Ca0.02.h5", "r+") as f:
        f.attrs["channel"] = "tube"
    with pytest.raises(DatabaseError, match="channel tube aspect 1, grid wants square aspect 1"):
        assemble_database(_small_grid(), "tube", cases, tmp_path / "tube.h5")


def test_a_tube_database_made_before_channels_is_a_tube() -> None:
    database = load_database("tube-dev")
    assert (database.channel, database.aspect) == ("tube", 1.0)
    assert np.isnan(database.law("NH").columns["L_z_mesh_error_rel"]).all()


def test_shipped_duct_database() -> None:
    database = load_database("duct-dev")
    assert (database.name, database.channel, database.aspect) == ("duct-dev", "square", 1.0)
    assert database.grid == load_grid(DUCT_GRID)
    for key, table in database.laws.items():
        a, ca = table.columns["a_over_l"], table.columns["Ca_s"]
        steady = table.steady
        assert steady.sum() >= len(table) // 2, f"{key}: {table!r}"
        for size in np.unique(a):
            rows = steady & (a == size)
            order = np.argsort(ca[rows])
            # A softer capsule (larger Ca_s) has the deeper parachute at the same size. (Not L_z: a
            # small capsule first shortens into a parachute, then lengthens; tube-paper NH at a/l
            # 0.7: L_z 1.320, 1.289, 1.334 at Ca_s 0.01, 0.05, 0.1.)
            assert np.all(np.diff(table.columns["L_p"][rows][order]) > 0), f"{key} a/w {size}"
        for value in np.unique(ca):
            rows = steady & (ca == value)
            order = np.argsort(a[rows])
            # At the same load, the larger capsule is the longer one.
            assert np.all(np.diff(table.columns["L_z"][rows][order]) > 0), f"{key} Ca_s {value}"
        vc = table.columns["vc_over_V"][steady]
        # No capsule outruns the fluid on the centreline; each moves faster than the mean flow.
        assert np.all(vc < DUCT_U_MAX) and np.all(vc > 1.0), f"{key}: {vc}"
        both = steady & np.isfinite(table.columns["L_z_mesh_check"])
        for column in ("L_z", "L_p", "vc_over_V"):
            assert np.all(np.isfinite(table.columns[f"{column}_mesh_error_rel"][both])), f"{key} {column}"
