"""The folds recorded in the shipped tube databases (scripts/add_folds.py): where each law's
steady branch ends, per a/l, found by the kernel's continuation, read by
``Database.critical`` and stated by fit-tube.

The databases' rows were time-stepped from a sphere, case by case, without the fold search: a
row steady below the recorded fold and one that elongates without end above it are facts the
search did not make, and each fold must lie between them."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from capsmech.api import fits_above_fold
from capsmech.inversion.fitting import add_fold_columns
from capsmech.io.catalog import database_path
from capsmech.io.database import DatabaseError, load_database

from conftest import REPO

sys.path.insert(0, str(REPO / "scripts"))
import add_folds  # noqa: E402
from checksum_databases import digest, unchecked_datasets  # noqa: E402

#: Published value of the fold for NH at a/l 0.85 on the paper grid's mesh (64 meridian
#: elements, docs/validation/performance.md), to the four digits it is stated with.
NH_085_FOLD = 0.1337
#: The fold's accuracy as the search states it (add_folds.FOLD_ACCURACY: up to 7e-4 relative
#: with the Ca_s requested; 1e-3 here), plus the rounding of the published four digits.
SEARCH_ACCURACY = 1e-3
NH_085_TOLERANCE = SEARCH_ACCURACY * NH_085_FOLD + 0.5e-4


def _rows_around(table, a_over_l: float) -> tuple[float, float]:
    """The largest steady Ca_s and the smallest continuously elongating Ca_s of one a/l's rows
    (inf where none elongates)."""
    at = np.isclose(table.columns["a_over_l"], a_over_l)
    ca, status = table.columns["Ca_s"][at], table.status[at]
    steady = ca[status == "steady"]
    elongating = ca[status == "continuous_elongation"]
    return (float(steady.max()) if steady.size else -math.inf,
            float(elongating.min()) if elongating.size else math.inf)


def _laws_with_folds(name: str) -> list[tuple[str, str]]:
    database = load_database(database_path(name))
    return [(name, key) for key, table in database.laws.items() if table.critical is not None]


FOLDED = [pair for name in ("tube-smoke", "tube-dev", "tube-paper", "tube-kb", "tube-prestress", "duct-dev")
          for pair in _laws_with_folds(name)]


def test_the_square_duct_records_where_its_3d_branches_end() -> None:
    """duct-dev's ends come from the 3D branch (Newton-Krylov continuation, its end bisected to
    1 %), checked against the rows solved case by case: every law and a/w has an end; a fold
    has no steady row above it (an end with one is a lost branch, 'failed', without a value);
    NH's largest capsule folds between its last steady row (0.12) and the row that failed
    from the sphere (0.15), above the circular tube's fold at a/l 0.9 (tube-paper)."""
    duct = load_database(database_path("duct-dev"))
    for key, table in duct.laws.items():
        ends = duct.critical(key)
        assert sorted(ends["a_over_l"]) == sorted(set(table.columns["a_over_l"]))
        for a_over_l, critical, kind in zip(ends["a_over_l"], ends["critical_Ca_s"], ends["kind"]):
            at = np.isclose(table.columns["a_over_l"], a_over_l)
            steady = table.columns["Ca_s"][at][table.status[at] == "steady"]
            if kind == "fold":
                assert steady.max() < critical and not np.any(steady > critical), (key, a_over_l)
            else:
                assert math.isnan(critical) and kind.startswith(("none", "failed")), (key, a_over_l, kind)
    nh = duct.critical("NH").set_index("a_over_l")
    assert nh.loc[0.9, "kind"] == "fold" and 0.12 < nh.loc[0.9, "critical_Ca_s"] < 0.15
    tube = load_database(database_path("tube-paper")).critical("NH").set_index("a_over_l")
    assert nh.loc[0.9, "critical_Ca_s"] > tube.loc[0.9, "critical_Ca_s"]


@pytest.mark.parametrize("name,law", FOLDED, ids=[f"{n}:{k}" for n, k in FOLDED])
def test_each_fold_lies_between_the_rows_steady_and_elongating(name: str, law: str) -> None:
    database = load_database(database_path(name))
    table = database.law(law)
    ends = database.critical(law)
    assert sorted(ends["a_over_l"]) == sorted(set(table.columns["a_over_l"]))
    for a_over_l, critical, kind in zip(ends["a_over_l"], ends["critical_Ca_s"], ends["kind"]):
        last_steady, first_elongating = _rows_around(table, a_over_l)
        if kind in ("fold", "mesh_limit"):
            # The time-stepped row below is steady, the one above elongates: the fold between.
            assert last_steady < critical, (a_over_l, critical, last_steady)
            if kind == "fold":
                assert critical < first_elongating, (a_over_l, critical, first_elongating)
        else:
            # No end inside the grid: no row is steady above where a fold would be, and the
            # NaN says so; a branch whose search failed says why.
            assert math.isnan(critical) and kind.startswith(("none", "failed")), (a_over_l, kind)


def test_dev_database_records_the_nh_folds_and_none_for_gh() -> None:
    """The dev grid's NH rows elongate inside its Ca_s (0.02-0.15) at every a/l, its GH nu_s 0.5
    rows stay steady there: the folds are recorded for NH, none for GH."""
    database = load_database(database_path("tube-dev"))
    nh, gh = database.critical("NH"), database.critical("GH_nu0.5")
    assert list(nh["kind"]) == ["fold"] * 5 and np.all(np.isfinite(nh["critical_Ca_s"]))
    # Folds come earlier for larger capsules (the paper's figure 5: continuous elongation sets
    # in at lower Ca_s as a/l grows).
    assert np.all(np.diff(nh.sort_values("a_over_l")["critical_Ca_s"]) < 0)
    assert database.law("GH_nu0.5").steady.all()
    assert gh["critical_Ca_s"].isna().all() and all(kind.startswith("none") for kind in gh["kind"])


def test_smoke_database_records_no_end_where_every_row_is_steady() -> None:
    database = load_database(database_path("tube-smoke"))
    for law, table in database.laws.items():
        assert table.steady.all()
        assert database.critical(law)["critical_Ca_s"].isna().all()


def test_paper_nh_fold_at_085_is_the_published_value() -> None:
    database = load_database(database_path("tube-paper"))
    if database.law("NH").critical is None:
        pytest.skip("tube-paper has no folds of NH yet: make folds GRID=paper")
    ends = database.critical("NH").set_index("a_over_l")
    assert ends.loc[0.85, "kind"] == "fold"
    assert abs(ends.loc[0.85, "critical_Ca_s"] - NH_085_FOLD) <= NH_085_TOLERANCE


def test_same_fold_from_two_grids_of_one_mesh() -> None:
    """The dev and paper grids request different Ca_s (the branch starts and is time-stepped at
    different points), on the same mesh: the fold is a property of the law, a/l and mesh, so
    the two agree to the search's stated accuracy."""
    paper = load_database(database_path("tube-paper"))
    if paper.law("NH").critical is None:
        pytest.skip("tube-paper has no folds of NH yet: make folds GRID=paper")
    dev = load_database(database_path("tube-dev")).critical("NH").set_index("a_over_l")["critical_Ca_s"]
    ends = paper.critical("NH").set_index("a_over_l")["critical_Ca_s"]
    for a_over_l, value in dev.items():
        assert value == pytest.approx(ends.loc[a_over_l], rel=SEARCH_ACCURACY), a_over_l


def test_critical_at_interpolates_between_the_grids_sizes() -> None:
    table = load_database(database_path("tube-dev")).law("NH")
    sizes, values = table.critical["a_over_l"], table.critical["Ca_s"]
    for a_over_l, value in zip(sizes, values):
        assert table.critical_at(float(a_over_l)) == (pytest.approx(value, rel=1e-12), "fold")
    between, _ = table.critical_at(0.875)
    assert values[1] < between < values[0]  # a/l 0.85 and 0.9: folds 0.1337 and 0.1218
    assert between == pytest.approx(math.sqrt(values[0] * values[1]), rel=1e-12)  # midway in ln Ca_s
    assert math.isnan(table.critical_at(0.8)[0]) and math.isnan(table.critical_at(1.1)[0])
    gh = load_database(database_path("tube-dev")).law("GH_nu0.5")
    assert math.isnan(gh.critical_at(0.9)[0])


def _row(law: str, a_over_l: float, ca: float, flag: str = "") -> dict:
    return {"id": f"{law}-{a_over_l}-{ca}", "law": law, "a_over_l": a_over_l, "Ca_s": ca, "flag": flag, "reason": ""}


def test_fit_above_the_fold_is_flagged_and_one_below_is_not() -> None:
    """Fits placed on the dev database's own rows at a/l 0.9: at Ca_s 0.12 the time-stepped row
    is steady, at 0.15 it elongates without end. The first is a steady capsule, the second
    cannot be one: flagged above_fold with the critical Ca_s in its reason."""
    database = load_database(database_path("tube-dev"))
    last_steady, first_elongating = _rows_around(database.law("NH"), 0.9)
    assert (last_steady, first_elongating) == (0.12, 0.15)
    rows = [_row("NH", 0.9, last_steady), _row("NH", 0.9, first_elongating), _row("NH", 0.9, first_elongating, "asymmetric"),
            _row("GH_nu0.5", 0.9, first_elongating), _row("NH", 0.7, 0.1)]
    add_fold_columns(rows, database)
    below, above, asymmetric, gh, outside = rows
    assert below["flag"] == "" and below["Ca_s_over_critical"] < 1
    assert above["flag"] == "above_fold" and above["Ca_s_over_critical"] > 1
    assert f"{above['critical_Ca_s']:.4g}" in above["reason"]
    # A flag of its own stays (it says more about the capsule); the columns are filled all the same.
    assert asymmetric["flag"] == "asymmetric" and asymmetric["Ca_s_over_critical"] > 1
    # No end known (GH steady over the grid; a/l 0.7 outside the dev grid): NaN, no flag.
    for row in (gh, outside):
        assert math.isnan(row["critical_Ca_s"]) and math.isnan(row["Ca_s_over_critical"]) and row["flag"] == ""
    assert fits_above_fold(rows) == {"NH": [above["id"]]}


def test_critical_groups_are_added_without_touching_the_rows(tmp_path: Path) -> None:
    path = tmp_path / "tube.h5"
    path.write_bytes(database_path("tube-smoke").read_bytes())
    before = digest(path, skip=add_folds.is_critical)
    rows = {"NH": {"a_over_l": [0.4, 0.6, 0.8], "Ca_s": [0.5, 0.4, float("nan")], "kind": ["fold", "fold", "none: x"],
                   "message": ["a", "b", "c"]}}
    add_folds.add_critical_groups(path, rows, {"code_version": "test"})
    assert digest(path, skip=add_folds.is_critical) == before
    assert unchecked_datasets(path) == []
    ends = load_database(path).critical("NH")
    assert list(ends["critical_Ca_s"][:2]) == [0.5, 0.4] and list(ends["message"]) == ["a", "b", "c"]
    # The other law's group, if any, is kept; a second write replaces, without growing the file.
    size = path.stat().st_size
    add_folds.add_critical_groups(path, {"NH": {**rows["NH"], "Ca_s": [0.3, 0.2, 0.1]}}, {})
    assert list(load_database(path).critical("NH")["critical_Ca_s"]) == [0.3, 0.2, 0.1]
    assert path.stat().st_size <= size + 1024
    assert digest(path, skip=add_folds.is_critical) == before
    assert not list(tmp_path.glob("*.tmp"))


def test_a_database_of_another_grid_is_refused(tmp_path: Path) -> None:
    grid = add_folds.load_grid(REPO / "config" / "dev.yaml")
    with pytest.raises(DatabaseError, match="not by the tube flow of grid 'dev'"):
        add_folds.check_database_is_the_grids(database_path("tube-smoke"), grid)
    # A law group whose parameters are not its key's (here GH's nu_s changed).
    path = tmp_path / "tube.h5"
    path.write_bytes(database_path("tube-dev").read_bytes())
    with h5py.File(path, "r+") as f:
        f["GH_nu0.5"].attrs["nu_s"] = 0.4
    with pytest.raises(DatabaseError, match="law group 'GH_nu0.5': nu_s 0.4"):
        add_folds.check_database_is_the_grids(path, grid)


def test_the_script_recomputes_the_smoke_databases_ends(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The whole path on the smoke grid (6 branches of 2 Ca_s at 24 elements, seconds): a copy of
    the shipped file gets the same ends, and a rerun reuses the branch files."""
    if not (REPO / "bin" / "capsim").is_file():
        pytest.skip("bin/capsim not built")
    path = tmp_path / "tube.h5"
    path.write_bytes(database_path("tube-smoke").read_bytes())
    argv = ["smoke", "--database", str(path), "--folds-dir", str(tmp_path / "folds")]
    assert add_folds.main(argv) == 0
    shipped, made = load_database(database_path("tube-smoke")), load_database(path)
    for law in shipped.laws:
        a, b = shipped.critical(law), made.critical(law)
        assert list(a["kind"]) == list(b["kind"])
        np.testing.assert_array_equal(a["critical_Ca_s"], b["critical_Ca_s"])
    assert not list((tmp_path / "folds").glob("cases_*"))  # the case files are thrown away
    capsys.readouterr()
    assert add_folds.main(argv) == 0
    assert capsys.readouterr().out.count(": reused") == 6
