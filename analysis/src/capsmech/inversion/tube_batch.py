"""The lengths-only tube inversion of many capsules at once, on every core of one process.

``TubeInverter.fit_many`` (``capsmech.inversion.inverters``) stays the reference: ``fit_batch``
gives its result (``fit``'s, to round-off: the same neighbours, weights, roots, iterations and
flags) with less arithmetic, and spreads the capsules over threads. None of the changes is
one of method:

- A refinement still cycling between neighbour sets after its 30 steps ends where its path
  does, and follows it here with this module's arithmetic as it does for the others: the
  path is ``fit``'s as long as round-off cannot have chosen other neighbours anywhere on it,
  which the margins of the neighbour sets (below) tell, and as long as the path does not
  grow round-off, which the same path from a start moved by ``_ROUND_OFF_PROBE`` tells
  (``_probe_cycling``, all the cycling capsules of a chunk at once). Only a capsule failing
  either gets ``fit``'s own arithmetic (``TubeInverter._fit_exact_many``, which ``fit_many``
  gives every cycling capsule: ~2 % of noisy capsules, a quarter of the CPU time before;
  here ~1 in 5000).
- Likewise for the first root: a Newton iteration on the local fit in lengths that never
  stops wanders about a fold of the fitted map, and where it stops is round-off's; if its
  iterates came near a root (within ``_FIRST_ROOT_SLACK`` times the root test's tolerance: a few
  capsules in 10^5), whether the last is a root is round-off's too, and the capsule gets
  ``fit``'s own arithmetic.
- The parameter-space refinement asks the KD-tree for the neighbours only where they can
  have changed: the query returns one neighbour more than the fit uses, and while the point
  stays within half the gap between the 14th and 15th distances of where it was asked, the
  14 nearest are the same points (triangle inequality); their distances are then computed
  directly. About two queries in three are saved. For a large batch, most of the others
  are a look-up (``NeighbourTable``: the neighbours of the centres of a fine grid's cells,
  built once per inverter and kept with it), the KD-tree asked only where a point is not
  well inside its cell centre's margin.
- A local fit with full rank is written about the current point (a quadratic's least-squares
  fit does not depend on where its basis is centred): the Newton step is read off its
  coefficients there. A rank-deficient one (the neighbours on two grid lines of one
  coordinate: u^2 = (alpha + beta) u - alpha beta; a quarter of the fits in lengths, 3 % in
  parameters) is lstsq's minimum-norm answer in fit's basis, computed from the fit
  without the dependent column (the same Cholesky factorisation, that pivot skipped) instead
  of one SVD per capsule; any other deficiency still gets lstsq's SVD.
- The weighted moments are sums of products in one pass (einsum), the coefficients stored
  component-major (6, 2, m), so that the Newton steps work on contiguous vectors.
- The capsules go in chunks, as many for each thread (one for 10^5 capsules on two), to a
  pool of threads, each chunk fitted, probed and stored by one thread: numpy's operations on
  whole chunks, the KD-tree's queries and LAPACK release the GIL, so the chunks run on the
  cores together, and no step waits for all of them. Large chunks keep the refinement's last
  steps (a few capsules still moving) few; the steps' arrays of 14 neighbours a capsule go in
  blocks of at most ``BLOCK`` capsules, which numpy works through faster than whole chunks.
- The first roots' Newton iterations work on the rows still moving, packed together, and
  the refinement evaluates its last fit only where a row stops: the same arithmetic, row by
  row, on fewer and smaller arrays.
"""
from __future__ import annotations

import os
import threading
import weakref
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from functools import partial, reduce
from typing import NamedTuple

import numpy as np

from capsmech.inversion import inverters
from capsmech.inversion.inverters import Modulus, TubeFits, TubeInverter

#: Capsules in one chunk of work (at most): enough that numpy's cost per call is spread over
#: many (the refinement's last steps run on the few capsules still moving: a chunk of 16384
#: spent a fifth of its time there), few enough that 10^5 capsules make a chunk for each of
#: two threads, to end together.
CHUNK = 65536
#: Capsules whose neighbour-major (14, m) arrays one step works on at once (measured on 10^5
#: capsules: whole chunks of 50000 ~15 % slower, numpy's passes over larger arrays leaving the
#: cache; blocks of 2048 ~10 % slower, numpy's cost per call again).
BLOCK = 16384
#: Side of the cells of ``NeighbourTable`` (scaled parameters), and the fewest capsules for
#: which ``fit_batch`` builds one (its ~10^5 cells cost as many queries as ~10^5 capsules'
#: refinements make a third of, and it is kept with the inverter).
NEIGHBOUR_CELL = 0.01
NEIGHBOUR_TABLE_MIN_CAPSULES = 20000
#: Fewest capsules worth a thread of their own.
MIN_THREAD_CAPSULES = 2048
#: Steps of the parameter-space refinement and its convergence threshold on the step (``fit``'s).
_REFINE_STEPS = 30
_REFINE_TOLERANCE = 1e-10
#: Least distance (scaled parameters) from a refinement's points to where their neighbour sets
#: change above which round-off cannot have chosen other neighbours on the way: this path's
#: arithmetic and ``fit``'s differ by ~1e-13 there.
_ROUND_OFF_SLACK = 1e-8
#: The start's shift (scaled parameters) that probes a cycling path's growth of round-off, and
#: the growth above which the path is ``fit``'s arithmetic's to follow: this arithmetic and
#: ``fit``'s differ by <~1e-13 at the start, so the ends stay within ~1e-10.
_ROUND_OFF_PROBE = 1e-12
_ROUND_OFF_GROWTH = 1e3
#: How near (in tolerances of the root test) the iterates of a first-root Newton iteration
#: that never stops must come to the lengths for the capsule to get ``fit``'s arithmetic:
#: such an iteration wanders about a fold of the fitted map, and its least miss is the
#: map's distance to the lengths, which ``fit``'s iterates and these reach alike (measured:
#: within 1 % mostly, within a factor 2 at worst, on 20000 drawn capsules of each of the
#: tube-paper database's five laws).
_FIRST_ROOT_SLACK = 10.0


#: The environment variable that bounds a process's threads (OpenMP's, which BLAS, batch
#: schedulers and job scripts already set): processes run side by side, each told its share
#: of the cores, do not start a thread per core each.
THREADS_ENV = "OMP_NUM_THREADS"


def default_workers() -> int:
    """Threads for a batch: the cores this process may run on, at most ``THREADS_ENV``'s
    number where that is a positive integer."""
    try:
        cores = max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not every platform has sched_getaffinity
        cores = max(1, os.cpu_count() or 1)
    bound = os.environ.get(THREADS_ENV, "").strip()
    return min(cores, int(bound)) if bound.isdigit() and int(bound) > 0 else cores


def fit_batch(inverter: TubeInverter, L_z: np.ndarray, L_p: np.ndarray, v_c: np.ndarray | float | None = None,
              mu: np.ndarray | float | None = None, workers: int | None = None) -> TubeFits:
    """``inverter.fit_many(L_z, L_p, v_c, mu)``, on ``workers`` threads (default: the cores).

    Parameters and result as ``TubeInverter.fit_many``: one entry per capsule, the values
    ``fit``'s to round-off, the flags ``fit``'s.
    """
    L_z, L_p, modulus = inverters.capsule_arrays(L_z, L_p, v_c, mu)
    n = len(L_z)
    # A thread for every MIN_THREAD_CAPSULES at most: for a few capsules, starting threads
    # costs more than it saves.
    threads = max(1, min(workers or default_workers(), n // MIN_THREAD_CAPSULES))
    # Chunks of at most CHUNK capsules, as many for each thread, so that they end together.
    size = max(1, -(-n // (threads * -(-n // (threads * CHUNK))))) if n else 1
    starts = range(0, max(n, 1), size)

    table = neighbour_table(inverter) if n >= NEIGHBOUR_TABLE_MIN_CAPSULES else None

    def chunk(start: int) -> tuple[np.ndarray, np.ndarray, Modulus]:
        part = slice(start, start + size)
        return L_z[part], L_p[part], (np.ascontiguousarray(modulus[0][part]),
                                      np.ascontiguousarray(modulus[1][part])) if modulus else None

    def fitted(start: int) -> TubeFits:
        L_z_part, L_p_part, modulus_part = chunk(start)
        out, rows, q_star = inverter._screen(L_z_part, L_p_part)
        if rows.size:
            roots = _roots(inverter, q_star, table)
            _probe_cycling(inverter, q_star, roots, table)
            inverter._store_roots(out, rows, roots.first, roots.scaled, roots.todo, roots.refined, roots.no_root,
                                  modulus_part)
            inverter._store_exact(out, rows[roots.fallback], L_z_part, L_p_part, modulus_part)
        return out

    threads = min(threads, len(starts))
    if threads <= 1:
        parts = [fitted(start) for start in starts]
    else:
        # Scipy builds some of the triangulation's arrays on first use: once, here, not in
        # two threads at once.
        inverter._velocity(np.zeros((1, 2)))
        with ThreadPoolExecutor(max_workers=threads) as pool:
            parts = list(pool.map(fitted, starts))
    return TubeFits.concatenate(parts)


class _Roots(NamedTuple):
    """What ``fit``'s steps find for m capsules."""

    #: The first root (a/l, ln Ca_s) (m, 2), from the local fit in lengths.
    first: np.ndarray
    #: The refined root in scaled parameters (m, 2).
    scaled: np.ndarray
    #: Capsules whose local fit in lengths has no root.
    no_root: np.ndarray
    #: Capsules refined from the first root (neither ``no_root`` nor ``fallback``).
    todo: np.ndarray
    #: Capsules of ``todo`` whose refined root reproduces their lengths.
    refined: np.ndarray
    #: Capsules left to ``fit``'s own arithmetic: a step not finite, a first-root iteration
    #: that never stopped but came within ``_FIRST_ROOT_SLACK`` tolerances of a root, or a
    #: refinement still moving after its steps that passed within ``_ROUND_OFF_SLACK`` of a
    #: change of neighbours (or, after ``_probe_cycling``, grows round-off).
    fallback: np.ndarray
    #: The capsules of ``todo`` whose refinement still moved after its steps (indices).
    cycling: np.ndarray


def _roots(inv: TubeInverter, q_star: np.ndarray, table: NeighbourTable | None = None) -> _Roots:
    """``fit``'s roots for the lengths q* (m, 2): the first root by the local forward map over
    the neighbours in lengths, then the refinement in parameter space (``_refine``).

    A refinement still moving after its steps (cycling between neighbour sets) ends where its
    path does. That path is this arithmetic's as it is ``fit``'s unless round-off could have
    chosen other neighbours somewhere on it: where the path passed within ``_ROUND_OFF_SLACK``
    of a change of neighbours the capsule gets ``fit``'s own arithmetic; the others are listed
    in ``_Roots.cycling`` for ``_probe_cycling``."""
    m = len(q_star)
    fallback = np.zeros(m, dtype=bool)
    # The local forward map over the neighbours in lengths (``fit``'s), its basis centred on
    # the nearest of them (in fit's coordinates), Newton from there.
    distance, index = inv._tree.query(q_star / inv._q_scale, k=inv.n_neighbours)
    index, distance = index.T, distance.T  # neighbour-major (n, m)
    coefficients = np.empty((6, 2, m))
    for start in range(0, m, BLOCK):
        block = slice(start, start + BLOCK)
        around = index[:, block]
        u = (inv._p[around, 0] - inv._p[around[0], 0]) / inv._p_scale[0]
        v = (inv._p[around, 1] - inv._p[around[0], 1]) / inv._p_scale[1]
        weight = (1 - (distance[:, block] / (1.01 * distance[-1, block] + 1e-300)) ** 2) ** 2
        values = [inv._q_z[around], inv._q_zp[around]]
        # The basis is centred on fit's centre (neighbour 0): the fit is fit's wherever it has rank.
        coefficients[:, :, block], _ = _local_fit(u, v, values, weight, np.zeros(u.shape[1], dtype=np.intp),
                                                  partial(_columns_of, u, v))
    target = q_star.T.copy()
    x = np.zeros((2, m))
    # The least miss |q - q*| (largest component) of each row's iterates, for the rows that
    # never stop.
    least_miss = np.full(m, np.inf)
    # The rows still moving, their coefficients, point and target packed together: gathered
    # again only when some stop.
    live = np.arange(m)
    c_live: np.ndarray = coefficients
    x_live: np.ndarray = x
    target_live: np.ndarray = target
    miss_live: np.ndarray = least_miss
    for _ in range(50):
        if live.size == 0:
            break
        x_live, norm, bad, residual = _damped_newton_step(c_live, x_live, target_live, 0.5)
        miss_live = np.minimum(miss_live, np.maximum(np.abs(residual[0]), np.abs(residual[1])))
        fallback[live[bad]] = True
        stop = (norm < 1e-12) | bad
        if stop.any():
            x[:, live[stop]] = x_live[:, stop]
            going = ~stop
            live, c_live, x_live, target_live, miss_live = (live[going], c_live[:, :, going], x_live[:, going],
                                                            target_live[:, going], miss_live[going])
    x[:, live] = x_live
    q = _quadratic_value(coefficients, x)
    tolerance = 1e-6 * np.abs(q_star).max(axis=1)
    # A row still moving after its steps wanders about a fold of the fitted map (q* just
    # outside its image, or at its edge), and where it stops is round-off's choice: if its
    # iterates come near a root (within _FIRST_ROOT_SLACK of the tolerance), whether the last
    # one is a root is round-off's too, and the capsule gets ``fit``'s own arithmetic.
    least_miss[live] = np.minimum(miss_live, np.abs(q[:, live] - target[:, live]).max(axis=0))
    fallback[live[least_miss[live] <= _FIRST_ROOT_SLACK * tolerance[live]]] = True
    no_root = np.any(np.abs(q - target) > tolerance, axis=0) & ~fallback
    first = inv._p[index[0]] + x.T * inv._p_scale

    todo = ~no_root & ~fallback
    refinement = _refine(inv, target, first / inv._p_scale, todo, table)
    fallback |= refinement.failed | (refinement.moving & (refinement.slack < _ROUND_OFF_SLACK))
    todo &= ~fallback
    refined = todo & ~np.any(np.abs(refinement.value - target) > tolerance, axis=0)
    return _Roots(first, refinement.scaled, no_root, todo, refined, fallback, np.flatnonzero(todo & refinement.moving))


def _columns_of(u: np.ndarray, v: np.ndarray, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The columns ``columns`` of the neighbour-major coordinates u, v (fit's own, already)."""
    return u[:, columns], v[:, columns]


def _probe_cycling(inv: TubeInverter, q_star: np.ndarray, roots: _Roots, table: NeighbourTable | None) -> None:
    """Hand to ``fit``'s arithmetic (``roots.fallback``) the cycling capsules (``roots.cycling``,
    of the lengths q* (m, 2)) whose path grows round-off: their refinement again, from a start
    moved by ``_ROUND_OFF_PROBE``, ends more than ``_ROUND_OFF_GROWTH`` times that away. All of
    them at once: each step of a few of them costs numpy's calls as much as many."""
    if not roots.cycling.size:
        return
    start = roots.first[roots.cycling] / inv._p_scale
    probe = _refine(inv, q_star[roots.cycling].T.copy(), start + _ROUND_OFF_PROBE,
                    np.ones(len(start), dtype=bool), table)
    grown = ~(np.abs(probe.scaled - roots.scaled[roots.cycling]).max(axis=1) < _ROUND_OFF_GROWTH * _ROUND_OFF_PROBE)
    sensitive = roots.cycling[grown]
    roots.fallback[sensitive] = True
    roots.todo[sensitive] = False
    roots.refined[sensitive] = False


class _Refinement(NamedTuple):
    """Where ``_refine`` ends, for m capsules."""

    #: Final scaled parameters (m, 2).
    scaled: np.ndarray
    #: The last local fit's value there (2, m).
    value: np.ndarray
    #: Rows still moving after the steps.
    moving: np.ndarray
    #: The least distance (scaled parameters), over the steps, from the point to where its
    #: neighbour set changes.
    slack: np.ndarray
    #: Rows with a non-finite step.
    failed: np.ndarray


def _refine(inv: TubeInverter, target: np.ndarray, scaled: np.ndarray, todo: np.ndarray,
            table: NeighbourTable | None = None) -> _Refinement:
    """``_refine_in_parameter_space``'s iteration on the rows ``todo`` of a stack, from the
    scaled parameters ``scaled`` (m, 2), towards the lengths ``target`` (2, m); the neighbours
    from ``table`` where it has them (``_nearest``).

    Each step fits q(p) over the 14 database points nearest to the current point s, weighted
    by their distance to s (``fit``'s fit). Where that fit has full rank, the fitted quadratic
    does not depend on where its basis is centred, and it is fitted about s itself (the step
    is then read off the coefficients at s). Where the neighbours make it rank-deficient (on
    two grid lines: a direction without curvature), lstsq's minimum-norm answer does depend on
    the centre, and it is taken as ``fit`` takes it, about the nearest database point."""
    k = inv.n_neighbours
    m = len(scaled)
    scaled = scaled.copy()
    # The last local fit's value at the point it stepped to, for the rows that stopped (or
    # reached the last step); 0 for the rows never refined (the empty fit's value).
    value_at_end = np.zeros((2, m))
    failed = np.zeros(m, dtype=bool)
    active = todo.copy()
    # Per row: its 14 neighbours (a row each), where they were asked for and the margin
    # (half the gap between the 14th and 15th distances) within which they stay the 14 nearest.
    neighbours = np.zeros((m, k), dtype=np.intp)
    asked_at = np.full((m, 2), np.nan)
    margin = np.full(m, -1.0)
    slack = np.full(m, np.inf)
    for step in range(_REFINE_STEPS):
        live = np.flatnonzero(active)
        if live.size == 0:
            break
        s_live = scaled[live]
        moved = np.hypot(s_live[:, 0] - asked_at[live, 0], s_live[:, 1] - asked_at[live, 1])
        asked = ~(moved < margin[live])  # NaN (never asked) compares False: asked
        stale = live[asked]
        if stale.size:
            neighbours[stale], margin[stale] = _nearest(inv, scaled[stale], table)
            asked_at[stale] = scaled[stale]
            moved[asked] = 0.0
        # The neighbours stay the 14 nearest within margin - moved of the point.
        slack[live] = np.minimum(slack[live], margin[live] - moved)
        # Blocks of at most BLOCK rows, all of one size.
        size = -(-live.size // -(-live.size // BLOCK))
        for start in range(0, live.size, size):
            rows = live[start:start + size]
            s_rows = s_live[start:start + size]
            # Neighbour-major (14, m), each capsule's 14 together in memory, the layout these
            # arrays have always had here: numpy's sums over the neighbours (and einsum's) add
            # in an order that depends on it. The other layout sums several times faster, but
            # moves the results by round-off, and with them a few knife-edge capsules' flags.
            index = neighbours[rows].T
            u = inv._p_u[index] - s_rows[:, 0]
            v = inv._p_v[index] - s_rows[:, 1]
            distance = np.sqrt(u * u + v * v)
            # The largest distance row by row (numpy's max over the 14 of each capsule, which lie
            # together in memory, costs three times as much).
            farthest = reduce(np.maximum, distance)
            weight = (1 - (distance / (1.01 * farthest + 1e-300)) ** 2) ** 2
            values = [inv._q_z[index], inv._q_zp[index]]
            nearest = np.argmin(distance, axis=0)
            coefficients, x_here = _local_fit(u, v, values, weight, nearest,
                                              partial(_fit_coordinates, inv, index, nearest))
            x_new, norm, bad, _ = _damped_newton_step(coefficients, x_here, target[:, rows], 0.25)
            scaled[rows] = s_rows + (x_new - x_here).T
            failed[rows[bad]] = True
            stop = (norm < _REFINE_TOLERANCE) | bad
            active[rows[stop]] = False
            ending = np.ones_like(stop) if step == _REFINE_STEPS - 1 else stop
            value_at_end[:, rows[ending]] = _quadratic_value(coefficients[:, :, ending], x_new[:, ending])
    return _Refinement(scaled, value_at_end, active, slack, failed)


def _nearest(inv: TubeInverter, points: np.ndarray, table: NeighbourTable | None) -> tuple[np.ndarray, np.ndarray]:
    """The 14 database points nearest to each of ``points`` (m, 2) in scaled parameters,
    a row (m, 14) for each point, and the margin (m,) within which they stay the 14 nearest (half
    the gap between the 14th and 15th distances, less an allowance for their round-off): from
    ``table`` where it has them, else from the KD-tree."""
    k = inv.n_neighbours
    index = np.empty((len(points), k), dtype=np.intp)
    margin = np.empty(len(points))
    asked: np.ndarray = np.arange(len(points))
    if table is not None:
        found, index_found, margin_found = table.lookup(points)
        index[found], margin[found] = index_found.T, margin_found
        asked = np.flatnonzero(~found)
    if asked.size:
        distance, nearest = inv._p_tree.query(points[asked], k=k + 1)
        index[asked] = nearest[:, :k]
        margin[asked] = _half_gap(distance, k)
    return index, margin


def _half_gap(distance: np.ndarray, k: int) -> np.ndarray:
    """Half the gap between the k-th and (k+1)-th distances of each row of a KD-tree's answer
    (m, k + 1), less an allowance for the distances' own round-off; infinite where the database
    has only k points (the tree's (k+1)-th distance is then infinite: the k nearest never change)."""
    far = distance[:, k]
    gap = np.full(len(distance), np.inf)
    some = np.isfinite(far)
    gap[some] = 0.5 * (far[some] - distance[some, k - 1]) - 1e-12 * far[some]
    return gap


class NeighbourTable:
    """The 14 nearest database points (scaled parameters) to the centres of the cells of a fine
    regular grid over the database, for one inverter, and the half gap between the 14th and
    15th distances there: within that half gap of the centre the 14 nearest are the same points
    (triangle inequality). A point s of a cell closer to its centre than that, by a tenth of a
    cell at least, has them as its 14 nearest, with margin (half gap) - |s - centre|: a look-up
    replaces the KD-tree's query (the same points; a smaller margin, so sooner asked again)."""

    def __init__(self, inv: TubeInverter, cell: float) -> None:
        k = inv.n_neighbours
        self.cell = cell
        # The refinement's points stay near the database: a margin of one grid spacing or so.
        self.origin = inv._p_scaled.min(axis=0) - 0.5
        self.counts = np.ceil((inv._p_scaled.max(axis=0) + 0.5 - self.origin) / cell).astype(np.intp)
        axes = [self.origin[i] + cell * (np.arange(self.counts[i]) + 0.5) for i in range(2)]
        centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 2)
        distance, index = inv._p_tree.query(centres, k=k + 1)
        # A row of 14 for each cell, in the smallest integer type: the look-ups gather rows from
        # all over the table, and a smaller one stays in the cache.
        self.index = index[:, :k].astype(np.min_scalar_type(len(inv._p) - 1))
        self.half_gap = _half_gap(distance, k)
        self.centres = centres

    def lookup(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(whether the table has each point's neighbours (m,); their indices, neighbour-major
        (14, found), and margins (found,) for those points)."""
        with np.errstate(invalid="ignore"):
            ij = np.floor((points - self.origin) / self.cell)
            inside = np.all((ij >= 0) & (ij < self.counts), axis=1)
        cells = np.where(inside, ij[:, 0] * self.counts[1] + ij[:, 1], 0).astype(np.intp)
        offset = points - self.centres[cells]
        margin = self.half_gap[cells] - np.sqrt(offset[:, 0] * offset[:, 0] + offset[:, 1] * offset[:, 1])
        # A margin of a tenth of a cell at least: a point asked again at once gains nothing.
        found = inside & (margin > 0.1 * self.cell)
        return found, self.index[cells[found]].T, margin[found]


_NEIGHBOUR_TABLES: weakref.WeakKeyDictionary[TubeInverter, NeighbourTable] = weakref.WeakKeyDictionary()
_NEIGHBOUR_TABLES_LOCK = threading.Lock()


def neighbour_table(inv: TubeInverter) -> NeighbourTable:
    """The inverter's ``NeighbourTable`` at ``NEIGHBOUR_CELL``, built on first use and kept."""
    with _NEIGHBOUR_TABLES_LOCK:
        table = _NEIGHBOUR_TABLES.get(inv)
        if table is None or table.cell != NEIGHBOUR_CELL:
            table = _NEIGHBOUR_TABLES[inv] = NeighbourTable(inv, NEIGHBOUR_CELL)
        return table


def _fit_coordinates(inv: TubeInverter, index: np.ndarray, nearest: np.ndarray, columns: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """fit's coordinates (to round-off) of the neighbours ``index`` (n, m) at ``columns``,
    about the nearest (row ``nearest`` (m,)): differences of the scaled parameters, so that the
    points on one grid line share a coordinate exactly, as in fit."""
    around, centre = index[:, columns], index[nearest[columns], columns]
    return inv._p_u[around] - inv._p_u[centre], inv._p_v[around] - inv._p_v[centre]


def _local_fit(u: np.ndarray, v: np.ndarray, value_columns: list[np.ndarray], w: np.ndarray, nearest: np.ndarray,
               fit_coordinates: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
               ) -> tuple[np.ndarray, np.ndarray]:
    """``fit``'s weighted quadratic fit (``np.linalg.lstsq`` on ``sqrt_w * _quadratic_basis``,
    centred on the nearest neighbour) of the values over neighbourhoods given about a point
    s: neighbour-major coordinates u, v relative to s, value columns and weights (n, m); the
    row of fit's centre among the neighbours, ``nearest`` (m,); and ``fit_coordinates``,
    which gives fit's own coordinates of the neighbours for some columns.

    -> (coefficients (6, len(value_columns), m), x (2, m): where s lies in the coefficients'
    basis). Where the basis has full rank the fitted quadratic does not depend on where the
    basis is centred: the fit about s is fit's, and x = 0. Where the neighbours lie on two grid
    lines of one coordinate (u in {alpha, beta}: u^2 = (alpha + beta) u - alpha beta, the
    common deficiency near the edge of a database's region), lstsq's answer is the
    minimum-norm one in fit's basis: the fit without the u^2 column (``_normal_equations_fit``
    drops it), carried to fit's centre and made orthogonal to the null vector
    (0, -b, 0, 1, 0, 0) there (b: the second line's u); likewise for v. Any other deficiency
    gets ``inverters._weighted_lstsq_neighbour_major``'s SVD (lstsq's cutoff) in fit's
    coordinates."""
    coefficients, dropped, deficient = _normal_equations_fit(u, v, value_columns, w)
    m = u.shape[1]
    x = np.zeros((2, m))
    columns = np.flatnonzero(dropped >= 0)
    if columns.size:
        a = coefficients[:, :, columns]
        # fit's centre in the coordinates about s, and s in fit's coordinates (x).
        centre_u, centre_v = u[nearest[columns], columns], v[nearest[columns], columns]
        du, dv = -centre_u, -centre_v
        x[:, columns] = du, dv
        carried = a.copy()
        carried[0] = (a[0] - du * a[1] - dv * a[2] + (du * du) * a[3] + (du * dv) * a[4]
                      + (dv * dv) * a[5])
        carried[1] = a[1] - (2 * du) * a[3] - dv * a[4]
        carried[2] = a[2] - du * a[4] - (2 * dv) * a[5]
        on_u_lines = dropped[columns] == 3
        # The second line's coordinate in fit's basis: the other value of u (or v).
        along = np.where(on_u_lines, 1, 2)
        coordinate = np.where(on_u_lines, u[:, columns] - centre_u, v[:, columns] - centre_v)
        b = coordinate[np.argmax(np.abs(coordinate), axis=0), np.arange(columns.size)]
        null = np.zeros((6, columns.size))
        null[along, np.arange(columns.size)] = -b
        null[np.where(on_u_lines, 3, 5), np.arange(columns.size)] = 1.0
        share = np.einsum("km,kqm->qm", null, carried) / np.einsum("km,km->m", null, null)
        coefficients[:, :, columns] = carried - null[:, None, :] * share[None, :, :]
    if deficient.any():
        columns = np.flatnonzero(deficient)
        u_fit, v_fit = fit_coordinates(columns)
        x[0, columns], x[1, columns] = -u[nearest[columns], columns], -v[nearest[columns], columns]
        coefficients[:, :, columns] = inverters._weighted_lstsq_neighbour_major(
            u_fit, v_fit, [c[:, columns] for c in value_columns], w[:, columns]).transpose(1, 2, 0)
    return coefficients, x


def _normal_equations_fit(u: np.ndarray, v: np.ndarray, value_columns: list[np.ndarray], w: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The weighted least-squares quadratic fit (basis 1, u, v, u^2, u v, v^2) of the values
    on neighbour-major arrays (u, v, value columns, weights (n, m)) by the normal equations,
    the Cholesky factorisation written out over the stack
    (``inverters._weighted_lstsq_neighbour_major``'s test of the pivots, without its SVD branch).

    -> (coefficients (6, len(value_columns), m); the column dropped (m,): 3 (u^2) where the
    points lie on two lines of u (its pivot vanishes, and the fit is the one without it:
    that column's coefficient 0), 5 (v^2) likewise, -1 elsewhere; rows whose basis is
    otherwise rank-deficient (a Cholesky pivot below ``_MIN_CHOLESKY_PIVOT``: their
    coefficients are not meaningful))."""
    m = u.shape[1]
    u2, v2 = u * u, v * v
    # Powers 1 to 4 (the zeroth is never formed: a sum of the weights needs no ones).
    u_powers = {1: u, 2: u2, 3: u2 * u, 4: u2 * u2}
    v_powers = {1: v, 2: v2, 3: v2 * v, 4: v2 * v2}
    # Each sum over the neighbours of a product in one pass (einsum): no temporary array.
    moment = {}
    for i in range(5):
        wu = w if i == 0 else w * u_powers[i]
        moment[i, 0] = wu.sum(axis=0)
        for j in range(1, 5 - i):
            moment[i, j] = np.einsum("nm,nm->m", wu, v_powers[j])
    exponents = inverters._EXPONENTS
    k = len(exponents)
    gram = [[moment[i1 + i2, j1 + j2] for (i2, j2) in exponents] for (i1, j1) in exponents]
    monomials = {(i, j): u_powers[i] if j == 0 else (v_powers[j] if i == 0 else u * v) for i, j in exponents[1:]}
    weighted_values = [w * column for column in value_columns]
    rhs = [[wq.sum(axis=0) if (i, j) == (0, 0) else np.einsum("nm,nm->m", wq, monomials[i, j])
            for wq in weighted_values] for i, j in exponents]
    deficient = np.zeros(m, dtype=bool)
    dropped = np.full(m, -1)
    for r in range(k):
        deficient |= ~(gram[r][r] > 0)
    # Cholesky of the Gram matrix itself: its pivots are those of the matrix scaled to a unit
    # diagonal times the diagonal (the factor's rows scale with it), so the test on the
    # scaled pivot reads pivot > _MIN_CHOLESKY_PIVOT * gram[j][j].
    lower: list[list[np.ndarray]] = [[np.zeros(m)] * k for _ in range(k)]
    inverse_diagonal: list[np.ndarray] = []
    for j in range(k):
        pivot = gram[j][j]
        for t in range(j):
            pivot = pivot - lower[j][t] * lower[j][t]
        small = ~(pivot > inverters._MIN_CHOLESKY_PIVOT * gram[j][j]) & ~deficient
        skip = np.zeros(m, dtype=bool)
        if j in (3, 5) and small.any():
            # A square's column in the span of the others: the points on two lines?
            candidates = np.flatnonzero(small & (dropped < 0))
            coordinate = (u if j == 3 else v)[:, candidates]
            first = coordinate[0]
            other = coordinate[np.argmax(np.abs(coordinate - first), axis=0), np.arange(candidates.size)]
            two_lines = np.all((coordinate == first) | (coordinate == other), axis=0) & (other != first)
            skip[candidates[two_lines]] = True
            dropped[skip] = j
            small &= ~skip
        deficient |= small
        # A dropped column: its coefficient 0, the other columns' fit without it.
        inverse_diagonal.append(np.where(skip, 0.0, 1 / np.sqrt(np.where(deficient | skip, 1.0, pivot))))
        for i in range(j + 1, k):
            entry = gram[i][j]
            for t in range(j):
                entry = entry - lower[i][t] * lower[j][t]
            lower[i][j] = entry * inverse_diagonal[j]
    coefficients = np.array(inverters._cholesky_substitutions(lower, rhs, lambda entry, i: entry * inverse_diagonal[i]))
    dropped[deficient] = -1
    return coefficients, dropped, deficient


def _quadratic_value(c: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The fitted map's value (2, m) at x (2, m), coefficients c (6, 2, m)."""
    u, v = x
    return c[0] + c[1] * u + c[2] * v + c[3] * u**2 + c[4] * (u * v) + c[5] * v**2


def _quadratic_value_and_jacobian(c: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fitted map's value (2, m) and its derivatives along the coordinates u and v (2, m
    each; rows: the lengths) at x (2, m), coefficients c (6, 2, m)."""
    u, v = x
    return _quadratic_value(c, x), c[1] + c[3] * (2 * u) + c[4] * v, c[2] + c[4] * u + c[5] * (2 * v)


def _damped_newton_step(c: np.ndarray, x: np.ndarray, target: np.ndarray, max_step: float
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``inverters._damped_newton_step_many``'s step, component-major (c (6, 2, m), x and
    target (2, m)): (new x (2, m), undamped step length (m,), rows whose step is not finite,
    the residual target - q at x (2, m))."""
    q, d_du, d_dv = _quadratic_value_and_jacobian(c, x)
    r = target - q
    a, b, cc, d = d_du[0], d_dv[0], d_du[1], d_dv[1]
    det = a * d - b * cc
    scale = np.maximum(np.maximum(np.abs(a), np.abs(b)), np.maximum(np.abs(cc), np.abs(d)))
    singular = ~(np.abs(det) > 1e-6 * scale**2)
    det = np.where(singular, 1.0, det)
    step = np.stack([(d * r[0] - b * r[1]) / det, (a * r[1] - cc * r[0]) / det])
    if singular.any():
        # The Jacobians (rows: the lengths, columns: the coordinates), one for each singular row.
        jacobian = np.stack([d_du[:, singular], d_dv[:, singular]], axis=-1).transpose(1, 0, 2)
        u_svd, s, vt = np.linalg.svd(jacobian)
        cutoff = np.finfo(float).eps * 2 * s[:, :1]
        s_inverse = np.where(s > cutoff, 1 / np.where(s > cutoff, s, 1.0), 0.0)
        step[:, singular] = np.einsum("mji,mj,mkj,mk->im", vt, s_inverse, u_svd, r[:, singular].T)
    norm = np.sqrt(step[0] * step[0] + step[1] * step[1])
    bad = ~np.isfinite(norm)
    if bad.any():
        step[:, bad] = 0.0
    damp = norm > max_step
    if damp.any():
        step[:, damp] *= max_step / norm[damp]
    return x + step, norm, bad, r
