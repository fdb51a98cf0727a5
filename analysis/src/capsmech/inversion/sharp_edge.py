"""The sharp parachute edge of a steady tube profile, and what it does to the databases'
accuracy.

At large Ca_s the rear rim of a capsule whose membrane has no bending stiffness becomes a
corner (the paper's figure 2c: "a sharp parachute edge at high flow strength"). In the kernel's
meridian (64 P1 elements) the corner is one node at which the meridian turns by 90-135 degrees
and the meridional tension is about zero; the corner stays at a material node and, as Ca_s
grows, moves to the next one in a jump. Two consequences, measured (docs/validation/databases.md):
L_p there is less accurate than on smooth shapes, and the discrete problem can have two stable
shapes whose corners sit at neighbouring nodes.

Measured against 128 elements (``ACCURACY_BY_TURN``), the databases hold their stated accuracy
(0.1 %) on smooth profiles only: at a corner L_z is good to 1.1 %, L_p to 6.5 % (0.1 l on a
deep parachute) and v_c/V to 0.5 %. ``interpolated_accuracy`` gives the
accuracy of a fit among rows of these classes; the fits' database error
(``capsmech.inversion.fitting.database_g_s_shifts``) uses it.

The database keeps no meridian nodes, only the profile resampled to 128 points, so the corner
is measured on that: the largest change of direction across two resampled segments (a corner
falls between resampled points, and its turn is split over two of them).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def largest_turn(r: np.ndarray, z: np.ndarray) -> float:
    """The largest change of direction [degrees] of the polyline (r, z) across two of its
    segments (NaN for fewer than three segments or non-finite points). On the databases'
    profiles (128 points) smooth shapes turn by less than 30 degrees (two segments of ~0.04 l
    at curvatures up to ~3/l) and corners by 90-155."""
    r, z = np.asarray(r, dtype=float), np.asarray(z, dtype=float)
    if r.size < 4 or not (np.all(np.isfinite(r)) and np.all(np.isfinite(z))):
        return float("nan")
    dr, dz = np.diff(r), np.diff(z)
    keep = np.hypot(dr, dz) > 0
    dr, dz = dr[keep], dz[keep]
    if dr.size < 3:
        return float("nan")
    # The angle between segment i and segment i + 2, through atan2 of cross and dot products
    # (exact at any angle, unlike an arccos of the dot product).
    cross = dr[:-2] * dz[2:] - dz[:-2] * dr[2:]
    dot = dr[:-2] * dr[2:] + dz[:-2] * dz[2:]
    return float(np.degrees(np.max(np.abs(np.arctan2(cross, dot)))))


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


#: The databases' accuracy by the largest turn of a row's profile [degrees]: (upper bound of
#: the class, accuracy). Measured with scripts/tube_mesh_accuracy.py (2026-11-26, kernel
#: 0.3.3): the shipped tube-paper database against the same cases on 128 elements from the
#: sphere, 3 rows per law and turn class (< 30, 30-60, 60-90, >= 90), 60 rows; the largest
#: differences of each class, rounded up, the rows at Ca_s 0.01 apart (``BUCKLING_ROW``).
#: Below 30 degrees they are the databases' stated 0.1 % (L_z 0.10 %, L_p 0.0019 l, v_c
#: 0.02 %). From 30 to 90 degrees L_z 0.34 %, L_p 0.0065 l, v_c 0.09 %. From 90 degrees (a
#: corner) L_z 1.1 %, v_c 0.51 %, and L_p up to 0.0078 l where L_p < 0.5 l, 3.3-6.5 % of L_p
#: on deeper parachutes (Ca_s 0.3-1.5, a/l 0.9-1.1: up to 0.10 l).
ACCURACY_BY_TURN: tuple[tuple[float, LengthAccuracy], ...] = (
    (30.0, LengthAccuracy(L_z_rel=1e-3, L_p_abs=2e-3, L_p_rel=0.0, v_c_rel=2e-4)),
    (90.0, LengthAccuracy(L_z_rel=3.5e-3, L_p_abs=6.5e-3, L_p_rel=0.0, v_c_rel=1e-3)),
    (math.inf, LengthAccuracy(L_z_rel=0.011, L_p_abs=0.008, L_p_rel=0.065, v_c_rel=5e-3)),
)
#: Rows at Ca_s up to ``BUCKLING_CA_S`` (the grids' Ca_s 0.01), whatever their turn: the rear of
#: a nearly rigid capsule buckles there (a fold of the steady branch at Ca_s 0.0114-0.0120,
#: docs/validation/performance.md), and the finer meridian moves it. Measured on the 6 such rows
#: among the 60: L_z up to 0.56 %, L_p 0.0128 l, v_c 0.03 %.
BUCKLING_CA_S = 0.011
BUCKLING_ROW = LengthAccuracy(L_z_rel=6e-3, L_p_abs=0.013, L_p_rel=0.0, v_c_rel=5e-4)


def row_accuracy(turn: float, Ca_s: float = math.inf) -> LengthAccuracy:
    """The accuracy of a database row at ``Ca_s`` whose profile's largest turn is ``turn``
    degrees (``largest_turn``); a profile that cannot be measured (NaN) gets the smooth class,
    the databases' own statement."""
    if Ca_s <= BUCKLING_CA_S:
        return BUCKLING_ROW
    if not math.isfinite(turn):
        return ACCURACY_BY_TURN[0][1]
    return next(accuracy for bound, accuracy in ACCURACY_BY_TURN if turn < bound)


def interpolated_accuracy(turns: np.ndarray, Ca_s: np.ndarray, weights: np.ndarray, L_p: float
                          ) -> tuple[float, float, float]:
    """(L_z relative, L_p [l], v_c/V relative) accuracy of a value interpolated between
    database rows with the given largest turns, Ca_s and interpolation weights: each row's
    accuracy weighted as its value is (the worst case, every row off the same way)."""
    rows = [row_accuracy(float(t), float(c)) for t, c in zip(turns, Ca_s)]
    w = np.abs(np.asarray(weights, dtype=float))
    return (float(w @ [r.L_z_rel for r in rows]), float(w @ [r.L_p(L_p) for r in rows]),
            float(w @ [r.v_c_rel for r in rows]))
