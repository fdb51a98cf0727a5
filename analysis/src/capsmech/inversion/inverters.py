"""Inverse analysis: from measured capsule lengths to (a/l, Ca_s) and the shear modulus G_s.

The method is the paper's (section 4.2 for the tube, 4.3 for shear), on numpy arrays, so that
it does not depend on how a database is stored (``capsmech.io.database`` loads the files).

Tube
----
For one membrane law the database maps the parameters p = (a/l, Ca_s) to the steady lengths
q = (L_z, L_z - L_p) (in tube radii l) and to v_c/V. Given measured q*, the 14 database
points nearest to q* (in q scaled by the database's spread) carry a local weighted
least-squares fit of the forward map, q(p) ~ quadratic in (a/l, ln Ca_s) (diffuse
approximation); the fitted p is the root of q(p) = q* (Newton, from the nearest point).
The velocity ratio comes from the Delaunay triangulation of the database's (a/l, ln Ca_s)
(linear, barycentric), and with the measured capsule velocity v_c and viscosity mu

    G_s = mu V / Ca_s = mu v_c / (Ca_s (v_c/V)).

A fitted point outside the database's convex hull is a flag with a reason, never a number.

Shear
-----
D12 increases with Ca_s along the steady branch: Ca_s and L3/a follow from monotone
(PCHIP) interpolation of the database in D12; volume conservation L1 L2 L3 = a**3 gives
a = (L1 L2 (L3/a))**(1/2) from the measured semi-axes, and G_s = mu gamma_dot a / Ca_s.
D12 below 0.35 is flagged as too imprecise (paper: +-20 % on D12 from blurred contours).
"""
from __future__ import annotations

import hashlib
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import LinearNDInterpolator, PchipInterpolator
from scipy.spatial import Delaunay, cKDTree

from capsmech.errors import DatabaseError
from capsmech.inversion.residuals import PreparedContour
from capsmech.inversion.sharp_edge import BUCKLING_CA_S, CORNER_TURN, largest_turn

#: Neighbours of the diffuse approximation (paper section 4.2).
N_NEIGHBOURS = 14
#: Grid rows around a point whose stated errors bound the database's accuracy there (the
#: corners of the grid cell that holds it).
STATED_ERROR_ROWS = 4
#: Points along a profile's normalised arclength at which each row's interpolation error is kept
#: (``row_interpolation_errors``).
INTERPOLATION_ERROR_POINTS = 64
#: Rows nearest a row (in the scaled parameters) among which the pairs on either side of it
#: are sought, and how far off the line between them it may lie (a fraction of their distance):
#: on it but for rounding, since a row off the line differs from the pair's interpolation by the
#: profile's gradient times the offset too (on tube-paper, 5 % off the line tripled the
#: estimates at the front pole). A grid's axes, and its diagonals where they are straight.
INTERPOLATION_PAIR_ROWS = 8
INTERPOLATION_PAIR_STRAIGHTNESS = 1e-6
#: Shear: D12 below this is too imprecise to fit (paper section 4.3).
MIN_SHEAR_D12 = 0.35
#: The five fits of paper section 4.2: factors on (L_z, L_p).
FIVE_FITS: tuple[tuple[str, float, float], ...] = (
    ("fit1", 1.00, 1.00),
    ("fit2", 0.98, 0.98),
    ("fit3", 1.02, 1.02),
    ("fit4", 1.00, 0.98),
    ("fit5", 1.00, 1.02),
)



#: The flags of a tube fit without a value (``fit`` and ``fit_many`` alike).
NO_ROOT_FLAG = "no parameters of the database reproduce these lengths (local fit has no root)"
INCONSISTENT_FLAG = ("no consistent parameters: the lengths' nearest database points lie on different branches and "
                     "the local forward map around the first root does not reproduce them")


def outside_flag(p: np.ndarray) -> str:
    """The flag of a fit whose parameters (a/l, ln Ca_s) lie outside the database's grid."""
    return f"outside the database: fitted a/l = {p[0]:.3f}, Ca_s = {np.exp(p[1]):.3g} lie outside its grid"

@dataclass(frozen=True)
class TubeTable:
    """Steady rows of a tube database for one law (lengths in l, velocity in V).

    Parameters
    ----------
    a_over_l, Ca_s : np.ndarray
        Parameters of the rows [1].
    L_z, L_p : np.ndarray
        Total length and parachute depth [l].
    vc_over_V : np.ndarray
        Capsule velocity over mean flow velocity [1].
    """

    a_over_l: np.ndarray
    Ca_s: np.ndarray
    L_z: np.ndarray
    L_p: np.ndarray
    vc_over_V: np.ndarray
    profile_r: np.ndarray | None = None
    profile_z: np.ndarray | None = None
    #: Whether each row is a root of the steady equations (``sharp_edge.is_steady_root``);
    #: None: all are.
    root: np.ndarray | None = None
    #: Each row's own stated relative error of L_z and L_p (a database with a mesh check:
    #: ``<column>_mesh_error_rel``); None, or NaN in a row: not stated.
    L_z_error_rel: np.ndarray | None = None
    L_p_error_rel: np.ndarray | None = None

    def __post_init__(self) -> None:
        arrays = [np.asarray(getattr(self, k), dtype=float) for k in ("a_over_l", "Ca_s", "L_z", "L_p", "vc_over_V")]
        n = len(arrays[0])
        if any(a.shape != (n,) for a in arrays):
            raise ValueError("tube table: every column must be 1-D with the same length")
        keep = np.all([np.isfinite(a) for a in arrays], axis=0)
        for name in ("profile_r", "profile_z"):
            profile = getattr(self, name)
            if profile is not None:
                profile = np.asarray(profile, dtype=float)
                if profile.ndim != 2 or profile.shape[0] != n:
                    raise ValueError(f"tube table: {name} must be (rows, points)")
                object.__setattr__(self, name, profile[keep])
        root = np.ones(n, dtype=bool) if self.root is None else np.asarray(self.root, dtype=bool)
        if root.shape != (n,):
            raise ValueError("tube table: root must be 1-D with one entry per row")
        object.__setattr__(self, "root", root[keep])
        for name in ("L_z_error_rel", "L_p_error_rel"):
            stated = np.full(n, np.nan) if getattr(self, name) is None else np.asarray(getattr(self, name), dtype=float)
            if stated.shape != (n,):
                raise ValueError(f"tube table: {name} must be 1-D with one entry per row")
            object.__setattr__(self, name, stated[keep])
        if np.any(arrays[1][keep] <= 0):
            raise ValueError("tube table: Ca_s must be > 0")
        if keep.sum() < N_NEIGHBOURS:
            # A database a user names (a smoke-test grid) can be this small: their error, not a bug.
            raise DatabaseError(f"the database has {keep.sum()} steady rows for this law, and a fit needs at least "
                                f"{N_NEIGHBOURS} (a grid made for smoke tests cannot be fitted against)")
        for name, a in zip(("a_over_l", "Ca_s", "L_z", "L_p", "vc_over_V"), arrays):
            object.__setattr__(self, name, a[keep])


@dataclass
class Fit:
    """What every fit carries: the modulus and, when the fit is not valid, the reason."""

    G_s: float = float("nan")
    flag: str = ""

    @property
    def ok(self) -> bool:
        return not self.flag


@dataclass
class TubeFit(Fit):
    """Result of one tube fit; ``flag`` is empty when the fit is valid.

    Attributes
    ----------
    a_over_l, Ca_s, vc_over_V : float
        Fitted parameters and velocity ratio [1] (NaN when flagged).
    G_s : float
        Surface shear modulus [units of mu * velocity] (NaN when flagged or without v_c, mu).
    flag : str
        Reason the fit is not valid ('' when valid).
    """

    a_over_l: float = float("nan")
    Ca_s: float = float("nan")
    vc_over_V: float = float("nan")


@dataclass
class TubeFits:
    """Results of ``TubeInverter.fit_many``: one entry per capsule, as arrays.

    Attributes
    ----------
    a_over_l, Ca_s, vc_over_V, G_s : np.ndarray
        As in ``TubeFit`` (NaN where flagged).
    flag : list of str
        Reason each fit is not valid ('' when valid).
    """

    a_over_l: np.ndarray
    Ca_s: np.ndarray
    vc_over_V: np.ndarray
    G_s: np.ndarray
    flag: list[str]

    def __len__(self) -> int:
        return len(self.flag)

    @property
    def ok(self) -> np.ndarray:
        return np.array([not f for f in self.flag], dtype=bool)

    def row(self, i: int) -> TubeFit:
        """Capsule i as the ``TubeFit`` that ``TubeInverter.fit`` returns."""
        return TubeFit(G_s=float(self.G_s[i]), flag=self.flag[i], a_over_l=float(self.a_over_l[i]),
                       Ca_s=float(self.Ca_s[i]), vc_over_V=float(self.vc_over_V[i]))

    @classmethod
    def concatenate(cls, parts: list[TubeFits]) -> TubeFits:
        """The results of consecutive groups of capsules as one."""
        a_over_l, Ca_s, vc_over_V, G_s = (np.concatenate([getattr(part, name) for part in parts])
                                          for name in ("a_over_l", "Ca_s", "vc_over_V", "G_s"))
        return cls(a_over_l, Ca_s, vc_over_V, G_s, flag=[f for part in parts for f in part.flag])


#: Each capsule's (v_c, mu), or None where G_s is not asked for.
Modulus = tuple[np.ndarray, np.ndarray] | None


def capsule_arrays(L_z: np.ndarray | float, L_p: np.ndarray | float, v_c: np.ndarray | float | None,
                   mu: np.ndarray | float | None) -> tuple[np.ndarray, np.ndarray, Modulus]:
    """``fit_many``'s arguments as arrays of one entry per capsule: (L_z, L_p, (v_c, mu) or
    None where either is not given)."""
    L_z, L_p = np.broadcast_arrays(np.atleast_1d(np.asarray(L_z, dtype=float)),
                                   np.atleast_1d(np.asarray(L_p, dtype=float)))
    if v_c is None or mu is None:
        return L_z, L_p, None
    n = len(L_z)
    return L_z, L_p, (np.broadcast_to(np.asarray(v_c, dtype=float), (n,)),
                      np.broadcast_to(np.asarray(mu, dtype=float), (n,)))


@dataclass
class FiveFits:
    """The five fits of paper section 4.2 and their statistics over the valid ones."""

    fits: dict[str, TubeFit] = field(default_factory=dict)

    def _values(self, name: str) -> np.ndarray:
        return np.array([getattr(f, name) for f in self.fits.values() if f.ok and np.isfinite(getattr(f, name))])

    def mean(self, name: str) -> float:
        values = self._values(name)
        return float(values.mean()) if values.size else float("nan")

    def spread(self, name: str) -> float:
        """Half the range of the valid fits (the paper's 'dispersion' is the full range)."""
        values = self._values(name)
        return float(0.5 * (values.max() - values.min())) if values.size else float("nan")

    @property
    def n_valid(self) -> int:
        return sum(f.ok for f in self.fits.values())


class TubeInverter:
    """Invert (L_z, L_p) -> (a/l, Ca_s) and v_c/V for one law's database table.

    Parameters
    ----------
    table : TubeTable
        Steady rows of the database.
    n_neighbours : int
        Points of the local weighted least-squares fit (the paper: 14).
    """

    def __init__(self, table: TubeTable, n_neighbours: int = N_NEIGHBOURS) -> None:
        self.table = table
        self.n_neighbours = n_neighbours
        self._p = np.column_stack([table.a_over_l, np.log(table.Ca_s)])
        self._q = np.column_stack([table.L_z, table.L_z - table.L_p])
        self._q_scale = self._q.std(axis=0)
        self._q_scale[self._q_scale == 0] = 1.0
        self._p_scale = self._p.std(axis=0)
        self._p_scale[self._p_scale == 0] = 1.0
        self._tree = cKDTree(self._q / self._q_scale)
        self._p_scaled = self._p / self._p_scale
        self._p_tree = cKDTree(self._p_scaled)
        # Columns of the scaled parameters and of the lengths, for gathers by neighbour index.
        self._p_u, self._p_v = self._p_scaled[:, 0].copy(), self._p_scaled[:, 1].copy()
        self._q_z, self._q_zp = self._q[:, 0].copy(), self._q[:, 1].copy()
        self._hull = Delaunay(self._p / self._p_scale)
        self._velocity = LinearNDInterpolator(self._hull, table.vc_over_V)
        #: The largest turn of each row's profile (triangle_turns), measured when first asked.
        self._turns: np.ndarray | None = None
        #: Each row's interpolation error (``row_interpolation_errors``), when first asked.
        self._interpolation_errors: np.ndarray | None = None

    def stated_error(self, a_over_l: float, Ca_s: float) -> tuple[float, float]:
        """The database's own stated relative error of (L_z, L_p) near (a/l, Ca_s): the largest
        that the grid rows around the point state (NaN where none states one)."""
        if not (math.isfinite(a_over_l) and Ca_s > 0):
            return math.nan, math.nan
        point = np.array([a_over_l, math.log(Ca_s)]) / self._p_scale
        _, index = self._p_tree.query(point, k=min(STATED_ERROR_ROWS, len(self.table.a_over_l)))
        index = np.atleast_1d(index)

        def largest(values: np.ndarray) -> float:
            finite = values[index][np.isfinite(values[index])]
            return float(finite.max()) if finite.size else math.nan

        assert self.table.L_z_error_rel is not None and self.table.L_p_error_rel is not None
        return largest(self.table.L_z_error_rel), largest(self.table.L_p_error_rel)

    def interpolation_error(self, a_over_l: float, Ca_s: float, points: int) -> np.ndarray:
        """The error [l] of the profile interpolated at (a/l, Ca_s) (``profile``), at ``points``
        points placed at equal arclength from the front pole to the rear pole: point by point
        the largest of the rows' own estimates (``row_interpolation_errors``, the most between
        a row and its neighbours) at the vertices of the triangle holding the point, or, where
        none of them has one, at the nearest rows that do; times where the point lies between
        the vertices (barycentric weights w): a linear interpolation is exact at its rows and
        misses most half-way between two, as t (1 - t) along an edge, so 4 sum_{i<j} w_i w_j
        (1 at an edge's middle, at most 1). NaN where no row has an estimate, or outside the
        database."""
        if self.table.profile_r is None or self.table.profile_z is None:
            return np.full(points, np.nan)
        triangle = self._triangle(a_over_l, Ca_s)
        if triangle is None:
            return np.full(points, np.nan)
        weights = triangle[1]
        between = min(1.0, 2.0 * float(weights.sum() ** 2 - weights @ weights))
        rows = self._row_interpolation_errors()
        chosen = triangle[0][np.isfinite(rows[triangle[0], 0])]
        if chosen.size == 0 and not np.any(self._smooth[triangle[0]]):
            # Between rows that are not smooth the databases' floor holds the error.
            return np.full(points, np.nan)
        if chosen.size == 0:
            point = np.array([a_over_l, math.log(Ca_s)]) / self._p_scale
            _, nearest = self._p_tree.query(point, k=min(STATED_ERROR_ROWS, len(rows)))
            nearest = np.atleast_1d(nearest)
            chosen = nearest[np.isfinite(rows[nearest, 0])]
        if chosen.size == 0:
            return np.full(points, np.nan)
        largest = rows[chosen].max(axis=0) * between
        return np.interp(np.linspace(0.0, 1.0, points), np.linspace(0.0, 1.0, INTERPOLATION_ERROR_POINTS), largest)

    @property
    def _smooth(self) -> np.ndarray:
        """Whether each row's shape is smooth in the parameters: no corner at its rim
        (``sharp_edge.CORNER_TURN``) and above the rear's buckling (``sharp_edge.BUCKLING_CA_S``)."""
        assert self.table.profile_r is not None and self.table.profile_z is not None
        if self._turns is None:
            self._turns = np.array([largest_turn(r, z) for r, z in zip(self.table.profile_r, self.table.profile_z)])
        return ~(self._turns >= CORNER_TURN) & (self.table.Ca_s > BUCKLING_CA_S)

    def _row_interpolation_errors(self) -> np.ndarray:
        """``row_interpolation_errors`` of this table, computed once per table's content."""
        if self._interpolation_errors is None:
            assert self.table.profile_r is not None and self.table.profile_z is not None
            key = hashlib.sha1(b"".join(np.ascontiguousarray(a, dtype=float).tobytes() for a in (
                self._p_scaled, self.table.profile_r, self.table.profile_z))).hexdigest()
            if key not in _ROW_INTERPOLATION_ERRORS:
                _ROW_INTERPOLATION_ERRORS[key] = row_interpolation_errors(
                    self._p_scaled, self.table.profile_r, self.table.profile_z, self._smooth)
            self._interpolation_errors = _ROW_INTERPOLATION_ERRORS[key]
        return self._interpolation_errors

    def _local_forward_map(self, q_star: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Weighted quadratic fit of q(p) over the neighbours of q_star: (coefficients, centre, p0)."""
        distance, index = self._tree.query(q_star / self._q_scale, k=self.n_neighbours)
        p = self._p[index]
        centre = p[0]
        x = (p - centre) / self._p_scale
        basis = _quadratic_basis(x)
        # Weights fall with the distance in scaled q (diffuse approximation); the farthest
        # neighbour keeps a small weight so that the system stays well posed.
        d_max = 1.01 * distance.max() + 1e-300
        weight = (1 - (distance / d_max) ** 2) ** 2
        sqrt_w = np.sqrt(weight)[:, None]
        coefficients, *_ = np.linalg.lstsq(sqrt_w * basis, sqrt_w * self._q[index], rcond=None)
        return coefficients, centre, p

    def fit(self, L_z: float, L_p: float, v_c: float | None = None, mu: float | None = None) -> TubeFit:
        """Fit one capsule.

        Parameters
        ----------
        L_z, L_p : float
            Measured total length and parachute depth [l].
        v_c, mu : float, optional
            Measured capsule velocity and outer viscosity; G_s = mu v_c / (Ca_s v_c/V) in
            the units of mu * v_c / l (with lengths in l, e.g. Pa s * m/s = N/m when v_c is m/s).
        """
        if not (np.isfinite(L_z) and np.isfinite(L_p)) or L_z <= 0 or L_p < 0 or L_p >= L_z:
            return TubeFit(flag=f"invalid lengths L_z = {L_z}, L_p = {L_p} (need L_z > 0 and 0 <= L_p < L_z)")
        q_star = np.array([L_z, L_z - L_p])
        if not self._within_reach(q_star[None, :])[0]:
            return TubeFit(flag=_beyond_reach(L_z, L_p))
        coefficients, centre, _ = self._local_forward_map(q_star)
        x = np.zeros(2)
        closest, closest_miss = x, math.inf
        for _ in range(50):
            # Damped: stay within a few grid spacings of the neighbours the fit is valid over.
            x, norm = _damped_newton_step(coefficients, x, q_star, 0.5)
            if norm < 1e-12:
                break
            miss = float(np.abs(_quadratic_value_and_jacobian(coefficients, x)[0] - q_star).max())
            if miss < closest_miss:
                closest, closest_miss = x, miss
        else:
            # Never stopped: the iteration wanders about a fold of the fitted map (q* at the
            # edge of its image), and where it ends is round-off's choice: the first root is
            # the iterate nearest to the lengths.
            x = closest
        q, _ = _quadratic_value_and_jacobian(coefficients, x)
        if np.any(np.abs(q - q_star) > 1e-6 * np.abs(q_star).max()):
            return TubeFit(flag=NO_ROOT_FLAG)
        first = centre + x * self._p_scale
        p = self._refine_in_parameter_space(q_star, first)
        if p is None and self._hull.find_simplex(first / self._p_scale) < 0:
            p = first  # reported as outside the database below
        if p is None:
            return TubeFit(flag=INCONSISTENT_FLAG)
        if self._hull.find_simplex(p / self._p_scale) < 0:
            return TubeFit(a_over_l=float("nan"), flag=outside_flag(p))
        velocity = float(self._velocity((p / self._p_scale)[None, :])[0])
        result = TubeFit(a_over_l=float(p[0]), Ca_s=float(np.exp(p[1])), vc_over_V=velocity)
        if v_c is not None and mu is not None:
            result.G_s = mu * v_c / (result.Ca_s * velocity)
        return result

    def fit_many(self, L_z: np.ndarray, L_p: np.ndarray, v_c: np.ndarray | float | None = None,
                 mu: np.ndarray | float | None = None) -> TubeFits:
        """Fit many capsules at once: the same result as ``fit`` on each (same neighbours,
        weights, iterations and flags, to round-off), vectorised over the capsules.

        ``fit`` stays the reference; here every step of it runs on all the capsules still
        iterating (per-capsule convergence masks), the small weighted least-squares systems
        stacked (``_weighted_lstsq_many``). A capsule whose parameter-space refinement has not
        converged after its 30 steps (~2 %: the iteration cycles between neighbour sets, and
        where it stops depends on round-off), or whose Newton step is not finite, is fitted
        with ``fit``'s own arithmetic, stacked (``_fit_exact_many``: bit for bit ``fit``'s
        result); what that leaves (a non-finite step) goes to ``fit`` itself.

        Parameters
        ----------
        L_z, L_p : array_like
            Measured total lengths and parachute depths [l], shape (n,).
        v_c, mu : array_like or float, optional
            Capsule velocities and outer viscosities (broadcast to (n,)); G_s as in ``fit``.
            NaN entries give G_s = NaN, as ``fit`` does.

        Returns
        -------
        TubeFits
            One entry per capsule; ``.row(i)`` is capsule i's ``TubeFit``.
        """
        L_z, L_p, modulus = capsule_arrays(L_z, L_p, v_c, mu)
        n = len(L_z)
        if n > _BATCH:
            # Each capsule is fitted on its own: chunks keep the (chunk, 14, ...) work arrays
            # in cache (~20 % faster than one pass over 10^5 capsules).
            chunks = [slice(i, i + _BATCH) for i in range(0, n, _BATCH)]
            return TubeFits.concatenate([self.fit_many(L_z[c], L_p[c], modulus[0][c] if modulus else None,
                                                       modulus[1][c] if modulus else None) for c in chunks])
        out, rows, q_star = self._screen(L_z, L_p)
        if rows.size == 0:
            return out
        fallback = np.zeros(len(rows), dtype=bool)

        # Local forward map around each q* (as _local_forward_map).
        distance, index = self._tree.query(q_star / self._q_scale, k=self.n_neighbours)
        centre = self._p[index[:, 0]]
        x_points = (self._p[index] - centre[:, None, :]) / self._p_scale
        d_max = 1.01 * distance.max(axis=1) + 1e-300
        weight = (1 - (distance / d_max[:, None]) ** 2) ** 2
        coefficients = _weighted_lstsq_many(x_points, self._q[index], weight)

        # Damped Newton to the root, each capsule until its own step is below 1e-12.
        x = np.zeros((len(rows), 2))
        active = ~fallback
        for _ in range(50):
            live = np.flatnonzero(active)
            if live.size == 0:
                break
            x_new, norm, bad = _damped_newton_step_many(coefficients[live], x[live], q_star[live], 0.5)
            x[live] = x_new
            fallback[live[bad]] = True
            active[live[(norm < 1e-12) | bad]] = False
        # An iteration that never stopped ends at ``fit``'s nearest iterate: ``fit``'s arithmetic.
        fallback |= active
        q, _ = _quadratic_value_and_jacobian_many(coefficients, x)
        tolerance = 1e-6 * np.abs(q_star).max(axis=1)
        no_root = np.any(np.abs(q - q_star) > tolerance[:, None], axis=1) & ~fallback
        first = centre + x * self._p_scale

        # Refinement in parameter space (as _refine_in_parameter_space).
        todo = ~no_root & ~fallback
        scaled, refine_coefficients, refine_centre, moving, bad = self._refine_many(q_star, first / self._p_scale, todo)
        fallback |= bad
        # A refinement still moving after its 30 steps (it cycles between neighbour sets) ends
        # wherever its path does, and round-off can move that end: such a capsule gets
        # ``fit``'s own arithmetic (``_fit_exact_many``, below).
        fallback |= moving
        todo &= ~fallback
        q, _ = _quadratic_value_and_jacobian_many(refine_coefficients, scaled - refine_centre)
        refined = todo & ~np.any(np.abs(q - q_star) > tolerance[:, None], axis=1)
        self._store_roots(out, rows, first, scaled, todo, refined, no_root, modulus)
        self._store_exact(out, rows[fallback], L_z, L_p, modulus)
        return out

    def _screen(self, L_z: np.ndarray, L_p: np.ndarray) -> tuple[TubeFits, np.ndarray, np.ndarray]:
        """A result for the capsules (n,) with no value yet, the flags of the invalid lengths
        and of those beyond the database's reach written; the rows of the others and their
        lengths q* = (L_z, L_z - L_p) (m, 2)."""
        n = len(L_z)
        out = TubeFits(np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan), flag=[""] * n)
        with np.errstate(invalid="ignore"):
            valid = np.isfinite(L_z) & np.isfinite(L_p) & (L_z > 0) & (L_p >= 0) & (L_p < L_z)
        for i in np.flatnonzero(~valid):
            out.flag[i] = (f"invalid lengths L_z = {float(L_z[i])}, L_p = {float(L_p[i])} "
                           "(need L_z > 0 and 0 <= L_p < L_z)")
        # Lengths so large that their distance to the database overflows have no neighbours.
        with np.errstate(invalid="ignore"):
            reach = self._within_reach(np.column_stack([L_z, L_z - L_p]))
        for i in np.flatnonzero(valid & ~reach):
            out.flag[i] = _beyond_reach(float(L_z[i]), float(L_p[i]))
        rows = np.flatnonzero(valid & reach)
        return out, rows, np.column_stack([L_z[rows], L_z[rows] - L_p[rows]])

    def _store_roots(self, out: TubeFits, rows: np.ndarray, first: np.ndarray, scaled: np.ndarray,
                     todo: np.ndarray, refined: np.ndarray, no_root: np.ndarray, modulus: Modulus) -> None:
        """``fit``'s choice between the first root ``first`` (m, 2) and the refined one (scaled
        parameters ``scaled``), written into ``out`` at ``rows``: the refined root where the
        refinement reproduced the lengths (``refined``); else, for the capsules ``todo``, the
        first root's outside flag if it lies outside the database, or that the two
        neighbourhoods disagree; the ``no_root`` capsules flagged so."""
        p = np.where(refined[:, None], scaled * self._p_scale, first)
        # Where the first root lies matters only where the refinement did not reproduce the lengths.
        unrefined = todo & ~refined
        first_outside = np.zeros(len(rows), dtype=bool)
        first_outside[unrefined] = self._hull.find_simplex(first[unrefined] / self._p_scale) < 0
        inconsistent = unrefined & ~first_outside
        ok = todo & ~inconsistent
        outside = np.zeros(len(rows), dtype=bool)
        outside[ok] = self._hull.find_simplex(p[ok] / self._p_scale) < 0
        ok &= ~outside
        self._store(out, rows, p, ok, no_root, inconsistent, outside, modulus)

    def _store_exact(self, out: TubeFits, exact: np.ndarray, L_z: np.ndarray, L_p: np.ndarray,
                     modulus: Modulus) -> None:
        """``fit``'s result for the capsules ``exact`` of ``out``, written there."""
        # The capsules that need ``fit``'s result get its arithmetic stacked (a loop over ``fit``
        # was ~30 % of the batch's time, and re-running the cycling refinements from shifted
        # starts to tell which ends round-off can move ~10 %); ``fit`` takes what is left.
        p_exact, outcome = self._fit_exact_many(L_z[exact], L_p[exact])
        self._store(out, exact, p_exact, outcome == _EXACT_OK, outcome == _EXACT_NO_ROOT,
                    outcome == _EXACT_INCONSISTENT, outcome == _EXACT_OUTSIDE, modulus)
        for i in exact[outcome == _EXACT_LEFT]:
            one = self.fit(float(L_z[i]), float(L_p[i]), float(modulus[0][i]) if modulus else None,
                           float(modulus[1][i]) if modulus else None)
            out.a_over_l[i], out.Ca_s[i], out.vc_over_V[i], out.G_s[i] = one.a_over_l, one.Ca_s, one.vc_over_V, one.G_s
            out.flag[i] = one.flag

    def _store(self, out: TubeFits, rows: np.ndarray, p: np.ndarray, ok: np.ndarray, no_root: np.ndarray,
               inconsistent: np.ndarray, outside: np.ndarray, modulus: Modulus) -> None:
        """Write the fitted parameters ``p`` of the ``ok`` capsules and the others' flags into
        ``out`` at ``rows``; G_s where ``modulus`` gives (v_c, mu) of every capsule of ``out``."""
        for j in np.flatnonzero(no_root):
            out.flag[rows[j]] = NO_ROOT_FLAG
        for j in np.flatnonzero(inconsistent):
            out.flag[rows[j]] = INCONSISTENT_FLAG
        for j in np.flatnonzero(outside):
            out.flag[rows[j]] = outside_flag(p[j])
        good = rows[ok]
        out.a_over_l[good] = p[ok, 0]
        out.Ca_s[good] = np.exp(p[ok, 1])
        out.vc_over_V[good] = self._velocity(p[ok] / self._p_scale)
        if modulus is not None:
            v_c, mu = modulus
            out.G_s[good] = mu[good] * v_c[good] / (out.Ca_s[good] * out.vc_over_V[good])

    def _fit_exact_many(self, L_z: np.ndarray, L_p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``fit``'s own arithmetic on a stack of valid lengths (m,): (p = (a/l, ln Ca_s) (m, 2),
        outcome (m,): ``_EXACT_OK``, a flag's ``_EXACT_NO_ROOT``, ``_EXACT_INCONSISTENT``,
        ``_EXACT_OUTSIDE`` (p: the point outside), or ``_EXACT_LEFT``). Every operation is
        ``fit``'s, elementwise or one LAPACK call per capsule (``_lstsq_stack``), so the result is
        ``fit``'s bit for bit; a capsule with a non-finite step is left to ``fit``. For the
        capsules whose result round-off decides (a refinement cycling between neighbour sets)."""
        m = len(L_z)
        p_out = np.full((m, 2), np.nan)
        outcome = np.full(m, _EXACT_OK)
        if m == 0:
            return p_out, outcome
        q_star = np.column_stack([L_z, L_z - L_p])
        done = np.ones(m, dtype=bool)
        # Local forward map around each q* (``_local_forward_map``).
        distance, index = self._tree.query(q_star / self._q_scale, k=self.n_neighbours)
        p = self._p[index]
        centre = p[:, 0]
        x_points = (p - centre[:, None, :]) / self._p_scale
        d_max = 1.01 * distance.max(axis=1) + 1e-300
        weight = (1 - (distance / d_max[:, None]) ** 2) ** 2
        sqrt_w = np.sqrt(weight)[..., None]
        coefficients = _lstsq_stack(sqrt_w * _quadratic_basis_stack(x_points), sqrt_w * self._q[index])
        x = np.zeros((m, 2))
        # ``fit``'s iterate nearest to the lengths, for the iterations that never stop.
        closest, closest_miss = np.zeros((m, 2)), np.full(m, np.inf)
        active = np.ones(m, dtype=bool)
        for _ in range(50):
            live = np.flatnonzero(active)
            if live.size == 0:
                break
            x[live], norm = _damped_newton_step_stack(coefficients[live], x[live], q_star[live], 0.5)
            outcome[live[~np.isfinite(norm)]] = _EXACT_LEFT
            moving = live[norm >= 1e-12]
            miss = np.abs(_quadratic_value_stack(coefficients[moving], x[moving]) - q_star[moving]).max(axis=1)
            nearer = moving[miss < closest_miss[moving]]
            closest[nearer], closest_miss[nearer] = x[nearer], miss[miss < closest_miss[moving]]
            active[live[~(norm >= 1e-12)]] = False
        x[active] = closest[active]
        done &= outcome == _EXACT_OK
        q = _quadratic_value_stack(coefficients, x)
        tolerance = 1e-6 * np.abs(q_star).max(axis=1)
        no_root = done & np.any(np.abs(q - q_star) > tolerance[:, None], axis=1)
        outcome[no_root] = _EXACT_NO_ROOT
        done &= ~no_root
        first = centre + x * self._p_scale
        # Refinement in parameter space (``_refine_in_parameter_space``).
        rows = np.flatnonzero(done)
        scaled = first[rows] / self._p_scale
        coefficients = np.zeros((len(rows), 6, 2))
        centre = np.zeros((len(rows), 2))
        active = np.ones(len(rows), dtype=bool)
        for _ in range(30):
            live = np.flatnonzero(active)
            if live.size == 0:
                break
            s_live = scaled[live]
            _, index = self._p_tree.query(s_live, k=self.n_neighbours)
            centre_live = self._p[index[:, 0]]
            x_points = (self._p[index] - centre_live[:, None, :]) / self._p_scale
            distance = np.linalg.norm(x_points - (s_live - centre_live / self._p_scale)[:, None, :], axis=2)
            weight = (1 - (distance / (1.01 * distance.max(axis=1) + 1e-300)[:, None]) ** 2) ** 2
            sqrt_w = np.sqrt(weight)[..., None]
            coefficients_live = _lstsq_stack(sqrt_w * _quadratic_basis_stack(x_points), sqrt_w * self._q[index])
            x_here = s_live - centre_live / self._p_scale
            x_new, norm = _damped_newton_step_stack(coefficients_live, x_here, q_star[rows[live]], 0.25)
            scaled[live] = s_live + (x_new - x_here)
            coefficients[live], centre[live] = coefficients_live, centre_live
            outcome[rows[live[~np.isfinite(norm)]]] = _EXACT_LEFT
            active[live[~(norm >= 1e-10)]] = False
        q = _quadratic_value_stack(coefficients, scaled - centre / self._p_scale)
        refined = ~np.any(np.abs(q - q_star[rows]) > tolerance[rows, None], axis=1)
        p_out[rows] = np.where(refined[:, None], scaled * self._p_scale, first[rows])
        # Not refined: ``fit`` reports the first root when it lies outside the database, else
        # that the two neighbourhoods disagree.
        first_outside = self._hull.find_simplex(first[rows] / self._p_scale) < 0
        finite = outcome[rows] == _EXACT_OK  # not left to ``fit`` for a non-finite step
        outcome[rows[finite & ~refined & ~first_outside]] = _EXACT_INCONSISTENT
        rows = rows[finite & (refined | first_outside)]
        outcome[rows[self._hull.find_simplex(p_out[rows] / self._p_scale) < 0]] = _EXACT_OUTSIDE
        return p_out, outcome

    def _within_reach(self, q_star: np.ndarray) -> np.ndarray:
        """Rows of q* (n, 2) whose scaled distance to the database is a finite number."""
        return np.all(np.abs(q_star / self._q_scale) < _REACH, axis=1)

    def _refine_many(self, q_star: np.ndarray, scaled: np.ndarray, todo: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``_refine_in_parameter_space``'s iteration on the rows ``todo`` of a stack, from the
        scaled parameters ``scaled`` (m, 2): (final scaled parameters, the last local fit's
        coefficients (m, 6, 2) and centre (m, 2), rows still moving after the 30 steps, rows
        with a non-finite step)."""
        scaled = scaled.copy()
        coefficients = np.zeros((len(scaled), 6, 2))
        centre = np.zeros((len(scaled), 2))
        failed = np.zeros(len(scaled), dtype=bool)
        active = todo.copy()
        for _ in range(30):
            live = np.flatnonzero(active)
            if live.size == 0:
                break
            s_live = scaled[live]
            distance, index = self._p_tree.query(s_live, k=self.n_neighbours)
            # In scaled parameters throughout (fit divides differences by the scale, and takes
            # the distances from the differences: the same to round-off), the work arrays
            # neighbour-major (n, m) as _weighted_lstsq_neighbour_major wants them.
            index, distance = index.T, distance.T
            centre_scaled = self._p_scaled[index[0]]
            u = self._p_u[index] - centre_scaled[:, 0]
            v = self._p_v[index] - centre_scaled[:, 1]
            weight = (1 - (distance / (1.01 * distance[-1] + 1e-300)) ** 2) ** 2
            coefficients_live = _weighted_lstsq_neighbour_major(u, v, [self._q_z[index], self._q_zp[index]], weight)
            x_here = s_live - centre_scaled
            x_new, norm, bad = _damped_newton_step_many(coefficients_live, x_here, q_star[live], 0.25)
            scaled[live] = s_live + (x_new - x_here)
            coefficients[live] = coefficients_live
            centre[live] = centre_scaled
            failed[live[bad]] = True
            active[live[(norm < 1e-10) | bad]] = False
        return scaled, coefficients, centre, active, failed

    def _refine_in_parameter_space(self, q_star: np.ndarray, p: np.ndarray) -> np.ndarray | None:
        """Newton on local fits of q(p) over the points nearest to p in parameter space, until
        p is a root of the fit around itself (None if that never happens).

        The first root comes from the points nearest in q, which near a fold of the map (L_p
        falls with a/l at small Ca_s and rises at large Ca_s) may come from two branches, and
        a quadratic through both can have a root that neither supports. In parameter space
        the forward map is smooth and the neighbours are those of p itself."""
        scaled = p / self._p_scale
        for _ in range(30):
            _, index = self._p_tree.query(scaled, k=self.n_neighbours)
            centre = self._p[index[0]]
            x_points = (self._p[index] - centre) / self._p_scale
            distance = np.linalg.norm(x_points - (scaled - centre / self._p_scale), axis=1)
            weight = (1 - (distance / (1.01 * distance.max() + 1e-300)) ** 2) ** 2
            sqrt_w = np.sqrt(weight)[:, None]
            coefficients, *_ = np.linalg.lstsq(sqrt_w * _quadratic_basis(x_points), sqrt_w * self._q[index], rcond=None)
            x = scaled - centre / self._p_scale
            x_new, norm = _damped_newton_step(coefficients, x, q_star, 0.25)
            scaled = scaled + (x_new - x)
            if norm < 1e-10:
                break
        q, _ = _quadratic_value_and_jacobian(coefficients, scaled - centre / self._p_scale)
        if np.any(np.abs(q - q_star) > 1e-6 * np.abs(q_star).max()):
            return None
        return scaled * self._p_scale

    def _triangle(self, a_over_l: float, Ca_s: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The rows at the vertices of the Delaunay triangle holding (a/l, Ca_s) and the point's
        barycentric weights there (None outside the database)."""
        x = np.array([a_over_l, np.log(Ca_s)]) / self._p_scale
        simplex = int(self._hull.find_simplex(x))
        if simplex < 0:
            return None
        transform = self._hull.transform[simplex]
        b = transform[:2] @ (x - transform[2])
        return self._hull.simplices[simplex], np.append(b, 1 - b.sum())

    def triangle_turns(self, a_over_l: float, Ca_s: float
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """The largest turns [degrees] of the database profiles at the vertices of the triangle
        holding (a/l, Ca_s) (``capsmech.inversion.sharp_edge.largest_turn``), the vertices'
        Ca_s, the point's barycentric weights there, and whether each vertex is a root of the
        steady equations (``sharp_edge.is_steady_root``): what the accuracy of a value
        interpolated there depends on (None outside the database or without profiles)."""
        if self.table.profile_r is None or self.table.profile_z is None:
            return None
        triangle = self._triangle(a_over_l, Ca_s)
        if triangle is None:
            return None
        if self._turns is None:
            self._turns = np.array([largest_turn(r, z) for r, z in zip(self.table.profile_r, self.table.profile_z)])
        roots = np.ones(len(self.table.Ca_s), dtype=bool) if self.table.root is None else self.table.root
        return self._turns[triangle[0]], self.table.Ca_s[triangle[0]], triangle[1], roots[triangle[0]]

    def profile(self, a_over_l: float, Ca_s: float) -> np.ndarray | None:
        """Meridian (points, 2) of (r, z) [l] at (a/l, Ca_s): the database profiles blended with
        the barycentric weights of the Delaunay triangle holding the point (None without profiles)."""
        if self.table.profile_r is None or self.table.profile_z is None:
            return None
        triangle = self._triangle(a_over_l, Ca_s)
        if triangle is None:
            return None
        vertices, weights = triangle
        r = weights @ self.table.profile_r[vertices]
        z = weights @ self.table.profile_z[vertices]
        return np.column_stack([r, z])

    def velocity_ratio(self, a_over_l: float, Ca_s: float) -> float:
        """v_c/V at (a/l, Ca_s), linear in the Delaunay triangle (NaN outside the database)."""
        return float(self._velocity((np.array([a_over_l, np.log(Ca_s)]) / self._p_scale)[None, :])[0])

    def five_fits(self, L_z: float, L_p: float, v_c: float | None = None, mu: float | None = None) -> FiveFits:
        """Fits 1-5 of paper section 4.2 (L_z and L_p -+2 %, then L_p alone -+2 %)."""
        return FiveFits({name: self.fit(L_z * fz, L_p * fp, v_c, mu) for name, fz, fp in FIVE_FITS})


#: ``row_interpolation_errors`` by table content: a database's law is estimated once a process.
_ROW_INTERPOLATION_ERRORS: dict[str, np.ndarray] = {}


def row_interpolation_errors(p_scaled: np.ndarray, profile_r: np.ndarray, profile_z: np.ndarray,
                             smooth: np.ndarray | None = None) -> np.ndarray:
    """Each row's estimate of the error [the profiles' units] of a profile linearly interpolated
    between it and its neighbours (``TubeInverter.profile``), at ``INTERPOLATION_ERROR_POINTS``
    points at equal arclength from the front pole to the rear pole; NaN for a row without a
    neighbour on either side, and for the rows that are not ``smooth`` (default: all are).

    Rows whose shape is not smooth in the parameters take no part (``TubeInverter`` leaves out
    those with a corner at the rim, ``sharp_edge.CORNER_TURN``, and those at the rear's buckling,
    ``sharp_edge.BUCKLING_CA_S``): there the rim moves from one material node to the next in
    jumps, or the rear folds, and the databases' floor holds those errors already
    (``sharp_edge.row_accuracy``); the differences between such rows measure the jumps, not the
    grid's spacing.

    Left out, a row is predicted from each pair of rows on either side of it (adjacent: no row
    between; within ``INTERPOLATION_PAIR_STRAIGHTNESS`` of the line through them, among its
    ``INTERPOLATION_PAIR_ROWS`` nearest in the scaled parameters ``p_scaled``: a grid's axes,
    and its diagonals where straight), linearly at its position t along the pair; the error is the unsigned normal
    distance between the prediction and the row's own profile, the axial shift that a contour's
    residual leaves free removed (``PreparedContour.residual``). Linear interpolation misses
    by the second derivative times t (1 - t) L^2 / 2 at a pair's distance L, and by at most
    h^2 / 8 times the same derivative inside a cell of edge h: the left-out error is scaled by
    max(t, 1 - t)^2 / (4 t (1 - t)) (1/4 at a grid's mid-points), the error the interpolation
    makes between the row and its neighbours, from the grid's own rows. The point-by-point
    largest over the directions is the row's estimate. (Measured on tube-paper, a/l every 0.05:
    the second differences at a/l spacing 0.1 are 3.5-4.0 times those at 0.05, the median over
    each law's rows; quadratic: 4.)"""
    n = len(p_scaled)
    errors = np.full((n, INTERPOLATION_ERROR_POINTS), np.nan)
    used = np.ones(n, dtype=bool) if smooth is None else np.asarray(smooth, dtype=bool)
    rows = np.flatnonzero(used)
    if len(rows) < 3:
        return errors
    tree = cKDTree(p_scaled[rows])
    _, nearest = tree.query(p_scaled[rows], k=min(INTERPOLATION_PAIR_ROWS + 1, len(rows)))
    nearest = rows[nearest]

    def off_line(point: np.ndarray, start: np.ndarray, end: np.ndarray) -> tuple[float, float]:
        """(position along start -> end, distance from the line over their distance)."""
        segment = end - start
        length2 = float(segment @ segment)
        t = float((point - start) @ segment / length2)
        return t, float(np.linalg.norm(start + t * segment - point)) / math.sqrt(length2)

    for i, neighbours in zip(rows, nearest):
        around = [int(j) for j in neighbours if j != i]
        prepared: PreparedContour | None = None
        for first, j in enumerate(around):
            for k in around[first + 1:]:
                t, off = off_line(p_scaled[i], p_scaled[j], p_scaled[k])
                if not (0.0 < t < 1.0 and off <= INTERPOLATION_PAIR_STRAIGHTNESS):
                    continue
                if any(0.0 < u < 1.0 and d <= INTERPOLATION_PAIR_STRAIGHTNESS
                       for m in around if m not in (j, k)
                       for u, d in (off_line(p_scaled[m], p_scaled[i], p_scaled[end]) for end in (j, k))):
                    continue
                if prepared is None:
                    # The row's profile as a contour: the meridian and its mirror image.
                    half = np.column_stack([profile_z[i], profile_r[i]])
                    mirror = np.column_stack([profile_z[i][::-1], -profile_r[i][::-1]])
                    prepared = PreparedContour(np.vstack([half, mirror]), axis_y=0.0)
                predicted = np.column_stack([(1 - t) * profile_r[j] + t * profile_r[k],
                                             (1 - t) * profile_z[j] + t * profile_z[k]])
                missed = np.abs(prepared.residual(predicted, points=INTERPOLATION_ERROR_POINTS)[1])
                errors[i] = np.fmax(errors[i], missed * max(t, 1 - t) ** 2 / (4 * t * (1 - t)))
    return errors


def _damped_newton_step(coefficients: np.ndarray, x: np.ndarray, q_star: np.ndarray, max_step: float
                        ) -> tuple[np.ndarray, float]:
    """One Newton step towards q(x) = q_star on the fitted quadratic map, its length capped at
    max_step (scaled units): (new x, length of the undamped step)."""
    q, jac = _quadratic_value_and_jacobian(coefficients, x)
    step = np.linalg.lstsq(jac, q_star - q, rcond=None)[0]
    norm = float(np.linalg.norm(step))
    if norm > max_step:
        step *= max_step / norm
    return x + step, norm


def _quadratic_basis(x: np.ndarray) -> np.ndarray:
    """Columns 1, x, y, x^2, x y, y^2 at the rows of x (n, 2)."""
    return np.column_stack([np.ones(len(x)), x[:, 0], x[:, 1], x[:, 0] ** 2, x[:, 0] * x[:, 1], x[:, 1] ** 2])


def _quadratic_value_and_jacobian(c: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Value (2,) and Jacobian (2, 2) of the fitted quadratic map at x (2,)."""
    value = _quadratic_basis(x[None, :])[0] @ c
    d_dx = np.array([0, 1, 0, 2 * x[0], x[1], 0]) @ c
    d_dy = np.array([0, 0, 1, 0, x[0], 2 * x[1]]) @ c
    return value, np.column_stack([d_dx, d_dy])


#: Outcomes of ``TubeInverter._fit_exact_many``: valid, ``fit``'s three flags after valid
#: lengths, and left to ``fit`` itself.
_EXACT_OK, _EXACT_NO_ROOT, _EXACT_INCONSISTENT, _EXACT_OUTSIDE, _EXACT_LEFT = range(5)


def _lstsq_stack(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.linalg.lstsq(a[i], b[i], rcond=None)[0]`` for every i of a stack a (m, r, c),
    b (m, r, k), bit for bit: numpy's lstsq is a generalised ufunc (one LAPACK gelsd call per
    matrix) behind a wrapper for one matrix; called on the stack where this numpy exposes it,
    one matrix at a time otherwise."""
    rcond = np.finfo(float).eps * max(a.shape[1:])
    gufunc = getattr(getattr(np.linalg, "_umath_linalg", None), "lstsq", None)
    if gufunc is None or len(a) == 0:
        return np.array([np.linalg.lstsq(ai, bi, rcond=None)[0] for ai, bi in zip(a, b)]).reshape(
            len(a), a.shape[2], b.shape[2])
    with np.errstate(over="ignore", divide="ignore", under="ignore", invalid="ignore"):
        return np.asarray(gufunc(a, b, rcond, signature="ddd->ddid")[0])


def _quadratic_basis_stack(x: np.ndarray) -> np.ndarray:
    """``_quadratic_basis`` on a stack: x (m, n, 2) -> (m, n, 6), the same elementwise operations."""
    u, v = x[..., 0], x[..., 1]
    return np.stack([np.ones_like(u), u, v, u**2, u * v, v**2], axis=-1)


def _quadratic_value_stack(c: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The value of ``_quadratic_value_and_jacobian`` on a stack (c (m, 6, 2), x (m, 2) -> (m, 2)),
    by the same product (one small matmul per capsule)."""
    return np.matmul(_quadratic_basis_stack(x[:, None, :]), c)[:, 0]


def _damped_newton_step_stack(c: np.ndarray, x: np.ndarray, q_star: np.ndarray, max_step: float
                              ) -> tuple[np.ndarray, np.ndarray]:
    """``_damped_newton_step`` on a stack with its own operations (c (m, 6, 2), x (m, 2)):
    (new x (m, 2), length of the undamped step (m,))."""
    u, v = x[:, 0], x[:, 1]
    zero, one = np.zeros_like(u), np.ones_like(u)
    value = _quadratic_value_stack(c, x)
    d_dx = np.matmul(np.stack([zero, one, zero, 2 * u, v, zero], axis=-1)[:, None, :], c)[:, 0]
    d_dy = np.matmul(np.stack([zero, zero, one, zero, u, 2 * v], axis=-1)[:, None, :], c)[:, 0]
    jac = np.stack([d_dx, d_dy], axis=-1)
    step = _lstsq_stack(jac, (q_star - value)[..., None])[..., 0]
    norm = np.sqrt(np.matmul(step[:, None, :], step[:, :, None])[:, 0, 0])
    damp = norm > max_step
    step[damp] *= (max_step / norm[damp])[:, None]
    return x + step, norm


#: Smallest Cholesky pivot of the column-scaled Gram matrix (unit diagonal) for which its
#: normal equations are solved directly: above it the Gram matrix's condition number stays
#: ~< 1e6 and the solution equals lstsq's to ~1e-10; below it (neighbours on one or two grid
#: lines: the basis is rank-deficient) lstsq's own minimum-norm SVD solution is used.
_MIN_CHOLESKY_PIVOT = 1e-6


#: fit_many: capsules fitted together (larger batches are split).
_BATCH = 16384
#: Largest scaled length fitted: the squared distances of larger ones to the database overflow.
_REACH = 1e150


def _beyond_reach(L_z: float, L_p: float) -> str:
    return (f"outside the database: L_z = {L_z:.3g}, L_p = {L_p:.3g} lie far beyond the lengths of any "
            "database point")
#: Exponents (of x, y) of the columns of ``_quadratic_basis``.
_EXPONENTS = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))


def _weighted_lstsq_many(x: np.ndarray, values: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """The weighted quadratic fit on a stack: points x (m, n, 2), values (m, n, 2), weights
    (m, n) -> coefficients (m, 6, 2), equal row by row to round-off to
    ``np.linalg.lstsq(sqrt_w * _quadratic_basis(x), sqrt_w * values)``.

    Well-conditioned rows (the usual case) are solved by the normal equations with the
    columns scaled to unit norm. Their entries are weighted moments sum w x^i y^j (i + j <= 4)
    and sum w q x^i y^j (i + j <= 2), and the 6 x 6 Cholesky factorisation and solves are
    written out over the stack: numpy operations on (m,) vectors cost much less than one
    LAPACK call per small system. The work arrays are neighbour-major, (n, m), so that each
    sum over the neighbours is n - 1 additions of whole (m,) vectors (a sum along a short
    last axis runs ~5 times slower). The error ~ cond**2 * eps stays ~1e-10 while every
    Cholesky pivot exceeds _MIN_CHOLESKY_PIVOT. Rows below it (neighbours on one or two grid
    lines make the basis rank-deficient, common near the edge of a database's steady region)
    get lstsq's own answer: the minimum-norm SVD solution with lstsq's cutoff on the singular
    values (eps * max(n, 6) times the largest)."""
    return _weighted_lstsq_neighbour_major(np.ascontiguousarray(x[..., 0].T), np.ascontiguousarray(x[..., 1].T),
                                           [np.ascontiguousarray(values[..., q].T) for q in range(values.shape[2])],
                                           np.ascontiguousarray(weight.T))


def _weighted_lstsq_neighbour_major(u: np.ndarray, v: np.ndarray, value_columns: list[np.ndarray], w: np.ndarray
                                    ) -> np.ndarray:
    """``_weighted_lstsq_many`` on neighbour-major arrays: the points' coordinates u, v (n, m),
    each column of the values (n, m) and the weights w (n, m) -> coefficients (m, 6, len(value_columns))."""
    m = u.shape[1]
    u_powers = [None, u, u * u]
    u_powers += [u_powers[2] * u, u_powers[2] * u_powers[2]]
    v_powers = [None, v, v * v]
    v_powers += [v_powers[2] * v, v_powers[2] * v_powers[2]]
    moment = {}
    weighted = {}  # w x^i y^j (i + j <= 2), for the right-hand sides
    for i in range(5):
        wu = w if i == 0 else w * u_powers[i]
        for j in range(5 - i):
            wuv = wu if j == 0 else wu * v_powers[j]
            if i + j <= 2:
                weighted[i, j] = wuv
            moment[i, j] = wuv.sum(axis=0)
    k = len(_EXPONENTS)
    gram = [[moment[i1 + i2, j1 + j2] for (i2, j2) in _EXPONENTS] for (i1, j1) in _EXPONENTS]
    rhs = [[(weighted[i, j] * column).sum(axis=0) for column in value_columns] for i, j in _EXPONENTS]
    column_norm = [np.sqrt(gram[r][r]) for r in range(k)]
    bad = np.zeros(m, dtype=bool)
    for norm in column_norm:
        bad |= norm == 0
    safe_norm = [np.where(norm > 0, norm, 1.0) for norm in column_norm]
    scaled_gram = [[gram[r][c] / (safe_norm[r] * safe_norm[c]) for c in range(k)] for r in range(k)]
    scaled_rhs = [[b / safe_norm[r] for b in rhs[r]] for r in range(k)]
    lower: list[list[np.ndarray]] = [[np.zeros(m)] * k for _ in range(k)]
    for j in range(k):
        pivot = scaled_gram[j][j]
        for t in range(j):
            pivot = pivot - lower[j][t] * lower[j][t]
        bad |= ~(pivot > _MIN_CHOLESKY_PIVOT)
        lower[j][j] = np.sqrt(np.where(bad, 1.0, pivot))
        for i in range(j + 1, k):
            entry = scaled_gram[i][j]
            for t in range(j):
                entry = entry - lower[i][t] * lower[j][t]
            lower[i][j] = entry / lower[j][j]
    n_rhs = len(value_columns)
    solution = _cholesky_substitutions(lower, scaled_rhs, lambda entry, i: entry / lower[i][i])
    coefficients = np.empty((m, k, n_rhs))
    for i in range(k):
        for q in range(n_rhs):
            coefficients[:, i, q] = solution[i][q] / safe_norm[i]
    if bad.any():
        sqrt_w = np.sqrt(w[:, bad].T)[..., None]
        ub, vb = u[:, bad].T, v[:, bad].T
        a = sqrt_w * np.stack([ub**i * vb**j for i, j in _EXPONENTS], axis=-1)
        b = sqrt_w * np.stack([column[:, bad].T for column in value_columns], axis=-1)
        u_svd, s_values, vt = np.linalg.svd(a, full_matrices=False)
        cutoff = np.finfo(float).eps * max(a.shape[1:]) * s_values[:, :1]
        s_inverse = np.where(s_values > cutoff, 1 / np.where(s_values > cutoff, s_values, 1.0), 0.0)
        coefficients[bad] = np.matmul(vt.transpose(0, 2, 1),
                                      s_inverse[:, :, None] * np.matmul(u_svd.transpose(0, 2, 1), b))
    return coefficients


def _cholesky_substitutions(lower: list[list[np.ndarray]], rhs: list[list[np.ndarray]],
                            divide_by_pivot: Callable[[np.ndarray, int], np.ndarray]) -> list[list[np.ndarray]]:
    """The solutions x[i][q] (m,) of L L^T x = b on a stack of small systems, by forward and
    back substitution written out over the stack: the Cholesky factor's entries below the
    diagonal ``lower[i][t]`` (m,), the right-hand sides ``rhs[i][q]`` (m,), and
    ``divide_by_pivot(entry, i)``, the division by the factor's i-th diagonal entry as the
    caller keeps it (the entry itself or its inverse)."""
    k, n_rhs = len(rhs), len(rhs[0])
    y: list[list[np.ndarray]] = []
    for i in range(k):
        row = []
        for q in range(n_rhs):
            entry = rhs[i][q]
            for t in range(i):
                entry = entry - lower[i][t] * y[t][q]
            row.append(divide_by_pivot(entry, i))
        y.append(row)
    solution: list[list[np.ndarray]] = [list(row) for row in y]
    for i in reversed(range(k)):
        for q in range(n_rhs):
            entry = y[i][q]
            for t in range(i + 1, k):
                entry = entry - lower[t][i] * solution[t][q]
            solution[i][q] = divide_by_pivot(entry, i)
    return solution


def _quadratic_value_and_jacobian_many(c: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``_quadratic_value_and_jacobian`` on a stack: c (m, 6, 2), x (m, 2) -> (m, 2), (m, 2, 2)."""
    u, v = x[:, :1], x[:, 1:]
    value = c[:, 0] + c[:, 1] * u + c[:, 2] * v + c[:, 3] * u**2 + c[:, 4] * (u * v) + c[:, 5] * v**2
    d_dx = c[:, 1] + c[:, 3] * (2 * u) + c[:, 4] * v
    d_dy = c[:, 2] + c[:, 4] * u + c[:, 5] * (2 * v)
    return value, np.stack([d_dx, d_dy], axis=-1)


def _damped_newton_step_many(c: np.ndarray, x: np.ndarray, q_star: np.ndarray, max_step: float
                             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``_damped_newton_step`` on a stack: (new x (m, 2), undamped step length (m,), rows whose
    step is not finite (m,), for ``fit`` to redo).

    The 2 x 2 systems are solved by the explicit inverse where the Jacobian is well
    conditioned (equal to lstsq to ~cond * eps) and, where it is nearly singular (a local fit
    through neighbours on one grid line), as lstsq does: minimum norm, SVD cutoff 2 eps."""
    q, jac = _quadratic_value_and_jacobian_many(c, x)
    r = q_star - q
    a, b, cc, d = jac[:, 0, 0], jac[:, 0, 1], jac[:, 1, 0], jac[:, 1, 1]
    det = a * d - b * cc
    scale = np.abs(jac).max(axis=(1, 2))
    singular = ~(np.abs(det) > 1e-6 * scale**2)
    det = np.where(singular, 1.0, det)
    step = np.column_stack([(d * r[:, 0] - b * r[:, 1]) / det, (a * r[:, 1] - cc * r[:, 0]) / det])
    if singular.any():
        u, s, vt = np.linalg.svd(jac[singular])
        cutoff = np.finfo(float).eps * 2 * s[:, :1]
        s_inverse = np.where(s > cutoff, 1 / np.where(s > cutoff, s, 1.0), 0.0)
        step[singular] = np.einsum("mji,mj,mkj,mk->mi", vt, s_inverse, u, r[singular])
    norm = np.sqrt(np.einsum("mi,mi->m", step, step))
    bad = ~np.isfinite(norm)
    step[bad] = 0.0
    damp = norm > max_step
    step[damp] *= (max_step / norm[damp])[:, None]
    return x + step, norm, bad


@dataclass
class ShearFit(Fit):
    """Result of one shear fit; ``flag`` is empty when the fit is valid."""

    Ca_s: float = float("nan")
    L3_over_a: float = float("nan")
    a: float = float("nan")
    #: Relative error of G_s (and of Ca_s) that the database's stated D12 errors imply at this
    #: D12 (NaN where the database states none): |d ln Ca_s / d D12| D12 e, e interpolated.
    database_error_rel: float = float("nan")


class ShearInverter:
    """Invert D12 -> (Ca_s, L3/a) along one law's steady shear branch.

    Parameters
    ----------
    Ca_s, D12, L3_over_a : array_like
        Steady rows of the shear database (NaN rows are ignored).
    min_D12 : float
        Smaller D12 values are flagged as too imprecise (paper section 4.3: 0.35).
    D12_error_rel : array_like, optional
        The rows' stated relative D12 errors (time and mesh; NaN where not stated). A fit's
        ``database_error_rel`` is the error of G_s they imply, interpolated between the rows
        that state one (NaN outside them).
    """

    def __init__(self, Ca_s: np.ndarray, D12: np.ndarray, L3_over_a: np.ndarray, min_D12: float = MIN_SHEAR_D12,
                 D12_error_rel: np.ndarray | None = None):
        ca, d12, l3 = (np.asarray(v, dtype=float) for v in (Ca_s, D12, L3_over_a))
        err = np.full(ca.shape, np.nan) if D12_error_rel is None else np.asarray(D12_error_rel, dtype=float)
        keep = np.isfinite(ca) & np.isfinite(d12) & np.isfinite(l3)
        order = np.argsort(ca[keep])
        ca, d12, l3, err = ca[keep][order], d12[keep][order], l3[keep][order], err[keep][order]
        stated = np.isfinite(err)
        self._error_d12, self._error = d12[stated], err[stated]
        if len(ca) < 2:
            raise DatabaseError("the shear database has fewer than 2 steady rows for this law: nothing to fit against")
        if np.any(np.diff(d12) <= 0):
            raise ValueError("shear table: D12 does not increase with Ca_s along the steady rows")
        self.min_D12 = min_D12
        self.D12_range = (float(d12[0]), float(d12[-1]))
        # Interpolate ln Ca_s and L3/a in D12: both smooth and monotone along the branch.
        self._log_ca = PchipInterpolator(d12, np.log(ca), extrapolate=False)
        # d ln Ca_s / d D12, for the database error of each fit (built once, not per fit).
        self._dlog_ca = self._log_ca.derivative()
        self._l3 = PchipInterpolator(d12, l3, extrapolate=False)

    def fit(self, D12: float | None = None, L1: float | None = None, L2: float | None = None,
            shear_rate: float | None = None, mu: float | None = None) -> ShearFit:
        """Fit one capsule from D12, or from its semi-axes L1 >= L2 (then a and G_s too).

        G_s = mu shear_rate a / Ca_s, in the units of mu * shear_rate * (units of L1).
        """
        if D12 is None:
            if L1 is None or L2 is None or not (L1 > 0 and L2 > 0):
                return ShearFit(flag="need D12, or both semi-axes L1, L2 > 0")
            D12 = (L1 - L2) / (L1 + L2)
        if not np.isfinite(D12) or not 0 <= D12 < 1:
            return ShearFit(flag=f"invalid D12 = {D12}")
        if D12 < self.min_D12:
            return ShearFit(flag=f"D12 = {D12:.3f} below {self.min_D12}: too imprecise to fit (paper section 4.3)")
        lo, hi = self.D12_range
        if not lo <= D12 <= hi:
            return ShearFit(flag=f"outside the database: D12 = {D12:.3f} not in the steady range [{lo:.3f}, {hi:.3f}]")
        result = ShearFit(Ca_s=float(np.exp(self._log_ca(D12))), L3_over_a=float(self._l3(D12)),
                          database_error_rel=self._database_error(D12))
        if L1 is not None and L2 is not None:
            result.a = float(np.sqrt(L1 * L2 * result.L3_over_a))
            if shear_rate is not None and mu is not None:
                result.G_s = mu * shear_rate * result.a / result.Ca_s
        return result

    def _database_error(self, D12: float) -> float:
        """The relative error of Ca_s (hence G_s) at D12 from the rows' stated D12 errors: the
        database's D12 may be off by e D12 at this Ca_s, which moves the Ca_s read at the
        measured D12 by |d ln Ca_s / d D12| e D12."""
        if len(self._error) == 0 or not self._error_d12[0] <= D12 <= self._error_d12[-1]:
            return float("nan")
        e = float(np.interp(D12, self._error_d12, self._error))
        return float(abs(self._dlog_ca(D12)) * e * D12)

    def modulus(self, D12: float, a: float, shear_rate: float, mu: float) -> ShearFit:
        """G_s when the capsule radius a is known (the paper's section 4.3 example)."""
        result = self.fit(D12=D12)
        if result.ok:
            result.a = a
            result.G_s = mu * shear_rate * a / result.Ca_s
        return result


def profile_elongation(meridian: np.ndarray, a: float) -> float:
    """Mean profile elongation Delta = p / (2 pi a) (paper section 4.4): p is the perimeter of
    the profile in a plane through the axis, twice the meridian's arclength (pole to pole)."""
    meridian = np.asarray(meridian, dtype=float)
    arclength = np.sum(np.hypot(*np.diff(meridian, axis=0).T))
    return float(2 * arclength / (2 * np.pi * a))

