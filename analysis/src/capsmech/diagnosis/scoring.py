"""Scoring a batch under a candidate: every capsule's contour chi2 against its own noise level,
the candidate's strength fitted with leave-one-out cross-validation and the BIC (see
``capsmech.diagnosis.diagnose`` for the method)."""
from __future__ import annotations

import hashlib
import math
import weakref
from collections.abc import Callable, Sequence
from dataclasses import KW_ONLY, dataclass, field
from typing import Any

import numpy as np
from scipy import stats
from scipy.optimize import minimize_scalar

from capsmech.diagnosis.candidates import (
    EXTRAPOLATION,
    BlendedInverter,
    BlendedLaw,
    Candidate,
    DatabaseSet,
    extrapolation_range,
    level_inverter,
)
from capsmech.diagnosis.goodness import MODEL_FLOOR_REL, GoodnessOfFit
from capsmech.inversion.fitting import database_g_s_shifts
from capsmech.inversion.inverters import TubeInverter, profile_elongation
from capsmech.inversion.lengths import contour_lengths
from capsmech.inversion.noise import CHI2_POINTS, tracing_noise
from capsmech.inversion.population import law_drift
from capsmech.inversion.residuals import PreparedContour
from capsmech.inversion.shape_fit import OUTSIDE, best_profile, on_database_edge
from capsmech.inversion.sharp_edge import profile_floor
from capsmech.io.database import TubeDatabase
from capsmech.io.measurements import Capsule

#: Points of each capsule's residual profile in the score (the noise model's: ``capsmech.inversion.noise``).
PROFILE_POINTS = CHI2_POINTS
#: Refinement of a continuous candidate's strength: evaluations of the batch (each a refit of
#: every capsule) on each side of the best grid value, and tolerance as a fraction of a side.
REFINE_EVALUATIONS = 6
REFINE_XATOL = 0.01
#: Rise of the batch's chi2 over its minimum that bounds the profile interval (two sigma).
PROFILE_RISE = 4.0
#: BIC drop that counts as strong evidence (Kass & Raftery 1995: > 6).
MIN_BIC_DROP = 6.0
#: Significance of the cross-validated improvement (one-sided Wilcoxon signed-rank test).
CV_ALPHA = 0.05
#: Level of the G_s intervals (Student t on the capsules' mean).
G_S_LEVEL = 0.95



@dataclass
class BatchScore:
    """Per-capsule chi2, G_s, Delta, fitted (a/l, Ca_s) and residual profile [px] (on
    ``PROFILE_POINTS`` points of normalised arclength) of one contour fit of the batch (NaN: no fit)."""

    chi2: np.ndarray
    g_s: np.ndarray
    delta: np.ndarray
    a_over_l: np.ndarray = field(default_factory=lambda: np.empty(0))
    Ca_s: np.ndarray = field(default_factory=lambda: np.empty(0))
    residual: np.ndarray = field(default_factory=lambda: np.empty((0, PROFILE_POINTS)))
    #: The databases' accuracy [px] at the residual's points (``profile_floor`` of the fitted
    #: profile: 0.1 % of L_z, more behind a sharp parachute edge); empty when not computed.
    floor: np.ndarray = field(default_factory=lambda: np.empty((0, PROFILE_POINTS)))


@dataclass
class Evidence:
    """What the criteria say about one candidate on a batch, for tube and shear diagnoses alike.

    ``name`` is positional; the criteria are keyword-only (they follow any positional field a
    subclass adds)."""

    name: str
    _: KW_ONLY
    capsules: int = 0
    chi2_base: float = math.nan
    chi2: float = math.nan
    bic_drop: float = math.nan
    cv_gain: float = math.nan
    cv_gain_error: float = math.nan
    cv_p_value: float = math.nan
    supported: bool = False
    g_s_before: tuple[float, float] = (math.nan, math.nan)
    g_s_after: tuple[float, float] = (math.nan, math.nan)
    drift_p_before: float = math.nan
    drift_p_after: float = math.nan
    note: str = ""


@dataclass
class CandidateResult(Evidence):
    """The outcome of one candidate on a tube batch: its parameter, fitted value and interval."""

    parameter: str = ""
    unit: str = ""
    theta: float = math.nan
    law: str = ""
    interval: tuple[float, float] = (math.nan, math.nan)
    #: BIC drop on the capsules that every supported candidate fits (``compare_supported``),
    #: what the choice between supported candidates uses.
    bic_drop_common: float = math.nan
    #: The grid the workflow must run before the candidate can be assessed (see effect_grid).
    needs: dict | None = None
    after: BatchScore | None = field(default=None, repr=False)
    #: The strengths evaluated and the batch's chi2 at each (grid and refinement).
    profile: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)
    #: What the candidate at its fitted value leaves, tested against the noise
    #: (``capsmech.diagnosis.goodness``; set by ``diagnose``).
    fit: GoodnessOfFit | None = field(default=None, repr=False)
    #: G_s [N/m] by lengths (each capsule's lengths, measured on its contour, inverted:
    #: ``length_g_s``) before and after the candidate: (mean, standard deviation, capsules
    #: fitted), so that the change the candidate makes is also read on fit-tube's kind of number.
    g_s_lengths_before: tuple[float, float, int] = (math.nan, math.nan, 0)
    g_s_lengths_after: tuple[float, float, int] = (math.nan, math.nan, 0)
    #: The part of the interval's half-width that the databases' own accuracy contributes
    #: (``_systematic_half_width``; combined in quadrature with the statistical part).
    systematic: float = 0.0
    #: The systematic part [N/m] of the contour fits' G_s before and after (the databases'
    #: accuracy; after, also the strength's interval carried into G_s), combined in quadrature
    #: with the statistical part by ``capsmech.diagnosis.record.g_s_interval``.
    g_s_systematic: tuple[float, float] = (0.0, 0.0)
    #: The same for G_s by lengths (``g_s_lengths_before`` and ``g_s_lengths_after``).
    g_s_lengths_systematic: tuple[float, float] = (0.0, 0.0)
    #: The databases' accuracy's part of G_s by lengths before and after [N/m]
    #: (``length_g_s_with_systematic``; NaN when not measured).
    lengths_floor: list[float] = field(default_factory=lambda: [math.nan, math.nan], repr=False)
    #: Between the base law and the lowest level, the interpolation error: how far the strength
    #: moves with the other interpolant there (``_add_interpolation_error``; 0 elsewhere), that
    #: interpolant's estimate and chi2, and how far G_s after moves with it [N/m] by the contour
    #: fits and by lengths (in ``g_s_systematic`` and ``g_s_lengths_systematic``).
    interpolation: float = 0.0
    interpolation_theta: float = math.nan
    interpolation_chi2: float = math.nan
    g_s_interpolation: tuple[float, float] = (0.0, 0.0)
    #: Every strength at which each capsule the criteria use was fitted, with the batch's score.
    scores: dict[float, BatchScore] = field(default_factory=dict, repr=False)

    #: The candidate's values in order (for a model effect, the database levels it is blended
    #: between, the base law's 0 first) and whether the strength sits at an edge of them: ""
    #: (bracketed), "low", "high" or "base" (between the base law and the lowest level:
    #: ``edge_of_levels``).
    levels: tuple[float, ...] = ()
    edge: str = ""
    #: As the candidate's (``Candidate.acts_on``): "capsules" for a measurement effect, whose
    #: values are a search range rather than simulated levels.
    acts_on: str = "law"

    @property
    def discrete(self) -> bool:
        """A yes/no candidate (another law group: parameter ``group``), with no strength to fit."""
        return self.parameter == "group"




def contour_fit(prepared: PreparedContour, inverter: TubeInverter, tube_radius: float, start: tuple[float, float],
                sigma: float) -> tuple[float, float, float]:
    """(a/l, Ca_s, chi2): the database point whose profile best fits the contour (least
    squares of the residual profile over the noise level sigma, ``best_profile`` from ``start``).
    A tolerance of 0.05 in chi2 is far below the differences the criteria act on."""
    return best_profile(prepared, inverter, tube_radius, start, PROFILE_POINTS,
                        lambda distance: float(np.sum((distance / sigma) ** 2)), 0.05)


def _nearest_row(inverter: TubeInverter | BlendedInverter, L_z: float, L_p: float) -> dict[str, float]:
    """The database row nearest to the lengths (L_z, L_z - L_p), each scaled by its spread,
    among the rows where the law has a profile (a blend's levels need not share their nodes)."""
    t = inverter.table
    q = np.column_stack([t.L_z, t.L_z - t.L_p])
    order = np.argsort(np.sum(((q - [L_z, L_z - L_p]) / q.std(axis=0)) ** 2, axis=1))
    k = next((int(j) for j in order if inverter.profile(float(t.a_over_l[j]), float(t.Ca_s[j])) is not None),
             int(order[0]))
    return {"a_over_l": float(t.a_over_l[k]), "Ca_s": float(t.Ca_s[k])}


def _central_fits(capsules: Sequence[Capsule], inverter: TubeInverter) -> list[dict[str, float | bool]]:
    """The length-based central fit of each capsule (the start of its contour fit). Where the
    law reproduces no such lengths (an effect the law lacks can do that: pre-stressed capsules
    fitted with NH), the nearest database row in lengths: the contour fit needs a start, not a
    root, and dropping those capsules would hide the very effect sought."""
    rows = []
    for capsule in capsules:
        l = capsule["tube_radius"]
        L_z, L_p = capsule["L_z"] / l, capsule["L_p"] / l
        # (a blend of levels starts from a level's fit where the blend has none: ``start_fit``)
        fit = inverter.start_fit(L_z, L_p) if isinstance(inverter, BlendedInverter) else inverter.fit(L_z, L_p)
        if fit.ok:
            rows.append({"a_over_l": fit.a_over_l, "Ca_s": fit.Ca_s})
        elif math.isfinite(L_z) and math.isfinite(L_p):
            rows.append({**_nearest_row(inverter, L_z, L_p), "fallback": True})
        else:
            rows.append({"a_over_l": float("nan"), "Ca_s": float("nan")})
    return rows


#: Each contour's measured lengths, by the contour array's id with a weak reference to it (an
#: id is reused only once its array is gone): G_s by lengths is computed several times a
#: candidate on the same contours (the tube radius leaves them as they are), and measuring
#: them, a smooth fit about the contour's symmetry axis, was a tenth of a diagnosis's CPU.
_CONTOUR_LENGTHS: dict[int, tuple[weakref.ref, tuple[float, float]]] = {}


def _measured_lengths(contour: np.ndarray) -> tuple[float, float]:
    known = _CONTOUR_LENGTHS.get(id(contour))
    if known is not None and known[0]() is contour:
        return known[1]
    lengths = contour_lengths(contour)
    if len(_CONTOUR_LENGTHS) > 4096:
        for key in [key for key, (ref, _) in _CONTOUR_LENGTHS.items() if ref() is None]:
            del _CONTOUR_LENGTHS[key]
    _CONTOUR_LENGTHS[id(contour)] = (weakref.ref(contour), lengths)
    return lengths


def capsule_lengths(capsule: Capsule) -> tuple[float, float]:
    """(L_z, L_p) [m] of a capsule: measured on its contour by a smooth fit where it has one
    (``capsmech.inversion.lengths``: the extremes of noisy points are biased long), else the
    file's."""
    if capsule.contour is not None:
        L_z, L_p = _measured_lengths(capsule.contour)
        if math.isfinite(L_z):
            return L_z, L_p
    return capsule["L_z"], capsule["L_p"]


def length_g_s(capsules: Sequence[Capsule], inverter: TubeInverter | None) -> tuple[float, float, int]:
    """G_s [N/m] of a batch from each capsule's lengths inverted with ``inverter`` (its central
    fit), G_s = mu v_c / (Ca_s v_c/V): (mean, standard deviation, capsules fitted).

    The lengths are measured on the contour where there is one (``capsule_lengths``), so this
    can differ from ``fit-tube``'s G_s, which inverts the file's lengths. The contour fits'
    G_s (``BatchScore.g_s``) answers the same question from the whole contour and can differ by
    more than its spread: a report compares like with like."""
    return length_g_s_with_systematic(capsules, inverter)[0]


def length_g_s_with_systematic(capsules: Sequence[Capsule], inverter: TubeInverter | None
                               ) -> tuple[tuple[float, float, int], float]:
    """``length_g_s`` and its systematic half-width [N/m]: how far the databases' own accuracy
    moves the mean. Their lengths are good to ``MODEL_FLOOR_REL`` of L_z on smooth shapes, less
    at a sharp parachute edge (``capsmech.inversion.sharp_edge``), an error shared by every
    capsule that no number of capsules averages away: the mean's shift when L_z, then L_p, then
    v_c/V are moved by that much, added in quadrature (NaN with no G_s). Measured on the
    independent generator's control capsules (96 meridian elements, their true lengths): the
    mean G_s 0.8 % low; this half-width is about 2.5 %. No inverter (``lengths_inverter``): NaN."""
    if inverter is None:
        return (math.nan, math.nan, 0), math.nan
    values: list[float] = []
    shifts: tuple[list[float], ...] = ([], [], [])
    for capsule in capsules:
        l = capsule["tube_radius"]
        L_z, L_p = (length / l for length in capsule_lengths(capsule))
        fit = inverter.fit(L_z, L_p, capsule["v_c"], capsule["mu"])
        if not (fit.ok and math.isfinite(fit.G_s)):
            continue
        values.append(fit.G_s)
        for kept, shift in zip(shifts, database_g_s_shifts(inverter, L_z, L_p, capsule["v_c"], capsule["mu"], fit)):
            if math.isfinite(shift):
                kept.append(shift)
    g = np.array(values)
    if len(g) < 2:
        return (math.nan, math.nan, len(g)), math.nan
    systematic = math.hypot(*(float(np.mean(kept)) if kept else 0.0 for kept in shifts))
    return (float(g.mean()), float(g.std(ddof=1)), len(g)), systematic


def _law_inverter(database, law: str | BlendedLaw):
    # (a law key's inverter made once per database, its lengths fits remembered: every
    # candidate starts its contour fits from the same base-law fits)
    return law.inverter(database) if isinstance(law, BlendedLaw) else level_inverter(database, law)


def lengths_inverter(database, law: str | BlendedLaw) -> TubeInverter | None:
    """The inverter of G_s by lengths under ``law``: a blend's own rows (``blended_table``: the
    lengths of the law the contour fits use), else the law's; None where a blend's levels share
    too few nodes."""
    return law.lengths_inverter(database) if isinstance(law, BlendedLaw) else level_inverter(database, law)


#: Prepared contours (folded halves and their k-d trees) by content, at most ``PREPARED_KEPT``:
#: a measurement effect makes the same moved contours again at every model strength it is
#: refitted with, and folding one (its symmetry axis) costs as much as a few contour fits.
_PREPARED: dict[bytes, PreparedContour] = {}
PREPARED_KEPT = 512


def contour_key(contour: np.ndarray) -> bytes:
    """A digest of a contour's points (equal digests: the same points, bit for bit)."""
    points = np.ascontiguousarray(contour, dtype=float)
    return hashlib.blake2b(points.tobytes(), digest_size=16).digest() + str(points.shape).encode()


def prepared_contour(contour: np.ndarray) -> PreparedContour:
    """The contour folded about its axis (``PreparedContour``), made once per contour content."""
    key = contour_key(contour)
    prepared = _PREPARED.get(key)
    if prepared is None:
        prepared = PreparedContour(contour)
        if len(_PREPARED) >= PREPARED_KEPT:
            del _PREPARED[next(iter(_PREPARED))]
        _PREPARED[key] = prepared
    return prepared


@dataclass(frozen=True)
class _CapsuleScore:
    """One capsule's contour fit under one law, as ``BatchScore`` holds it (NaN: no fit)."""

    chi2: float
    g_s: float = math.nan
    delta: float = math.nan
    a_over_l: float = math.nan
    Ca_s: float = math.nan
    residual: np.ndarray | None = None
    floor: np.ndarray | None = None


#: Each database's capsule scores by law, contour, capsule values, start and noise level, at
#: most ``SCORES_KEPT`` per database: a diagnosis asks for the same fit again (a measurement
#: effect's best model strength is scored by its search, then by the round's grid), and a
#: fit is a deterministic function of these, so that a remembered one is the same bit for bit.
_SCORES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
SCORES_KEPT = 20000


def _law_key(law: str | BlendedLaw) -> tuple:
    return (law,) if isinstance(law, str) else (tuple(law.keys), tuple(law.weights))


def _score_capsule(capsule: Capsule, contour: PreparedContour, inverter: Any, start: tuple[float, float],
                   sigma: float) -> _CapsuleScore:
    """Fit one capsule's contour from ``start`` (``contour_fit``): chi2, G_s, Delta, the fitted
    point, the residual profile and the databases' accuracy there [px]. ``inverter``: the law's
    (a ``TubeInverter``, or a ``BlendedInverter`` with its interface)."""
    l = capsule["tube_radius"]
    a_over_l, ca, chi2 = contour_fit(contour, inverter, l, start, sigma)
    if chi2 >= OUTSIDE or on_database_edge(inverter, a_over_l, ca):
        return _CapsuleScore(math.nan)
    g_s = math.nan
    velocity = inverter.velocity_ratio(a_over_l, ca)
    if math.isfinite(capsule["v_c"]) and math.isfinite(capsule["mu"]) and velocity > 0:
        g_s = capsule["mu"] * capsule["v_c"] / (ca * velocity)
    meridian = inverter.profile(a_over_l, ca)
    if meridian is None:
        return _CapsuleScore(chi2, g_s, a_over_l=a_over_l, Ca_s=ca)
    pixel = capsule["pixel_size"] if math.isfinite(capsule["pixel_size"]) else 1.0
    residual = contour.residual(meridian * l, points=PROFILE_POINTS)[1] / pixel
    floor = profile_floor(meridian * l, capsule["L_z"], PROFILE_POINTS, l) / pixel
    return _CapsuleScore(chi2, g_s, profile_elongation(meridian, a_over_l), a_over_l, ca, residual, floor)


def score_batch(capsules: Sequence[Capsule], database: TubeDatabase | DatabaseSet, law: str | BlendedLaw, sigma: np.ndarray,
                prepared: Sequence[PreparedContour] | None = None, starts: BatchScore | None = None,
                only: Sequence[int] | None = None, stop_on_failure: bool = False) -> BatchScore:
    """Fit every capsule's contour with one law (a key or a BlendedLaw); chi2, G_s and Delta per
    capsule. A capsule whose lengths the law cannot reproduce starts from its fit in ``starts``
    (the base fit), else from the database row nearest in lengths.

    ``only``: the indices of the capsules to fit, in this order (the others are left NaN);
    ``stop_on_failure``: stop at the first of them not fitted (the rest left NaN), for a caller
    that needs all or nothing. Each capsule's fit is that of the whole batch's, bit for bit:
    it depends on nothing but the capsule, the law, its start and its noise level."""
    inverter = _law_inverter(database, law)
    order = list(range(len(capsules))) if only is None else [int(i) for i in only]
    rows = dict(zip(order, _central_fits([capsules[i] for i in order], inverter)))
    if starts is not None:
        for i, row in rows.items():
            # (a start the law does not cover would leave the contour fit outside: no fit)
            if (row.get("fallback") and math.isfinite(starts.a_over_l[i])
                    and inverter.profile(float(starts.a_over_l[i]), float(starts.Ca_s[i])) is not None):
                row.update(a_over_l=float(starts.a_over_l[i]), Ca_s=float(starts.Ca_s[i]))
    n = len(capsules)
    chi2, g_s, delta = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    fitted_a, fitted_ca = np.full(n, np.nan), np.full(n, np.nan)
    residual = np.full((n, PROFILE_POINTS), np.nan)
    floor = np.full((n, PROFILE_POINTS), np.nan)
    known = _SCORES.setdefault(database, {})
    law_key = _law_key(law)
    for i, row in rows.items():
        capsule = capsules[i]
        if capsule.contour is None or not math.isfinite(row["a_over_l"]) or not math.isfinite(sigma[i]):
            if stop_on_failure:
                break
            continue
        start = (row["a_over_l"], row["Ca_s"])
        key = (law_key, contour_key(capsule.contour), start, float(sigma[i]),
               *(float(capsule[name]) for name in ("tube_radius", "v_c", "mu", "pixel_size", "L_z")))
        score = known.get(key)
        if score is None:
            contour = prepared[i] if prepared is not None else prepared_contour(capsule.contour)
            score = _score_capsule(capsule, contour, inverter, start, sigma[i])
            if len(known) >= SCORES_KEPT:
                del known[next(iter(known))]
            known[key] = score
        chi2[i], g_s[i], delta[i] = score.chi2, score.g_s, score.delta
        if score.residual is not None and score.floor is not None:
            residual[i], floor[i] = score.residual, score.floor
        fitted_a[i], fitted_ca[i] = score.a_over_l, score.Ca_s
        if stop_on_failure and not math.isfinite(score.chi2):
            break
    return BatchScore(chi2, g_s, delta, fitted_a, fitted_ca, residual, floor)


def noise_levels(capsules: Sequence[Capsule], database: TubeDatabase | DatabaseSet,
                 law: str | BlendedLaw) -> np.ndarray:
    """Each capsule's tracing-noise level: the rms over the meridian of the half difference of
    its contour's two halves (the standard error of the mean residual at a point), measured
    against its length-based fit; or, where larger, the noise measured across the video
    frames (the measurement's ``contour_noise``; ``capsmech.inversion.noise.tracing_noise``)."""
    inverter = _law_inverter(database, law)
    rows = _central_fits(capsules, inverter)
    sigma = np.full(len(capsules), np.nan)
    for i, (capsule, row) in enumerate(zip(capsules, rows)):
        if capsule.contour is None or not math.isfinite(row["a_over_l"]):
            continue
        meridian = inverter.profile(row["a_over_l"], row["Ca_s"])
        if meridian is None:
            continue
        sigma[i] = tracing_noise(prepared_contour(capsule.contour), meridian * capsule["tube_radius"],
                                 capsule["contour_noise"])
    return sigma


def _window_minimum(x: np.ndarray, y: np.ndarray, on_grid: np.ndarray) -> float:
    """Minimum of the least-squares parabola through every point of y(x) between the grid
    neighbours of the lowest grid point (refined points included; the grid's own spacing keeps
    the fit well posed); the lowest grid point itself at the grid's ends."""
    xg, yg = x[on_grid], y[on_grid]
    k = int(np.nanargmin(yg))
    if k == 0 or k == len(xg) - 1:
        return float(xg[k])
    low, high = xg[k - 1], xg[k + 1]
    window = (x >= low) & (x <= high) & np.isfinite(y)
    a, b, _ = np.polyfit(x[window], y[window], 2)
    if a <= 0:
        return float(x[window][np.argmin(y[window])])
    return float(np.clip(-b / (2 * a), low, high))


def _g_s_summary(score: BatchScore, keep: np.ndarray) -> tuple[tuple[float, float], float]:
    g = score.g_s[keep]
    g = g[np.isfinite(g)]
    summary = (float(np.mean(g)), float(np.std(g, ddof=1))) if len(g) > 1 else (math.nan, math.nan)
    p = math.nan
    finite = keep & np.isfinite(score.g_s) & np.isfinite(score.delta)
    if finite.sum() >= 3 and np.ptp(score.delta[finite]) > 0:
        p = law_drift("batch", score.delta[finite], score.g_s[finite]).p_value
    return summary, p


def _extend_beyond_levels(candidate: Candidate, grid: dict[float, BatchScore], usable: np.ndarray,
                          evaluate: Callable[[float], BatchScore]) -> None:
    """While the batch's chi2 is lowest at an end of the values evaluated, evaluate the strength
    ``EXTRAPOLATION`` of the outer spacing beyond it, within the ``extrapolation_range``, and add
    it to ``grid`` (when every usable capsule is fitted there): the minimum can then lie beyond
    the levels instead of being pinned at the last one (Skalak C = 10 was read as 8 [6.8, 9.2]
    with the levels 1-8)."""
    values = sorted(candidate.values)
    steps = (EXTRAPOLATION * (values[1] - values[0]), EXTRAPOLATION * (values[-1] - values[-2]))
    low_end, high_end = extrapolation_range(candidate)
    while True:
        values = sorted(grid)
        k = int(np.argmin([grid[v].chi2[usable].sum() for v in values]))
        if k == 0 and values[0] > low_end + 1e-9 * steps[0]:
            beyond = max(values[0] - steps[0], low_end)
        elif k == len(values) - 1 and values[-1] < high_end - 1e-9 * steps[1]:
            beyond = min(values[-1] + steps[1], high_end)
        else:
            return
        score = evaluate(beyond)
        if not np.all(np.isfinite(score.chi2[usable])):
            return
        grid[round(beyond, 12)] = score


def _refine(grid: dict[float, BatchScore], usable: np.ndarray, evaluate: Callable[[float], BatchScore],
            refine_evaluations: int) -> np.ndarray:
    """Refine the strength: a bounded 1D minimisation of the batch's chi2 on each side of the
    lowest grid point, up to its grid neighbours; returns the capsules the criteria use.

    Every evaluation is kept (``evaluate`` caches them), so that the minimum chi2 the criteria
    compare is computed, not extrapolated (a parabola through three grid points misplaces a
    sharp minimum: on the pre-stress batches by 20-40 % of the level spacing). Each side is
    searched separately: a blended law is piecewise in the strength, kinked at the levels, and
    one search across the kink stays on one side.

    A blend of two levels has a profile only where both levels have nodes, so a capsule fitted
    at both levels can be left unfitted between them; a strength where a usable capsule is not
    fitted is never the minimum, which pinned the strength at a level (pre-stress 0.03 read as
    0.04 or 0.02). Such capsules are then left out and the search repeated, once, when at
    least three quarters of the usable capsules remain."""
    for _ in range(2):
        failed = _search_sides(grid, usable, evaluate, refine_evaluations)
        kept = usable & ~failed
        if not failed.any() or kept.sum() < max(3, 0.75 * usable.sum()):
            return usable
        usable = kept
    return usable


def _search_sides(grid: dict[float, BatchScore], usable: np.ndarray, evaluate: Callable[[float], BatchScore],
                  refine_evaluations: int) -> np.ndarray:
    """One search of ``_refine`` (both sides of the lowest grid point); returns the usable
    capsules left unfitted at some strength it evaluated."""
    failed = np.zeros_like(usable)

    def batch_chi2(theta: float) -> float:
        chi2 = evaluate(float(theta)).chi2
        missing = usable & ~np.isfinite(chi2)
        if missing.any():
            failed[missing] = True
            return 1e30
        return float(chi2[usable].sum())

    values = np.array(sorted(grid))
    k = int(np.argmin([grid[v].chi2[usable].sum() for v in values]))
    low, high = values[max(k - 1, 0)], values[min(k + 1, len(values) - 1)]
    for side in ((low, values[k]), (values[k], high)):
        if side[1] > side[0]:
            minimize_scalar(batch_chi2, bounds=side, method="bounded",
                            options={"xatol": REFINE_XATOL * (side[1] - side[0]), "maxiter": refine_evaluations})
    return failed


def evaluate_candidate(candidate: Candidate, capsules: Sequence[Capsule], database: TubeDatabase | DatabaseSet,
                       base_law: str | BlendedLaw,
                       sigma: np.ndarray, base: BatchScore, prepared: Sequence[PreparedContour],
                       refine_evaluations: int = REFINE_EVALUATIONS) -> CandidateResult:
    """Refit the batch over the candidate's grid; fit theta (refined with at most
    ``refine_evaluations`` refits on each side of the best grid value), its interval, the criteria.

    A supported model effect's strength between the base law and the lowest level (edge
    "base") is fitted a second time with the other interpolant there
    (``Candidate.near_base_alternative``: the quadratic through the base law and the two lowest
    levels), and the interval holds both estimates (``_add_interpolation_error``). Only where
    supported: on a batch without the effect its strength lies near the base law, and the
    second fit would cost a tenth of the diagnosis for an interval no verdict reports."""
    result, evaluated, usable = _evaluate(candidate, capsules, database, base_law, sigma, base, prepared,
                                          refine_evaluations)
    if result.note:
        return result
    alternative = candidate.near_base_alternative
    if result.edge == "base" and result.supported and alternative is not None:
        # Outside the segment between the base law and the lowest level both laws are the same.
        segment = (min(candidate.values), sorted(candidate.values)[1])
        same = {v: s for v, s in evaluated.items() if not segment[0] < v < segment[1]}
        # (each interpolant's search can leave out a few capsules it cannot fit: the difference
        # is then also that of their capsules, which only widens the interval)
        other, _, _ = _evaluate(alternative, capsules, database, base_law, sigma, base, prepared,
                                refine_evaluations, known=same,
                                lengths_before=(result.g_s_lengths_before, result.lengths_floor[0]))
        if not other.note:
            _add_interpolation_error(result, other)
    _g_s_systematic(result, candidate, capsules, database, base_law, usable)
    return result


def _add_interpolation_error(result: CandidateResult, other: CandidateResult) -> None:
    """Widen ``result``'s strength and G_s intervals by the interpolation error: the difference
    of the two interpolants' estimates, added in quadrature to each interval, and the strength's
    interval made to hold the other interpolant's (so widened) too.

    Between the base law and the lowest level the linear blend is the least accurate (pre-stress
    removes the parachute there). Measured on the independent generator's alpha = 0.03 batches
    with the shipped levels 0.04-0.08: the linear blend read 0.0307-0.0364, the quadratic
    through alpha 0, 0.04, 0.06 0.0282-0.0334 (its chi2 lower by 20-90 on 8-14 capsules), and
    the linear blend's interval alone missed 0.03 on a third of the batches."""
    difference = abs(result.theta - other.theta)
    if not math.isfinite(difference):
        return

    def widened(r: CandidateResult) -> tuple[float, float]:
        return (r.theta - math.hypot(r.theta - r.interval[0], difference),
                r.theta + math.hypot(r.interval[1] - r.theta, difference))

    own, others = widened(result), widened(other)
    result.interval = (min(own[0], others[0]), max(own[1], others[1]))
    result.interpolation = difference
    result.interpolation_theta = other.theta
    result.interpolation_chi2 = other.chi2
    contour = abs(result.g_s_after[0] - other.g_s_after[0])
    lengths = abs(result.g_s_lengths_after[0] - other.g_s_lengths_after[0])
    result.g_s_interpolation = (contour if math.isfinite(contour) else 0.0, lengths if math.isfinite(lengths) else 0.0)


def _evaluate(candidate: Candidate, capsules: Sequence[Capsule], database: TubeDatabase | DatabaseSet,
              base_law: str | BlendedLaw, sigma: np.ndarray, base: BatchScore, prepared: Sequence[PreparedContour],
              refine_evaluations: int, known: dict[float, BatchScore] | None = None,
              lengths_before: tuple[tuple[float, float, int], float] | None = None
              ) -> tuple[CandidateResult, dict[float, BatchScore], np.ndarray]:
    """``evaluate_candidate`` without the systematic part of G_s's intervals: the result, every
    strength evaluated with its score, and the capsules the criteria use. ``known``: scores
    already made at some strengths (the candidate's law there is the same), not refitted;
    ``lengths_before``: G_s by lengths under the base law and its systematic part, when known."""
    result = CandidateResult(candidate.name, candidate.parameter, candidate.unit)
    values = np.array(candidate.values, dtype=float)
    known = known or {}

    def refit(value: float) -> BatchScore:
        key = round(float(value), 12)
        if key in known:
            return known[key]
        changed, law = candidate.apply(capsules, value)
        # Contours the candidate leaves alone keep their prepared halves.
        same = all(c.contour is o.contour for c, o in zip(changed, capsules))
        return score_batch(changed, database, law, sigma, prepared if same else None, starts=base)

    grid = {float(value): base if value == candidate.neutral else refit(float(value)) for value in values}
    usable = np.all([np.isfinite(score.chi2) for score in grid.values()], axis=0) & np.isfinite(base.chi2)
    if usable.sum() < 3:
        result.note = f"only {int(usable.sum())} capsules fitted at every {candidate.parameter}: not assessed"
        return result, {}, usable
    off_grid: dict[float, BatchScore] = {}

    def evaluate(theta: float) -> BatchScore:
        key = round(float(theta), 12)
        if key not in off_grid:
            off_grid[key] = refit(key)
        return off_grid[key]

    if candidate.continuous and refine_evaluations > 0:
        _extend_beyond_levels(candidate, grid, usable, evaluate)
        usable = _refine(grid, usable, evaluate, refine_evaluations)
    result.capsules = int(usable.sum())
    # Every strength evaluated at which each usable capsule was fitted, in order.
    points = {**{v: s for v, s in off_grid.items() if np.all(np.isfinite(s.chi2[usable]))}, **grid}
    values = np.array(sorted(points))
    scores = [points[v] for v in values]
    table = np.array([score.chi2[usable] for score in scores])   # (values, capsules)
    grid_values = np.array(sorted(grid))
    total = table.sum(axis=1)
    k = int(np.argmin(total))
    theta, chi2_min = float(values[k]), float(total[k])
    result.theta, result.chi2 = theta, chi2_min
    result.chi2_base = float(base.chi2[usable].sum())
    n_points = result.capsules * PROFILE_POINTS
    result.bic_drop = float(result.chi2_base - chi2_min - math.log(n_points))
    # Leave one capsule out: theta from the others, scored on the one left out. Theta comes
    # from a least-squares parabola over the grid window around the minimum: a parabola
    # through the three lowest points only would pass through the refinement's points, so
    # close to the batch's minimum that every theta_i would be pinned there.
    on_grid = np.isin(values, grid_values)
    gain_list, theta_list = [], []
    for i in range(result.capsules):
        others = total - table[:, i]
        theta_i = _window_minimum(values, others, on_grid)
        theta_list.append(theta_i)
        held_out = float(np.interp(theta_i, values, table[:, i]))
        gain_list.append(float(base.chi2[usable][i]) - held_out)
    gains, thetas = np.array(gain_list), np.array(theta_list)
    # The interval holds two things: the scatter between capsules (two jackknife standard
    # errors of the leave-one-out fits; model error included, which a chi2 rise alone would
    # not see) and the flatness of the batch's chi2 around its minimum (every evaluated
    # strength within a rise of 4, i.e. two standard deviations, scaled by the reduced chi2
    # when above 1). Either alone was too narrow on the pre-stress batch: the contour fits
    # make the chi2 rough by a few units along a flat valley.
    n = len(thetas)
    jackknife = math.sqrt((n - 1) / n * np.sum((thetas - thetas.mean()) ** 2))
    rise = PROFILE_RISE * max(1.0, chi2_min / (result.capsules * PROFILE_POINTS))
    flat = values[total <= chi2_min + rise]
    result.profile = (values, total)
    statistical = (min(theta - 2 * jackknife, float(flat.min())), max(theta + 2 * jackknife, float(flat.max())))
    # Systematic: the databases' own profiles are accurate to MODEL_FLOOR_REL of a capsule's
    # length, an error shared by every capsule that no number of capsules averages away. At
    # worst it lies along the candidate's signature (how far the residual moves per unit of the
    # strength, after each capsule's refit), and moves the strength by floor / signature; it is
    # added in quadrature to each side. Measured without it on batches of an independent
    # generator (96-element capsules): strength intervals held the truth in 8-74 % of the
    # batches, the estimates biased by about floor / signature (offset +0.2 px, radius +0.002).
    systematic = _systematic_half_width(capsules, values, scores, usable, on_grid, theta)
    result.interval = (theta - math.hypot(theta - statistical[0], systematic),
                       theta + math.hypot(statistical[1] - theta, systematic))
    result.systematic = systematic
    result.acts_on = candidate.acts_on
    if candidate.continuous:
        result.levels = tuple(sorted(float(v) for v in candidate.values))
        result.edge = edge_of_levels(candidate, theta, result.interval)
    result.cv_gain = float(gains.mean())
    result.cv_gain_error = float(gains.std(ddof=1) / np.sqrt(n))
    # Paired, one-sided: do held-out capsules fit better? (Wilcoxon: the gains are far from normal.)
    p_value = float(stats.wilcoxon(gains, alternative="greater").pvalue) if np.any(gains != 0) else 1.0
    result.cv_p_value = p_value
    result.supported = bool(p_value < CV_ALPHA and result.bic_drop > MIN_BIC_DROP)
    # theta is a point of the table: its score is there already.
    after = scores[k]
    changed, law = candidate.apply(capsules, theta)
    result.law = str(law)
    result.after = after
    result.g_s_before, result.drift_p_before = _g_s_summary(base, usable)
    result.g_s_after, result.drift_p_after = _g_s_summary(after, usable)
    result.g_s_lengths_before, result.lengths_floor[0] = lengths_before or length_g_s_with_systematic(
        capsules, lengths_inverter(database, base_law))
    result.g_s_lengths_after, result.lengths_floor[1] = length_g_s_with_systematic(changed, lengths_inverter(database, law))
    result.scores = dict(zip(values, scores))
    return result, {**grid, **off_grid}, usable


def _g_s_systematic(result: CandidateResult, candidate: Candidate, capsules: Sequence[Capsule],
                    database: TubeDatabase | DatabaseSet, base_law: str | BlendedLaw, usable: np.ndarray) -> None:
    """The systematic parts of G_s's intervals before and after (``CandidateResult.g_s_systematic``).

    G_s after the candidate is computed at the fitted strength, which is itself uncertain:
    its interval carries into G_s (half the change of G_s across the strength's interval),
    beside the databases' own accuracy (``length_g_s_with_systematic``, for both estimators:
    the contour fits match the same profiles) and, near the base law, the interpolation error
    (``_add_interpolation_error``). Measured on the independent generator's batches, G_s by the
    contour fits held the truth in 40-88 % of them without the first two, in 64 of 64 with both
    (docs/validation/diagnosis.md)."""
    values = np.array(sorted(result.scores))
    scores = [result.scores[v] for v in values]
    floor_before, floor_after = (float(np.nan_to_num(v)) for v in result.lengths_floor)
    lengths_change = contour_change = 0.0
    ends = np.clip(result.interval, values.min(), values.max())
    if not result.discrete and np.all(np.isfinite(ends)):
        apply = candidate.apply_between or candidate.apply
        lengths_change = _half_change([length_g_s(c, lengths_inverter(database, law))[0]
                                       for c, law in (apply(capsules, float(end)) for end in ends)])
        means = np.array([np.mean(g[np.isfinite(g)]) if np.any(np.isfinite(g)) else np.nan
                          for g in (score.g_s[usable] for score in scores)])
        known = np.isfinite(means)
        if known.sum() > 1:
            contour_change = _half_change(np.interp(ends, values[known], means[known]))
    contour_interpolation, lengths_interpolation = result.g_s_interpolation
    result.g_s_lengths_systematic = (floor_before, math.hypot(floor_after, lengths_change, lengths_interpolation))
    result.g_s_systematic = (floor_before, math.hypot(floor_after, contour_change, contour_interpolation))


def edge_of_levels(candidate: Candidate, theta: float, interval: tuple[float, float]) -> str:
    """Whether a strength sits at an edge of the candidate's values: "high" when the estimate is
    at or beyond the highest value or (a model effect) its interval reaches past it, "low"
    likewise at the lowest, "base" when a model effect's estimate lies between the base law
    (its neutral value, a physical limit) and the lowest simulated level, "" when the levels
    bracket it.

    Beyond a model effect's levels the law is extrapolated, so its interval must lie within
    them. Between the base law and the lowest level the blend is the least accurate (pre-stress
    removes the parachute there: the blend of alpha 0 and 0.04 misses the kernel's 0.02 shape
    by 1.2-5.3 px where the blend of 0.04 and 0.08 misses 0.06 by 0.3-1.9 px, at l = 100 px),
    and alpha = 0.03 read 0.0315-0.0364 on three batches, two intervals missing it. A
    measurement effect is exact at any value (its values are only where the search starts), so
    only its estimate counts. An end that is a physical limit (``Candidate.limits``) is no edge."""
    values = sorted(candidate.values)
    tolerance = 1e-6 * (values[-1] - values[0])
    model = candidate.acts_on == "law"
    high = theta >= values[-1] - tolerance or (model and interval[1] > values[-1])
    low = theta <= values[0] + tolerance or (model and interval[0] < values[0])
    if values[-1] < candidate.limits[1] and high:
        return "high"
    if values[0] > candidate.limits[0] and low:
        return "low"
    if model and values[0] == candidate.neutral == candidate.limits[0] and theta < values[1] - tolerance:
        return "base"
    return ""


def g_s_half_width(sd: float, n: int, systematic: float = 0.0, level: float = G_S_LEVEL) -> float:
    """Half-width [N/m] of the interval of a mean G_s over n capsules: the Student-t half-width
    of their scatter (standard deviation ``sd``) and the ``systematic`` half-width (the
    databases' accuracy, and the uncertainty of an effect's strength G_s was computed at)
    added in quadrature, as for the strengths' intervals. NaN with fewer than 2 capsules."""
    if n < 2 or not math.isfinite(sd):
        return math.nan
    statistical = float(stats.t.ppf(0.5 + level / 2, n - 1)) * sd / math.sqrt(n)
    return math.hypot(statistical, float(systematic) if math.isfinite(systematic) else 0.0)


def _half_change(ends: Sequence[float]) -> float:
    """Half the change of G_s between the strength's interval ends (0 where either is unknown)."""
    change = 0.5 * abs(float(ends[1]) - float(ends[0]))
    return change if math.isfinite(change) else 0.0


def _systematic_half_width(capsules: Sequence[Capsule], values: np.ndarray, scores: Sequence[BatchScore],
                           usable: np.ndarray, on_grid: np.ndarray, theta: float) -> float:
    """How far the databases' own accuracy moves the strength: that error over the candidate's
    signature, the rms over the usable capsules and profile points of d(residual)/d(strength)
    [px per unit] between the grid values around ``theta`` (grid values, not the refinement's:
    their spacing keeps the contour fits' own tolerance out of the slope). The error is an
    error pattern along the signature with the databases' accuracy at each point
    (``BatchScore.floor``: ``MODEL_FLOOR_REL`` of the capsule's length, more behind a sharp
    parachute edge), i.e. the floor averaged with the signature's squares as weights; without
    floors, ``MODEL_FLOOR_REL`` of the capsules' median length [px]. 0 when it cannot be
    measured (no pixel size, one value)."""
    grid = np.flatnonzero(on_grid)
    below, above = grid[values[grid] <= theta], grid[values[grid] > theta]
    low = int(below[-1]) if len(below) else int(grid[0])
    high = int(above[0]) if len(above) else int(grid[-1])
    if high == low:
        low = int(grid[max(int(np.searchsorted(grid, low)) - 1, 0)])
    if high == low or values[high] == values[low]:
        return 0.0
    slope = (scores[high].residual[usable] - scores[low].residual[usable]) / (values[high] - values[low])
    signature = float(np.sqrt(np.nanmean(slope ** 2))) if np.any(np.isfinite(slope)) else math.nan
    lengths = [c["L_z"] / c["pixel_size"] for c, keep in zip(capsules, usable) if keep and math.isfinite(c["pixel_size"])]
    if not lengths or not math.isfinite(signature) or signature <= 0:
        return 0.0
    floor = MODEL_FLOOR_REL * float(np.median(lengths))
    floors = scores[high].floor
    if floors.shape == scores[high].residual.shape:
        weight = np.where(np.isfinite(slope) & np.isfinite(floors[usable]), slope ** 2, 0.0)
        if weight.sum() > 0:
            floor = float(np.sum(weight * np.nan_to_num(floors[usable])) / weight.sum())
    return floor / signature


def rivals_of(chosen, results: Sequence, drop: Callable[[Any], float] = lambda r: r.bic_drop) -> list:
    """The supported results whose BIC drop (``drop``) is within MIN_BIC_DROP of the chosen one's."""
    if chosen is None:
        return []
    return [r for r in results if r.supported and r is not chosen and drop(chosen) - drop(r) < MIN_BIC_DROP]


def capsules_prefer(chosen: CandidateResult, other: CandidateResult) -> bool:
    """Whether the capsules prefer ``chosen`` to ``other`` one by one: its contour chi2 at its
    fitted value is lower on the capsules both fit, consistently (one-sided Wilcoxon signed-rank
    test, p < CV_ALPHA). A BIC difference alone can come from a few capsules: an undeclared
    contour offset of 1 and 2.2 px was named a tube-radius error by 2.4 and 7.1 units of chi2
    (Wilcoxon p 0.45 and 0.20), two effects that scale a near-spherical contour alike."""
    if chosen.after is None or other.after is None:
        return False
    a, b = chosen.after.chi2, other.after.chi2
    common = np.isfinite(a) & np.isfinite(b)
    differences = b[common] - a[common]
    if common.sum() < 3 or not np.any(differences != 0):
        return False
    return bool(stats.wilcoxon(differences, alternative="greater").pvalue < CV_ALPHA)


def compare_supported(results: Sequence[CandidateResult], base: BatchScore) -> CandidateResult | None:
    """Set ``bic_drop_common`` of the supported results and return the one with the largest.

    Each candidate's own BIC drop is over the capsules it fits at every value it tried, and
    those sets differ (an effect database covers less than the base one): comparing drops over
    different data favours the candidate that fits more capsules, not the better model. On
    the two-effect batch the bending candidate won that way (26352 over 23 capsules) against
    pre-stress (22451 over 21), whose chi2 on the common capsules is 468 against bending's 1764.
    The choice is made on the capsules every supported candidate fits, at its fitted value."""
    supported = [(r, r.after) for r in results if r.supported and r.after is not None]
    if not supported:
        return None
    common = np.isfinite(base.chi2)
    for _, after in supported:
        common &= np.isfinite(after.chi2)
    n_points = max(int(common.sum()), 1) * PROFILE_POINTS
    for r, after in supported:
        r.bic_drop_common = float(np.sum(base.chi2[common] - after.chi2[common]) - math.log(n_points))
    return max((r for r, _ in supported), key=lambda r: r.bic_drop_common)

