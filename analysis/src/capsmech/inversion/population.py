"""Population analysis (paper section 4.4): which membrane law gives one G_s at every deformation.

G_s is a material property: fitted with the right law it does not drift with the capsules'
deformation, measured by the mean profile elongation Delta = p / (2 pi a). For each law the
fitted G_s of a batch are regressed on Delta (least squares, ``scipy.stats.linregress``); the
drift is the slope relative to the mean G_s, with its 95 % confidence interval (Student t)
and the p-value of "no drift".

The drift test alone has little power where two laws map the same lengths onto each other by
a rescaling of G_s (an NH fit of a GH nu_s = 0.5 batch gives twice the modulus and no drift
over Delta 1.03-1.2). The contours tell those laws apart: each capsule's misfit H/a to the
profile fitted with each law is compared across the batch by a paired Wilcoxon signed-rank
test (``shape_comparison``). The verdict (``population_verdict``):

- when the contours single out a law (smaller H/a than every other law, p < alpha), that law,
  provided its G_s does not drift; if it drifts, no law (the two tests disagree);
- otherwise (no contours, or no significant difference) the law whose drift is least
  significant (largest p-value) among those with p >= alpha; when every law drifts, none.
"""
from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike
from scipy import stats

if TYPE_CHECKING:
    from matplotlib.figure import Figure

#: Significance level of the drift test.
ALPHA = 0.05


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
        Student statistic of the slope and the two-sided p-value of slope = 0.
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

    @property
    def drifts(self) -> bool:
        return self.p_value < ALPHA


def law_drift(law: str, delta: ArrayLike, g_s: ArrayLike) -> LawDrift:
    """Regress G_s / mean(G_s) on Delta for one law (needs at least 3 capsules)."""
    x, g = np.asarray(delta, dtype=float), np.asarray(g_s, dtype=float)
    keep = np.isfinite(x) & np.isfinite(g)
    x, g = x[keep], g[keep]
    if len(x) < 3:
        raise ValueError(f"law {law}: {len(x)} capsules with G_s and Delta, the drift test needs 3")
    if np.ptp(x) == 0:
        raise ValueError(f"law {law}: every capsule has the same Delta, the drift cannot be measured")
    mean = float(g.mean())
    fit = stats.linregress(x, g / mean)
    t_crit = stats.t.ppf(1 - ALPHA / 2, len(x) - 2)
    t_stat = fit.slope / fit.stderr if fit.stderr > 0 else math.inf
    return LawDrift(law=law, n=len(x), mean=mean, std=float(g.std(ddof=1)), slope=float(fit.slope),
                    ci_low=float(fit.slope - t_crit * fit.stderr), ci_high=float(fit.slope + t_crit * fit.stderr),
                    t=float(t_stat), p_value=float(fit.pvalue))


#: Capsules with a contour misfit under every law that the shape comparison needs (the
#: two-sided signed-rank test cannot reach p < 0.05 with fewer than 6 pairs).
MIN_SHAPE_PAIRS = 6


@dataclass(frozen=True)
class ShapeComparison:
    """Contour misfit H/a of the same capsules under each law.

    Attributes
    ----------
    n : int
        Capsules fitted (without flag, finite H/a) by every law compared.
    median : dict
        Median H/a per law over those capsules.
    p_values : dict
        Two-sided p-value of the paired signed-rank test per pair of laws (sorted keys).
    best : str or None
        The law whose H/a is the smallest and smaller than each other law's with p < alpha.
    """

    n: int
    median: dict[str, float]
    p_values: dict[tuple[str, str], float]
    best: str | None


@dataclass(frozen=True)
class PopulationVerdict:
    """Drift per law, the shape comparison (None without contours) and the law reported."""

    drifts: dict[str, LawDrift]
    shape: ShapeComparison | None
    best: str | None
    reason: str


def _number(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def shape_comparison(rows: Iterable[Mapping[str, Any]]) -> ShapeComparison | None:
    """Compare the laws by the contour misfit ``H_over_a`` of fit-tube rows (flagged rows
    excluded); None when fewer than two laws or ``MIN_SHAPE_PAIRS`` capsules have one."""
    misfit: dict[str, dict[str, float]] = {}
    for row in rows:
        value = _number(row.get("H_over_a"))
        if not row.get("flag") and np.isfinite(value):
            misfit.setdefault(str(row["law"]), {})[str(row["id"])] = value
    laws = sorted(misfit)
    if len(laws) < 2:
        return None
    common = sorted(set.intersection(*(set(misfit[law]) for law in laws)))
    if len(common) < MIN_SHAPE_PAIRS:
        return None
    h = {law: np.array([misfit[law][c] for c in common]) for law in laws}
    p_values = {(a, b): float(stats.wilcoxon(h[a], h[b]).pvalue) for i, a in enumerate(laws) for b in laws[i + 1:]}
    median = {law: float(np.median(h[law])) for law in laws}
    smallest = min(laws, key=median.__getitem__)
    decisive = all(p_values[(min(smallest, other), max(smallest, other))] < ALPHA for other in laws if other != smallest)
    return ShapeComparison(len(common), median, p_values, smallest if decisive else None)


def population_verdict(rows: Iterable[Mapping[str, Any]]) -> PopulationVerdict:
    """Drift per law from fit-tube result rows (columns id, law, Delta, G_s, flag, and
    H_over_a where contours were measured) and the law the data support (see the module)."""
    rows = list(rows)
    by_law: dict[str, tuple[list[float], list[float]]] = {}
    for row in rows:
        if row.get("flag"):
            continue
        delta, g = by_law.setdefault(str(row["law"]), ([], []))
        delta.append(float(row["Delta"]))
        g.append(float(row["G_s"]))
    drifts = {law: law_drift(law, d, g) for law, (d, g) in by_law.items() if len(d) >= 3}
    shape = shape_comparison(rows)
    if shape is not None and shape.best is not None and shape.best in drifts:
        if drifts[shape.best].drifts:
            return PopulationVerdict(drifts, shape, None, f"the contours favour {shape.best}, but its G_s drifts "
                                     f"with Delta (p = {drifts[shape.best].p_value:.2g}): the tests disagree")
        return PopulationVerdict(drifts, shape, shape.best, f"contours fit best (median H/a "
                                 f"{shape.median[shape.best]:.4f}, n = {shape.n}) and G_s does not drift "
                                 f"(p = {drifts[shape.best].p_value:.2g})")
    steady = [d for d in drifts.values() if not d.drifts]
    if not steady:
        return PopulationVerdict(drifts, shape, None, "every law's G_s drifts with the deformation (p < 0.05)")
    best = max(steady, key=lambda d: d.p_value).law
    why = "no contours to compare" if shape is None else "the contours do not tell the laws apart"
    return PopulationVerdict(drifts, shape, best, f"{why}; G_s does not drift (p = {drifts[best].p_value:.2g})")


#: Columns of the population table (``write_population``) and their units.
POPULATION_UNITS = {"law": "", "n": "1", "G_s_mean": "N/m", "G_s_std": "N/m", "drift": "1",
                    "drift_ci_low": "1", "drift_ci_high": "1", "t": "1", "p_value": "1", "verdict": ""}


def population_rows(drifts: Mapping[str, LawDrift], best: str | None) -> list[dict[str, Any]]:
    """One row per law (columns of ``POPULATION_UNITS``); the verdict is 'supported' for the
    law reported, 'no drift' for another law that does not drift, 'drifts' otherwise."""
    rows = []
    for law, d in drifts.items():
        verdict = "supported" if law == best else ("drifts" if d.drifts else "no drift")
        rows.append({"law": law, "n": float(d.n), "G_s_mean": d.mean, "G_s_std": d.std, "drift": d.slope,
                     "drift_ci_low": d.ci_low, "drift_ci_high": d.ci_high, "t": d.t, "p_value": d.p_value,
                     "verdict": verdict})
    return rows


def read_results(path: str | Path) -> list[dict[str, Any]]:
    """Read a fit-tube results CSV (header cells 'name [unit]')."""
    with open(path, newline="", encoding="utf-8") as stream:
        reader = csv.reader(stream)
        header = [cell.split(" [")[0] for cell in next(reader)]
        return [dict(zip(header, row)) for row in reader]


def plot_population(rows: Iterable[Mapping[str, Any]], drifts: Mapping[str, LawDrift]) -> Figure:
    """Figure 10 of the paper: G_s against Delta per law, error bars = spread of the five fits,
    with each law's regression line. Returns the Figure (no pyplot state: safe in scripts and
    notebooks alike; ``capsmech.plotting.save_figure`` writes it)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 4.2), layout="constrained")
    ax = fig.subplots()
    rows = [r for r in rows if not r.get("flag")]
    for law in drifts:
        mine = [r for r in rows if r["law"] == law]
        delta = np.array([float(r["Delta"]) for r in mine])
        g = np.array([float(r["G_s"]) for r in mine])
        err = np.array([float(r.get("G_s_spread", "nan")) for r in mine])
        line = ax.errorbar(delta, g, yerr=np.where(np.isfinite(err), err, 0), fmt="o", ms=4, capsize=2,
                           label=f"{law}: drift {drifts[law].slope:+.2f}/unit Δ (p = {drifts[law].p_value:.2g})")
        x = np.linspace(delta.min(), delta.max(), 2)
        d = drifts[law]
        intercept = d.mean * (1 - d.slope * delta.mean())
        ax.plot(x, intercept + d.slope * d.mean * x, color=line[0].get_color(), lw=1)
    ax.set_xlabel("mean profile elongation Δ = p / 2πa")
    ax.set_ylabel("G_s [N/m]")
    ax.legend(fontsize=8)
    return fig
