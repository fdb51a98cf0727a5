"""Close the loop (issue 7): which effect the base model lacks, from what the fits leave.

For a batch fitted with a base law, each candidate effect adds one parameter theta (shared
by the batch) to the forward model. The batch is refitted over a grid of theta, and every
capsule's contour residual (``capsmech.residuals.profile_residual``) is scored by

    chi2_i(theta) = sum over PROFILE_POINTS points of (d(s) / sigma_i)**2,

sigma_i the capsule's own noise level, measured once on the base fit from the disagreement
of its contour's two halves (independent tracing errors; ``ProfileResidual.error``). The
points are few enough (16 along the meridian, ~20 px apart on a 90 px capsule) to be nearly
independent.

A candidate is **supported** when both
- leave-one-capsule-out cross-validation improves: theta fitted on the other capsules
  lowers the held-out capsules' chi2 (one-sided Wilcoxon signed-rank test across
  capsules, p < 0.05); and
- the Bayesian information criterion falls by more than ``MIN_BIC_DROP`` (strong evidence),
  counting one parameter.
The supported candidate with the largest BIC drop is reported, with theta and its interval
(two jackknife standard errors from the leave-one-out fits, widened to every strength whose
chi2 is within a rise of 4 of the minimum), and G_s before and after. When no
candidate is supported, the residual is within noise: that is a valid answer.

Candidates
----------
Measurement effects need no new simulation:
- ``contour_offset`` (pixels): the traced line lies delta outside the membrane (e.g. the
  dark line's outer edge instead of its middle); the contour is moved in by delta along its
  normals and L_z shortened by 2 delta.
- ``tube_radius`` (relative): the capillary's radius is l (1 + eps), not the nominal l.
Model effects come from the database: every other law group (another law or nu_s, or a
law key with an effect such as ``NH+prestress0.05``) is a candidate with its group as the
one discrete parameter.
- ``prestress`` (alpha) and ``kb`` (bending stiffness k_b), continuous: the groups
  ``<base>+prestress<alpha>`` and ``<base>+kb<k_b>`` of effect databases
  (``capsmech.effect_grid``) at a few levels, the base law being 0. Between two levels the
  law is their blend (profiles and velocity ratio linear in the strength at the same a/l and
  Ca_s, ``BlendedLaw``), so the batch is refitted at any strength like the other continuous
  candidates.
- ``viscosity ratio`` is not a candidate for tube batches: a steady capsule translates as a
  rigid body, its inner fluid with it, so lambda drops out of every steady observable (the
  kernel reproduces the lambda = 1 shape to 6e-8 at lambda 0.2 and 5); it acts on the shear
  method (``capsmech.shear_diagnose``: ``capsmech diagnose-shear``). ``NOT_ASSESSED``
  says so in every report.
- ``off-centre position`` is not a batch effect: each capsule has its own offset b. Its
  first-order signature, an up-down asymmetric contour, is what the inversion flags; such
  capsules are left out of the batch's diagnosis (``screen_asymmetric``) and, given an
  off-centre table (``capsmech.offcentre``: the 3D kernel's antisymmetric mode over a/l
  0.7-0.85), each is fitted with its own b (linear least squares of its contour's
  antisymmetric part), its lengths corrected by the second-order elongation c b**2 before
  (a/l, Ca_s) and G_s are refitted (``fit_offcentre``; reported apart from the batch's
  candidates). A capsule released off the axis centres itself (by a factor e every 2-3 l of
  travel at a/l 0.75-0.85, 9 l at 0.7, 26 l at 0.6), so the capsules the method is made for
  (a/l >~ 0.85) are mostly centred where they are imaged.
A candidate whose law groups the databases lack is not guessed: it is reported as "not
assessed: needs simulations", with the grid the workflow must run (``needs``).
"""
from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import KW_ONLY, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from scipy import stats
from scipy.optimize import minimize, minimize_scalar

from capsmech.contours import contour_asymmetry
from capsmech.database import TubeDatabase
from capsmech.fitting import tube_inverter
from capsmech.inverse import TubeInverter, profile_elongation
from capsmech.measurements import Capsule
from capsmech.population import law_drift
from capsmech.residuals import PreparedContour

#: Effects of the library diagnose does not fit on tube batches, and why (in every report).
NOT_ASSESSED: dict[str, str] = {
    "viscosity ratio": "not identifiable: a steady capsule moves as a rigid body with its inner fluid, so lambda "
                       "leaves its shape and velocity unchanged (kernel: lambda 0.2 and 5 reproduce lambda = 1 to "
                       "6e-8); it acts on the shear method: capsmech diagnose-shear tests it on Couette batches",
    "off-centre position": "not a batch effect (each capsule has its own): an off-centre capsule's contour is up-down "
                           "asymmetric (3D kernel: 0.04-0.07 a at 0.02-0.07 l off the axis), so such capsules are "
                           "screened out of the batch (screen_asymmetric) and, with the off-centre table "
                           "(capsmech.offcentre, a/l 0.7-0.85), each is fitted with its own offset b from its "
                           "contour's antisymmetric part, its lengths corrected by the offset's second-order "
                           "elongation before G_s",
}
#: Points of each capsule's residual profile in the score.
PROFILE_POINTS = 16
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


def offset_contour(contour: np.ndarray, delta: float) -> np.ndarray:
    """The closed contour moved outward by delta along its normals (inward for delta < 0).

    The normals come from the contour smoothed over 5 neighbouring points, so that tracing
    noise does not turn them; the traced points themselves are moved."""
    kernel = np.ones(5) / 5
    padded = np.vstack([contour[-2:], contour, contour[:2]])
    smooth = np.column_stack([np.convolve(padded[:, k], kernel, mode="valid") for k in range(2)])
    tangent = np.roll(smooth, -1, axis=0) - np.roll(smooth, 1, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1)[:, None]
    normal = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    if np.mean(np.sum((smooth - smooth.mean(axis=0)) * normal, axis=1)) < 0:
        normal = -normal
    return contour + delta * normal


@dataclass(frozen=True)
class Candidate:
    """One effect: a name, its parameter's name and unit, the grid of values to try, the
    neutral value (the base model), and how a value changes the capsules or the law."""

    name: str
    parameter: str
    unit: str
    values: tuple[float, ...]
    neutral: float
    apply: Callable[[Sequence[Capsule], float], tuple[list[Capsule], str]]
    #: Law groups the candidate needs from the databases (beyond the base law).
    laws: tuple[str, ...] = ()
    #: "capsules" (a measurement effect: changes the data, keeps the law it was built on) or
    #: "law" (a model effect: changes the law, keeps the data); what makes two effects compose.
    acts_on: str = "law"


def contour_offset_candidate(base_law: str | BlendedLaw, max_px: float = 3.0, step_px: float = 0.75) -> Candidate:
    """Traced contour offset outward by delta pixels (needs a ``pixel_size`` column)."""

    def apply(capsules: Sequence[Capsule], delta: float) -> tuple[list[Capsule], str]:
        out = []
        for c in capsules:
            pixel = c["pixel_size"]
            if c.contour is None or not math.isfinite(pixel):
                out.append(c)
                continue
            values = dict(c.values)
            values["L_z"] = c["L_z"] - 2 * delta * pixel
            out.append(replace(c, values=values, contour=offset_contour(c.contour, -delta * pixel)))
        return out, base_law

    values = tuple(np.round(np.arange(-2 * step_px, max_px + 1e-9, step_px), 6))
    return Candidate("contour_offset", "delta", "px", values, 0.0, apply, acts_on="capsules")


def tube_radius_candidate(base_law: str | BlendedLaw, max_rel: float = 0.045, step: float = 0.015) -> Candidate:
    """The capillary radius is l (1 + eps) instead of the nominal l."""

    def apply(capsules: Sequence[Capsule], eps: float) -> tuple[list[Capsule], str]:
        out = []
        for c in capsules:
            values = dict(c.values)
            values["tube_radius"] = c["tube_radius"] * (1 + eps)
            out.append(replace(c, values=values))
        return out, base_law

    values = tuple(np.round(np.arange(-max_rel, max_rel + 1e-9, step), 6))
    return Candidate("tube_radius", "eps", "1", values, 0.0, apply, acts_on="capsules")


def law_candidate(base_law: str, other_law: str) -> Candidate:
    """Another database group (law, nu_s, or a law key with an effect) instead of the base:
    one discrete parameter, 0 = base, 1 = the other group."""

    def apply(capsules: Sequence[Capsule], which: float) -> tuple[list[Capsule], str]:
        return list(capsules), other_law if which >= 0.5 else base_law

    return Candidate(f"law {other_law}", "group", "", (0.0, 1.0), 0.0, apply, laws=(other_law,))


#: Kernel effects with one scalar strength that an effect database holds at a few levels
#: (law keys ``<base>+<effect><value>``): effect -> (parameter name, default levels).
SCALAR_EFFECTS: dict[str, tuple[str, tuple[float, ...]]] = {
    "prestress": ("alpha", (0.04, 0.06, 0.08)),
    "kb": ("k_b", (0.0025, 0.005, 0.01)),
}


def effect_key(base_law: str, effect: str, value: float) -> str:
    """The database law key of the base law with a scalar effect (``NH+prestress0.05``,
    ``NH+kb0.01``); the base law itself at value 0."""
    return base_law if value == 0 else f"{base_law}+{effect}{value:g}"


def prestress_key(base_law: str, alpha: float) -> str:
    """The database law key of the base law with pre-stress alpha (``NH+prestress0.05``)."""
    return effect_key(base_law, "prestress", alpha)


def interpolation_weights(levels: Sequence[float], value: float) -> list[tuple[int, float]]:
    """Weights of the levels whose blend is the law at ``value``: linear between the two
    levels that bracket it, [(level index, weight)].

    Linear, not a quadratic through three levels: an effect can change a shape abruptly
    between two levels (pre-stress removes the parachute between alpha = 0 and 0.04), and a
    quadratic carries that into the next interval (measured on the pre-stress batch: alpha
    0.0482 [0.0474, 0.0490] and chi2 418 against the linear blend's 0.0508 and 366, truth 0.05)."""
    levels = np.asarray(levels, dtype=float)
    k = int(np.clip(np.searchsorted(levels, value) - 1, 0, len(levels) - 2))
    w = (value - levels[k]) / (levels[k + 1] - levels[k])
    return [(k, 1 - w), (k + 1, w)]


class BlendedLaw:
    """A law between database groups (a scalar effect between its levels): its profiles and
    velocity ratio are the weighted sum of the groups', at the same (a/l, Ca_s); its length
    fit is that of the group with the largest weight (a contour fit's start only)."""

    def __init__(self, keys: Sequence[str], weights: Sequence[float]) -> None:
        self.keys, self.weights = list(keys), [float(w) for w in weights]

    def __str__(self) -> str:
        return " + ".join(f"{w:.3g} {key}" for key, w in zip(self.keys, self.weights))

    def inverter(self, database) -> _BlendedInverter:
        return _BlendedInverter([tube_inverter(database, key) for key in self.keys], self.weights)


class _BlendedInverter:
    """The TubeInverter interface diagnose uses, for a BlendedLaw."""

    def __init__(self, inverters: Sequence[TubeInverter], weights: Sequence[float]) -> None:
        self.inverters, self.weights = list(inverters), list(weights)
        self.nearer = self.inverters[int(np.argmax(self.weights))]
        self.table = self.nearer.table

    def fit(self, L_z: float, L_p: float):
        return self.nearer.fit(L_z, L_p)

    def profile(self, a_over_l: float, Ca_s: float) -> np.ndarray | None:
        profiles = [inverter.profile(a_over_l, Ca_s) for inverter in self.inverters]
        if any(p is None for p in profiles):
            return None
        return sum(w * p for w, p in zip(self.weights, profiles))

    def velocity_ratio(self, a_over_l: float, Ca_s: float) -> float:
        return sum(w * inverter.velocity_ratio(a_over_l, Ca_s) for w, inverter in zip(self.weights, self.inverters))


def scalar_effect_candidate(base_law: str, effect: str, levels: Sequence[float] | None = None) -> Candidate:
    """A kernel effect with one scalar strength (``SCALAR_EFFECTS``: pre-stress alpha, bending
    stiffness k_b), fitted between the effect database's levels: between levels the law is
    their blend (``BlendedLaw``, ``interpolation_weights``), so that the batch is refitted at
    any strength, not only at the levels."""
    parameter, default_levels = SCALAR_EFFECTS[effect]
    values = (0.0, *sorted(float(v) for v in (default_levels if levels is None else levels)))

    def apply(capsules: Sequence[Capsule], theta: float) -> tuple[list[Capsule], str | BlendedLaw]:
        at = [v for v in values if math.isclose(v, theta, rel_tol=0, abs_tol=1e-12)]
        if at:
            return list(capsules), effect_key(base_law, effect, at[0])
        weights = interpolation_weights(values, theta)
        return list(capsules), BlendedLaw([effect_key(base_law, effect, values[k]) for k, _ in weights],
                                          [w for _, w in weights])

    return Candidate(effect, parameter, "", values, 0.0, apply,
                     laws=tuple(effect_key(base_law, effect, v) for v in values[1:]))


def prestress_candidate(base_law: str, levels: Sequence[float] = SCALAR_EFFECTS["prestress"][1]) -> Candidate:
    """Membrane pre-stress alpha (``--prestress``) between the database's levels."""
    return scalar_effect_candidate(base_law, "prestress", levels)


def bending_candidate(base_law: str, levels: Sequence[float] = SCALAR_EFFECTS["kb"][1]) -> Candidate:
    """Bending stiffness k_b = K_B/(G_s a^2) (``--kb``) between the database's levels."""
    return scalar_effect_candidate(base_law, "kb", levels)


def candidate_library(base_law: str, database_laws: Sequence[str], prestress_levels: Sequence[float] | None = None,
                      other_laws: Sequence[str] | None = None, kb_levels: Sequence[float] | None = None
                      ) -> list[Candidate]:
    """The effect library (issue 7): contour offset, tube radius, pre-stress, bending
    stiffness, and every other law group of the databases without an effect (another law,
    nu_s or C) unless ``other_laws`` names them. Levels None: the defaults of
    ``SCALAR_EFFECTS``; empty: no such candidate."""
    candidates = [contour_offset_candidate(base_law), tube_radius_candidate(base_law)]
    for effect, levels in (("prestress", prestress_levels), ("kb", kb_levels)):
        if levels is None or len(levels):
            candidates.append(scalar_effect_candidate(base_law, effect, levels))
    if other_laws is None:
        other_laws = [key for key in database_laws if key != base_law and "+" not in key]
    return candidates + [law_candidate(base_law, key) for key in other_laws]


class DatabaseSet:
    """Several tube databases seen as one: a law key is taken from the first that has it
    (the base database, then effect databases such as data/databases/effects/*/tube.h5)."""

    flow = "tube"

    def __init__(self, databases: Sequence[TubeDatabase]) -> None:
        self.databases = list(databases)

    @property
    def laws(self) -> list[str]:
        return list(dict.fromkeys(key for d in self.databases for key in d.laws))

    def law(self, key: str):
        for database in self.databases:
            if key in database.laws:
                return database.law(key)
        raise KeyError(f"no database has law {key!r}")


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




def contour_fit(prepared: PreparedContour, inverter: TubeInverter, tube_radius: float, start: tuple[float, float],
                sigma: float) -> tuple[float, float, float]:
    """(a/l, Ca_s, chi2): the database point whose profile best fits the contour (least
    squares of the residual profile, Nelder-Mead in (a/l, ln Ca_s) from ``start``)."""

    def chi2(p: np.ndarray) -> float:
        meridian = inverter.profile(float(p[0]), float(np.exp(p[1])))
        if meridian is None:
            return 1e12
        _, distance, _ = prepared.residual(meridian * tube_radius, points=PROFILE_POINTS)
        return float(np.sum((distance / sigma) ** 2))

    x0 = np.array([start[0], math.log(start[1])])
    # Tolerances: 1e-3 in a/l and ln Ca_s is far below the five fits' spread; 0.05 in chi2 is
    # far below the differences the criteria act on.
    best = minimize(chi2, x0, method="Nelder-Mead",
                    options={"xatol": 1e-3, "fatol": 0.05, "initial_simplex": [x0, x0 + [0.02, 0], x0 + [0, 0.1]]})
    return float(best.x[0]), float(np.exp(best.x[1])), float(best.fun)


def _on_database_edge(inverter: TubeInverter, a_over_l: float, Ca_s: float, step: float = 2e-3) -> bool:
    """Whether a contour fit ended on the edge of the database (a step of 2e-3 in a/l or
    ln Ca_s leaves it): its minimum may lie outside, so it is no fit."""
    return any(inverter.profile(a_over_l + da, Ca_s * math.exp(dc)) is None
               for da, dc in ((step, 0), (-step, 0), (0, step), (0, -step)))


def _nearest_row(inverter: TubeInverter, L_z: float, L_p: float) -> dict[str, float]:
    """The database row nearest to the lengths (L_z, L_z - L_p), each scaled by its spread."""
    t = inverter.table
    q = np.column_stack([t.L_z, t.L_z - t.L_p])
    k = int(np.argmin(np.sum(((q - [L_z, L_z - L_p]) / q.std(axis=0)) ** 2, axis=1)))
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
        fit = inverter.fit(L_z, L_p)
        if fit.ok:
            rows.append({"a_over_l": fit.a_over_l, "Ca_s": fit.Ca_s})
        elif math.isfinite(L_z) and math.isfinite(L_p):
            rows.append({**_nearest_row(inverter, L_z, L_p), "fallback": True})
        else:
            rows.append({"a_over_l": float("nan"), "Ca_s": float("nan")})
    return rows


def _law_inverter(database, law: str | BlendedLaw):
    return law.inverter(database) if isinstance(law, BlendedLaw) else tube_inverter(database, law)


def score_batch(capsules: Sequence[Capsule], database: TubeDatabase, law: str | BlendedLaw, sigma: np.ndarray,
                prepared: Sequence[PreparedContour] | None = None, starts: BatchScore | None = None) -> BatchScore:
    """Fit every capsule's contour with one law (a key or a BlendedLaw); chi2, G_s and Delta per
    capsule. A capsule whose lengths the law cannot reproduce starts from its fit in ``starts``
    (the base fit), else from the database row nearest in lengths."""
    inverter = _law_inverter(database, law)
    rows = _central_fits(capsules, inverter)
    if starts is not None:
        for i, row in enumerate(rows):
            if row.get("fallback") and math.isfinite(starts.a_over_l[i]):
                row.update(a_over_l=float(starts.a_over_l[i]), Ca_s=float(starts.Ca_s[i]))
    n = len(capsules)
    chi2, g_s, delta = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    fitted_a, fitted_ca = np.full(n, np.nan), np.full(n, np.nan)
    residual = np.full((n, PROFILE_POINTS), np.nan)
    for i, (capsule, row) in enumerate(zip(capsules, rows)):
        if capsule.contour is None or not math.isfinite(row["a_over_l"]) or not math.isfinite(sigma[i]):
            continue
        contour = prepared[i] if prepared is not None else PreparedContour(capsule.contour)
        l = capsule["tube_radius"]
        a_over_l, ca, chi2[i] = contour_fit(contour, inverter, l, (row["a_over_l"], row["Ca_s"]), sigma[i])
        if chi2[i] >= 1e12 or _on_database_edge(inverter, a_over_l, ca):
            chi2[i] = np.nan
            continue
        velocity = inverter.velocity_ratio(a_over_l, ca)
        if math.isfinite(capsule["v_c"]) and math.isfinite(capsule["mu"]) and velocity > 0:
            g_s[i] = capsule["mu"] * capsule["v_c"] / (ca * velocity)
        meridian = inverter.profile(a_over_l, ca)
        if meridian is not None:
            delta[i] = profile_elongation(meridian, a_over_l)
            pixel = capsule["pixel_size"] if math.isfinite(capsule["pixel_size"]) else 1.0
            residual[i] = contour.residual(meridian * l, points=PROFILE_POINTS)[1] / pixel
        fitted_a[i], fitted_ca[i] = a_over_l, ca
    return BatchScore(chi2, g_s, delta, fitted_a, fitted_ca, residual)


def noise_levels(capsules: Sequence[Capsule], database: TubeDatabase, law: str | BlendedLaw) -> np.ndarray:
    """Each capsule's tracing-noise level: the rms over the meridian of the half difference of
    its contour's two halves (the standard error of the mean residual at a point), measured
    against its length-based fit."""
    inverter = _law_inverter(database, law)
    rows = _central_fits(capsules, inverter)
    sigma = np.full(len(capsules), np.nan)
    for i, (capsule, row) in enumerate(zip(capsules, rows)):
        if capsule.contour is None or not math.isfinite(row["a_over_l"]):
            continue
        meridian = inverter.profile(row["a_over_l"], row["Ca_s"])
        if meridian is None:
            continue
        _, error = PreparedContour(capsule.contour).residual(meridian * capsule["tube_radius"], points=64)[1:]
        sigma[i] = float(np.sqrt(np.mean(error ** 2)))
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


def evaluate_candidate(candidate: Candidate, capsules: Sequence[Capsule], database: TubeDatabase, base_law: str,
                       sigma: np.ndarray, base: BatchScore, prepared: Sequence[PreparedContour],
                       refine_evaluations: int = REFINE_EVALUATIONS) -> CandidateResult:
    """Refit the batch over the candidate's grid; fit theta (refined with at most
    ``refine_evaluations`` refits on each side of the best grid value), its interval, the criteria."""
    result = CandidateResult(candidate.name, candidate.parameter, candidate.unit)
    values = np.array(candidate.values, dtype=float)

    def refit(value: float) -> BatchScore:
        changed, law = candidate.apply(capsules, value)
        # Contours the candidate leaves alone keep their prepared halves.
        same = all(c.contour is o.contour for c, o in zip(changed, capsules))
        return score_batch(changed, database, law, sigma, prepared if same else None, starts=base)

    scores = [base if value == candidate.neutral else refit(float(value)) for value in values]
    table = np.array([s.chi2 for s in scores])                  # (values, capsules)
    usable = np.all(np.isfinite(table), axis=0) & np.isfinite(base.chi2)
    result.capsules = int(usable.sum())
    if result.capsules < 3:
        result.note = f"only {result.capsules} capsules fitted at every {candidate.parameter}: not assessed"
        return result
    table = table[:, usable]
    grid_values = values.copy()
    # Refine: a bounded 1D minimisation of the batch's chi2 between the grid neighbours of the
    # lowest grid point, every evaluation kept in the table, so that the minimum chi2 the
    # criteria compare is computed, not extrapolated (a parabola through three grid points
    # misplaces a sharp minimum: on the pre-stress batches by 20-40 % of the level spacing).
    if len(values) > 2 and refine_evaluations > 0:
        k = int(np.argmin(table.sum(axis=1)))
        low, high = values[max(k - 1, 0)], values[min(k + 1, len(values) - 1)]
        extras: list[tuple[float, BatchScore]] = []

        def batch_chi2(theta: float) -> float:
            extra = refit(float(theta))
            if not np.all(np.isfinite(extra.chi2[usable])):
                return 1e30  # outside what every capsule can be fitted at: never the minimum
            extras.append((float(theta), extra))
            return float(extra.chi2[usable].sum())

        # Each side of the best grid value separately: a blended law is piecewise in the
        # strength, kinked at the levels, and one search across the kink stays on one side.
        for side in ((low, values[k]), (values[k], high)):
            if side[1] > side[0]:
                minimize_scalar(batch_chi2, bounds=side, method="bounded",
                                options={"xatol": REFINE_XATOL * (side[1] - side[0]), "maxiter": refine_evaluations})
        for theta, extra in extras:
            if np.any(np.isclose(values, theta, rtol=0, atol=1e-12)):
                continue
            order = np.argsort(np.append(values, theta), kind="stable")
            values = np.append(values, theta)[order]
            table = np.vstack([table, extra.chi2[usable]])[order]
            scores = [(scores + [extra])[j] for j in order]
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
    gains, thetas = [], []
    for i in range(result.capsules):
        others = total - table[:, i]
        theta_i = _window_minimum(values, others, on_grid)
        thetas.append(theta_i)
        held_out = float(np.interp(theta_i, values, table[:, i]))
        gains.append(float(base.chi2[usable][i]) - held_out)
    gains, thetas = np.array(gains), np.array(thetas)
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
    result.interval = (min(theta - 2 * jackknife, float(flat.min())), max(theta + 2 * jackknife, float(flat.max())))
    result.cv_gain = float(gains.mean())
    result.cv_gain_error = float(gains.std(ddof=1) / np.sqrt(n))
    # Paired, one-sided: do held-out capsules fit better? (Wilcoxon: the gains are far from normal.)
    p_value = float(stats.wilcoxon(gains, alternative="greater").pvalue) if np.any(gains != 0) else 1.0
    result.cv_p_value = p_value
    result.supported = bool(p_value < CV_ALPHA and result.bic_drop > MIN_BIC_DROP)
    # theta is a point of the table: its score is there already.
    after = scores[k]
    result.law = str(candidate.apply(capsules, theta)[1])
    result.after = after
    result.g_s_before, result.drift_p_before = _g_s_summary(base, usable)
    result.g_s_after, result.drift_p_after = _g_s_summary(after, usable)
    return result


def rivals_of(chosen, results: Sequence, drop: Callable[[Any], float] = lambda r: r.bic_drop) -> list:
    """The supported results whose BIC drop (``drop``) is within MIN_BIC_DROP of the chosen one's."""
    if chosen is None:
        return []
    return [r for r in results if r.supported and r is not chosen and drop(chosen) - drop(r) < MIN_BIC_DROP]


def compare_supported(results: Sequence[CandidateResult], base: BatchScore) -> CandidateResult | None:
    """Set ``bic_drop_common`` of the supported results and return the one with the largest.

    Each candidate's own BIC drop is over the capsules it fits at every value it tried, and
    those sets differ (an effect database covers less than the base one): comparing drops over
    different data favours the candidate that fits more capsules, not the better model. On
    the two-effect batch the bending candidate won that way (26352 over 23 capsules) against
    pre-stress (22451 over 21), whose chi2 on the common capsules is 468 against bending's 1764.
    The choice is made on the capsules every supported candidate fits, at its fitted value."""
    supported = [r for r in results if r.supported and r.after is not None]
    if not supported:
        return None
    common = np.isfinite(base.chi2)
    for r in supported:
        common &= np.isfinite(r.after.chi2)
    n_points = max(int(common.sum()), 1) * PROFILE_POINTS
    for r in supported:
        r.bic_drop_common = float(np.sum(base.chi2[common] - r.after.chi2[common]) - math.log(n_points))
    return max(supported, key=lambda r: r.bic_drop_common)


@dataclass
class Diagnosis:
    """Every candidate's result and the verdict."""

    base_law: str
    results: list[CandidateResult]
    chosen: CandidateResult | None
    base: BatchScore | None = field(default=None, repr=False)
    #: Capsules left out before the diagnosis, as (id, reason) (``screen_asymmetric``).
    excluded: list[tuple[str, str]] = field(default_factory=list)
    #: The left-out capsules fitted with their own offset (``capsmech.offcentre``), when an
    #: off-centre table was given.
    offcentre: list = field(default_factory=list)
    #: Why no candidate was assessed, when none was.
    note: str = ""

    @property
    def rivals(self) -> list[CandidateResult]:
        """Other supported candidates the data cannot tell from the chosen one (BIC within
        MIN_BIC_DROP of it)."""
        return rivals_of(self.chosen, self.results, lambda r: r.bic_drop_common)

    @property
    def verdict(self) -> str:
        if self.note and not self.results:
            return self.note
        if self.chosen is None:
            return "no candidate effect is supported: the residual is within noise"
        c = self.chosen
        rivals = ""
        if self.rivals:
            rivals = ("; these data cannot tell it from " + ", ".join(
                f"{r.name} ({r.parameter} = {r.theta:.3g} {r.unit}, BIC drop {r.bic_drop_common:.1f})" for r in self.rivals)
                + ": measure what separates them (the flow rate, the tube radius) to decide")
        return (f"{c.name}: {c.parameter} = {c.theta:.3g} {c.unit} [{c.interval[0]:.3g}, {c.interval[1]:.3g}], "
                f"BIC drop {c.bic_drop:.1f} ({c.bic_drop_common:.1f} on the capsules every supported candidate fits), "
                f"cross-validated chi2 gain {c.cv_gain:.2f} +- {c.cv_gain_error:.2f} "
                f"per capsule (p = {c.cv_p_value:.2g})" + rivals)


def diagnose(capsules: Sequence[Capsule], database: TubeDatabase | DatabaseSet, base_law: str | BlendedLaw,
             candidates: Sequence[Candidate] | None = None, sigma: np.ndarray | None = None,
             refine_evaluations: int = REFINE_EVALUATIONS, screen: bool = True,
             offcentre_table=None) -> Diagnosis:
    """Test the candidate effects on a batch fitted with ``base_law`` (see the module).

    ``database`` is one tube database or a ``DatabaseSet`` (the base database first, then
    effect databases). A candidate whose law groups none has is not assessed; its result
    carries the grid to run (``needs``, see ``capsmech.effect_grid``). ``sigma``: the
    capsules' tracing-noise levels when already measured (``noise_levels``), so that the chi2
    of successive diagnoses of one batch share their scale. ``refine_evaluations``: refits of
    the batch on each side of a continuous candidate's best grid value (0: the grid only).
    ``screen``: leave out asymmetric contours first (``screen_asymmetric``); False when the
    caller has screened the batch already (``diagnose_sequential``: once, so that every round
    sees the same capsules). ``offcentre_table``: an ``capsmech.offcentre.OffcentreTable``;
    the capsules screened out are then fitted with their own offset (``fit_offcentre``)."""
    from capsmech.effect_grid import needed_grid

    if candidates is None:
        candidates = [contour_offset_candidate(base_law), tube_radius_candidate(base_law)]
    with_contours: list[Capsule] = [c for c in capsules if c.contour is not None]
    excluded: list[tuple[str, str]] = []
    if screen:
        with_contours, excluded = screen_asymmetric(with_contours)
    if len(with_contours) < 3 and offcentre_table is not None and excluded:
        # A batch caught off the axis: no batch effect can be tested, the offsets still can.
        return Diagnosis(base_law, [], None, None, excluded,
                         fit_offcentre(capsules, excluded, _base_database(database), base_law, offcentre_table),
                         note=f"no candidate assessed: {len(with_contours)} centred capsules with contours, "
                              "diagnose needs at least 3")
    if len(with_contours) < 3:
        raise ValueError(f"diagnose needs contours of at least 3 capsules, the batch has {len(with_contours)}"
                         + (f" ({len(excluded)} more left out as asymmetric)" if excluded else ""))
    if sigma is None:
        sigma = noise_levels(with_contours, database, base_law)
    prepared = [PreparedContour(c.contour) for c in with_contours]
    base = score_batch(with_contours, database, base_law, sigma, prepared)
    base_database = _base_database(database)
    results = []
    for candidate in candidates:
        missing = [key for key in candidate.laws if key not in database.laws]
        if not missing:
            results.append(evaluate_candidate(candidate, with_contours, database, base_law, sigma, base, prepared,
                                              refine_evaluations))
            continue
        result = CandidateResult(candidate.name, candidate.parameter, candidate.unit,
                                 note="not assessed: needs simulations")
        name = re.sub(r"[^A-Za-z0-9_-]", "_", candidate.name.replace(".", "p"))
        result.needs = needed_grid(name, missing, base_database, base.a_over_l, base.Ca_s)
        results.append(result)
    chosen = compare_supported(results, base)
    offcentre = (fit_offcentre(capsules, excluded, base_database, base_law, offcentre_table)
                 if offcentre_table is not None else [])
    return Diagnosis(base_law, results, chosen, base, excluded, offcentre)


def _base_database(database: TubeDatabase | DatabaseSet) -> TubeDatabase:
    """The base law's database: the first of a set."""
    return database.databases[0] if isinstance(database, DatabaseSet) else database


def fit_offcentre(capsules: Sequence[Capsule], excluded: Sequence[tuple[str, str]], database: TubeDatabase,
                  base_law: str | BlendedLaw, table) -> list:
    """Fit every screened-out capsule with its own offset (``capsmech.offcentre``)."""
    from capsmech.offcentre import fit_offcentre_capsule

    if not isinstance(base_law, str) or not excluded:
        return []
    left_out = {capsule for capsule, _ in excluded}
    inverter = tube_inverter(database, base_law)
    return [fit_offcentre_capsule(c, inverter, table) for c in capsules if c.id in left_out]


def screen_asymmetric(capsules: Sequence[Capsule]) -> tuple[list[Capsule], list[tuple[str, str]]]:
    """Leave out the capsules whose contour the inversion flags as asymmetric.

    An axisymmetric model cannot explain an up-down asymmetric contour, and a batch effect
    should not be fitted to one: such a capsule is off the axis (still migrating towards it)
    or not yet steady. Returns the capsules kept and, for the others, (id, reason)."""
    kept, excluded = [], []
    for capsule in capsules:
        asymmetry, limit, _ = contour_asymmetry(capsule.contour, capsule["pixel_size"])
        if asymmetry > limit:
            excluded.append((capsule.id, f"asymmetric contour: its halves differ by {asymmetry:.4f} a "
                                         f"(> {limit:.4f} a): off-centre or not steady"))
        else:
            kept.append(capsule)
    return kept, excluded


@dataclass
class SequentialDiagnosis:
    """Effects found one after another (``diagnose_sequential``): each round's diagnosis
    (round k on the batch with the effects of rounds 1..k-1 fixed), the effects found with
    their values after the joint refinement, and the batch's G_s through the rounds."""

    rounds: list[Diagnosis]
    effects: list[tuple[str, float]]
    g_s: list[tuple[float, float]]
    note: str = ""
    #: The two strengths fitted together (``joint_refine``), when both effects have one.
    joint: JointFit | None = None

    @property
    def verdict(self) -> str:
        if not self.effects:
            return self.rounds[0].verdict
        found = "; then ".join(f"{name} = {theta:.3g}" for name, theta in self.effects)
        return f"{found} ({self.note})" if self.note else found


def _apply_all(capsules: Sequence[Capsule], base_law: str, fixed: Sequence[tuple[Candidate, float]],
               library: Callable[[str | BlendedLaw], Sequence[Candidate]]) -> tuple[list[Capsule], str | BlendedLaw]:
    """The batch and law with the effects ``fixed`` switched on: measurement effects change the
    capsules, a model effect the law; each candidate is rebuilt (by name) on the law so far."""
    capsules, law = list(capsules), base_law
    for candidate, theta in sorted(fixed, key=lambda f: f[0].acts_on != "law"):
        rebuilt = next(c for c in library(law) if c.name == candidate.name)
        capsules, law = rebuilt.apply(capsules, theta)
    return capsules, law


JOINT_EVALUATIONS = 40


@dataclass
class JointFit:
    """Two effects' strengths fitted together: the values, each one's interval, the batch's
    chi2 (over ``capsules``, those fitted at the start) at the start and at the minimum, the
    points evaluated ((n, 2) strengths, (n,) chi2)."""

    names: tuple[str, str]
    start: tuple[float, float]
    values: tuple[float, float]
    intervals: tuple[tuple[float, float], tuple[float, float]]
    chi2_start: float
    chi2: float
    capsules: int
    points: np.ndarray = field(repr=False)
    chi2_points: np.ndarray = field(repr=False)


def _grid_step(candidate: Candidate) -> float:
    return float(np.min(np.diff(np.asarray(candidate.values, dtype=float))))


def joint_refine(capsules: Sequence[Capsule], database: TubeDatabase | DatabaseSet, base_law: str,
                 fixed: Sequence[tuple[Candidate, float]],
                 library: Callable[[str | BlendedLaw], Sequence[Candidate]], sigma: np.ndarray,
                 max_evaluations: int = JOINT_EVALUATIONS) -> JointFit:
    """Fit two effects' strengths at once, from the values ``fixed`` (the sequential fit).

    Coordinate descent stops in a valley when two effects trade off against each other: on
    the two-effect batch (pre-stress 0.05 and a 1.5 px contour offset) one sweep stopped at
    alpha 0.036, 0.14 px with chi2 473 on the 22 capsules fitted at both points, where the
    truth has 320. Here Nelder-Mead moves both strengths together (each in units of its
    candidate's grid step, kept within its grid), on the batch chi2 summed over the capsules
    fitted at the start; a point where one of them cannot be fitted is never the minimum.
    Then the eight neighbours at half a grid step are evaluated, and each interval is the
    range of that strength over the evaluated points whose chi2 is within PROFILE_RISE of the
    minimum (scaled by the reduced chi2 when above 1). That is only the flatness half of the
    one-effect rule (``evaluate_candidate``), so these intervals are narrower: no jackknife,
    since leaving each capsule out would repeat the search per capsule, and the per-capsule
    minima over the evaluated points are pinned to the cluster the search leaves at the
    batch's minimum (a quadratic surface through the neighbours does not follow the narrow,
    curved valley: residuals of 28 on batch_F, where the valley floor varies by 5-10).
    """
    (first, theta_1), (second, theta_2) = fixed
    steps = np.array([_grid_step(first), _grid_step(second)])
    low = np.array([min(first.values), min(second.values)])
    high = np.array([max(first.values), max(second.values)])
    start = np.array([theta_1, theta_2], dtype=float)
    usable: np.ndarray | None = None
    points: list[np.ndarray] = []
    totals: list[float] = []

    def batch_chi2(theta: np.ndarray) -> float:
        nonlocal usable
        theta = np.clip(theta, low, high)
        state, law = _apply_all(capsules, base_law, [(first, float(theta[0])), (second, float(theta[1]))], library)
        chi2 = score_batch(state, database, law, sigma).chi2
        if usable is None:
            usable = np.isfinite(chi2)
        if not np.all(np.isfinite(chi2[usable])):
            return 1e30
        points.append(theta.copy())
        totals.append(float(chi2[usable].sum()))
        return totals[-1]

    chi2_start = batch_chi2(start)
    if usable is None or usable.sum() < 3 or chi2_start >= 1e30:
        raise ValueError("joint fit: fewer than 3 capsules fitted at the sequential strengths")
    simplex = np.array([start, start + [steps[0] / 2, 0.0], start + [0.0, steps[1] / 2]]) / steps
    minimize(lambda x: batch_chi2(x * steps), start / steps, method="Nelder-Mead",
             options={"initial_simplex": simplex, "maxfev": max_evaluations, "xatol": 0.02, "fatol": 0.5})
    best = points[int(np.argmin(totals))]
    for d1 in (-0.5, 0.0, 0.5):
        for d2 in (-0.5, 0.0, 0.5):
            if d1 or d2:
                batch_chi2(best + [d1 * steps[0], d2 * steps[1]])
    values, total = np.array(points), np.array(totals)
    k = int(np.argmin(total))
    n_usable = int(usable.sum())
    rise = PROFILE_RISE * max(1.0, total[k] / (n_usable * PROFILE_POINTS))
    flat = values[total <= total[k] + rise]
    intervals = tuple((float(flat[:, j].min()), float(flat[:, j].max())) for j in range(2))
    return JointFit((first.name, second.name), (float(theta_1), float(theta_2)),
                    (float(values[k, 0]), float(values[k, 1])), intervals,  # type: ignore[arg-type]
                    chi2_start, float(total[k]), n_usable, values, total)


def diagnose_sequential(capsules: Sequence[Capsule], database: TubeDatabase | DatabaseSet, base_law: str,
                        library: Callable[[str | BlendedLaw], Sequence[Candidate]],
                        max_effects: int = 2, offcentre_table=None) -> SequentialDiagnosis:
    """A second effect after fixing the first: diagnose the batch; if a candidate is
    supported, switch it on at its fitted value and diagnose again with the other candidates
    that compose with it (any measurement effect; a model effect only on top of a measurement
    one: two model effects at once need law groups with both, which the databases do not
    hold); then refit the first effect with the second fixed (one sweep of coordinate
    descent, since the first was fitted with the second missing), and, when both effects have
    a continuous strength, fit the two together from there (``joint_refine``: coordinate
    descent stops in the valley along which two effects trade off).

    ``library(law)`` builds the candidate list on a law (a key or a ``BlendedLaw``), e.g.
    ``lambda law: candidate_library(law, laws)`` for the base key. The noise levels are
    measured once, on the base fit. ``offcentre_table``: as in ``diagnose``."""
    with_contours, excluded = screen_asymmetric([c for c in capsules if c.contour is not None])
    if len(with_contours) < 3 and offcentre_table is not None and excluded:
        only = diagnose(capsules, database, base_law, [], offcentre_table=offcentre_table)
        return SequentialDiagnosis([only], [], [(math.nan, math.nan)], only.note, None)
    sigma = noise_levels(with_contours, database, base_law)
    rounds = [diagnose(with_contours, database, base_law, list(library(base_law)), sigma, screen=False)]
    rounds[0].excluded = excluded
    if offcentre_table is not None:
        rounds[0].offcentre = fit_offcentre(capsules, excluded, _base_database(database), base_law, offcentre_table)
    fixed: list[tuple[Candidate, float]] = []
    note = ""
    while rounds[-1].chosen is not None:
        chosen = rounds[-1].chosen
        fixed.append((next(c for c in library(base_law) if c.name == chosen.name), chosen.theta))
        if len(fixed) == max_effects:
            break
        state, law = _apply_all(with_contours, base_law, fixed, library)
        model_fixed = any(c.acts_on == "law" for c, _ in fixed)
        names = {c.name for c, _ in fixed}
        rest = [c for c in library(law) if c.name not in names and not (model_fixed and c.acts_on == "law")]
        if not rest:
            break
        rounds.append(diagnose(state, database, law, rest, sigma, screen=False))
        if model_fixed and rounds[-1].chosen is None:
            note = "model effects on top of a model effect not assessed (no database holds both)"
    if len(fixed) == 2:
        (first, _), (second, theta_2) = fixed
        state, law = _apply_all(with_contours, base_law, [(second, theta_2)], library)
        rebuilt = [c for c in library(law) if c.name == first.name]
        refit = diagnose(state, database, law, rebuilt, sigma, screen=False)
        result = refit.results[0]
        if math.isfinite(result.theta):
            fixed[0] = (first, result.theta)
            note = (f"{first.name} refitted with {second.name} fixed: {result.theta:.3g}, "
                    f"interval [{result.interval[0]:.3g}, {result.interval[1]:.3g}]")
    joint = None
    if len(fixed) == 2 and all(len(c.values) > 2 for c, _ in fixed):
        joint = joint_refine(with_contours, database, base_law, fixed, library, sigma)
        fixed = [(c, value) for (c, _), value in zip(fixed, joint.values)]
        found = ", ".join(f"{name} {value:.3g} [{lo:.3g}, {hi:.3g}]"
                          for name, value, (lo, hi) in zip(joint.names, joint.values, joint.intervals))
        note = (f"fitted together: {found}; chi2 {joint.chi2_start:.0f} -> {joint.chi2:.0f} "
                f"over {joint.capsules} capsules")
    effects = [(c.name, theta) for c, theta in fixed]
    g_s = [rounds[0].chosen.g_s_before if rounds[0].chosen else (math.nan, math.nan)]
    if fixed:
        state, law = _apply_all(with_contours, base_law, fixed, library)
        final = score_batch(state, database, law, sigma)
        keep = np.isfinite(final.g_s)
        g_s.append(_g_s_summary(final, keep)[0])
    return SequentialDiagnosis(rounds, effects, g_s, note, joint)


def write_report(diagnosis: Diagnosis, out: str | Path, batch: str = "") -> Path:
    """The Markdown report with its figures (``capsmech.diagnose_report``)."""
    from capsmech.diagnose_report import write_report as write

    return write(diagnosis, out, batch)
