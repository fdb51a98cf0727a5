"""The shipped paper-grid shear database, as issue 23 asks of it: every row steady, on the finer
mesh level, with a stated mesh and time error below 0.5 %, and the small-deformation limit met.

These are facts about the shipped file (made by the workflow from kernel runs on levels 3 and 4
with the grid's bending stiffness k_b = 3e-4, a model choice: validation page "shear flow");
the limit is Barthes-Biesel's (1980) D12 = 5/4 (2 + nu_s)/(1 + nu_s) Ca_s, NH's area
dilatation being that of nu_s = 1/2.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from capsmech.inversion.small_deformation import law_d12_slope
from capsmech.io.database import load_database


@pytest.fixture(scope="module")
def database():
    return load_database("shear-paper")


def test_the_model_and_levels_are_stated(database) -> None:
    from capsmech.io.case import decode_str

    grid = json.loads(decode_str(database.provenance["grid"]))
    settings = json.loads(decode_str(database.provenance["settings"]))
    assert grid["shear"]["mesh_check"] == {"level": 4, "Ca_s_min": 0, "rows": "finer"}
    assert settings["k_b"] == pytest.approx(3e-4)
    for table in database.laws.values():
        assert table.attrs["kb"] == pytest.approx(3e-4)


def test_every_row_is_steady_on_the_finer_level(database) -> None:
    for law, table in database.laws.items():
        assert (table.status == "steady").all(), (law, table.status, table.message)
        assert (table.columns["mesh_level"] == 4).all(), law


def test_every_row_states_errors_below_half_a_percent(database) -> None:
    for law, table in database.laws.items():
        mesh, time = table.columns["D12_mesh_error_rel"], table.columns["D12_time_error_rel"]
        assert np.isfinite(mesh).all() and np.isfinite(time).all(), law
        assert (mesh + time < 5e-3).all(), (law, np.round((mesh + time) * 100, 3))


def test_small_deformation_limit_at_ca_s_0_01(database) -> None:
    """NH within 0.5 % of the limit at Ca_s = 0.01 (issue 23); every law within 1 %, the
    area-hardening GH laws falling away from it linearly in Ca_s (their O(Ca_s^2) term)."""
    for law, table in database.laws.items():
        ca, d12 = table.columns["Ca_s"], table.columns["D12"]
        (row,) = np.flatnonzero(ca == 0.01)
        deviation = d12[row] / ca[row] / law_d12_slope(law) - 1
        assert abs(deviation) < (5e-3 if law == "NH" else 1e-2), (law, deviation)


@pytest.mark.parametrize("law,g_s", [("NH", 0.044), ("GH_nu0.5", 0.024), ("GH_nu0.2", 0.038)])
def test_the_reference_papers_example_within_its_rounding(database, law, g_s) -> None:
    """The reference paper's own code (P1 finite elements and boundary integrals, 2562 nodes,
    G_s, D12 of the inertia ellipsoid: our definitions), §4.3: the capsule of D12 = 0.38 at
    gamma_dot = 350 1/s, mu = 0.756 Pa s, a = 45 um has G_s = 0.044 (NH), 0.024, 0.038 N/m
    (GH nu_s 0.5, 0.2). At that Ca_s = mu gamma_dot a / G_s our row interpolation (PCHIP in
    ln Ca_s, as the shear inversion) gives a D12 that rounds to the paper's 0.38."""
    from scipy.interpolate import PchipInterpolator

    table = database.laws[law]
    ca_s = 0.756 * 350.0 * 45e-6 / g_s
    d12 = float(PchipInterpolator(np.log(table.columns["Ca_s"]), table.columns["D12"])(np.log(ca_s)))
    assert 0.375 <= d12 < 0.385, (law, ca_s, d12)


def test_the_neo_hookean_branch_reaches_the_papers_d12_at_ca_s_1(database) -> None:
    """§3.2 of the reference paper: the NH capsule elongates without end "around Ca_s = 1 and
    D12 = 0.6" (one digit); our last steady row, Ca_s = 1, rounds to it."""
    table = database.laws["NH"]
    (row,) = np.flatnonzero(table.columns["Ca_s"] == 1.0)
    assert round(float(table.columns["D12"][row]), 1) == 0.6
