"""The grid a diagnose candidate asks for is named after its base where the base is not the
geometry of the shipped effect libraries: writing or refilling a square duct's pre-stress grid
must not replace the circular tube's ``effects_prestress`` config nor its ``tube-prestress``
database (contract: names and places, not values)."""
from __future__ import annotations

import numpy as np
import pytest

from capsmech.diagnosis.effect_grid import needed_grid
from capsmech.io.catalog import database_path
from capsmech.io.database import DatabaseError, load_database


def _grid(name: str, effect: str, law: str) -> dict:
    try:
        database = load_database(database_path(name))
    except (DatabaseError, OSError, KeyError) as err:
        pytest.skip(f"database {name} is not there ({err})")
    nodes = database.grid["tube"]
    a = np.array([np.mean(nodes["a_over_l"][:2])])
    ca = np.array([np.mean(nodes["Ca_s"][:2])])
    return needed_grid(effect, [law], database, a, ca)


@pytest.mark.parametrize("effect,law", [("prestress", "NH+prestress0.04"), ("kb", "NH+kb0.005")])
def test_a_circular_tube_base_keeps_the_effect_librarys_names(effect, law):
    grid = _grid("tube-paper", effect, law)
    assert grid["name"] == f"effects_{effect}"
    assert grid["tube"]["database"]["name"] == f"tube-{effect}"
    assert grid["databases_dir"].endswith(f"effects/{effect}")


@pytest.mark.parametrize("effect,law", [("prestress", "NH+prestress0.04"), ("kb", "NH+kb0.005")])
def test_a_square_duct_base_gets_names_and_places_of_its_own(effect, law):
    grid = _grid("duct-dev", effect, law)
    library = _grid("tube-paper", effect, law)
    assert grid["name"] != library["name"] and "duct" in grid["name"]
    assert grid["tube"]["database"]["name"] != library["tube"]["database"]["name"]
    assert grid["databases_dir"] != library["databases_dir"]
    assert grid["results_dir"] != library["results_dir"]
    # The duct's own model and channel, which the grid's cases are run with.
    assert grid["tube"]["settings"]["model"] == "3d" and grid["tube"]["settings"]["channel"] == "square"
