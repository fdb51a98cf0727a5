"""Batch tube inversion (``TubeInverter.fit_many``) against the reference ``fit`` (issue 5).

The contract is equality: capsule by capsule, fit_many gives what fit gives (a/l, Ca_s,
G_s, v_c/V to 1e-9 relative, the same flags), on random noisy capsules inside the paper
database's steady region, on points outside it and invalid lengths, and on the shipped
example batches' five-fit lengths. And the batch inversion is exact where the method is:
the nodes of a database whose forward map is quadratic in (a/l, ln Ca_s) come back to
round-off.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.interpolate import LinearNDInterpolator

from capsmech.inversion import inverters as inverse
from capsmech.inversion.fitting import fit_tube_rows, tube_inverter
from capsmech.inversion.inverters import FIVE_FITS, TubeInverter, TubeTable
from capsmech.io.catalog import database_path
from capsmech.io.database import load_database
from capsmech.io.measurements import read_measurements

REPO = Path(__file__).resolve().parents[2]
TUBE_DB = database_path("tube-paper")
EXAMPLES = REPO / "data" / "examples"
FIELDS = ("a_over_l", "Ca_s", "G_s", "vc_over_V")


@pytest.fixture(scope="module")
def tube_db():
    return load_database(TUBE_DB)


def assert_same_as_fit(inverter, l_z, l_p, v_c=None, mu=None):
    """fit_many equals fit on every capsule; returns the batch result."""
    many = inverter.fit_many(l_z, l_p, v_c, mu)
    assert len(many) == len(l_z)
    for i in range(len(l_z)):
        reference = inverter.fit(float(l_z[i]), float(l_p[i]), v_c, mu)
        batch = many.row(i)
        assert batch.flag == reference.flag, i
        for name in FIELDS:
            expected, got = getattr(reference, name), getattr(batch, name)
            if np.isnan(expected):
                assert np.isnan(got), (i, name, got)
            else:
                assert got == pytest.approx(expected, rel=1e-9, abs=0), (i, name)
    return many


def noisy_steady_capsules(inverter, n, seed):
    """n (L_z, L_p) drawn uniformly in the database's (a/l, ln Ca_s) hull, lengths linear in
    its Delaunay triangles, with 2 % Gaussian noise on each length."""
    rng = np.random.default_rng(seed)
    p = inverter._p
    low, high = p.min(axis=0), p.max(axis=0)
    points = np.empty((0, 2))
    while len(points) < n:
        draw = rng.uniform(low, high, size=(2 * n, 2))
        points = np.vstack([points, draw[inverter._hull.find_simplex(draw / inverter._p_scale) >= 0]])
    scaled = points[:n] / inverter._p_scale
    l_z = LinearNDInterpolator(inverter._hull, inverter.table.L_z)(scaled)
    l_p = LinearNDInterpolator(inverter._hull, inverter.table.L_p)(scaled)
    return l_z * (1 + 0.02 * rng.standard_normal(n)), l_p * (1 + 0.02 * rng.standard_normal(n))


@pytest.mark.parametrize("law,batch", [("NH", 64), ("GH_nu0.5", None)])
def test_fit_many_equals_fit_on_noisy_capsules_in_the_steady_region(tube_db, law, batch, monkeypatch):
    if batch is not None:   # large inputs are fitted in chunks: the same results
        monkeypatch.setattr(inverse, "_BATCH", batch)
    inverter = tube_inverter(tube_db, law)
    l_z, l_p = noisy_steady_capsules(inverter, 300, seed=5)
    many = assert_same_as_fit(inverter, l_z, l_p, v_c=2.5e-3, mu=1.2e-3)
    # Most are fitted (2 % noise near the hull's edge moves some outside it).
    assert many.ok.sum() > 200


def test_fit_many_flags_outside_and_invalid_lengths_as_fit_does(tube_db):
    inverter = tube_inverter(tube_db, "NH")
    l_z = np.array([1.0, 2.0, -1.0, np.nan, 2.0, np.inf, 0.5, 6.0, 1.2, 3.0, 2.0])
    l_p = np.array([1.5, 2.0, 0.1, 0.1, np.nan, 0.1, 0.0, 0.1, 0.9, 2.5, -0.1])
    many = assert_same_as_fit(inverter, l_z, l_p)
    assert not many.ok.any()
    assert sum("invalid" in f for f in many.flag) == 7
    assert np.all(np.isnan(many.a_over_l)) and np.all(np.isnan(many.G_s))
    empty = inverter.fit_many(np.array([]), np.array([]))
    assert len(empty) == 0


@pytest.mark.parametrize("batch", ["NH", "GH_nu0.5"])
def test_fit_many_equals_fit_on_the_example_batches_five_fits(tube_db, batch):
    capsules = read_measurements(EXAMPLES / f"tube_batch_{batch}.csv", "tube")
    l_z = np.array([c["L_z"] / c["tube_radius"] for c in capsules])
    l_p = np.array([c["L_p"] / c["tube_radius"] for c in capsules])
    five_z = np.concatenate([l_z * fz for _, fz, _ in FIVE_FITS])
    five_p = np.concatenate([l_p * fp for _, _, fp in FIVE_FITS])
    for law in tube_db.laws:
        assert_same_as_fit(tube_inverter(tube_db, law), five_z, five_p, v_c=1e-3, mu=1e-3)


def test_database_nodes_come_back_where_the_forward_map_is_quadratic():
    # The local fit's basis holds a forward map quadratic in (a/l, ln Ca_s): every interior
    # node's lengths give back its own parameters (to round-off, far below 1e-6).
    a_grid = np.arange(0.70, 1.101, 0.05)
    ca_grid = np.array([0.01, 0.02, 0.03, 0.05, 0.07, 0.1, 0.15, 0.2])
    a, ca = (v.ravel() for v in np.meshgrid(a_grid, ca_grid, indexing="ij"))
    x, y = a - 0.9, np.log(ca) - np.log(0.05)
    l_z = 1.8 + 2.0 * x + 0.25 * y + 0.3 * x * y + 0.05 * y**2
    front = 1.5 + 1.2 * x + 0.1 * y + 0.2 * x**2
    inverter = TubeInverter(TubeTable(a_over_l=a, Ca_s=ca, L_z=l_z, L_p=l_z - front, vc_over_V=2 - a))
    many = inverter.fit_many(l_z, l_z - front)
    interior = (a > 0.72) & (a < 1.08) & (ca > 0.011) & (ca < 0.19)
    assert many.ok[interior].all()
    assert np.abs(many.a_over_l[interior] - a[interior]).max() < 1e-9
    assert np.abs(np.log(many.Ca_s[interior] / ca[interior])).max() < 1e-9


def test_fit_many_equals_fit_on_the_paper_database_nodes(tube_db):
    # On the simulated database the local weighted fit smooths (it does not interpolate its
    # nodes): the batch must reproduce the reference there too, flags included.
    inverter = tube_inverter(tube_db, "NH")
    assert_same_as_fit(inverter, inverter.table.L_z, inverter.table.L_p)


@pytest.mark.parametrize("batch", ["NH", "GH_nu0.5"])
def test_fit_tube_rows_are_the_capsules_five_fits(tube_db, batch):
    # fit_tube_rows fits all capsules at once; each row's statistics are those of the capsule's
    # own five fits by the reference fit.
    capsules = read_measurements(EXAMPLES / f"tube_batch_{batch}.csv", "tube")
    rows = fit_tube_rows(capsules, tube_db, ["NH", "GH_nu0.5"])
    inverters = {law: tube_inverter(tube_db, law) for law in ("NH", "GH_nu0.5")}
    for k, capsule in enumerate(capsules):
        l = capsule["tube_radius"]
        for row in rows[2 * k:2 * k + 2]:
            fits = inverters[row["law"]].five_fits(capsule["L_z"] / l, capsule["L_p"] / l,
                                                   capsule["v_c"], capsule["mu"])
            assert row["id"] == capsule.id and row["valid_fits"] == fits.n_valid
            for name in FIELDS[:3]:
                for value, expected in ((row[name], fits.mean(name)), (row[f"{name}_spread"], fits.spread(name))):
                    assert value == pytest.approx(expected, rel=1e-9, nan_ok=True), (row["id"], row["law"], name)
