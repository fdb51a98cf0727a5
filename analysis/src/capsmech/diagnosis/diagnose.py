"""Close the loop (issue 7): which effect the base model lacks, from what the fits leave.

For a batch fitted with a base law, each candidate effect adds one parameter theta (shared
by the batch) to the forward model. The batch is refitted over a grid of theta, and every
capsule's contour residual (``capsmech.inversion.residuals.profile_residual``) is scored by

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
  (``capsmech.diagnosis.effect_grid``) at a few levels, the base law being 0. Between two levels the
  law is their blend (profiles and velocity ratio linear in the strength at the same a/l and
  Ca_s, ``BlendedLaw``), so the batch is refitted at any strength like the other continuous
  candidates.
- ``viscosity ratio`` is not a candidate for tube batches: a steady capsule translates as a
  rigid body, its inner fluid with it, so lambda drops out of every steady observable (the
  kernel reproduces the lambda = 1 shape to 6e-8 at lambda 0.2 and 5); it acts on the shear
  method (``capsmech.diagnosis.shear``: ``capsmech diagnose-shear``). ``NOT_ASSESSED``
  says so in every report.
- ``off-centre position`` is not a batch effect: each capsule has its own offset b. Its
  first-order signature, an up-down asymmetric contour, is what the inversion flags; such
  capsules are left out of the batch's diagnosis (``screen_asymmetric``) and, given an
  off-centre table (``capsmech.diagnosis.offcentre``: the 3D kernel's antisymmetric mode over a/l
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
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from capsmech.diagnosis.candidates import (
    BlendedLaw,
    Candidate,
    DatabaseSet,
    contour_offset_candidate,
    tube_radius_candidate,
)
from capsmech.diagnosis.goodness import GoodnessOfFit, goodness_of_fit
from capsmech.diagnosis.scoring import (
    REFINE_EVALUATIONS,
    BatchScore,
    CandidateResult,
    capsules_prefer,
    compare_supported,
    evaluate_candidate,
    g_s_half_width,
    noise_levels,
    prepared_contour,
    rivals_of,
    score_batch,
)
from capsmech.inversion.fitting import tube_inverter
from capsmech.io.contours import contour_asymmetry
from capsmech.io.database import TubeDatabase
from capsmech.io.measurements import Capsule

#: Effects of the library diagnose does not fit on tube batches, and why (in every report).
NOT_ASSESSED: dict[str, str] = {
    "viscosity ratio": "not identifiable: a steady capsule moves as a rigid body with its inner fluid, so lambda "
                       "leaves its shape and velocity unchanged (kernel: lambda 0.2 and 5 reproduce lambda = 1 to "
                       "6e-8); it acts on the shear method: capsmech diagnose-shear tests it on Couette batches",
    "off-centre position": "not a batch effect (each capsule has its own): an off-centre capsule's contour is up-down "
                           "asymmetric (3D kernel: 0.04-0.07 a at 0.02-0.07 l off the axis), so such capsules are "
                           "screened out of the batch (screen_asymmetric) and, with the off-centre table "
                           "(capsmech.diagnosis.offcentre, a/l 0.7-0.85), each is fitted with its own offset b from its "
                           "contour's antisymmetric part, its lengths corrected by the offset's second-order "
                           "elongation before G_s",
}


#: The measurement that tells a measurement effect from its rivals (``separating_measurement``).
SEPARATING_MEASUREMENTS: dict[str, str] = {
    "tube_radius": "measure the tube radius independently (the empty capillary's bore on the same optics, or "
                   "its specification)",
    "contour_offset": "calibrate the contour offset (trace objects of known size, e.g. beads, with the same "
                      "optics and settings)",
}
#: What tells model effects apart (pre-stress, bending, another law): how the shape changes
#: with the capillary number.
SEPARATING_MODEL_EFFECTS = "measure capsules over a wider range of flow rates (Ca_s)"


def separating_measurement(names: Sequence[str]) -> str:
    """The measurement that would separate tied candidates: for each measurement effect among
    them, what measures it directly; for model effects only, a wider range of flow rates."""
    known = [SEPARATING_MEASUREMENTS[n] for n in dict.fromkeys(names) if n in SEPARATING_MEASUREMENTS]
    return " or ".join(known) if known else SEPARATING_MODEL_EFFECTS


@dataclass
class TiedGs:
    """G_s after under each of the candidates a batch cannot tell apart (the chosen one first),
    by one estimator (``contour_fits`` or ``lengths``), and one interval that covers them all:
    whichever candidate is right, G_s lies in it (at the level of each one's interval)."""

    estimator: str
    names: list[str]
    values: list[float]
    intervals: list[tuple[float, float]]

    @property
    def interval(self) -> tuple[float, float]:
        """The union of the candidates' intervals (NaN when one of them has none: a G_s
        that only some of the rivals give covers nothing whichever is right)."""
        if not self.intervals or not all(math.isfinite(v) for pair in self.intervals for v in pair):
            return (math.nan, math.nan)
        return (min(low for low, _ in self.intervals), max(high for _, high in self.intervals))

    @property
    def spread(self) -> float:
        """Largest relative difference between the candidates' G_s."""
        finite = [v for v in self.values if math.isfinite(v)]
        return max(finite) / min(finite) - 1 if len(finite) > 1 and min(finite) > 0 else math.nan

    def text(self) -> str:
        each = ", ".join(f"{n} {v:.4g} [{lo:.4g}, {hi:.4g}]"
                         for n, v, (lo, hi) in zip(self.names, self.values, self.intervals))
        low, high = self.interval
        whichever = (f"{low:.4g}-{high:.4g} N/m whichever it is" if math.isfinite(low) else
                     "no interval covers them all (a candidate gives no G_s)")
        return f"G_s after ({self.estimator.replace('_', ' ')}) under each: {each}: {whichever}"


def tied_g_s(results: Sequence[CandidateResult]) -> list[TiedGs]:
    """G_s after under each tied candidate, by the contour fits and by the lengths, each with its
    interval (the capsules' scatter, the databases' accuracy and the strength's interval carried
    into G_s: ``CandidateResult.g_s_systematic``)."""
    out = []
    for estimator in ("contour_fits", "lengths"):
        values, intervals = [], []
        for r in results:
            if estimator == "contour_fits":
                (mean, sd), n, systematic = r.g_s_after, r.capsules, r.g_s_systematic[1]
            else:
                (mean, sd, n), systematic = r.g_s_lengths_after, r.g_s_lengths_systematic[1]
            half = g_s_half_width(sd, n, systematic)
            values.append(mean)
            intervals.append((mean - half, mean + half))
        out.append(TiedGs(estimator, [r.name for r in results], values, intervals))
    return out


@dataclass
class Diagnosis:
    """Every candidate's result and the verdict."""

    #: A law key, or a BlendedLaw in a later round of a sequential diagnosis.
    base_law: str | BlendedLaw
    results: list[CandidateResult]
    chosen: CandidateResult | None
    base: BatchScore | None = field(default=None, repr=False)
    #: Capsules left out before the diagnosis, as (id, reason) (``screen_asymmetric``).
    excluded: list[tuple[str, str]] = field(default_factory=list)
    #: The left-out capsules fitted with their own offset (``capsmech.diagnosis.offcentre``), when an
    #: off-centre table was given.
    offcentre: list = field(default_factory=list)
    #: Why no candidate was assessed, when none was.
    note: str = ""
    #: What the explanation leaves (the chosen candidate at its value, else the base fit),
    #: tested against the noise (``capsmech.diagnosis.goodness``); None when not assessed.
    fit: GoodnessOfFit | None = None
    #: The ids of the capsules diagnosed, in the order of the scores' arrays (``base``, each
    #: result's ``after``): those with contours, less those left out.
    ids: list[str] = field(default_factory=list)

    @property
    def rivals(self) -> list[CandidateResult]:
        """Other supported candidates the data cannot tell from the chosen one: BIC within
        MIN_BIC_DROP of it, or capsules that do not prefer the chosen one consistently
        (``capsules_prefer``)."""
        if self.chosen is None:
            return []
        chosen = self.chosen
        close = rivals_of(chosen, self.results, lambda r: r.bic_drop_common)
        return close + [r for r in self.results if r.supported and r is not chosen and r not in close
                        and not capsules_prefer(chosen, r)]

    @property
    def tied_g_s(self) -> list[TiedGs]:
        """G_s after under the chosen candidate and each rival, by both estimators, with one
        interval covering them (``tied_g_s``); empty without rivals."""
        if self.chosen is None or not self.rivals:
            return []
        return tied_g_s([self.chosen, *self.rivals])

    @property
    def separating_measurement(self) -> str:
        """What would tell the chosen candidate from its rivals (``separating_measurement``)."""
        return separating_measurement([r.name for r in [self.chosen, *self.rivals] if r is not None])

    @property
    def kind(self) -> str:
        """``effect`` (the chosen candidate leaves the batch consistent with noise), ``cannot_tell``
        (so does it, but the data cannot tell it from a rival: ``rivals``), ``none`` (no candidate
        supported, and none needed), ``unexplained`` (what is left is not noise) or
        ``not_assessed``."""
        if self.fit is None:
            return "not_assessed"
        if not self.fit.consistent:
            return "unexplained"
        if self.chosen is None:
            return "none"
        return "cannot_tell" if self.rivals else "effect"

    @property
    def closest(self) -> CandidateResult | None:
        """The candidate that came closest to explaining the batch: the chosen one, else the
        assessed candidate whose fit leaves the smallest chi2 per degree of freedom."""
        if self.chosen is not None:
            return self.chosen
        assessed = [r for r in self.results if r.fit is not None]
        return min(assessed, key=lambda r: r.fit.reduced_chi2) if assessed else None  # type: ignore[union-attr]

    @property
    def verdict(self) -> str:
        if self.note and not self.results:
            return self.note
        if self.kind == "not_assessed":
            return "not assessed: " + (self.note or "no capsule could be fitted")
        if self.kind == "unexplained":
            assert self.fit is not None
            closest = self.closest
            if closest is None or closest.fit is None:
                near = "no candidate was assessed"
            else:
                near = (f"closest: {closest.name} ({strength_text(closest)}), which "
                        f"leaves chi2/dof {closest.fit.reduced_chi2:.2f} where noise reaches at most "
                        f"{closest.fit.reduced_chi2_limit:.2f}" + ("" if closest.supported else
                                                                    ", and is not supported"))
            return ("unexplained: no candidate leaves the batch consistent with its tracing noise ("
                    + "; ".join(self.fit.failures) + "); " + near
                    + "; G_s from these fits is not supported")
        if self.chosen is None:
            return f"no candidate effect is supported: the residual is within noise ({self.fit.summary()})"  # type: ignore[union-attr]
        c = self.chosen
        rivals = ""
        if self.rivals:
            rivals = ("; these data cannot tell it from " + ", ".join(
                f"{r.name} ({strength_text(r)}, BIC drop {r.bic_drop_common:.1f})" for r in self.rivals)
                + "; " + "; ".join(tie.text() for tie in self.tied_g_s)
                + f"; to tell them apart, {self.separating_measurement}")
        prefix = "cannot tell which of these: " if self.rivals else ""
        return (prefix + f"{c.name}: {strength_text(c)}, "
                f"BIC drop {c.bic_drop:.1f} ({c.bic_drop_common:.1f} on the capsules every supported candidate fits), "
                f"cross-validated chi2 gain {c.cv_gain:.2f} +- {c.cv_gain_error:.2f} "
                f"per capsule (p = {c.cv_p_value:.2g}); what it leaves is within noise ({self.fit.summary()})"  # type: ignore[union-attr]
                + rivals)


def strength_text(result: CandidateResult) -> str:
    """The candidate's fitted strength with its interval, in words; a yes/no candidate (another
    law group) has no strength and no interval."""
    if result.discrete:
        return "a yes/no candidate: no strength, no interval"
    text = (f"{result.parameter} = {result.theta:.3g} {result.unit} "
            f"[{result.interval[0]:.3g}, {result.interval[1]:.3g}]").replace("  ", " ")
    return text + (f", {edge_text(result)}" if result.edge else "")


def edge_text(result: CandidateResult) -> str:
    """That a strength sits at an edge of the candidate's values, in words (empty when the
    values bracket its interval)."""
    if not result.edge:
        return ""
    low, high = result.levels[0], result.levels[-1]
    side = "above the highest" if result.edge == "high" else "below the lowest"
    if result.edge == "base":
        interpolation = (f"; the interval holds the interpolation error there ({result.parameter} "
                         f"{result.interpolation_theta:.3g} with the quadratic through the base law and the two "
                         "lowest levels)" if result.interpolation > 0 else "")
        return (f"between the base law and the lowest level ({result.levels[1]:.3g}), where the blend with "
                f"the base law is the least accurate{interpolation}: a level in between would bracket it "
                "(diagnose --simulate adds it)")
    if result.acts_on == "capsules":
        return (f"AT THE EDGE of the range searched ({low:.3g}-{high:.3g}, extended by half a step): the "
                "strength may lie further out")
    return (f"AT THE EDGE of the levels ({low:.3g}-{high:.3g}): the interval reaches {side} level, where the "
            "law is extrapolated linearly; a level beyond would bracket it (diagnose --simulate adds levels "
            "until they do)")


def batch_fit(capsules: Sequence[Capsule], score: BatchScore) -> GoodnessOfFit | None:
    """What one fit of the batch leaves, tested against the noise (None: fewer than 2 fitted)."""
    lengths = np.array([c["L_z"] / c["pixel_size"] if math.isfinite(c["pixel_size"]) else math.nan
                        for c in capsules])
    # The score's chi2 sums the same PROFILE_POINTS residuals over the capsule's noise level:
    # their ratio gives that level in pixels.
    with np.errstate(invalid="ignore", divide="ignore"):
        sigma_px = np.sqrt(np.sum(score.residual ** 2, axis=1) / score.chi2)
    try:
        return goodness_of_fit(score.residual, sigma_px, lengths, score.g_s, score.delta,
                               score.floor if score.floor.shape == score.residual.shape else None)
    except ValueError:
        return None


def diagnose(capsules: Sequence[Capsule], database: TubeDatabase | DatabaseSet, base_law: str | BlendedLaw,
             candidates: Sequence[Candidate] | None = None, sigma: np.ndarray | None = None,
             refine_evaluations: int = REFINE_EVALUATIONS, screen: bool = True,
             offcentre_table=None, progress: bool = False) -> Diagnosis:
    """Test the candidate effects on a batch fitted with ``base_law`` (see the module).

    ``database`` is one tube database or a ``DatabaseSet`` (the base database first, then
    effect databases). A candidate whose law groups none has is not assessed; its result
    carries the grid to run (``needs``, see ``capsmech.diagnosis.effect_grid``). ``sigma``: the
    capsules' tracing-noise levels when already measured (``noise_levels``), so that the chi2
    of successive diagnoses of one batch share their scale. ``refine_evaluations``: refits of
    the batch on each side of a continuous candidate's best grid value (0: the grid only).
    ``screen``: leave out asymmetric contours first (``screen_asymmetric``); False when the
    caller has screened the batch already (``diagnose_sequential``: once, so that every round
    sees the same capsules). ``offcentre_table``: an ``capsmech.diagnosis.offcentre.OffcentreTable``;
    the capsules screened out are then fitted with their own offset (``fit_offcentre``).
    ``progress``: a progress bar over the candidates (each refits the batch many times)."""
    from capsmech.diagnosis.effect_grid import FAMILY_CA_SPREAD, needed_grid
    from capsmech.diagnosis.law_family import LAW_FAMILIES

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
    # (every capsule of with_contours has one)
    prepared = [prepared_contour(c.contour) for c in with_contours if c.contour is not None]
    base = score_batch(with_contours, database, base_law, sigma, prepared)
    base_database = _base_database(database)
    results = []
    for candidate in tqdm(candidates, desc=f"candidates on {getattr(base_law, 'name', base_law)}", unit="candidate",
                          disable=not progress, leave=False):
        missing = [key for key in candidate.laws if key not in database.laws]
        if not missing:
            results.append(evaluate_candidate(candidate, with_contours, database, base_law, sigma, base, prepared,
                                              refine_evaluations))
            continue
        result = CandidateResult(candidate.name, candidate.parameter, candidate.unit,
                                 note="not assessed: needs simulations")
        name = re.sub(r"[^A-Za-z0-9_-]", "_", candidate.name.replace(".", "p"))
        # A law family moves the fitted Ca_s far more than an effect does: a wider Ca_s range.
        spread = FAMILY_CA_SPREAD if candidate.name in LAW_FAMILIES else (1.0, 1.0)
        result.needs = needed_grid(name, missing, base_database, base.a_over_l, base.Ca_s, spread)
        results.append(result)
    chosen = compare_supported(results, base)
    for result in results:
        if result.after is not None:
            result.fit = batch_fit(with_contours, result.after)
    fit = chosen.fit if chosen is not None else batch_fit(with_contours, base)
    offcentre = (fit_offcentre(capsules, excluded, base_database, base_law, offcentre_table)
                 if offcentre_table is not None else [])
    return Diagnosis(base_law, results, chosen, base, excluded, offcentre, fit=fit, ids=[c.id for c in with_contours])


def _base_database(database: TubeDatabase | DatabaseSet) -> TubeDatabase:
    """The base law's database: the first of a set."""
    return database.databases[0] if isinstance(database, DatabaseSet) else database


def fit_offcentre(capsules: Sequence[Capsule], excluded: Sequence[tuple[str, str]], database: TubeDatabase,
                  base_law: str | BlendedLaw, table) -> list:
    """Fit every screened-out capsule with its own offset (``capsmech.diagnosis.offcentre``)."""
    from capsmech.diagnosis.offcentre import fit_offcentre_capsule

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
        assert capsule.contour is not None, "screen_asymmetric takes capsules with contours"
        asymmetry, limit, _ = contour_asymmetry(capsule.contour, capsule["pixel_size"])
        if asymmetry > limit:
            excluded.append((capsule.id, f"asymmetric contour: its halves differ by {asymmetry:.4f} a "
                                         f"(> {limit:.4f} a): off-centre or not steady"))
        else:
            kept.append(capsule)
    return kept, excluded

