"""The fast paths of the batch tube inversion give what the straightforward computation gives.

``TubeInverter.fit_many`` hands the capsules whose result round-off decides (a refinement
cycling between neighbour sets) to ``_fit_exact_many``, ``fit``'s own arithmetic stacked over
the capsules: it must be ``fit``'s result bit for bit, flags included. The stacked weighted
quadratic fits (normal equations over neighbour-major arrays, SVD where the basis is
rank-deficient) must equal one ``np.linalg.lstsq`` per capsule to round-off. ``tube_batch.fit_batch``
(threads over chunks, its steps in blocks, its own refinement and minimum-norm fits, its own
arithmetic also for the refinements that cycle unless round-off could have changed their path,
the neighbours from its table for large batches) must give ``fit``'s flags and values to
round-off, the same on one thread as on two and whatever the chunks and blocks. The capsules are
drawn here, from the database's rows by the test's own triangulation, with 2 % noise on the
lengths; no timing is asserted (``bench/bench_lengths_inversion.py`` measures it). On a capsule
whose first-root iteration wanders about a fold of its fitted map, where the last iterate's
verdict was round-off's, the paths agree too, and find the root that the rows' own interpolants
(scipy's) have.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import CloughTocher2DInterpolator, LinearNDInterpolator
from scipy.optimize import root
from thread_pools import spy_on_pools

from capsmech.inversion import inverters, tube_batch
from capsmech.inversion.fitting import tube_inverter
from capsmech.io.catalog import database_path
from capsmech.io.database import load_database

FIELDS = ("a_over_l", "Ca_s", "vc_over_V", "G_s")


@pytest.fixture(scope="module")
def tube_db():
    return load_database(database_path("tube-paper"))


def drawn_capsules(table: inverters.TubeTable, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """n noisy (L_z, L_p) [l]: (a/l, ln Ca_s) uniform over the rows' bounding box, the lengths
    linear between the rows (the test's own Delaunay triangulation; NaN outside it is redrawn)."""
    rng = np.random.default_rng(seed)
    p = np.column_stack([table.a_over_l, np.log(table.Ca_s)])
    lengths = LinearNDInterpolator(p, np.column_stack([table.L_z, table.L_p]))
    drawn = np.empty((0, 2))
    while len(drawn) < n:
        q = lengths(rng.uniform(p.min(axis=0), p.max(axis=0), size=(2 * n, 2)))
        drawn = np.vstack([drawn, q[np.all(np.isfinite(q), axis=1)]])
    drawn = drawn[:n] * (1 + 0.02 * rng.standard_normal((n, 2)))
    return drawn[:, 0], drawn[:, 1]


def assert_same_fit(reference: inverters.TubeFit, batch: inverters.TubeFit, i: int) -> None:
    """Capsule i of a batch is ``fit``'s: the same flag, each value to 1e-9 relative (NaN where
    fit's is NaN)."""
    assert batch.flag == reference.flag, i
    for name in FIELDS:
        expected, got = getattr(reference, name), getattr(batch, name)
        if np.isnan(expected):
            assert np.isnan(got), (i, name)
        else:
            assert got == pytest.approx(expected, rel=1e-9, abs=0), (i, name)


@pytest.mark.parametrize("law", ["NH", "GH_nu0.5"])
def test_stacked_exact_path_is_fit_bit_for_bit(tube_db, law):
    inverter = tube_inverter(tube_db, law)
    l_z, l_p = drawn_capsules(inverter.table, 300, seed=11)
    p, outcome = inverter._fit_exact_many(l_z, l_p)
    flags = {inverters._EXACT_NO_ROOT: "no parameters of the database reproduce",
             inverters._EXACT_INCONSISTENT: "no consistent parameters",
             inverters._EXACT_OUTSIDE: "outside the database: fitted"}
    for i in range(len(l_z)):
        reference = inverter.fit(float(l_z[i]), float(l_p[i]))
        if outcome[i] == inverters._EXACT_OK:
            assert reference.ok, (i, reference.flag)
            assert (p[i, 0], np.exp(p[i, 1])) == (reference.a_over_l, reference.Ca_s), i
        else:
            assert outcome[i] != inverters._EXACT_LEFT, i  # finite lengths: no step is left to fit
            assert reference.flag.startswith(flags[int(outcome[i])]), (i, reference.flag)
    # The draw reaches every outcome but the non-finite one: valid fits and the three flags.
    assert set(outcome.tolist()) == {inverters._EXACT_OK, *flags}
    assert (outcome == inverters._EXACT_OK).sum() > 200


@pytest.mark.parametrize("law", ["NH", "GH_nu0.5"])
def test_batch_equals_fit_on_drawn_capsules(tube_db, law, monkeypatch):
    monkeypatch.setattr(inverters, "_BATCH", 128)  # several chunks, each with its own cycling capsules
    inverter = tube_inverter(tube_db, law)
    l_z, l_p = drawn_capsules(inverter.table, 300, seed=12)
    many = inverter.fit_many(l_z, l_p, 2.5e-3, 1.2e-3)
    for i in range(len(l_z)):
        assert_same_fit(inverter.fit(float(l_z[i]), float(l_p[i]), 2.5e-3, 1.2e-3), many.row(i), i)


def test_stacked_weighted_fits_equal_lstsq_per_capsule(tube_db):
    """The stacked fits on the neighbourhoods that fit_many meets (in lengths: a quarter are
    rank-deficient; in parameters: well conditioned) equal one lstsq per capsule."""
    inverter = tube_inverter(tube_db, "NH")
    l_z, l_p = drawn_capsules(inverter.table, 400, seed=13)
    q_star = np.column_stack([l_z, l_z - l_p])
    for tree, points, scale in ((inverter._tree, q_star, inverter._q_scale),
                                (inverter._p_tree, np.column_stack([np.full(400, 0.9), np.log(np.geomspace(
                                    inverter.table.Ca_s.min(), inverter.table.Ca_s.max(), 400))]),
                                 inverter._p_scale)):
        distance, index = tree.query(points / scale, k=inverters.N_NEIGHBOURS)
        x = (inverter._p[index] - inverter._p[index[:, :1]]) / inverter._p_scale
        weight = (1 - (distance / (1.01 * distance.max(axis=1, keepdims=True))) ** 2) ** 2
        values = inverter._q[index]
        stacked = inverters._weighted_lstsq_many(x, values, weight)
        for i in range(len(x)):
            sqrt_w = np.sqrt(weight[i])[:, None]
            a = sqrt_w * np.column_stack([x[i, :, 0] ** e[0] * x[i, :, 1] ** e[1] for e in inverters._EXPONENTS])
            expected = np.linalg.lstsq(a, sqrt_w * values[i], rcond=None)[0]
            assert np.abs(stacked[i] - expected).max() <= 1e-9 * np.abs(expected).max(), i


def test_stacked_lstsq_is_lstsq_with_or_without_the_generalised_ufunc(monkeypatch):
    rng = np.random.default_rng(14)
    a, b = rng.standard_normal((50, 14, 6)), rng.standard_normal((50, 14, 2))
    a[:10, :, 5] = a[:10, :, 4]  # rank-deficient: lstsq's minimum-norm answer
    expected = np.array([np.linalg.lstsq(a[i], b[i], rcond=None)[0] for i in range(50)])
    assert np.array_equal(inverters._lstsq_stack(a, b), expected)
    monkeypatch.setattr(np.linalg, "_umath_linalg", None, raising=False)
    assert np.array_equal(inverters._lstsq_stack(a, b), expected)


@pytest.mark.parametrize("law", ["NH", "GH_nu0.5"])
def test_threaded_batch_equals_fit_on_drawn_capsules(tube_db, law, monkeypatch):
    """``tube_batch.fit_batch`` (its own refinement: neighbours asked for only where they can
    have changed, full-rank fits about the current point, two-line fits by their reduced
    system) gives ``fit``'s flags and values, on two threads over several chunks; invalid and
    far lengths get ``fit``'s flags too."""
    monkeypatch.setattr(tube_batch, "CHUNK", 64)
    monkeypatch.setattr(tube_batch, "MIN_THREAD_CAPSULES", 16)
    pools = spy_on_pools(monkeypatch)
    inverter = tube_inverter(tube_db, law)
    l_z, l_p = drawn_capsules(inverter.table, 300, seed=15)
    l_z[:4], l_p[:4] = [np.nan, 1.0, 1e200, 3.0], [0.1, 1.5, 0.5, 2.0]  # not finite, L_p > L_z, far, outside
    v_c, mu = np.linspace(2e-3, 3e-3, 300), 1.2e-3
    many = tube_batch.fit_batch(inverter, l_z, l_p, v_c, mu, workers=2)
    assert pools == [2]
    for i in range(len(l_z)):
        assert_same_fit(inverter.fit(float(l_z[i]), float(l_p[i]), float(v_c[i]), mu), many.row(i), i)
    assert many.ok.sum() > 200


def test_threads_do_not_change_the_result(tube_db, monkeypatch):
    """Each capsule is fitted on its own: the threaded batch equals the one-thread batch bit
    for bit."""
    monkeypatch.setattr(tube_batch, "CHUNK", 100)
    monkeypatch.setattr(tube_batch, "MIN_THREAD_CAPSULES", 100)
    pools = spy_on_pools(monkeypatch)
    inverter = tube_inverter(tube_db, "NH")
    l_z, l_p = drawn_capsules(inverter.table, 1000, seed=16)
    one, two = (tube_batch.fit_batch(inverter, l_z, l_p, workers=w) for w in (1, 2))
    assert pools == [2]
    assert one.flag == two.flag
    for name in ("a_over_l", "Ca_s", "vc_over_V"):
        assert np.array_equal(getattr(one, name), getattr(two, name), equal_nan=True), name


def test_blocks_and_chunks_do_not_change_the_result(tube_db, monkeypatch):
    """Each capsule's arithmetic is its own: the batch in chunks of 150 whose steps (the first
    roots' fits, each refinement step) go in blocks of 37 capsules equals, bit for bit, the
    batch in one chunk and one block, on the same thread; and it is ``fit``'s."""
    inverter = tube_inverter(tube_db, "NH")
    l_z, l_p = drawn_capsules(inverter.table, 400, seed=21)
    monkeypatch.setattr(tube_batch, "CHUNK", 150)
    monkeypatch.setattr(tube_batch, "BLOCK", 37)
    blocks = tube_batch.fit_batch(inverter, l_z, l_p, workers=1)
    monkeypatch.setattr(tube_batch, "CHUNK", 10**6)
    monkeypatch.setattr(tube_batch, "BLOCK", 10**6)
    whole = tube_batch.fit_batch(inverter, l_z, l_p, workers=1)
    assert blocks.flag == whole.flag
    for name in ("a_over_l", "Ca_s", "vc_over_V"):
        assert np.array_equal(getattr(blocks, name), getattr(whole, name), equal_nan=True), name
    assert 200 < whole.ok.sum() < len(l_z)
    for i in range(0, len(l_z), 4):
        assert_same_fit(inverter.fit(float(l_z[i]), float(l_p[i])), blocks.row(i), i)


def test_local_fits_are_lstsq_in_fits_own_basis(tube_db):
    """``tube_batch._local_fit`` on neighbourhoods of the database's points given about a point
    s beside them: where the quadratic basis has full rank, its coefficients about s are
    lstsq's fitted map (value and gradient at s); where the points lie on two grid lines of
    one coordinate (u^2 = b u: rank-deficient), they are ``np.linalg.lstsq``'s minimum-norm
    answer in fit's basis (centred on the nearest point) and x is s there; a neighbourhood on
    two lines of each coordinate (four places, the reduced fit deficient too) gets lstsq's
    answer as well."""
    inverter = tube_inverter(tube_db, "NH")
    rng = np.random.default_rng(17)
    p = inverter._p_scaled
    cases = []
    for axis in (0, 1):
        lines = np.unique(p[:, axis])
        for left in range(len(lines) - 1):
            on_lines = np.flatnonzero((p[:, axis] == lines[left]) | (p[:, axis] == lines[left + 1]))
            on_lines = on_lines[np.argsort(p[on_lines, 1 - axis])]
            cases += [on_lines[start:start + 14] for start in range(0, len(on_lines) - 13, 3)]
    two_line_cases = len(cases)
    lines = np.unique(p[:, 0])
    four = np.flatnonzero(np.isin(p[:, 0], lines[:2]))
    cases.append(np.resize(four[np.argsort(p[four, 1])][:4], 14))
    for point in rng.uniform(p.min(axis=0), p.max(axis=0), size=(60, 2)):  # the 14 nearest: full rank mostly
        cases.append(inverter._p_tree.query(point, k=14)[1])
    index = np.array(cases).T  # neighbour-major (14, m)
    m = index.shape[1]
    s = p[index].mean(axis=0) + rng.uniform(-0.2, 0.2, size=(m, 2))
    u, v = p[index, 0] - s[:, 0], p[index, 1] - s[:, 1]
    nearest = np.argmin(u * u + v * v, axis=0)
    centre = index[nearest, np.arange(m)]

    def fit_coordinates(columns):
        return p[index[:, columns], 0] - p[centre[columns], 0], p[index[:, columns], 1] - p[centre[columns], 1]

    weight = rng.uniform(0.05, 1.0, size=(14, m))
    values = [inverter._q_z[index], inverter._q_zp[index]]
    coefficients, x = tube_batch._local_fit(u, v, values, weight, nearest, fit_coordinates)
    u_fit, v_fit = fit_coordinates(np.arange(m))
    deficient = 0
    for i in range(m):
        sqrt_w = np.sqrt(weight[:, i])[:, None]
        basis = np.column_stack([u_fit[:, i] ** a * v_fit[:, i] ** b for a, b in inverters._EXPONENTS])
        expected, _, rank, _ = np.linalg.lstsq(sqrt_w * basis, sqrt_w * np.column_stack([c[:, i] for c in values]),
                                               rcond=None)
        if rank < 6:
            deficient += 1
            assert np.array_equal(x[:, i], s[i] - p[centre[i]]), i
            assert np.abs(coefficients[:, :, i] - expected).max() <= 1e-9 * np.abs(expected).max(), i
        else:
            assert np.array_equal(x[:, i], [0.0, 0.0]), i
            value, jacobian = inverters._quadratic_value_and_jacobian(expected, s[i] - p[centre[i]])
            got_jacobian = coefficients[1:3, :, i].T
            assert np.abs(coefficients[0, :, i] - value).max() <= 1e-9 * np.abs(value).max(), i
            assert np.abs(got_jacobian - jacobian).max() <= 1e-9 * np.abs(jacobian).max(), i
    assert deficient >= two_line_cases + 1


def test_cycling_refinements_end_where_fits_do(tube_db, monkeypatch):
    """A refinement still moving after its 30 steps (cycling between neighbour sets) ends where
    its path does. ``fit_batch`` follows that path with its own arithmetic and hands to
    ``fit``'s arithmetic only the capsules whose path passed within ``_ROUND_OFF_SLACK`` of a
    change of neighbours (there round-off could have chosen other neighbours): every cycling
    capsule still gets ``fit``'s flag and values."""
    inverter = tube_inverter(tube_db, "NH")
    l_z, l_p = drawn_capsules(inverter.table, 3000, seed=18)
    q_star = np.column_stack([l_z, l_z - l_p])
    roots = tube_batch._roots(inverter, q_star)
    start = roots.first / inverter._p_scale
    refinement = tube_batch._refine(inverter, q_star.T.copy(), start, ~roots.no_root & ~np.isnan(start[:, 0]))
    cycling = np.flatnonzero(refinement.moving)
    handed_to_fit = []
    exact = inverter._fit_exact_many

    def spy(L_z, L_p):
        handed_to_fit.append(len(L_z))
        return exact(L_z, L_p)

    monkeypatch.setattr(inverter, "_fit_exact_many", spy)
    monkeypatch.setattr(tube_batch, "NEIGHBOUR_TABLE_MIN_CAPSULES", 1)  # as for a large batch
    many = tube_batch.fit_batch(inverter, l_z[cycling], l_p[cycling], workers=1)
    for j, i in enumerate(cycling):
        assert_same_fit(inverter.fit(float(l_z[i]), float(l_p[i])), many.row(j), int(i))
    # The draw meets enough cycling capsules, valid and flagged, and most follow their own path.
    assert len(cycling) >= 30
    assert 0 < many.ok.sum() < len(cycling)
    assert sum(handed_to_fit) <= len(cycling) // 10
    # Where the path comes that close to a change of neighbours, the capsule is fit's to fit.
    handed_to_fit.clear()
    monkeypatch.setattr(tube_batch, "_ROUND_OFF_SLACK", np.inf)
    again = tube_batch.fit_batch(inverter, l_z[cycling], l_p[cycling], workers=1)
    assert sum(handed_to_fit) == len(cycling)
    assert again.flag == many.flag


def test_neighbour_table_gives_the_kd_trees_neighbours(tube_db, monkeypatch):
    """``tube_batch.NeighbourTable`` answers a point with its 14 nearest database points (the
    KD-tree's, as a set) and a margin within which they stay the 14 nearest (at most the true
    half gap between the 14th and 15th distances); ``fit_batch`` with the table gives ``fit``'s
    flags and values."""
    inverter = tube_inverter(tube_db, "NH")
    table = tube_batch.NeighbourTable(inverter, tube_batch.NEIGHBOUR_CELL)
    rng = np.random.default_rng(19)
    p = inverter._p_scaled
    points = rng.uniform(p.min(axis=0) - 0.3, p.max(axis=0) + 0.3, size=(5000, 2))
    found, index, margin = table.lookup(points)
    distance, expected = inverter._p_tree.query(points[found], k=inverters.N_NEIGHBOURS + 1)
    assert found.mean() > 0.5
    assert np.array_equal(np.sort(index.T, axis=1), np.sort(expected[:, :-1], axis=1))
    assert np.all((margin > 0) & (margin <= 0.5 * (distance[:, -1] - distance[:, -2])))
    monkeypatch.setattr(tube_batch, "NEIGHBOUR_TABLE_MIN_CAPSULES", 1)
    l_z, l_p = drawn_capsules(inverter.table, 300, seed=20)
    many = tube_batch.fit_batch(inverter, l_z, l_p, workers=1)
    for i in range(len(l_z)):
        assert_same_fit(inverter.fit(float(l_z[i]), float(l_p[i])), many.row(i), i)


# Capsule 9790 of drawn_capsules(GH_nu0.2 rows, 20000, seed=41): its 14 nearest rows in lengths
# lie on the lines a/l 0.8 and 0.85 but one, and the quadratic through them folds just beside
# its lengths (least miss ~0.8 of the root test's tolerance), so that the first root's Newton
# iteration never stops and the last iterate's verdict was round-off's.
FOLD_CAPSULE = (1.6328871361731179, 0.1707523203908501)


def rows_root(table: inverters.TubeTable, L_z: float, L_p: float, interpolant: type) -> np.ndarray:
    """(a/l, ln Ca_s) where the rows' own interpolant (scipy, over (a/l, ln Ca_s)) gives the
    lengths, solved from each corner of the grid cell a/l 0.85-0.9, Ca_s 0.01-0.02: one root,
    inside the cell."""
    lengths = interpolant(np.column_stack([table.a_over_l, np.log(table.Ca_s)]), np.column_stack([table.L_z, table.L_p]))
    roots = []
    for start in ((0.85, 0.01), (0.85, 0.02), (0.9, 0.01), (0.9, 0.02)):
        solution = root(lambda p: lengths(p[None, :])[0] - (L_z, L_p), [start[0], np.log(start[1])])
        assert solution.success, start
        roots.append(solution.x)
    assert np.ptp(roots, axis=0) == pytest.approx([0, 0], abs=1e-8)
    assert 0.85 < roots[0][0] < 0.9 and np.log(0.01) < roots[0][1] < np.log(0.02)
    return roots[0]


def test_paths_agree_where_the_lengths_fit_folds(tube_db):
    """On the fold capsule ``fit``, ``fit_many`` and ``fit_batch`` (alone, and among the
    20000 capsules it was drawn with, where the neighbour table serves the refinement) give
    the same flag and values."""
    inverter = tube_inverter(tube_db, "GH_nu0.2")
    reference = inverter.fit(*FOLD_CAPSULE)
    assert_same_fit(reference, inverter.fit_many(*map(np.atleast_1d, FOLD_CAPSULE)).row(0), 0)
    assert_same_fit(reference, tube_batch.fit_batch(inverter, *map(np.atleast_1d, FOLD_CAPSULE), workers=1).row(0), 0)
    l_z, l_p = drawn_capsules(inverter.table, 20000, seed=41)
    assert (l_z[9790], l_p[9790]) == FOLD_CAPSULE
    assert_same_fit(reference, tube_batch.fit_batch(inverter, l_z, l_p, workers=1).row(9790), 9790)


def test_fold_capsule_gets_the_root_the_rows_have(tube_db):
    """The database's rows reproduce the fold capsule's lengths: their C1 interpolant
    (Clough-Tocher) has one root in its grid cell, a/l 0.867, Ca_s 0.0149. Both paths find a
    root there, within the interpolation's own uncertainty (the distance from that root to the
    piecewise-linear interpolant's: 0.004 in a/l, 6.6 % in Ca_s)."""
    inverter = tube_inverter(tube_db, "GH_nu0.2")
    cubic = rows_root(inverter.table, *FOLD_CAPSULE, CloughTocher2DInterpolator)
    linear = rows_root(inverter.table, *FOLD_CAPSULE, LinearNDInterpolator)
    for fitted in (inverter.fit(*FOLD_CAPSULE),
                   tube_batch.fit_batch(inverter, *map(np.atleast_1d, FOLD_CAPSULE), workers=1).row(0)):
        assert fitted.ok, fitted.flag
        assert abs(fitted.a_over_l - cubic[0]) <= abs(linear[0] - cubic[0])
        assert abs(np.log(fitted.Ca_s) - cubic[1]) <= abs(linear[1] - cubic[1])
