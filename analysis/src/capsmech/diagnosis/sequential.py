"""Sequential diagnosis: effects added one after another, each round on the batch the previous
rounds corrected, then two continuous effects refined together (``joint_refine``)."""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize

from capsmech.diagnosis.candidates import BlendedLaw, Candidate, DatabaseSet
from capsmech.diagnosis.diagnose import (
    Diagnosis,
    _base_database,
    batch_fit,
    diagnose,
    fit_offcentre,
    screen_asymmetric,
)
from capsmech.diagnosis.goodness import GoodnessOfFit
from capsmech.diagnosis.scoring import (
    PROFILE_POINTS,
    PROFILE_RISE,
    BatchScore,
    _g_s_summary,
    _law_inverter,
    length_g_s_with_systematic,
    noise_levels,
    score_batch,
)
from capsmech.io.database import TubeDatabase
from capsmech.io.measurements import Capsule


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

    #: What the effects found leave (all of them switched on), tested against the noise; the
    #: first round's when none was found.
    fit: GoodnessOfFit | None = None
    #: G_s by lengths (``length_g_s``: mean, sd, capsules) before and, when effects were found,
    #: with all of them switched on.
    g_s_lengths: list[tuple[float, float, int]] = field(default_factory=list)
    #: The systematic half-widths [N/m] of ``g_s`` and ``g_s_lengths`` (before, after): the
    #: databases' accuracy and, after, the largest that a round's strength interval carries
    #: into G_s (``CandidateResult.g_s_systematic``).
    g_s_systematic: list[float] = field(default_factory=list)
    g_s_lengths_systematic: list[float] = field(default_factory=list)
    #: The batch's fit with every effect found switched on (None when none was found).
    final: BatchScore | None = field(default=None, repr=False)

    @property
    def kind(self) -> str:
        """``effect``, ``none``, ``unexplained`` or ``not_assessed`` (as ``Diagnosis.kind``), for
        the batch with every effect found switched on."""
        if not self.effects:
            return self.rounds[0].kind
        if self.fit is None:
            return "not_assessed"
        if not self.fit.consistent:
            return "unexplained"
        return "cannot_tell" if any(r.rivals for r in self.rounds) else "effect"

    @property
    def verdict(self) -> str:
        if not self.effects:
            return self.rounds[0].verdict
        found = "; then ".join(f"{name} = {theta:.3g}" for name, theta in self.effects)
        found = f"{found} ({self.note})" if self.note else found
        if self.kind == "unexplained":
            assert self.fit is not None
            return (f"unexplained: the effects found ({found}) leave the batch inconsistent with its tracing noise ("
                    + "; ".join(self.fit.failures) + "); G_s from these fits is not supported")
        return found


def _apply_all(capsules: Sequence[Capsule], base_law: str, fixed: Sequence[tuple[Candidate, float]],
               library: Callable[[str | BlendedLaw], Sequence[Candidate]]) -> tuple[list[Capsule], str | BlendedLaw]:
    """The batch and law with the effects ``fixed`` switched on: measurement effects change the
    capsules, a model effect the law; each candidate is rebuilt (by name) on the law so far."""
    law: str | BlendedLaw = base_law
    capsules = list(capsules)
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
    low_high = [(float(flat[:, j].min()), float(flat[:, j].max())) for j in range(2)]
    return JointFit((first.name, second.name), (float(theta_1), float(theta_2)),
                    (float(values[k, 0]), float(values[k, 1])), (low_high[0], low_high[1]),
                    chi2_start, float(total[k]), n_usable, values, total)


def diagnose_sequential(capsules: Sequence[Capsule], database: TubeDatabase | DatabaseSet, base_law: str,
                        library: Callable[[str | BlendedLaw], Sequence[Candidate]],
                        max_effects: int = 2, offcentre_table=None, progress: bool = False) -> SequentialDiagnosis:
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
    measured once, on the base fit. ``offcentre_table`` and ``progress``: as in ``diagnose``."""
    with_contours, excluded = screen_asymmetric([c for c in capsules if c.contour is not None])
    if len(with_contours) < 3 and offcentre_table is not None and excluded:
        only = diagnose(capsules, database, base_law, [], offcentre_table=offcentre_table)
        return SequentialDiagnosis([only], [], [(math.nan, math.nan)], only.note, None)
    sigma = noise_levels(with_contours, database, base_law)
    rounds = [diagnose(with_contours, database, base_law, list(library(base_law)), sigma, screen=False, progress=progress)]
    rounds[0].excluded = excluded
    if offcentre_table is not None:
        rounds[0].offcentre = fit_offcentre(capsules, excluded, _base_database(database), base_law, offcentre_table)
    fixed: list[tuple[Candidate, float]] = []
    note = ""
    # A round whose choice the data cannot make (rivals) ends the sequence: fixing one of two
    # indistinguishable effects would build the next round on a guess.
    while rounds[-1].chosen is not None and not rounds[-1].rivals:
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
        rounds.append(diagnose(state, database, law, rest, sigma, screen=False, progress=progress))
        if model_fixed and rounds[-1].chosen is None:
            note = "model effects on top of a model effect not assessed (no database holds both)"
    if len(fixed) == 2:
        (first, _), (second, theta_2) = fixed
        state, law = _apply_all(with_contours, base_law, [(second, theta_2)], library)
        rebuilt = [c for c in library(law) if c.name == first.name]
        refit = diagnose(state, database, law, rebuilt, sigma, screen=False, progress=progress)
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
    fit, final = rounds[0].fit, None
    lengths, floor = length_g_s_with_systematic(with_contours, _law_inverter(database, base_law))
    floor = float(np.nan_to_num(floor))
    g_s_lengths, contour_systematic, lengths_systematic = [lengths], [floor], [floor]
    if fixed:
        state, law = _apply_all(with_contours, base_law, fixed, library)
        final = score_batch(state, database, law, sigma)
        keep = np.isfinite(final.g_s)
        g_s.append(_g_s_summary(final, keep)[0])
        lengths, floor = length_g_s_with_systematic(state, _law_inverter(database, law))
        g_s_lengths.append(lengths)
        # Each round's strength interval carried into G_s: the largest (an approximation for
        # two effects, whose joint interval is not propagated).
        round_choices = [r.chosen for r in rounds if r.chosen is not None]
        floor = float(np.nan_to_num(floor))
        contour_systematic.append(max([floor, *(c.g_s_systematic[1] for c in round_choices)]))
        lengths_systematic.append(max([floor, *(c.g_s_lengths_systematic[1] for c in round_choices)]))
        fit = batch_fit(with_contours, final)
    return SequentialDiagnosis(rounds, effects, g_s, note, joint, fit, g_s_lengths, final=final,
                               g_s_systematic=contour_systematic, g_s_lengths_systematic=lengths_systematic)

