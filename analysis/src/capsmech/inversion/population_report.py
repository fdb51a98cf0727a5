"""The population verdict written out (``capsmech.inversion.population``): the per-law table
(``population_rows``), the JSON data (``verdict_dict``, ``write_verdict_json``; schema in
``capsmech.inversion.population``), the results reader and the paper's figure 10
(``plot_population``)."""
from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from capsmech.inversion.noise import DOF, GOODNESS_ALPHA
from capsmech.inversion.population import (
    ALPHA,
    CONTOUR_LEVEL,
    ESTIMATORS,
    FAIL_SCORE,
    MIN_CAPSULES,
    MIN_FITTED_FRACTION,
    LawDrift,
    PopulationVerdict,
    flag_of,
    number_of,
)
from capsmech.io.atomic import write_text_atomically

if TYPE_CHECKING:
    from matplotlib.figure import Figure


#: Columns of the population table (``population_rows``; ``capsmech population --out`` writes it) and their units.
POPULATION_UNITS = {"law": "", "fitted": "1", "used": "1", "score_median": "1", "p_vs_reference": "1",
                    "G_s_mean": "N/m", "G_s_std": "N/m", "G_s_low": "N/m", "G_s_high": "N/m",
                    "drift": "1/Delta", "drift_ci_low": "1/Delta", "drift_ci_high": "1/Delta", "drift_p": "1",
                    "drift_database": "1/Delta", "chi2_per_dof": "1", "chi2_limit": "1", "chi2_p": "1", "status": ""}


def population_rows(verdict: PopulationVerdict) -> list[dict[str, Any]]:
    """One row per law, best ranked first (columns of ``POPULATION_UNITS``): capsules fitted of
    those used, median misfit score, p-value against the reference law, mean G_s with its
    spread and 95 % interval, the drift per unit Delta with its 95 % interval and p-value (and
    the steepest drift the database's own error can make, ``drift_database``), the
    best shapes' chi2 per degree of freedom against the noise with its limit and p-value, and
    the law's status ('verdict', 'candidate', 'fits < half', 'drifts', 'misfits noise',
    'worse contours', 'no verdict')."""
    rows = []
    for law, e in verdict.evidence.items():
        d = e.drift
        rows.append({"law": law, "fitted": float(e.fitted), "used": float(e.used), "score_median": e.score_median,
                     "p_vs_reference": e.p_vs_reference, "G_s_mean": e.g_s_mean, "G_s_std": e.g_s_std,
                     "G_s_low": e.g_s_interval[0], "G_s_high": e.g_s_interval[1],
                     "drift": d.slope if d else math.nan, "drift_ci_low": d.ci_low if d else math.nan,
                     "drift_ci_high": d.ci_high if d else math.nan, "drift_p": d.p_value if d else math.nan,
                     "drift_database": d.database_slope if d else math.nan,
                     "chi2_per_dof": e.noise.reduced_chi2 if e.noise else math.nan,
                     "chi2_limit": e.noise.limit if e.noise else math.nan,
                     "chi2_p": e.noise.p_value if e.noise else math.nan, "status": e.status})
    return rows


def _jsonnumber_of(value: float) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def _json_pair(pair: tuple[float, float] | None) -> list[float] | None:
    if pair is None or not all(math.isfinite(v) for v in pair):
        return None
    return [float(pair[0]), float(pair[1])]


def verdict_dict(verdict: PopulationVerdict) -> dict[str, Any]:
    """The verdict as plain JSON-ready data (schema in the module docstring; null, never NaN)."""
    laws = {}
    for law, e in verdict.evidence.items():
        d = e.drift
        laws[law] = {"fitted": e.fitted, "used": e.used, "measured": e.measured,
                     "score_median": _jsonnumber_of(e.score_median), "p_vs_reference": _jsonnumber_of(e.p_vs_reference),
                     "G_s_mean": _jsonnumber_of(e.g_s_mean), "G_s_std": _jsonnumber_of(e.g_s_std),
                     "G_s_interval": _json_pair(e.g_s_interval), "G_s_systematic": _jsonnumber_of(e.g_s_systematic),
                     "drift": _jsonnumber_of(d.slope) if d else None,
                     "drift_interval": _json_pair((d.ci_low, d.ci_high)) if d else None,
                     "drift_p": _jsonnumber_of(d.p_value) if d else None, "drift_n": d.n if d else None,
                     "drift_database": _jsonnumber_of(d.database_slope) if d else None,
                     "chi2_per_dof": _jsonnumber_of(e.noise.reduced_chi2) if e.noise else None,
                     "chi2_limit": _jsonnumber_of(e.noise.limit) if e.noise else None,
                     "chi2_p": _jsonnumber_of(e.noise.p_value) if e.noise else None,
                     "chi2_capsules": e.noise.capsules if e.noise else None,
                     "status": e.status, "status_reason": e.status_reason + (f" ({e.drift_note})" if e.drift_note
                                                                            and d is None else "")}
    return {"verdict": verdict.kind, "law": verdict.best, "candidates": list(verdict.candidates),
            "G_s": _jsonnumber_of(verdict.g_s), "G_s_std": _jsonnumber_of(verdict.g_s_std),
            "G_s_interval": _json_pair(verdict.g_s_interval), "G_s_estimator": verdict.estimator,
            "G_s_systematic": _jsonnumber_of(verdict.g_s_systematic), "reason": verdict.reason,
            "reference": verdict.reference,
            "criterion": {"score": "H/a of the law's best shape on the capsule's contour (contour fit; in results "
                                   "without it, the misfit at the length fit), fail_score where the law cannot "
                                   "fit the capsule",
                          "test": "paired one-sided Wilcoxon signed-rank over the used capsules; drift: least-squares "
                                  "slope of G_s/mean(G_s) on Delta, Student t on the slope beyond drift_database "
                                  "(the steepest slope the database's own error can make)",
                          "noise": "total chi2 of the law's best shapes (chi2_shape) against the tracing noise, "
                                   f"{DOF} degrees of freedom a capsule, noise level estimated (F reference)",
                          "noise_alpha": GOODNESS_ALPHA,
                          "alpha": ALPHA, "contour_level": CONTOUR_LEVEL, "fail_score": FAIL_SCORE, "min_capsules": MIN_CAPSULES,
                          "min_fitted_fraction": MIN_FITTED_FRACTION},
            "units": {"G_s": "N/m", "drift": "1/Delta", "score": "1"},
            "laws": laws,
            "capsules": {"measured": verdict.measured, "used": verdict.used,
                         "left_out": [{"id": cid, "reason": why} for cid, why in verdict.left_out]},
            # One material or several (capsmech.inversion.heterogeneity), on the reference law's G_s.
            "heterogeneity": verdict.heterogeneity.as_dict() if verdict.heterogeneity is not None else None}


def write_verdict_json(verdict: PopulationVerdict, path: str | Path) -> Path:
    """Write ``verdict_dict(verdict)`` to ``path`` whole or not at all (temporary file renamed)."""
    path = Path(path)
    text = json.dumps(verdict_dict(verdict), indent=2, allow_nan=False) + "\n"
    return write_text_atomically(path, text)


def read_results(path: str | Path) -> list[dict[str, Any]]:
    """Read a results file (a CSV with header cells 'name [unit]', or the HDF5 that fit-tube
    writes), checked by ``capsmech.io.results.read_results_file`` (a ``ResultsFileError`` names
    file, line or dataset, and field)."""
    from capsmech.io.results import read_results_file

    return list(read_results_file(path, required=()))


def plot_population(rows: Iterable[Mapping[str, Any]], drifts: Mapping[str, LawDrift],
                    estimator: str = "lengths") -> Figure:
    """Figure 10 of the paper: G_s against Delta per law (by ``estimator``), error bars = spread
    of the five fits (lengths),
    with each law's regression line. Returns the Figure (no pyplot state: safe in scripts and
    notebooks alike; ``capsmech.plotting.save_figure`` writes it)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 4.2), layout="constrained")
    ax = fig.subplots()
    g_key, delta_key = ESTIMATORS[estimator]
    rows = [r for r in rows if (math.isfinite(number_of(r.get("chi2_shape"))) if estimator == "contour fits"
                                else not flag_of(r))]
    for law in drifts:
        mine = [r for r in rows if r["law"] == law]
        delta = np.array([number_of(r.get(delta_key)) for r in mine])
        g = np.array([number_of(r.get(g_key)) for r in mine])
        # The five fits' spread belongs to the lengths; a contour fit has no such spread.
        err = np.array([number_of(r.get("G_s_spread", "nan")) if estimator == "lengths" else math.nan for r in mine])
        keep = np.isfinite(delta) & np.isfinite(g)
        delta, g, err = delta[keep], g[keep], err[keep]
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
