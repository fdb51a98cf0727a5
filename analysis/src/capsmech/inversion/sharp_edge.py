"""The sharp parachute edge of a steady tube profile, and what it does to the databases'
accuracy.

At large Ca_s the rear rim of a capsule whose membrane has no bending stiffness becomes a
corner (the paper's figure 2c: "a sharp parachute edge at high flow strength"). In the kernel's
meridian (64 P1 elements) the corner is one node at which the meridian turns by 100-155 degrees
and the meridional tension is about zero; the corner stays at a material node and, as Ca_s
grows, moves to the next one in a jump. Two consequences, measured (docs/validation/databases.md):
L_p there is less accurate than on smooth shapes, and the discrete problem can have two stable
shapes whose corners sit at neighbouring nodes.

Measured against 128 elements and against a second filling by other time steps
(``ACCURACY_BY_TURN``), the databases hold their stated accuracy (0.1 %) on smooth profiles
only: at a corner L_z is good to 1.6 %, L_p to 6.5 % (0.1 l on a deep parachute) and v_c/V to
0.6 %; near the rear's buckling at Ca_s 0.01-0.03, see ``BUCKLING_ROW`` and ``NEAR_FOLD_ROW``;
a row that is not a root of the steady equations, ``NOT_A_ROOT_ROW``.
``interpolated_accuracy`` gives the accuracy of a fit among rows of these classes, for the
fits' database error
(``capsmech.inversion.fitting.database_g_s_shifts``); ``profile_floor`` the accuracy point by
point along a profile, for the contour's chi2 (``capsmech.inversion.noise.contour_chi2``, the
diagnosis's goodness of fit).

The database keeps no meridian nodes, only the profile resampled to 128 points, so the corner
is measured on that: the largest change of direction across two resampled segments (a corner
falls between resampled points, and its turn is split over two of them).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from capsmech.io.case import polish_discarded


def sharpest_turn(r: np.ndarray, z: np.ndarray) -> tuple[float, float]:
    """The largest change of direction [degrees] of the polyline (r, z) across two of its
    segments, and where it is: the arclength of the point between them, as a fraction of
    the polyline's length ((NaN, NaN) for fewer than three segments or non-finite points)."""
    r, z = np.asarray(r, dtype=float), np.asarray(z, dtype=float)
    if r.size < 4 or not (np.all(np.isfinite(r)) and np.all(np.isfinite(z))):
        return float("nan"), float("nan")
    dr, dz = np.diff(r), np.diff(z)
    step = np.hypot(dr, dz)
    keep = step > 0
    dr, dz, step = dr[keep], dz[keep], step[keep]
    if dr.size < 3:
        return float("nan"), float("nan")
    # The angle between segment i and segment i + 2, through atan2 of cross and dot products
    # (exact at any angle, unlike an arccos of the dot product).
    cross = dr[:-2] * dz[2:] - dz[:-2] * dr[2:]
    dot = dr[:-2] * dr[2:] + dz[:-2] * dz[2:]
    turns = np.abs(np.arctan2(cross, dot))
    i = int(np.argmax(turns))
    s = np.concatenate([[0.0], np.cumsum(step)])
    # Segments i and i + 2 enclose segment i + 1: the corner is about its middle.
    return float(np.degrees(turns[i])), float(0.5 * (s[i + 1] + s[i + 2]) / s[-1])


def largest_turn(r: np.ndarray, z: np.ndarray) -> float:
    """The largest change of direction [degrees] of the polyline (r, z) across two of its
    segments (``sharpest_turn``). On the databases' profiles (128 points) smooth shapes turn
    by less than 30 degrees (two segments of ~0.04 l at curvatures up to ~3/l) and corners by
    90-155."""
    return sharpest_turn(r, z)[0]


@dataclass(frozen=True)
class LengthAccuracy:
    """How far a database row (64 meridian elements) can be from the same case on 128: L_z
    relative, L_p in tube radii l (the larger of an absolute part and a part relative to L_p),
    v_c/V relative: the largest differences measured (``ACCURACY_BY_TURN``)."""

    L_z_rel: float
    L_p_abs: float
    L_p_rel: float
    v_c_rel: float

    def L_p(self, L_p: float) -> float:
        """The accuracy [l] of a parachute depth L_p [l]."""
        return max(self.L_p_abs, self.L_p_rel * abs(L_p))


#: The databases' accuracy on smooth profiles, relative to the capsule's length L_z (64 against
#: 128 meridian elements): ``capsmech.inversion.noise.MODEL_FLOOR_REL``.
SMOOTH_FLOOR_REL = 1e-3

#: The databases' accuracy by the largest turn of a row's profile [degrees]: (upper bound of
#: the class, accuracy). Each is the larger of two measured spreads, rounded up:
#: - the mesh: scripts/tube_mesh_accuracy.py (2026-11-27, kernel 0.3.5), the shipped tube-paper
#:   database against the same cases on 128 elements from the sphere, 3 rows per law and turn
#:   class (< 30, 30-60, 60-90, >= 90), 60 rows, the rows at Ca_s <= 0.03 apart (below);
#: - the path: the same grid filled twice case by case from the sphere, by kernels 0.3.2 and
#:   0.3.5, whose implicit steps differ (scripts/tube_database_diff.py), over the rows that are
#:   roots of the steady equations in both fillings (for the others, ``NOT_A_ROOT_ROW``).
#: Below 30 degrees: the databases' stated 0.1 % (mesh L_z 0.04 %, L_p 0.0012 l, v_c 0.02 %;
#: path 0, 151 rows). 30-90 degrees: mesh L_z 0.34 %, L_p 0.0065 l, v_c 0.09 %; path 0 (221
#: rows). From 90 degrees (a corner): mesh L_z 1.1 %, v_c 0.51 %, and L_p up to 0.0078 l where
#: L_p < 0.5 l, up to 6.5 % of L_p on deeper parachutes (Ca_s 0.3-1.5, a/l 0.9-1.1: up to
#: 0.10 l); path (221 rows) L_z 1.53 %, v_c 0.59 %, L_p 0.0035 l / 3.2 %: two stable corner shapes.
#: The turn [degrees] from which a profile's rim is a corner (the last class of ``ACCURACY_BY_TURN``).
CORNER_TURN = 90.0
ACCURACY_BY_TURN: tuple[tuple[float, LengthAccuracy], ...] = (
    (30.0, LengthAccuracy(L_z_rel=SMOOTH_FLOOR_REL, L_p_abs=2e-3, L_p_rel=0.0, v_c_rel=2e-4)),
    (CORNER_TURN, LengthAccuracy(L_z_rel=3.5e-3, L_p_abs=7e-3, L_p_rel=0.0, v_c_rel=1e-3)),
    (math.inf, LengthAccuracy(L_z_rel=0.016, L_p_abs=0.008, L_p_rel=0.065, v_c_rel=6e-3)),
)
#: Rows at Ca_s up to ``BUCKLING_CA_S`` (the grids' Ca_s 0.01), whatever their turn: the rear of
#: a nearly rigid capsule buckles there (a fold of the steady branch at Ca_s 0.0114-0.0120,
#: docs/validation/performance.md), and the finer meridian moves it. Mesh, the 6 such rows
#: among the 60: L_z up to 1.19 %, L_p 0.026 l, v_c 0.016 %; path, 20 rows that are roots in
#: both fillings: 0.06 %, 0.0004 l, 0.012 %.
BUCKLING_CA_S = 0.011
BUCKLING_ROW = LengthAccuracy(L_z_rel=0.012, L_p_abs=0.027, L_p_rel=0.0, v_c_rel=2e-4)
#: Rows above ``BUCKLING_CA_S`` up to ``NEAR_FOLD_CA_S`` (the grids' Ca_s 0.02, 0.03) are at
#: least this far, whatever their turn: next to the fold the finer meridian moves the shape
#: more than on smooth rows elsewhere (mesh, 11 such rows: L_z 0.16 %, L_p 0.0030 l, v_c
#: 0.017 %, at SK C = 1 a/l 0.7, Ca_s 0.03; path: 0 over 81 rows that are roots in both).
NEAR_FOLD_CA_S = 0.035
NEAR_FOLD_ROW = LengthAccuracy(L_z_rel=2e-3, L_p_abs=3e-3, L_p_rel=0.0, v_c_rel=2e-4)
#: A steady row that is not a root of the steady equations: the kernel's Newton polish after
#: time stepping did not converge (or found an unstable shape) and was discarded, so the row is
#: wherever the slow drift passed the steady rule (``is_steady_root``). The path spread comes
#: from these rows: discarded in either filling, 41 rows moved by up to L_z 1.85 % (GH nu_s 0,
#: a/l 1, Ca_s 0.5), L_p 0.018 l (GH nu_s 0, a/l 0.8, Ca_s 0.01), v_c 0.10 %. The workflow now
#: reruns such a case with a steady rule 100, then 1000 times stricter (``workflow.runner``):
#: in tube-paper 20 of the 26 then reach a root, moving by up to L_z 1.81 % (GH nu_s 0, a/l 1,
#: Ca_s 0.5; 0.17 % at Ca_s 0.02-0.03), L_p 0.0154 l above Ca_s 0.011 (0.027 l at Ca_s 0.01,
#: the buckling class), v_c 0.56 % (a corner): within this and the other classes. 6 of the 744
#: steady rows stay no root, all at Ca_s 0.01.
NOT_A_ROOT_ROW = LengthAccuracy(L_z_rel=0.019, L_p_abs=0.018, L_p_rel=0.0, v_c_rel=1e-3)


def is_steady_root(message: str) -> bool:
    """Whether a steady database row is a converged root of the steady equations, from the
    kernel's message for the case: time stepping ends with a Newton polish, and a polish that
    stalls or finds an unstable shape is reported at the message's end as "... and was
    discarded". (A case the workflow reran with a stricter steady rule after that says so at
    its message's start, then gives the rerun's own outcome: ``workflow.runner``.)"""
    return not polish_discarded(message)


def _larger(a: LengthAccuracy, b: LengthAccuracy) -> LengthAccuracy:
    """The larger of two accuracies, component by component."""
    return LengthAccuracy(L_z_rel=max(a.L_z_rel, b.L_z_rel), L_p_abs=max(a.L_p_abs, b.L_p_abs),
                          L_p_rel=max(a.L_p_rel, b.L_p_rel), v_c_rel=max(a.v_c_rel, b.v_c_rel))


def row_accuracy(turn: float, Ca_s: float = math.inf, root: bool = True) -> LengthAccuracy:
    """The accuracy of a database row at ``Ca_s`` whose profile's largest turn is ``turn``
    degrees (``largest_turn``); a profile that cannot be measured (NaN) gets the smooth class,
    the databases' own statement. A row that is not a root (``is_steady_root``) is at least
    ``NOT_A_ROOT_ROW`` off."""
    if Ca_s <= BUCKLING_CA_S:
        accuracy = BUCKLING_ROW
    else:
        accuracy = ACCURACY_BY_TURN[0][1] if not math.isfinite(turn) else next(
            accuracy for bound, accuracy in ACCURACY_BY_TURN if turn < bound)
        if Ca_s <= NEAR_FOLD_CA_S:
            accuracy = _larger(accuracy, NEAR_FOLD_ROW)
    return accuracy if root else _larger(accuracy, NOT_A_ROOT_ROW)


def smooth_accuracy(L_p: float) -> tuple[float, float, float]:
    """(L_z relative, L_p [l], v_c/V relative): the smooth profiles' accuracy, the databases'
    own statement, where the rows behind a value are not known."""
    smooth = ACCURACY_BY_TURN[0][1]
    return smooth.L_z_rel, smooth.L_p(L_p), smooth.v_c_rel


def interpolated_accuracy(turns: np.ndarray, Ca_s: np.ndarray, weights: np.ndarray, L_p: float,
                          roots: np.ndarray | None = None) -> tuple[float, float, float]:
    """(L_z relative, L_p [l], v_c/V relative) accuracy of a value interpolated between
    database rows with the given largest turns, Ca_s, interpolation weights and whether each is
    a root (``is_steady_root``; all, when not given): each row's accuracy weighted as its value
    is (the worst case, every row off the same way)."""
    roots = np.ones(len(turns), dtype=bool) if roots is None else np.asarray(roots, dtype=bool)
    rows = [row_accuracy(float(t), float(c), bool(r)) for t, c, r in zip(turns, Ca_s, roots)]
    w = np.abs(np.asarray(weights, dtype=float))
    return (float(w @ [r.L_z_rel for r in rows]), float(w @ [r.L_p(L_p) for r in rows]),
            float(w @ [r.v_c_rel for r in rows]))


def parachute_depth(meridian: np.ndarray) -> float:
    """L_p of a meridian (r, z) from the front pole to the rear pole, in its units: from the rear
    pole to the rear-most point along the axis (0 for a convex rear)."""
    z = np.asarray(meridian, dtype=float)[:, 1]
    rearward = -1.0 if z[0] > z[-1] else 1.0     # the direction from the front pole to the rear
    return float(np.max(rearward * z) - rearward * z[-1])


def profile_floor(meridian: np.ndarray, length: float, points: int, tube_radius: float = math.nan,
                  stated_error_rel: tuple[float, float] = (math.nan, math.nan),
                  interpolation_error: np.ndarray | None = None) -> np.ndarray:
    """The databases' accuracy [the meridian's units] at each of ``points`` points placed at
    equal arclength along a database profile (r, z) from the front pole to the rear pole, as a
    residual profile places them: ``SMOOTH_FLOOR_REL`` of the capsule's ``length`` everywhere
    (the smooth shapes' accuracy), and from the profile's sharpest turn (the parachute's rim) to
    the rear pole the L_p accuracy of the turn's class (``row_accuracy``; its absolute part
    needs ``tube_radius``): the rim's position along the meridian is what the databases hold
    least well, and the parachute's cavity behind it moves with it. ``stated_error_rel``, the
    relative errors of (L_z, L_p) that the database's own rows state around the fitted point
    (``TubeInverter.stated_error``; NaN: not stated), raises the floor to that L_z share of
    ``length`` everywhere and to that L_p share of the parachute's depth behind the rim (behind
    the profile's middle where it has no turn): a database is no more accurate than it says.
    ``interpolation_error``, the error of the profile's interpolation between the database's
    rows at the ``points`` points [the meridian's units] (``TubeInverter.interpolation_error``;
    None, or NaN at a point: not known), is added in quadrature: the rows' own accuracy and the
    grid's spacing are independent errors.

    Measured (2026-11-26): capsules of the right law whose shape is the 128-element kernel's,
    traced with 0.45 px noise at a 100 px tube radius and fitted on the 64-element database,
    leave -3 px at the first two points behind the rim of a deep parachute with a corner (GH
    nu_s 0.5 and 0.2, a/l 0.9, Ca_s 1.5 and 0.8; up to 1.1 px further back) and stay within
    the tracing noise in front of it: chi2/DOF 10-15 with the smooth floor alone, 0.7-3.0 with
    this one (docs/validation/databases.md)."""
    L_z_rel, L_p_rel = (v if math.isfinite(v) else 0.0 for v in stated_error_rel)
    floor = np.full(points, max(SMOOTH_FLOOR_REL, L_z_rel) * length)
    meridian = np.asarray(meridian, dtype=float)
    # A database that states each row's own error (a mesh check): the parachute's rear holds
    # no better than its L_p, whatever the turn's class says.
    depth = parachute_depth(meridian)
    stated_rim = L_p_rel * depth
    turn, where = sharpest_turn(meridian[:, 0], meridian[:, 1])
    if not math.isfinite(turn):
        rear = np.arange(points) >= points // 2
        floor[rear] = np.maximum(floor[rear], stated_rim)
    else:
        accuracy = row_accuracy(turn)
        rim = max(accuracy.L_p_rel * depth, stated_rim)
        if math.isfinite(tube_radius):
            rim = max(rim, accuracy.L_p_abs * tube_radius)
        behind = np.arange(points) >= math.floor(where * (points - 1))
        floor[behind] = np.maximum(floor[behind], rim)
    if interpolation_error is None:
        return floor
    known = np.nan_to_num(np.asarray(interpolation_error, dtype=float), nan=0.0)
    return np.hypot(floor, known)
