"""The report of ``capsmech diagnose``: Markdown with its figures (PNG beside it).

Figures (``<report stem>_<name>.png``):
- ``residuals``: the batch's residual profile (signed normal distance of the traced contour
  from the fitted meridian [px] along the normalised arclength, rear pole 0 to front pole 1):
  median over capsules and the band between the 16th and 84th percentiles, before (base law)
  and after the chosen effect (or the candidate with the largest BIC drop when none is chosen);
- ``gs_delta``: each capsule's G_s against its perimeter elongation Delta, before and after;
- ``criteria``: BIC drop and cross-validated chi2 gain per capsule of every assessed candidate.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from capsmech.io.atomic import write_text_atomically

if TYPE_CHECKING:
    from capsmech.diagnosis.diagnose import Diagnosis
    from capsmech.diagnosis.scoring import CandidateResult
    from capsmech.inversion.heterogeneity import Heterogeneity


def _shown(diagnosis: Diagnosis) -> CandidateResult | None:
    """The candidate the before/after figures show: the chosen one, else the largest BIC drop."""
    if diagnosis.chosen is not None:
        return diagnosis.chosen
    assessed = [r for r in diagnosis.results if r.after is not None and math.isfinite(r.bic_drop)]
    return max(assessed, key=lambda r: r.bic_drop) if assessed else None


def _label(result: CandidateResult) -> str:
    return f"{result.name} ({result.parameter} = {result.theta:.3g}{' ' + result.unit if result.unit not in ('', '1') else ''})"


def write_figures(diagnosis: Diagnosis, stem: Path) -> dict[str, Path]:
    """Draw the three figures as ``<stem>_<name>.png``; name -> path of those drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from capsmech.diagnosis.scoring import PROFILE_POINTS

    written: dict[str, Path] = {}
    shown = _shown(diagnosis)
    base = diagnosis.base
    if base is not None and base.residual.size:
        pairs = [("before (base law)", base, "tab:grey")]
        if shown is not None and shown.after is not None:
            pairs.append((f"after: {_label(shown)}", shown.after, "tab:blue"))
        fig, ax = plt.subplots(figsize=(6, 3.6))
        s = np.linspace(0, 1, PROFILE_POINTS)
        for label, score, colour in pairs:
            rows = score.residual[np.all(np.isfinite(score.residual), axis=1)]
            if len(rows) == 0:
                continue
            low, median, high = np.percentile(rows, [16, 50, 84], axis=0)
            ax.fill_between(s, low, high, color=colour, alpha=0.25, lw=0)
            ax.plot(s, median, color=colour, label=label)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_xlabel("arclength along the meridian (rear pole 0, front pole 1)")
        ax.set_ylabel("contour - model, outward [px]")
        ax.legend(fontsize=8)
        ax.set_title("Residual profile: median and 16-84 % band over capsules", fontsize=9)
        fig.tight_layout()
        written["residuals"] = stem.with_name(f"{stem.name}_residuals.png")
        fig.savefig(written["residuals"], dpi=110)
        plt.close(fig)
        fig, ax = plt.subplots(figsize=(5, 3.6))
        for label, score, colour in pairs:
            ok = np.isfinite(score.g_s) & np.isfinite(score.delta)
            ax.plot(score.delta[ok], score.g_s[ok], "o", ms=4, color=colour, label=label)
            if ok.sum() >= 3:
                slope, intercept = np.polyfit(score.delta[ok], score.g_s[ok], 1)
                x = np.linspace(score.delta[ok].min(), score.delta[ok].max(), 2)
                ax.plot(x, intercept + slope * x, color=colour, lw=1)
        ax.set_xlabel(r"perimeter elongation $\Delta$")
        ax.set_ylabel(r"$G_s$ [N/m]")
        ax.legend(fontsize=8)
        fig.tight_layout()
        written["gs_delta"] = stem.with_name(f"{stem.name}_gs_delta.png")
        fig.savefig(written["gs_delta"], dpi=110)
        plt.close(fig)
    assessed = [r for r in diagnosis.results if math.isfinite(r.bic_drop)]
    if assessed:
        from capsmech.diagnosis.scoring import MIN_BIC_DROP

        fig, axes = plt.subplots(1, 2, figsize=(7.5, 0.5 + 0.45 * len(assessed) + 1.2))
        names = [r.name for r in assessed]
        y = np.arange(len(assessed))
        colours = ["tab:blue" if r.supported else "tab:grey" for r in assessed]
        axes[0].barh(y, [r.bic_drop for r in assessed], color=colours)
        axes[0].axvline(MIN_BIC_DROP, color="k", ls="--", lw=0.8)
        axes[0].set_xlabel("BIC drop (dashed: strong evidence)")
        axes[1].barh(y, [r.cv_gain for r in assessed], xerr=[r.cv_gain_error for r in assessed], color=colours)
        axes[1].axvline(0, color="k", lw=0.5)
        axes[1].set_xlabel(r"cross-validated $\chi^2$ gain per capsule")
        for ax in axes:
            ax.set_yticks(y, names if ax is axes[0] else [""] * len(y), fontsize=8)
        fig.suptitle("Criterion per candidate (blue: supported)", fontsize=9)
        fig.tight_layout()
        written["criteria"] = stem.with_name(f"{stem.name}_criteria.png")
        fig.savefig(written["criteria"], dpi=110)
        plt.close(fig)
    return written


def batch_heterogeneity(diagnosis: Diagnosis) -> Heterogeneity | None:
    """One material or several (``capsmech.inversion.heterogeneity``) on the per-capsule G_s of
    the contour fits: after the chosen effect, else the base law's. The contour fits carry no
    per-capsule uncertainty, so the mixture test stands alone. Capsules are named by their ids
    (by their rank among those diagnosed where the diagnosis has none). None without a fit."""
    from capsmech.inversion.heterogeneity import heterogeneity

    g_s = capsule_g_s(diagnosis)
    if not g_s:
        return None
    return heterogeneity([capsule for capsule, _ in g_s], [g for _, g in g_s])


def capsule_g_s(diagnosis: Diagnosis) -> list[tuple[str, float]]:
    """Each diagnosed capsule's G_s [N/m] by its contour fit (after the chosen effect, else the
    base law's; NaN where not fitted), by id (``Diagnosis.ids``; "capsule k" by rank without)."""
    score = diagnosis.chosen.after if diagnosis.chosen is not None else diagnosis.base
    if score is None or not len(score.g_s):
        return []
    ids = (diagnosis.ids if len(diagnosis.ids) == len(score.g_s) else
           [f"capsule {k + 1}" for k in range(len(score.g_s))])
    return [(capsule, float(g)) for capsule, g in zip(ids, score.g_s)]


def _lengths(summary: tuple[float, float, int]) -> str:
    """G_s by lengths (mean, sd, capsules) in words."""
    mean, sd, n = summary
    return f"{mean:.4g} ± {sd:.2g} ({n})" if math.isfinite(mean) else f"none ({n})"


def write_report(diagnosis: Diagnosis, out: str | Path, batch: str = "", figures: bool = True) -> Path:
    """A Markdown report: the verdict, per candidate its parameter with the interval, the
    criteria and G_s before and after, the grids candidates need, and the figures (written
    whole: temporary name, then renamed)."""
    from capsmech.diagnosis.diagnose import NOT_ASSESSED, strength_text
    from capsmech.diagnosis.goodness import ALPHA
    from capsmech.diagnosis.scoring import CV_ALPHA, MIN_BIC_DROP, PROFILE_POINTS

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"# capsmech diagnose{': ' + batch if batch else ''}", "",
             f"Base law: `{diagnosis.base_law}`.", "", f"**Verdict:** {diagnosis.verdict}.", "",
             "| candidate | strength [interval] | chi2 base -> fitted | chi2/dof left (limit) | BIC drop "
             "| CV gain per capsule (p) | G_s contour fits, before -> after [N/m] "
             "| G_s lengths (fit-tube), before -> after [N/m] | supported |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in diagnosis.results:
        if r.note:
            lines.append(f"| {r.name} | | | | | | | | {r.note} |")
            continue
        left = f"{r.fit.reduced_chi2:.2f} ({r.fit.reduced_chi2_limit:.2f})" if r.fit is not None else ""
        lines.append(
            f"| {r.name} | {strength_text(r)} "
            f"| {r.chi2_base:.1f} -> {r.chi2:.1f} | {left} | {r.bic_drop:.1f} | {r.cv_gain:.2f} ({r.cv_p_value:.2g}) "
            f"| {r.g_s_before[0]:.4g} ± {r.g_s_before[1]:.2g} -> {r.g_s_after[0]:.4g} ± {r.g_s_after[1]:.2g} "
            f"| {_lengths(r.g_s_lengths_before)} -> {_lengths(r.g_s_lengths_after)} "
            f"| {'yes' if r.supported else 'no'} |")
    lines += [f"| {name} | | | | | | | | {why} |" for name, why in NOT_ASSESSED.items()]
    lines += ["", "Supported: leave-one-capsule-out cross-validation improves (one-sided Wilcoxon p < "
              f"{CV_ALPHA}) and the BIC drops by more than {MIN_BIC_DROP:g}. Interval: two jackknife "
              "standard errors. chi2: contour residuals over each capsule's tracing noise, "
              f"{PROFILE_POINTS} points a capsule. G_s, mean ± standard deviation over the capsules, by two "
              "estimators, each the same before and after: the contour fits (each capsule's whole contour fitted "
              "over (a/l, Ca_s); the capsules every value of the candidate fits) and fit-tube's (each capsule's "
              "lengths L_z, L_p inverted; in brackets the capsules it fits). They answer the same question "
              "from different data and need not agree; compare before with after within one.", ""]
    if diagnosis.fit is not None:
        fit = diagnosis.fit
        lines += ["## What the explanation leaves", "",
                  f"Tested against the tracing noise (capsmech.diagnosis.goodness, each test at p < {ALPHA:g}): "
                  f"{fit.summary()}. " + ("Consistent with noise." if fit.consistent else
                                          "**Not consistent with noise**: " + "; ".join(fit.failures) + "."), "",
                  "Mean residual profile over the capsules [px] (front pole to rear pole, "
                  f"{len(fit.profile)} points, ± standard error): "
                  + ", ".join(f"{v:+.2f}±{e:.2f}" for v, e in zip(fit.profile, fit.profile_error)) + ".", ""]
    mixture = batch_heterogeneity(diagnosis)
    if mixture is not None:
        lines += ["## One material or several", "",
                  f"On the contour fits' G_s (capsmech.inversion.heterogeneity): "
                  f"{'**' + mixture.line() + '**' if not mixture.one_material else mixture.line()}.", ""]
        each = dict(capsule_g_s(diagnosis))
        for k, group in enumerate(mixture.groups, start=1):
            lines.append(f"- group {k}: G_s = {group.g_s:.4g} N/m [{group.interval[0]:.4g}, {group.interval[1]:.4g}], "
                         f"{len(group.members)} capsules: "
                         + ", ".join(f"{capsule} ({each[capsule]:.4g})" for capsule in group.members))
        lines += [""] if mixture.groups else []
    compared = sorted((r for r in diagnosis.results if r.supported and math.isfinite(r.bic_drop_common)),
                      key=lambda r: -r.bic_drop_common)
    if len(compared) > 1:
        lines += ["Choice between the supported candidates: BIC drop on the capsules every one of them fits "
                  "(their own drops are over different capsules): "
                  + ", ".join(f"{r.name} {r.bic_drop_common:.1f}" for r in compared) + ".", ""]
    for r in diagnosis.results:
        if r.needs is not None:
            tube = r.needs["tube"]
            lines += [f"Candidate {r.name} needs simulations: laws {', '.join(tube['laws'])} on a/l "
                      f"{tube['a_over_l']} x Ca_s {tube['Ca_s']} (`make database GRID={r.needs['name']}`).", ""]
    if diagnosis.excluded:
        lines += [f"Left out before the diagnosis ({len(diagnosis.excluded)}; an axisymmetric model cannot "
                  "explain them):", ""] + [f"- {capsule}: {why}" for capsule, why in diagnosis.excluded] + [""]
    if diagnosis.offcentre:
        lines += ["Their own offsets (off-centre table: the 3D kernel's antisymmetric mode; b > 0 towards the "
                  "contour's upper side, interval two standard errors with the mode's 20 % uncertainty):", ""]
        lines += [f"- {fit.summary}" for fit in diagnosis.offcentre] + [""]
    if figures:
        titles = {"residuals": "Residual profile before and after", "gs_delta": "G_s against Delta before and after",
                  "criteria": "Criterion per candidate"}
        for name, path in write_figures(diagnosis, out.with_suffix("")).items():
            lines += [f"![{titles[name]}]({path.name})", ""]
    return write_text_atomically(out, "\n".join(lines))
