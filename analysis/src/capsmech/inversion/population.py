"""Population analysis (paper section 4.4): which membrane law describes a batch, and its G_s.

G_s is a material property: fitted with the right law it does not drift with the capsules'
deformation, measured by the mean profile elongation Delta = p / (2 pi a), and the law's
steady shapes reproduce every capsule. ``population_verdict`` weighs both kinds of evidence
over **every measured capsule** of a batch of ``fit-tube`` result rows (one row per capsule
and law).

Capsules
--------
A flag that is the same for every law says nothing about the law: an asymmetric contour, an
invalid input (and, for shear rows, an imprecise D12). Such a capsule is left out of the
comparison for every law, with its reason (``PopulationVerdict.left_out``). Every other
capsule is *used*. A law-dependent failure (``outside_database``, ``central_fit_outside``,
``profile_misfit``, any other flag, or no row of that law for the capsule) is evidence
against that law: the law cannot reproduce the capsule (it counts as not *fitted*: no G_s;
for the contour score, a law's contour fit supersedes ``central_fit_outside`` and
``profile_misfit``, see below). A ``no_velocity`` row is a fit (its shape counts) without a
G_s. Fewer than ``MIN_CAPSULES`` (5) used capsules: no verdict.

Criterion: the contours
-----------------------
Each used capsule gets, under each law, a misfit score: the H/a of the law's **best shape on
the contour** (``H_over_a_shape``: the contour fit of :mod:`capsmech.inversion.shape_fit`,
started from the length fit) when the law fits the capsule, ``FAIL_SCORE`` (1, a contour
missed by a whole radius; a fitted capsule has H/a <= ``MAX_H_OVER_A`` = 0.06) when it cannot:
no fit of five reproduces the lengths (``outside_database``), the contour fit ends on the
database's edge, or its H/a is above the limit. (The length fit's own troubles,
``central_fit_outside`` and ``profile_misfit``, are superseded by the contour fit.) Results
written without contour fits are scored by ``H_over_a``, the misfit at the length fit, as
before; where the capsule has no contour, a fit scores 0, so that only "fitted or not" counts.
Two laws are compared by a **paired one-sided Wilcoxon signed-rank test** of the score
differences over the used capsules (``p_better[(a, b)]``: p-value of "a fits no better than
b"; capsules with equal scores, e.g. fitted by neither law, carry no information and drop
out). Where ``fit-tube`` measured each best shape's chi2 against the contour's noise
(``chi2_shape``, below), the test compares those instead of H/a: the misfit the contour fit
minimises, each capsule over its own noise (H/a, a Hausdorff distance, stays the reported
score). On 50 SK C = 1 batches of the independent generator, the H/a test let GH nu_s 0.5
through twice, when SK's G_s drifted by chance (p 0.037) and GH's H/a lost only at p ~ 0.03;
on the chi2 (GH 1.26 and 1.44 a degree of freedom against SK's 0.82 and 1.07) SK wins.

Why the best shape rather than the misfit at the length fit: the lengths' 2 % error moves the
length fit's parameters, and the profile there misses the contour by much more
than the law's shapes do. On the shipped GH nu_s = 0.5 batch with the right law, the median
H/a is 0.0107 at the length fit, 0.0046 for the database's profile at the true parameters
(the kernel's exact profile there: also 0.0046; the two profiles differ by 0.0007 a: the
database's interpolation error is negligible), 0.0047 for the contour fit: the right law's
best shape reaches the tracing noise, a wrong law's does not (SK C = 1, same area modulus:
0.0051, larger on every capsule), and the misfit at the length fit buried that difference
under the lengths' error (Wilcoxon p = 0.18 over 10 pairs, now < 0.001 over 12). Why this
criterion rather than a batch likelihood:

- it counts every used capsule: a capsule one law cannot fit is the largest possible
  difference in the other law's favour, whatever the value of ``FAIL_SCORE``, because the
  test uses only the ranks of the differences;
- it is exact without a noise model: under "the two laws fit equally well" the sign of each
  capsule's difference is a fair coin, which is all the test assumes. A likelihood would need
  the distribution of H/a (a modified Hausdorff distance, not a sum of squares) and a noise
  level whose own error (it is estimated from the contour's two halves) and correlation
  along the contour would have to be modelled to make its p-values right;
- a law's median score is its typical misfit, and it is 1 when the law fits fewer than half
  of the capsules.

Criterion: the drift
--------------------
For each law the fitted G_s are regressed on Delta (least squares, ``law_drift``): the
slope of G_s/mean(G_s) per unit Delta, its 95 % interval (Student t) and the p-value of "no
drift". A law whose G_s drifts (p < ``ALPHA``) is not the verdict.

Criterion: the noise
--------------------
Being the best of the database's laws does not make a law the capsules' law: a batch of a law
the database does not hold is fitted best by its nearest neighbour. So each law's best shapes
are also tested against the tracing noise measured on the contours themselves: the total of
the capsules' ``chi2_shape`` (16 residuals along the meridian over the contour's own noise,
from its two halves, and the databases' accuracy; :mod:`capsmech.inversion.noise`) against its
distribution under noise alone (14 degrees of freedom a capsule, the noise level itself
estimated). A law whose total noise alone reaches with probability below ``GOODNESS_ALPHA``
(0.01) *misfits noise*. Measured on the shipped batches (chi2 per degree of freedom; the
limit at 12 and 10 capsules is 1.54 and 1.57): GH nu_s = 0.5 batch, GH_nu0.5 0.95, SK_C1 1.68,
NH 6.9, GH_nu0.2 20 and GH_nu0 43; NH batch, NH 0.68, SK_C1 5.2, GH_nu0.5 8.4. Results
written without ``chi2_shape`` are not tested.

Verdict
-------
A law is *eligible* when it fits at least half of the used capsules. Each eligible law whose
G_s does not drift and whose shapes do not misfit the noise is a *candidate* unless another
eligible law fits the contours significantly better (``p_better`` < ``CONTOUR_LEVEL`` =
0.025, one-sided: the two-sided 5 % level in the direction of the better law; a law exactly
as good as the right one thus beats it by chance in at most 2.5 % of batches, and is then
named only if it also survives the drift test and every other law). Then:

- one candidate: ``kind = 'law'``, that law, with G_s the mean over the capsules it fits and
  the 95 % interval of that mean (Student t; ``G_s_std`` is the spread between capsules);
- several: ``kind = 'cannot_tell'`` ("cannot tell A from B"): neither the contours nor the
  drift separate them. No law and no single G_s; ``G_s_interval`` is the hull of the
  candidates' intervals (G_s lies in it whichever candidate is right; the reason says when
  their own intervals do not overlap, so that knowing the law would narrow it); None only
  where a candidate has no interval;
- none: ``kind = 'none'``, "no law of the database fits", with the reason (every law fits
  fewer than half of the capsules; every eligible law drifts; the closest law's shapes misfit
  the noise, by how much; or the contours favour a law whose G_s drifts, so that the two tests
  disagree).

JSON (``capsmech.inversion.population_report``: ``verdict_dict``, ``write_verdict_json``;
``capsmech population --json FILE``)::

    {"verdict": "law" | "not_one_material" | "none" | "cannot_tell",
     "law": "NH" | null,                       # the law when verdict == "law"
     "candidates": ["GH_nu0.5", "SK_C1"],       # the law, the laws not told apart, or []
     "G_s": 0.0400 | null,                      # N/m, verdict == "law" only
     "G_s_std": 0.0013 | null,                  # N/m, spread between capsules
     "G_s_interval": [0.0391, 0.0409] | null,   # N/m, 95 % (see above for cannot_tell)
     "reason": "...",                           # the verdict in words
     "reference": "NH" | null,                  # the law the p-values are against
     "criterion": {"score": ..., "test": ..., "noise": ..., "noise_alpha": 0.01,
                   "alpha": 0.05, "contour_level": 0.025,
                   "fail_score": 1.0,
                   "min_capsules": 5, "min_fitted_fraction": 0.5},
     "units": {"G_s": "N/m", "drift": "1/Delta", "score": "1"},
     "laws": {"NH": {"fitted": 10, "used": 10, "measured": 10, "score_median": 0.0121,
                     "p_vs_reference": null, "G_s_mean": 0.04, "G_s_std": 0.0013,
                     "G_s_interval": [..], "drift": 0.2, "drift_interval": [..],
                     "drift_p": 0.40, "drift_n": 10, "chi2_per_dof": 0.68, "chi2_limit": 1.57,
                     "chi2_p": 0.99, "chi2_capsules": 10, "status": "verdict",
                     "status_reason": "..."}, ...},
     "capsules": {"measured": 10, "used": 10,
                  "left_out": [{"id": "s003", "reason": "asymmetric contour: ..."}]}}

One material or several
------------------------
The verdict's law's per-capsule G_s are then tested for one material against two
(:mod:`capsmech.inversion.heterogeneity`: their scatter against each capsule's own uncertainty,
``G_s_shape_error``, and one component against a two-component mixture of ln G_s by BIC). Two
materials make ``kind = 'not_one_material'``: the law is still named, but no single G_s; the
two groups with their G_s, intervals and members are in ``heterogeneity`` (JSON:
``"heterogeneity": {"verdict": "not one material", "groups": [{"G_s": .., "G_s_interval": [..],
"members": [..]}, ..], "chi2": .., "chi2_p": .., "bic_gain": .., ...}``). Where the capsules
have their own uncertainties, the interval of the mean G_s is never narrower than they allow
(the Student-t half-width uses the larger of the scatter's standard error and the weighted
mean's): noisy tracing widens it.

Numbers that cannot be computed are null (never NaN). ``status`` is one of 'verdict',
'candidate', 'fits < half', 'drifts', 'misfits noise', 'worse contours', 'no verdict' (too few
capsules).
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy import stats

from capsmech.errors import CapsmechError
from capsmech.inversion.heterogeneity import Heterogeneity, heterogeneity
from capsmech.inversion.noise import DOF, GOODNESS_ALPHA, chi2_test
from capsmech.io.contours import MAX_H_OVER_A

#: Significance level of the drift test and of the contour comparison (two-sided).
ALPHA = 0.05
#: A law is beaten on the contours when ``p_better`` (one-sided) is below this: the two-sided
#: 5 % level, in the direction of the better law.
CONTOUR_LEVEL = ALPHA / 2
#: A batch needs this many usable capsules for a verdict (issue 19: "fewer than 5: none").
MIN_CAPSULES = 5
#: Fraction of the used capsules a law must fit to be the verdict.
MIN_FITTED_FRACTION = 0.5
#: Misfit score of a capsule a law cannot reproduce (worse than any fitted H/a <= 0.06), and
#: its chi2 in the paired test (worse than any fitted capsule's).
FAIL_SCORE = 1.0
FAIL_CHI2 = 1e12
#: Flags that are the same for every law: the capsule is left out for every law.
LAW_INDEPENDENT_FLAGS = ("asymmetric", "invalid_input", "imprecise")
#: A fit whose shape counts but that has no G_s.
NO_G_S_FLAGS = ("no_velocity",)
#: Flags under which the law's contour fit (``H_over_a_shape``) is the capsule's score: the
#: length fit's own troubles (the central fit of five outside the database, the misfit at the
#: length fit above the limit) say nothing about the law's shapes once the contour is fitted.
#: Any other flag (``outside_database``: no fit of five reproduces the lengths) is a failure.
SHAPE_SCORED_FLAGS = ("", *NO_G_S_FLAGS, "central_fit_outside", "profile_misfit")
#: The two G_s estimators (columns of G_s and Delta in fit-tube's results): at each law's best
#: shape on the contour, used when fit-tube tested those shapes against the noise
#: (``chi2_shape``), else at the length fit.
ESTIMATORS = {"contour fits": ("G_s_shape", "Delta_shape"), "lengths": ("G_s", "Delta")}


class PopulationInputError(CapsmechError, ValueError):
    """Result rows that cannot be compared (no capsule id, a capsule twice for one law)."""


@dataclass(frozen=True)
class LawDrift:
    """Drift of G_s with Delta for one law.

    Attributes
    ----------
    law : str
        Law key.
    n : int
        Capsules used (valid fits with finite G_s and Delta).
    mean, std : float
        Mean and standard deviation of G_s [N/m].
    slope : float
        d(G_s / mean G_s) / d Delta [1].
    ci_low, ci_high : float
        95 % confidence interval of the slope.
    t, p_value : float
        Student statistic of the slope and the two-sided p-value of slope = 0; where the
        database's accuracy is given, of |slope| beyond ``database_slope``.
    database_slope : float
        The largest slope the database's own accuracy could make (0 when not given): see
        ``law_drift``.
    """

    law: str
    n: int
    mean: float
    std: float
    slope: float
    ci_low: float
    ci_high: float
    t: float
    p_value: float
    database_slope: float = 0.0

    @property
    def drifts(self) -> bool:
        return self.p_value < ALPHA


def law_drift(law: str, delta: ArrayLike, g_s: ArrayLike, database_error: ArrayLike | None = None) -> LawDrift:
    """Regress G_s / mean(G_s) on Delta for one law (needs at least 3 capsules).

    ``database_error`` [N/m, per capsule] is how far the database's own accuracy can move each
    capsule's G_s (fit-tube's ``G_s_database_error``). That error is not noise: it can grow with
    the deformation (a 64-element database reads G_s up to 10 % high on deep parachutes with a
    corner at the rim, and within 1 % on smooth shapes, docs/validation/databases.md), and so
    make a slope of its own. The steepest linear bias within +-e_i at every capsule is the
    smallest (e_i + e_j) / (Delta_i - Delta_j) over pairs (over the mean G_s); the law drifts
    only where the measured slope exceeds it by more than the scatter allows (the interval is
    widened by it on each side). Measured on the independent
    generator's Skalak C = 1 batches of deep parachutes (Ca_s 0.2-0.93, 96 elements): without
    it the right law's G_s "drifted" (p = 0.03 and 0.009) and no law was named."""
    x, g = np.asarray(delta, dtype=float), np.asarray(g_s, dtype=float)
    e = np.zeros_like(g) if database_error is None else np.asarray(database_error, dtype=float)
    keep = np.isfinite(x) & np.isfinite(g)
    # A capsule whose database error is unknown (NaN) bounds no bias: it takes no part in the pairs.
    x, g, e = x[keep], g[keep], np.where(np.isfinite(e[keep]), np.abs(e[keep]), np.inf)
    if len(x) < 3:
        raise ValueError(f"law {law}: {len(x)} capsules with G_s and Delta, the drift test needs 3")
    if np.ptp(x) == 0:
        raise ValueError(f"law {law}: every capsule has the same Delta, the drift cannot be measured")
    mean = float(g.mean())
    fit = stats.linregress(x, g / mean)
    # The steepest bias b(Delta) = b0 + s Delta with |b(Delta_i)| <= e_i at every capsule: a
    # linear programme whose optimum is the pair (i, j) with the smallest (e_i + e_j) /
    # (Delta_i - Delta_j), so that one capsule of large error does not widen it.
    dx = x[:, None] - x[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        bounds = np.where(dx > 0, (e[:, None] + e[None, :]) / dx, np.inf)
    database_slope = float(bounds.min()) / mean if np.isfinite(bounds.min()) else 0.0
    t_crit = stats.t.ppf(1 - ALPHA / 2, len(x) - 2)
    beyond = max(abs(fit.slope) - database_slope, 0.0)
    t_stat = beyond / fit.stderr if fit.stderr > 0 else (math.inf if beyond > 0 else 0.0)
    p_value = float(fit.pvalue) if database_slope == 0 else float(2 * stats.t.sf(t_stat, len(x) - 2))
    return LawDrift(law=law, n=len(x), mean=mean, std=float(g.std(ddof=1)), slope=float(fit.slope),
                    ci_low=float(fit.slope - t_crit * fit.stderr - database_slope),
                    ci_high=float(fit.slope + t_crit * fit.stderr + database_slope),
                    t=float(math.copysign(t_stat, fit.slope)), p_value=p_value, database_slope=database_slope)


@dataclass(frozen=True)
class NoiseTest:
    """A law's best shapes on the batch's contours against the tracing noise.

    Attributes
    ----------
    capsules : int
        Capsules whose contour the law's best shape was fitted to (finite ``chi2_shape``).
    reduced_chi2 : float
        Their total chi2 per degree of freedom (``capsmech.inversion.noise``).
    limit : float
        The chi2 per degree of freedom that noise alone exceeds with probability
        ``GOODNESS_ALPHA``.
    p_value : float
        Probability that noise alone reaches the total.
    """

    capsules: int
    reduced_chi2: float
    limit: float
    p_value: float

    @property
    def consistent(self) -> bool:
        return self.p_value >= GOODNESS_ALPHA

    def line(self) -> str:
        return (f"chi2/dof {self.reduced_chi2:.2f} over {self.capsules} contours against the {self.limit:.2f} that "
                f"noise reaches at p = {GOODNESS_ALPHA:g} (p = {self.p_value:.2g})")


def noise_test(chi2: ArrayLike) -> NoiseTest | None:
    """Test a law's per-capsule ``chi2_shape`` (NaN: not fitted, left out) against the noise;
    None below 2 capsules."""
    values = np.asarray(chi2, dtype=float)
    values = values[np.isfinite(values)]
    if len(values) < 2:
        return None
    total = float(values.sum())
    p, limit = chi2_test(total, len(values), GOODNESS_ALPHA)
    return NoiseTest(capsules=len(values), reduced_chi2=total / (len(values) * DOF), limit=limit, p_value=p)


@dataclass(frozen=True)
class LawEvidence:
    """What the batch says about one law.

    Attributes
    ----------
    law : str
        Law key.
    fitted, used, measured : int
        Used capsules the law fits (shape reproduced, flag empty or ``no_velocity``); capsules
        used (measured minus those left out); capsules measured.
    score_median : float
        Median misfit score over the used capsules (H/a, ``FAIL_SCORE`` where not fitted).
    p_vs_reference : float
        One-sided p-value of "the reference law fits no better than this one" (NaN for the
        reference itself).
    g_s_mean, g_s_std : float
        Mean of the fitted G_s [N/m] and their spread between capsules (NaN below 2).
    g_s_interval : tuple of float
        95 % interval of the mean G_s (Student t), NaN below 2 capsules.
    drift : LawDrift or None
        The drift test; None when it cannot be made (``drift_note`` says why).
    status : str
        'verdict', 'candidate', 'fits < half', 'drifts', 'misfits noise', 'worse contours' or
        'no verdict'.
    status_reason : str
        The status in words.
    noise : NoiseTest or None
        The law's best shapes against the tracing noise; None where not measured (results
        without ``chi2_shape``, fewer than 2 capsules with one).
    g_s_systematic : float
        The part of the interval's half-width [N/m] that the database's own accuracy adds (the
        mean of the capsules' ``G_s_database_error``; 0 where not written).
    """

    law: str
    fitted: int
    used: int
    measured: int
    score_median: float
    p_vs_reference: float
    g_s_mean: float
    g_s_std: float
    g_s_interval: tuple[float, float]
    drift: LawDrift | None
    drift_note: str
    status: str
    status_reason: str
    noise: NoiseTest | None = None
    g_s_systematic: float = 0.0


@dataclass(frozen=True)
class PopulationVerdict:
    """The law the batch supports, with its evidence.

    Attributes
    ----------
    kind : str
        'law', 'not_one_material', 'cannot_tell' or 'none'.
    best : str or None
        The law when ``kind`` is 'law' or 'not_one_material'.
    candidates : tuple of str
        The law, or the laws that cannot be told apart; empty for 'none'.
    reason : str
        The verdict in words.
    evidence : dict
        ``LawEvidence`` per law: the verdict or candidates first, then by median score.
    drifts : dict
        ``LawDrift`` per law where the drift could be measured.
    p_better : dict
        ``p_better[(a, b)]``: one-sided paired signed-rank p-value of "a fits no better than b".
    reference : str or None
        The law ``LawEvidence.p_vs_reference`` is against: the verdict, the first candidate, or
        the best-ranked eligible law.
    measured, used : int
        Capsules measured and used.
    left_out : list of (id, reason)
        Capsules left out for every law, and why.
    g_s, g_s_std : float
        Mean G_s of the verdict's law and its spread between capsules [N/m]; NaN otherwise.
    g_s_interval : tuple of float or None
        95 % interval of G_s [N/m] (see the module for 'cannot_tell'); None when none.
    estimator : str
        How G_s and Delta were measured: 'contour fits' (at each law's best shape on the
        contour) or 'lengths' (at the length fit); see ``ESTIMATORS``.
    g_s_systematic : float
        The database's share of the verdict's interval [N/m] (NaN without a verdict).
    heterogeneity : Heterogeneity or None
        One material or several, on the reference law's per-capsule G_s (None where it has
        no G_s).
    """

    kind: str
    best: str | None
    candidates: tuple[str, ...]
    reason: str
    evidence: dict[str, LawEvidence]
    drifts: dict[str, LawDrift]
    p_better: dict[tuple[str, str], float]
    reference: str | None
    measured: int
    used: int
    left_out: list[tuple[str, str]] = field(default_factory=list)
    g_s: float = math.nan
    g_s_std: float = math.nan
    g_s_interval: tuple[float, float] | None = None
    estimator: str = "lengths"
    g_s_systematic: float = math.nan
    heterogeneity: Heterogeneity | None = None

    def line(self) -> str:
        """The verdict on one line (what ``capsmech population`` prints)."""
        if self.kind == "law" and self.best is not None and not math.isfinite(self.g_s):
            return f"verdict: {self.best}, no G_s (no capsule has one: v_c or mu missing) ({self.reason})"
        if self.kind == "law" and self.best is not None:
            interval = self.g_s_interval
            where = (f"95 % interval of the mean {interval[0]:.4g}-{interval[1]:.4g} N/m; "
                     if interval is not None else "")
            return (f"verdict: {self.best}, G_s = {self.g_s:.4g} +- {self.g_s_std:.2g} N/m by {self.estimator} "
                    f"({where}{self.reason})")
        if self.kind == "not_one_material":
            # The reason opens with the groups (capsmech.inversion.heterogeneity).
            return f"verdict: {self.best}, {self.reason}"
        if self.kind == "cannot_tell":
            names = " from ".join([", ".join(self.candidates[:-1]), self.candidates[-1]])
            where = (f"; G_s {self.g_s_interval[0]:.4g}-{self.g_s_interval[1]:.4g} N/m whichever it is"
                     if self.g_s_interval is not None else "; their G_s disagree")
            return f"verdict: cannot tell {names}{where} ({self.reason})"
        return f"verdict: none ({self.reason})"


def number_of(value: Any) -> float:
    """A result cell as a float (NaN where it is not a number)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def flag_of(row: Mapping[str, Any]) -> str:
    """A result row's flag ('' where it has none)."""
    flag = row.get("flag")
    if flag is None or (isinstance(flag, float) and math.isnan(flag)):
        return ""
    return str(flag)


def _mean_interval(values: np.ndarray, systematic: float = 0.0,
                   errors: np.ndarray | None = None) -> tuple[float, float, tuple[float, float]]:
    """(mean, std, 95 % interval of the mean), NaN where fewer than 2 values. The interval's
    half-width is the Student-t one and a systematic half-width (an error every value shares)
    in quadrature; where every value has its own standard deviation (``errors``), the Student
    t multiplies the larger of the scatter's standard error and that of the weighted mean."""
    if len(values) == 0:
        return math.nan, math.nan, (math.nan, math.nan)
    mean = float(values.mean())
    if len(values) < 2:
        return mean, math.nan, (math.nan, math.nan)
    std = float(values.std(ddof=1))
    standard_error = std / math.sqrt(len(values))
    if errors is not None and len(errors) == len(values) and np.all(np.isfinite(errors) & (errors > 0)):
        standard_error = max(standard_error, float(np.sum(errors ** -2.0)) ** -0.5)
    half = math.hypot(float(stats.t.ppf(1 - ALPHA / 2, len(values) - 1)) * standard_error, systematic)
    return mean, std, (mean - half, mean + half)


def paired_p(better: np.ndarray, worse: np.ndarray) -> float:
    """One-sided paired Wilcoxon signed-rank p-value of "``better`` is not smaller than
    ``worse``" (exact for up to 50 capsules; equal pairs and pairs with a NaN drop out; 1 when
    none is left)."""
    d = np.asarray(better, dtype=float) - np.asarray(worse, dtype=float)
    d = d[np.isfinite(d) & (d != 0)]
    if len(d) == 0:
        return 1.0
    return float(stats.wilcoxon(d, alternative="less").pvalue)


def _group(rows: Iterable[Mapping[str, Any]]) -> tuple[list[str], list[str], dict[str, dict[str, Mapping[str, Any]]]]:
    """(capsule ids in order, laws in order, rows by capsule and law)."""
    ids: list[str] = []
    laws: list[str] = []
    table: dict[str, dict[str, Mapping[str, Any]]] = {}
    for row in rows:
        if "id" not in row or "law" not in row:
            raise PopulationInputError("population: every result row needs an 'id' and a 'law' (fit-tube results)")
        cid, law = str(row["id"]), str(row["law"])
        if cid not in table:
            ids.append(cid)
            table[cid] = {}
        if law not in laws:
            laws.append(law)
        if law in table[cid]:
            raise PopulationInputError(f"population: capsule {cid!r} appears twice for law {law} (two batches with "
                                       "the same capsule ids? give each capsule its own id)")
        table[cid][law] = row
    return ids, laws, table


def _left_out(by_law: Mapping[str, Mapping[str, Any]]) -> tuple[str, str] | None:
    """(flag code, reason) of a capsule's law-independent flag, None when it has none."""
    for row in by_law.values():
        if flag_of(row) in LAW_INDEPENDENT_FLAGS:
            return flag_of(row), str(row.get("reason") or "") or f"{flag_of(row)} (the same for every law)"
    return None


def population_verdict(rows: Iterable[Mapping[str, Any]]) -> PopulationVerdict:
    """The law the batch supports (see the module) from fit-tube result rows (columns id, law,
    Delta, G_s, flag, reason, and H_over_a where contours were measured)."""
    ids, laws, table = _group(rows)
    flagged = {cid: flag for cid in ids if (flag := _left_out(table[cid])) is not None}
    left_out = [(cid, reason) for cid, (_, reason) in flagged.items()]
    out = set(flagged)
    used = [cid for cid in ids if cid not in out]

    # G_s and Delta at each law's best shape where fit-tube tested those shapes against the
    # noise (``chi2_shape``): without that test a nearby law's best shapes absorb what the
    # database lacks and its G_s stops drifting (a GH nu_s = 0.35 batch was named GH nu_s = 0.2
    # with G_s 25 % high and a 1.2 % interval); with it such a law misfits the noise.
    estimator = ("contour fits" if any(math.isfinite(number_of(row.get("chi2_shape")))
                                       for cid in used for row in table[cid].values()) else "lengths")
    g_key, delta_key = ESTIMATORS[estimator]

    # Scores and fitted G_s per law over the used capsules.
    scores = {law: np.full(len(used), FAIL_SCORE) for law in laws}
    any_contours = False
    fitted = {law: np.zeros(len(used), dtype=bool) for law in laws}
    # Each law's best shape against the contour's tracing noise, where it was fitted.
    chi2 = {law: np.full(len(used), np.nan) for law in laws}
    for k, cid in enumerate(used):
        fits = {law: row for law, row in table[cid].items() if flag_of(row) in ("", *NO_G_S_FLAGS)}
        for law in fits:
            fitted[law][k] = True
        shapes = {law: number_of(row.get("H_over_a_shape")) for law, row in table[cid].items()}
        if any(np.isfinite(h) for h in shapes.values()):
            # The laws' best shapes on the contour (``capsmech.inversion.shape_fit``).
            any_contours = True
            for law, row in table[cid].items():
                scored = flag_of(row) in SHAPE_SCORED_FLAGS and shapes[law] <= MAX_H_OVER_A
                if scored:
                    scores[law][k] = shapes[law]
                    chi2[law][k] = number_of(row.get("chi2_shape"))
                # With the contour fits as estimator, a law fits a capsule when its best shape
                # does: the length fit's own troubles are superseded (as above), and a length fit
                # whose contour fit fails gives no G_s.
                if estimator == "contour fits":
                    fitted[law][k] = scored
            continue
        # Results without contour fits (written before them): the misfit at the length fit.
        misfit = {law: number_of(row.get("H_over_a")) for law, row in fits.items()}
        contours = bool(fits) and all(np.isfinite(h) for h in misfit.values())
        any_contours = any_contours or contours
        for law in fits:
            scores[law][k] = misfit[law] if contours else 0.0
    drifts: dict[str, LawDrift] = {}
    drift_notes: dict[str, str] = {}
    g_stats = {}
    g_systematic: dict[str, float] = {}
    # Each law's per-capsule G_s with their ids and the contour fits' own uncertainties.
    per_capsule: dict[str, tuple[list[str], np.ndarray, np.ndarray]] = {}
    for law in laws:
        if estimator == "contour fits":
            mine = [table[cid][law] for k, cid in enumerate(used) if math.isfinite(chi2[law][k])]
        else:
            mine = [table[cid][law] for k, cid in enumerate(used) if fitted[law][k] and flag_of(table[cid][law]) == ""]
        delta = np.array([number_of(r.get(delta_key)) for r in mine])
        g = np.array([number_of(r.get(g_key)) for r in mine])
        # The database's own accuracy, shared by every capsule (fit-tube's G_s_database_error):
        # in the interval of the mean, and as the drift it can make.
        errors = np.array([number_of(r.get("G_s_database_error")) for r in mine])
        shared = errors[np.isfinite(g)]
        g_systematic[law] = float(np.mean(shared[np.isfinite(shared)])) if np.any(np.isfinite(shared)) else 0.0
        own = np.array([number_of(r.get("G_s_shape_error")) if estimator == "contour fits" else math.nan
                        for r in mine])
        g_stats[law] = _mean_interval(g[np.isfinite(g)], g_systematic[law], own[np.isfinite(g)])
        per_capsule[law] = ([str(r["id"]) for r in mine], g, own)
        try:
            drifts[law] = law_drift(law, delta, g, errors)
        except ValueError as exc:
            drift_notes[law] = str(exc)

    noise = {law: noise_test(chi2[law]) for law in laws}
    n = len(used)
    # The paired test compares the contours' chi2 where fit-tube measured it (the misfit the fit
    # minimises, each capsule over its own noise), else the H/a scores. On the independent
    # generator's SK C = 1 batches, H/a let GH nu_s 0.5 through twice in 50 (its chi2 1.26 and
    # 1.44 a degree of freedom against SK's 0.82 and 1.07, Wilcoxon p on H/a ~0.03) when SK's
    # G_s drifted by chance; on the chi2 SK wins both, and no verdict is lost elsewhere.
    compared: dict[str, np.ndarray] = dict(scores)
    if estimator == "contour fits":
        compared = {law: np.where(scores[law] >= FAIL_SCORE, FAIL_CHI2, chi2[law]) for law in laws}
    p_better = {(a, b): paired_p(compared[a], compared[b]) for a in laws for b in laws if a != b} if n else {}
    medians = {law: float(np.median(scores[law])) if n else math.nan for law in laws}
    means = {law: float(np.mean(scores[law])) if n else math.nan for law in laws}
    order = sorted(laws, key=lambda law: (medians[law], means[law], law))
    count = {law: int(fitted[law].sum()) for law in laws}
    eligible = [law for law in order if n and count[law] >= MIN_FITTED_FRACTION * n]

    status: dict[str, tuple[str, str]] = {}
    for law in order:
        if n < MIN_CAPSULES:
            status[law] = ("no verdict", f"{n} usable capsules, a verdict needs {MIN_CAPSULES}")
        elif law not in eligible:
            status[law] = ("fits < half", f"fits {count[law]} of {n} capsules, fewer than half")
        elif law in drifts and drifts[law].drifts:
            status[law] = ("drifts", f"G_s drifts with Delta (p = {drifts[law].p_value:.2g})"
                           + ("; its best shapes also miss the contours by more than the tracing noise ("
                              + test.line() + ")" if (test := noise[law]) is not None and not test.consistent else ""))
        elif (test := noise[law]) is not None and not test.consistent:
            status[law] = ("misfits noise", "its best shapes miss the contours by more than the tracing noise: "
                           + test.line())
        else:
            rivals = [(p_better[(other, law)], other) for other in eligible if other != law]
            beaten = min(rivals) if rivals else (1.0, "")
            if beaten[0] < CONTOUR_LEVEL:
                status[law] = ("worse contours", f"{beaten[1]} fits the contours better (p = {beaten[0]:.2g})")
            else:
                note = (f"G_s does not drift (p = {drifts[law].p_value:.2g})" if law in drifts
                        else "drift not measured: " + drift_notes[law])
                status[law] = ("candidate", f"no law fits the contours significantly better; {note}")
    candidates = [law for law in order if status[law][0] == "candidate"]

    kind, best, g_s, g_s_std, interval = "none", None, math.nan, math.nan, None
    if n < MIN_CAPSULES:
        codes = sorted({code for code, _ in flagged.values()})
        why = "; ".join(f"{sum(c == code for c, _ in flagged.values())} {code} ("
                        + ", ".join(cid for cid, (c, _) in flagged.items() if c == code) + ")" for code in codes)
        reason = (f"{n} usable capsules of {len(ids)} measured, a verdict needs {MIN_CAPSULES}"
                  + (f"; left out for every law: {why}" if why else ""))
    elif len(candidates) == 1:
        kind = "law"
        best = candidates[0]
        g_s, g_s_std, (low, high) = g_stats[best]
        interval = (low, high) if np.isfinite(low) else None
        others = [law for law in order if law != best]
        against = "; ".join(f"{law}: {status[law][1]}" for law in others)
        drift = f"G_s does not drift (p = {drifts[best].p_value:.2g})" if best in drifts else "drift not measured"
        shape = f"median H/a {medians[best]:.4f}" if any_contours else "no contours (fitted or not counted)"
        if (test := noise[best]) is not None:
            shape += f", its shapes consistent with the tracing noise ({test.line()})"
        reason = (f"fits {count[best]} of {n} capsules, {shape}, {drift}"
                  + (f"; {against}" if against else ""))
    elif candidates:
        kind = "cannot_tell"
        lows = [g_stats[law][2][0] for law in candidates]
        highs = [g_stats[law][2][1] for law in candidates]
        # G_s lies in the hull of the candidates' intervals whichever of them is right, also when
        # they do not overlap: that is the answer the batch supports, and the gap between them is
        # what telling the law would remove.
        if all(np.isfinite(lows + highs)):
            interval = (min(lows), max(highs))
        top = candidates[0]
        ps = ", ".join(f"{law} p = {p_better[(top, law)]:.2g}" for law in candidates[1:])
        apart = ("; their own intervals do not overlap: knowing the law would narrow G_s (capsules at larger "
                 "deformation, where the laws' shapes differ most, tell them apart)"
                 if interval is not None and max(lows) > min(highs) else "")
        reason = (f"the contours do not tell them apart ({top} fits best; against it {ps}) and the drift does "
                  "not separate them"
                  + "; " + ", ".join(f"{law}: G_s = {g_stats[law][0]:.4g} N/m "
                                     f"[{g_stats[law][2][0]:.4g}, {g_stats[law][2][1]:.4g}]" for law in candidates)
                  + apart)
    elif not eligible:
        most = max(order, key=lambda law: count[law]) if order else None
        reason = (f"no law of the database fits: every law fits fewer than half of the {n} usable capsules"
                  + (f" (the most, {most}, fits {count[most]})" if most else ""))
    else:
        outshone = [law for law in eligible if status[law][0] == "worse contours"]
        misfits = [law for law in eligible if status[law][0] == "misfits noise"]
        details = "; ".join(f"{law}: {status[law][1]}" for law in eligible)
        if misfits:
            # The closest: the smallest chi2 per degree of freedom among the laws that pass
            # every other test; by how much it falls short, and what the others did.
            tests = {law: test for law in misfits if (test := noise[law]) is not None}
            closest = min(tests, key=lambda law: tests[law].reduced_chi2)
            rest = "; ".join(f"{law}: {status[law][1]}" for law in eligible if law != closest)
            reason = (f"no law of the database fits: the closest, {closest}, misses the contours by more than the "
                      f"tracing noise ({tests[closest].line()})"
                      + (f"; {rest}" if rest else ""))
        elif outshone:
            reason = (f"no law of the database fits: the laws whose G_s does not drift fit the contours worse than "
                      f"a law whose G_s drifts ({details}): the tests disagree")
        else:
            reason = ("no law of the database fits: every law that fits at least half of the capsules has a G_s "
                      f"that drifts with Delta ({details})")

    reference = best or (candidates[0] if candidates else (eligible[0] if eligible else (order[0] if order else None)))
    # One material or several, on the reference law's G_s: a mixed batch gets no single G_s.
    mixture = None
    if reference is not None and np.any(np.isfinite(per_capsule[reference][1])):
        mean_g = g_stats[reference][0]
        mixture = heterogeneity(*per_capsule[reference],
                                systematic_rel=g_systematic[reference] / mean_g if mean_g > 0 else 0.0)
    if mixture is not None and not mixture.one_material and kind in ("law", "cannot_tell"):
        reason = f"{mixture.line()}; " + reason
        if kind == "law":
            kind, g_s, interval = "not_one_material", math.nan, None
        else:
            interval = None
    evidence = {}
    # The verdict and the candidates first, then by contour score.
    for law in sorted(order, key=lambda law: (law not in candidates, order.index(law))):
        mean, std, g_interval = g_stats[law]
        evidence[law] = LawEvidence(
            law=law, fitted=count[law], used=n, measured=len(ids), score_median=medians[law],
            p_vs_reference=p_better.get((reference, law), math.nan) if reference else math.nan,
            g_s_mean=mean, g_s_std=std, g_s_interval=g_interval, drift=drifts.get(law),
            drift_note=drift_notes.get(law, ""),
            status="verdict" if law == best else status[law][0], status_reason=status[law][1], noise=noise[law],
            g_s_systematic=g_systematic[law])
    return PopulationVerdict(kind=kind, best=best, candidates=tuple(candidates) if kind != "none" else (),
                             reason=reason, evidence=evidence, drifts=drifts, p_better=p_better, reference=reference,
                             measured=len(ids), used=n, left_out=left_out, g_s=g_s, g_s_std=g_s_std,
                             g_s_interval=interval, estimator=estimator,
                             g_s_systematic=g_systematic[best] if best is not None else math.nan,
                             heterogeneity=mixture)
