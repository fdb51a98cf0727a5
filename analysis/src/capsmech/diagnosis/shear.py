"""Diagnose shear (Couette microrheometry) batches: is the viscosity ratio lambda, or another
law, what the base analysis lacks? (issue 7, "viscosity ratio lambda (shear)")

Tube batches cannot see lambda (a steady capsule moves rigidly with its inner fluid,
``capsmech.diagnosis.diagnose.NOT_ASSESSED``); a capsule in shear tank-treads, so lambda sets its steady
D12 and the Ca_s read from it. A batch of one material analysed with the wrong lambda gives a
G_s that drifts with D12 (the two databases' G_s ratio grows from 1.13 to 1.37 over D12
0.35-0.5 for NH, ``capsmech.inversion.microrheometry``), and that drift is the signature used here.

Score of a law group (a database law key, e.g. ``NH`` or ``NH+lambda0.001``)
-------------------------------------------------------------------------------
How well one G_s explains the batch. Each capsule is fitted along the group's steady branch
(``ShearInverter``: Ca_s and L3/a from D12 = (L1 - L2)/(L1 + L2), a = sqrt(L1 L2 L3/a),
G_s = mu gamma_dot a / Ca_s), giving y_i = ln G_s,i with standard error s_i propagated from
the semi-axes' measurement noise (finite differences of y in L1 and L2):

    noise model: L1 and L2 each off by an independent uniform error in [-e, e] pixels
    (e = 1, the paper's +-1 pixel), standard deviation e p / sqrt(3) with p the capsule's
    ``pixel_size`` column, else ``pixel_size`` given (0.5 um by default); gamma_dot and mu exact.

    chi2 = sum_i ((y_i - y_bar) / s_i)^2,   y_bar the weighted mean (weights 1/s_i^2).

When the batch carries the inclination angle theta (optional column), each capsule adds
((theta_i - theta_g(D12_i)) / sigma_theta,i)^2, theta_g the group's steady theta at the
measured D12 (no free parameter: lambda turns the capsule towards the flow, 5-7 deg at
D12 ~ 0.5); sigma_theta,i^2 = e_theta^2 + (theta_g' s_D12)^2, e_theta the angle's measurement
error (1 deg by default), s_D12 from the semi-axes' noise (its correlation with y_i is left out:
the angle's own error dominates).

Candidates: the viscosity ratio (the group ``<base>+lambda<X>`` of the lambda database, a
discrete candidate as ``capsmech.diagnosis.candidates.law_candidate``) and every other law of the shear
database. A capsule outside a group's D12 range (or below D12 = 0.35, paper section 4.3) is
flagged with the reason, never given a number; a candidate is scored on the capsules both
its group and the base group fit.

A candidate is **supported** (the rule of ``capsmech.diagnose``) when
- the BIC falls by more than ``MIN_BIC_DROP``: chi2_base - chi2_candidate - ln n > 6 (one
  parameter more: the group), and
- leave-one-capsule-out cross-validation improves: each held-out capsule's y_i predicted by
  the weighted mean of the others, its squared standardised error smaller under the
  candidate (one-sided Wilcoxon signed-rank test across capsules, p < 0.05).
The supported candidate with the largest BIC drop is named; none supported is a valid answer.
G_s is reported as exp(y_bar) with its standard error, scaled by sqrt(chi2/(n-1)) when that
exceeds 1 (scatter beyond the noise model), and beside it the database's share of the error
(``database_error``: the capsules read the same rows, so the G_s errors that the rows' stated
D12 errors imply are shared and do not average out; ``Evidence.g_s_systematic``), and the drift of G_s with D12 as the p-value of
``capsmech.inversion.population.law_drift`` (G_s/mean against D12).
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import stats
from scipy.interpolate import PchipInterpolator

from capsmech.diagnosis.scoring import CV_ALPHA, MIN_BIC_DROP, Evidence, rivals_of
from capsmech.inversion.fitting import shear_inverter
from capsmech.inversion.inverters import ShearInverter
from capsmech.inversion.population import law_drift
from capsmech.io.measurements import Capsule

#: Default pixel size [m] when the batch has no ``pixel_size`` column, and the error bound
#: of each semi-axis in pixels (uniform in [-e, e]).
PIXEL_SIZE = 0.5e-6
ERROR_PX = 1.0
#: Standard deviation of a measured inclination angle [rad] (1 deg).
THETA_ERROR = math.radians(1.0)
#: The lambda database's viscosity ratio, as in its law keys.
LAMBDA_VALUE = "0.001"


def lambda_key(base_law: str, value: str = LAMBDA_VALUE) -> str:
    """The law key of the base law at another viscosity ratio (``NH+lambda0.001``)."""
    return f"{base_law}+lambda{value}"


@dataclass
class GroupScore:
    """One law group's fit of the batch: per capsule y = ln G_s [ln N/m], its standard error s,
    the measured D12, a flag (empty when fitted), the standardised inclination residual t
    (0 where the capsule has no theta), and e, the relative error of G_s that the database's
    stated D12 errors imply at the capsule's D12 (``ShearFit.database_error_rel``; NaN where
    the rows state none)."""

    law: str
    ids: list[str]
    y: np.ndarray
    s: np.ndarray
    d12: np.ndarray
    flags: list[str]
    t: np.ndarray = field(default_factory=lambda: np.empty(0))
    e: np.ndarray = field(default_factory=lambda: np.empty(0))

    @property
    def fitted(self) -> np.ndarray:
        return np.isfinite(self.y) & np.isfinite(self.s) & (self.s > 0)


def length_error(capsule: Capsule, pixel_size: float = PIXEL_SIZE, error_px: float = ERROR_PX) -> float:
    """Standard deviation [m] of a semi-axis under the noise model (see the module)."""
    pixel = capsule["pixel_size"] if math.isfinite(capsule["pixel_size"]) else pixel_size
    return error_px * pixel / math.sqrt(3.0)


def _ln_g(inverter: ShearInverter, L1: float, L2: float, rate: float, mu: float) -> float:
    fit = inverter.fit(L1=L1, L2=L2, shear_rate=rate, mu=mu)
    return math.log(fit.G_s) if fit.ok and fit.G_s and fit.G_s > 0 else math.nan


def theta_curve(rows: dict[str, np.ndarray]) -> PchipInterpolator:
    """A group's steady inclination theta [rad] against D12 (PCHIP, no extrapolation), from
    its database rows (``LawTable.steady_rows()``)."""
    ca, d12, theta = (np.asarray(rows[k], dtype=float) for k in ("Ca_s", "D12", "theta"))
    keep = np.isfinite(ca) & np.isfinite(d12) & np.isfinite(theta)
    order = np.argsort(ca[keep])
    return PchipInterpolator(d12[keep][order], theta[keep][order], extrapolate=False)


def score_group(capsules: Sequence[Capsule], inverter: ShearInverter, law: str, pixel_size: float = PIXEL_SIZE,
                error_px: float = ERROR_PX, theta: PchipInterpolator | None = None,
                theta_error: float = THETA_ERROR) -> GroupScore:
    """Fit every capsule with one group; ln G_s, its standard error, flags, and with ``theta``
    (the group's theta(D12)) the inclination residual of capsules that carry theta (see the module)."""
    n = len(capsules)
    y, s, d12 = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    t = np.zeros(n)
    e = np.full(n, np.nan)
    flags = [""] * n
    for i, c in enumerate(capsules):
        L1, L2, rate, mu = c["L1"], c["L2"], c["shear_rate"], c["mu"]
        d12[i] = (L1 - L2) / (L1 + L2)
        fit = inverter.fit(L1=L1, L2=L2, shear_rate=rate, mu=mu)
        if not fit.ok:
            flags[i] = fit.flag
            continue
        y[i] = math.log(fit.G_s)
        e[i] = fit.database_error_rel
        sigma = length_error(c, pixel_size, error_px)
        # A step well below the noise: the branch is smooth on that scale. One-sided at a
        # range edge (the perturbed capsule leaves the database).
        h = 1e-3 * sigma
        gradient = []
        for dL1, dL2 in ((h, 0.0), (0.0, h)):
            up = _ln_g(inverter, L1 + dL1, L2 + dL2, rate, mu)
            down = _ln_g(inverter, L1 - dL1, L2 - dL2, rate, mu)
            if math.isfinite(up) and math.isfinite(down):
                gradient.append((up - down) / (2 * h))
            elif math.isfinite(up) or math.isfinite(down):
                gradient.append((up - y[i]) / h if math.isfinite(up) else (y[i] - down) / h)
            else:
                gradient.append(math.nan)
        s[i] = sigma * math.hypot(*gradient)
        if not math.isfinite(s[i]):
            y[i] = np.nan
            flags[i] = "no standard error: the capsule sits on the database's edge"
            continue
        if theta is not None and math.isfinite(c["theta"]):
            s_d12 = sigma * 2 * math.hypot(L1, L2) / (L1 + L2) ** 2
            predicted, slope = float(theta(d12[i])), float(theta.derivative()(d12[i]))
            t[i] = (c["theta"] - predicted) / math.hypot(theta_error, slope * s_d12)
    return GroupScore(law, [c.id for c in capsules], y, s, d12, flags, t, e)


def weighted_mean(y: np.ndarray, s: np.ndarray) -> tuple[float, float, float]:
    """(y_bar, its standard error from the noise model alone, chi2) of values y with errors s."""
    w = 1.0 / s ** 2
    mean = float(np.sum(w * y) / np.sum(w))
    return mean, float(1.0 / math.sqrt(np.sum(w))), float(np.sum(w * (y - mean) ** 2))


def leave_one_out_errors(y: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Squared standardised error of each value predicted by the weighted mean of the others."""
    w = 1.0 / s ** 2
    others = (np.sum(w * y) - w * y) / (np.sum(w) - w)
    return ((y - others) / s) ** 2


def modulus(y: np.ndarray, s: np.ndarray) -> tuple[float, float]:
    """G_s [N/m] = exp(y_bar) and its standard error, scaled by sqrt(chi2/(n-1)) when above 1."""
    mean, se, chi2 = weighted_mean(y, s)
    birge = math.sqrt(chi2 / (len(y) - 1)) if len(y) > 1 else 1.0
    g = math.exp(mean)
    return g, g * se * max(1.0, birge)


def database_error(g_s: float, s: np.ndarray, e: np.ndarray) -> float:
    """The database's share [N/m] of the error of the batch G_s ``modulus`` gives: every
    capsule's G_s reads the same rows, so their stated errors move all capsules the same way
    and do not average out. It is the weighted mean (weights 1/s^2, as the modulus) of the
    capsules' relative errors e, times G_s; capsules whose rows state no error count 0."""
    if len(s) == 0 or not math.isfinite(g_s):
        return 0.0
    w = 1.0 / s ** 2
    return float(g_s * np.sum(w * np.nan_to_num(e)) / np.sum(w))


def drift_p_value(law: str, d12: np.ndarray, y: np.ndarray) -> float:
    """p-value of the slope of G_s/mean against D12 (``law_drift``); NaN when not measurable."""
    if len(y) < 3 or np.ptp(d12) == 0:
        return math.nan
    return law_drift(law, d12, np.exp(y)).p_value


@dataclass
class ShearCandidateResult(Evidence):
    """One candidate group against the base group, on the capsules both fit."""

    law: str = ""
    #: The inclination's part of chi2_base and chi2 (0 without theta).
    chi2_theta_base: float = math.nan
    chi2_theta: float = math.nan
    #: The database's share [N/m] of the error of G_s before and after (``database_error``).
    g_s_systematic: tuple[float, float] = (0.0, 0.0)
    score: GroupScore | None = field(default=None, repr=False)
    used: np.ndarray | None = field(default=None, repr=False)


def evaluate(base: GroupScore, candidate: GroupScore, name: str) -> ShearCandidateResult:
    """The criteria of one candidate group against the base (see the module)."""
    result = ShearCandidateResult(name, candidate.law, score=candidate)
    used = base.fitted & candidate.fitted
    result.used = used
    result.capsules = n = int(used.sum())
    if n < 3:
        result.note = f"only {n} capsules fitted by both groups: not assessed"
        return result
    yb, sb, yc, sc = base.y[used], base.s[used], candidate.y[used], candidate.s[used]
    tb, tc = base.t[used] ** 2, candidate.t[used] ** 2
    result.chi2_theta_base, result.chi2_theta = float(tb.sum()), float(tc.sum())
    result.chi2_base = weighted_mean(yb, sb)[2] + result.chi2_theta_base
    result.chi2 = weighted_mean(yc, sc)[2] + result.chi2_theta
    result.bic_drop = result.chi2_base - result.chi2 - math.log(n)
    # theta has no fitted parameter: its held-out error is its own residual.
    gains = (leave_one_out_errors(yb, sb) + tb) - (leave_one_out_errors(yc, sc) + tc)
    result.cv_gain = float(gains.mean())
    result.cv_gain_error = float(gains.std(ddof=1) / math.sqrt(n))
    result.cv_p_value = float(stats.wilcoxon(gains, alternative="greater").pvalue) if np.any(gains != 0) else 1.0
    result.supported = bool(result.cv_p_value < CV_ALPHA and result.bic_drop > MIN_BIC_DROP)
    result.g_s_before, result.g_s_after = modulus(yb, sb), modulus(yc, sc)
    result.g_s_systematic = (database_error(result.g_s_before[0], sb, base.e[used]),
                             database_error(result.g_s_after[0], sc, candidate.e[used]))
    d12 = base.d12[used]
    result.drift_p_before = drift_p_value(base.law, d12, yb)
    result.drift_p_after = drift_p_value(candidate.law, d12, yc)
    return result


@dataclass
class ShearDiagnosis:
    """Every candidate's result, the base group's fit and the verdict."""

    base_law: str
    base: GroupScore
    results: list[ShearCandidateResult]
    chosen: ShearCandidateResult | None

    @property
    def rivals(self) -> list[ShearCandidateResult]:
        """Other supported candidates within MIN_BIC_DROP of the chosen one."""
        return rivals_of(self.chosen, self.results)

    @property
    def verdict(self) -> str:
        if self.chosen is None:
            return "no candidate is supported: one G_s explains the batch within its noise"
        c = self.chosen
        rivals = ""
        if self.rivals:
            rivals = "; these data cannot tell it from " + ", ".join(
                f"{r.name} (BIC drop {r.bic_drop:.1f})" for r in self.rivals)
        return (f"{c.name} (group {c.law}): BIC drop {c.bic_drop:.1f}, cross-validated chi2 gain "
                f"{c.cv_gain:.2f} +- {c.cv_gain_error:.2f} per capsule (p = {c.cv_p_value:.2g}); G_s "
                f"{g_s_text(c.g_s_before, c.g_s_systematic[0], '+-')} -> "
                f"{g_s_text(c.g_s_after, c.g_s_systematic[1], '+-')} N/m, "
                f"drift p {c.drift_p_before:.2g} -> {c.drift_p_after:.2g}" + rivals)


def g_s_text(g_s: tuple[float, float], database: float, plus_minus: str = "±") -> str:
    """G_s ± its standard error, and the database's share (``database_error``) when stated."""
    text = f"{g_s[0]:.4g} {plus_minus} {g_s[1]:.2g}"
    return text + (f" (database {plus_minus} {database:.2g})" if database > 0 else "")


class ShearGroups:
    """Shear databases seen as one: a law key is read from the first database that has it."""

    def __init__(self, databases: Sequence) -> None:
        self.databases = list(databases)

    @property
    def laws(self) -> list[str]:
        return list(dict.fromkeys(key for d in self.databases for key in d.laws))

    def _database(self, key: str):
        for database in self.databases:
            if key in database.laws:
                return database
        raise KeyError(f"no shear database has law {key!r} (they have {', '.join(self.laws)})")

    def inverter(self, key: str) -> ShearInverter:
        return shear_inverter(self._database(key), key)

    def theta(self, key: str) -> PchipInterpolator:
        return theta_curve(self._database(key).law(key).steady_rows())


def default_candidates(base_law: str, laws: Iterable[str], lambda_value: str = LAMBDA_VALUE) -> dict[str, str]:
    """Candidate name -> law key: the viscosity ratio, then every other law without an effect."""
    out = {f"viscosity ratio lambda = {lambda_value}": lambda_key(base_law, lambda_value)}
    out.update({f"law {key}": key for key in laws if key != base_law and "+" not in key})
    return out


def diagnose_shear(capsules: Sequence[Capsule], databases: ShearGroups | Sequence, base_law: str = "NH",
                   candidates: dict[str, str] | None = None, pixel_size: float = PIXEL_SIZE,
                   error_px: float = ERROR_PX, theta_error: float = THETA_ERROR) -> ShearDiagnosis:
    """Test the candidate groups on a shear batch fitted with ``base_law`` (see the module).

    Parameters
    ----------
    capsules : sequence of Capsule
        The batch in SI units (``read_measurements(path, 'shear')``).
    databases : ShearGroups or sequence of ShearDatabase
        The lambda = 1 shear database first, then the lambda database(s).
    base_law : str
        The law key the batch is analysed with.
    candidates : dict, optional
        Candidate name -> law key (default ``default_candidates``).
    pixel_size, error_px : float
        The noise model where the batch has no ``pixel_size`` column [m], and the error bound [px].
    theta_error : float
        Standard deviation of a measured theta [rad] (used for capsules that carry theta).

    Raises
    ------
    ValueError
        Fewer than 3 capsules, or a law key no database has.
    """
    groups = databases if isinstance(databases, ShearGroups) else ShearGroups(databases)
    if len(capsules) < 3:
        raise ValueError(f"diagnose-shear needs at least 3 capsules, the batch has {len(capsules)}")
    if candidates is None:
        candidates = default_candidates(base_law, groups.laws)
    for key in [base_law, *candidates.values()]:
        if key not in groups.laws:
            raise ValueError(f"no shear database has law {key!r} (they have {', '.join(groups.laws)})")
    def score(key: str) -> GroupScore:
        return score_group(capsules, groups.inverter(key), key, pixel_size, error_px, groups.theta(key), theta_error)

    base = score(base_law)
    results = [evaluate(base, score(key), name) for name, key in candidates.items()]
    supported = [r for r in results if r.supported]
    chosen = max(supported, key=lambda r: r.bic_drop) if supported else None
    return ShearDiagnosis(base_law, base, results, chosen)


def _shown(diagnosis: ShearDiagnosis) -> ShearCandidateResult | None:
    if diagnosis.chosen is not None:
        return diagnosis.chosen
    assessed = [r for r in diagnosis.results if math.isfinite(r.bic_drop)]
    return max(assessed, key=lambda r: r.bic_drop) if assessed else None


def write_figure(diagnosis: ShearDiagnosis, path: Path) -> Path | None:
    """G_s of each capsule against D12 before (base group) and after (the chosen candidate, else
    the one with the largest BIC drop), error bars from the noise model."""
    shown = _shown(diagnosis)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.6))
    pairs = [(f"before: {diagnosis.base_law}", diagnosis.base, "tab:grey")]
    if shown is not None and shown.score is not None:
        pairs.append((f"after: {shown.name}", shown.score, "tab:blue"))
    for label, score, colour in pairs:
        ok = score.fitted
        g = np.exp(score.y[ok])
        ax.errorbar(score.d12[ok], g, yerr=g * score.s[ok], fmt="o", ms=4, color=colour, label=label, capsize=2)
        if ok.sum() >= 2:
            mean, _ = modulus(score.y[ok], score.s[ok])
            ax.axhline(mean, color=colour, lw=0.8, ls="--")
    ax.set_xlabel("measured D12")
    ax.set_ylabel(r"$G_s$ [N/m]")
    ax.legend(fontsize=8)
    ax.set_title("One material, one G_s: a drift with D12 is a missing effect", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_report(diagnosis: ShearDiagnosis, out: str | Path, batch: str = "", figures: bool = True) -> Path:
    """A Markdown report: the verdict, a table of the candidates, the flagged capsules and the
    figure of G_s against D12 (written whole: temporary name, then renamed)."""
    out = Path(out)

    def theta_part(r: ShearCandidateResult) -> str:
        return f" (theta: {r.chi2_theta_base:.1f} -> {r.chi2_theta:.1f})" if r.chi2_theta_base or r.chi2_theta else ""

    lines = [f"# capsmech diagnose-shear{': ' + batch if batch else ''}", "",
             f"Base law: `{diagnosis.base_law}` (lambda = 1).", "", f"**Verdict:** {diagnosis.verdict}.", "",
             "| candidate | group | capsules | chi2 base -> candidate | BIC drop | CV gain per capsule (p) "
             "| G_s before [N/m] | G_s after [N/m] | drift p before -> after | supported |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in diagnosis.results:
        if r.note:
            lines.append(f"| {r.name} | {r.law} | {r.capsules} | | | | | | | {r.note} |")
            continue
        lines.append(
            f"| {r.name} | {r.law} | {r.capsules} | {r.chi2_base:.1f} -> {r.chi2:.1f}{theta_part(r)} | {r.bic_drop:.1f} "
            f"| {r.cv_gain:.2f} ± {r.cv_gain_error:.2f} ({r.cv_p_value:.2g}) "
            f"| {g_s_text(r.g_s_before, r.g_s_systematic[0])} | {g_s_text(r.g_s_after, r.g_s_systematic[1])} "
            f"| {r.drift_p_before:.2g} -> {r.drift_p_after:.2g} | {'yes' if r.supported else 'no'} |")
    lines += ["", f"Supported: the BIC drops by more than {MIN_BIC_DROP:g} (chi2_base - chi2 - ln n) and "
              f"leave-one-capsule-out cross-validation improves (one-sided Wilcoxon p < {CV_ALPHA}). chi2: "
              "scatter of ln G_s about the weighted mean, over each capsule's standard error from +-1 pixel "
              "(uniform) on L1 and L2, plus, for capsules with theta, its residuals over the angle's error. G_s: weighted mean ± standard error (scaled by sqrt(chi2/(n-1)) when "
              "above 1); in brackets the database's share, which averaging over capsules does not reduce: the "
              "weighted mean of the relative G_s errors that its rows' stated D12 errors imply (time and mesh, "
              "`fit-shear`'s G_s_database_error). Drift p: slope of G_s/mean against D12 (capsmech.inversion.population.law_drift).", ""]
    groups = [diagnosis.base] + [r.score for r in diagnosis.results if r.score is not None]
    flagged = [(g.law, cid, flag) for g in groups for cid, flag in zip(g.ids, g.flags) if flag]
    if flagged:
        lines += ["Flagged capsules (not fitted by that group):", "", "| group | capsule | reason |", "|---|---|---|"]
        lines += [f"| {law} | {cid} | {flag} |" for law, cid, flag in flagged] + [""]
    if figures:
        path = write_figure(diagnosis, out.with_name(f"{out.stem}_gs_d12.png"))
        if path is not None:
            lines += [f"![G_s against D12 before and after]({path.name})", ""]
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text("\n".join(lines), encoding="utf-8")
    tmp.replace(out)
    return out
