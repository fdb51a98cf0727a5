"""capsmech.io.catalog: the shipped databases, found by name from anywhere."""

from __future__ import annotations

import os
import re
from pathlib import Path

import h5py
import numpy as np
import pytest

from capsmech.diagnosis.offcentre import OffcentreTable
from capsmech.io.case import decode_str
from capsmech.io.catalog import (
    CATALOG,
    DatabaseNotFoundError,
    database_path,
    effect_database_paths,
    offcentre_table_path,
    shipped_databases,
)
from capsmech.io.database import DatabaseError, load_database

NAMES = ["tube-paper", "shear-paper", "tube-prestress", "tube-kb", "offcentre", "shear-microrheometry",
         "tube-smoke", "shear-smoke", "tube-dev", "shear-dev", "duct-dev"]
DATABASES = [name for name in NAMES if CATALOG[name].kind == "database"]


def test_the_catalog_holds_the_shipped_names() -> None:
    assert list(CATALOG) == NAMES


@pytest.mark.parametrize("name", NAMES)
def test_every_name_resolves_to_a_file_that_names_itself(name: str) -> None:
    path = database_path(name)
    assert path.is_file()
    assert "capsmech" in path.parts and "databases" in path.parts
    with h5py.File(path, "r") as f:
        assert decode_str(f.attrs["name"]) == name
        assert int(f.attrs["version"]) >= 1
        accuracy = decode_str(f.attrs["accuracy"])
        assert accuracy and "\n" not in accuracy
        assert decode_str(f.attrs["code_version"]) and decode_str(f.attrs["grid_name"])
        if CATALOG[name].kind == "database":
            assert decode_str(f.attrs["flow"]) == CATALOG[name].flow


def test_names_are_found_from_another_directory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert database_path("tube-paper").is_absolute()
    assert database_path(Path("tube-paper")) == database_path("tube-paper")  # a name given as a Path
    assert load_database("shear-smoke").name == "shear-smoke"


def test_unknown_name_lists_the_valid_names(tmp_path: Path) -> None:
    with pytest.raises(DatabaseError) as error:
        database_path("tube-papr")
    message = str(error.value)
    assert "'tube-papr'" in message and all(name in message for name in NAMES)
    # The same error from load_database; it is also a FileNotFoundError (a missing path).
    with pytest.raises(DatabaseNotFoundError, match="shipped databases: tube-paper"):
        load_database(tmp_path / "nowhere.h5")
    assert issubclass(DatabaseNotFoundError, FileNotFoundError)


def test_a_path_is_taken_as_it_is(tmp_path: Path) -> None:
    path = database_path("tube-smoke")
    assert database_path(path) == path and database_path(str(path)) == path
    copy = tmp_path / "mine.h5"
    copy.write_bytes(path.read_bytes())
    assert database_path(copy) == copy and load_database(os.fspath(copy)).name == "tube-smoke"


@pytest.mark.parametrize("name", ["tube-smoke", "shear-dev", "tube-paper"])
def test_load_by_name_equals_load_by_path(name: str) -> None:
    by_name, by_path = load_database(name), load_database(database_path(name))
    assert type(by_name) is type(by_path)
    assert by_name.path == by_path.path
    assert by_name.provenance.keys() == by_path.provenance.keys()
    assert all(np.array_equal(by_name.provenance[k], by_path.provenance[k]) for k in by_name.provenance)
    assert list(by_name.laws) == list(by_path.laws)
    for key, table in by_name.laws.items():
        other = by_path.laws[key]
        assert table.status.tolist() == other.status.tolist()
        for column, values in {**table.columns, **table.profiles}.items():
            np.testing.assert_array_equal(values, {**other.columns, **other.profiles}[column])


@pytest.mark.parametrize("name", DATABASES)
def test_database_shows_its_identity_and_a_short_repr(name: str) -> None:
    database = load_database(name)
    assert database.name == name and database.flow == CATALOG[name].flow
    assert database.version == 1 and database.accuracy
    # The kernel that made it (0.3.0 for most; the smoke grid refilled with 0.3.2).
    assert re.fullmatch(r"0\.3\.[0-9]+", database.code_version)
    assert database.code_version == database.provenance["code_version"]
    text = repr(database)
    assert len(text) < 300 and "\n" not in text
    assert name in text and database.flow in text and next(iter(database.laws)) in text
    assert f"{database.provenance['case_count']} cases" in text
    assert all(len(repr(table)) < 100 for table in database.laws.values())


def test_paper_accuracy_is_the_grids() -> None:
    assert load_database("tube-paper").accuracy == (
        "64 meridian elements against 128, and against a refill by other time steps: L_z within 0.1 %, L_p 0.002 l, "
        "v_c 0.02 % on smooth profiles; at a sharp parachute edge L_z 1.6 %, L_p 6.5 % (up to 0.1 l), v_c 0.6 %; "
        "at Ca_s 0.01, where the rear buckles, L_z 1.2 %, L_p 0.027 l; a row whose Newton polish was discarded "
        "L_z 1.9 %, L_p 0.018 l (capsmech.inversion.sharp_edge)")
    assert "level 4" in load_database("shear-paper").accuracy


def test_shipped_databases_lists_the_catalog() -> None:
    shipped = shipped_databases()
    assert [s.name for s in shipped] == NAMES
    for entry in shipped:
        assert entry.path == database_path(entry.name) and entry.flow in ("tube", "shear")
        assert entry.description and entry.accuracy


def test_diagnose_defaults() -> None:
    effects = effect_database_paths()
    assert effects == [database_path("tube-kb"), database_path("tube-prestress")]
    for path in effects:
        database = load_database(path)
        assert database.flow == "tube" and all("+" in key for key in database.laws)
    table = OffcentreTable.read(offcentre_table_path())
    assert table.b0 == 0.025 and table.mode.shape[:2] == (len(table.a_over_l), len(table.Ca_s))


def test_the_offcentre_table_is_not_a_database() -> None:
    with pytest.raises(DatabaseError, match="not a capsmech-database file"):
        load_database("offcentre")
