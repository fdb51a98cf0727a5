"""Sequential diagnosis: effects added one after another, each round on the batch the previous
rounds corrected, then two continuous effects refined together (``joint_refine``)."""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import minimize

from capsmech.diagnosis.candidates import BlendedLaw, Candidate, DatabaseSet, extrapolation_range
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
    MIN_BIC_DROP,
    PROFILE_POINTS,
    PROFILE_RISE,
    BatchScore,
    CandidateResult,
    _g_s_summary,
    length_g_s_with_systematic,
    lengths_inverter,
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
    #: Whether the first round's tie was resolved by a model and a measurement effect fitted
    #: together (``combine_with_measurement``: the two beat each alone).
    tie_resolved: bool = False

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
        tied = [r for k, r in enumerate(self.rounds) if r.rivals and not (k == 0 and self.tie_resolved)]
        return "cannot_tell" if tied else "effect"

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
        if self.kind == "cannot_tell":
            # A later round's tie (a model effect with either of two measurement effects): the
            # effects found stand, and G_s is given under each rival.
            tied = next(r for k, r in enumerate(self.rounds) if r.rivals and not (k == 0 and self.tie_resolved))
            assert tied.chosen is not None
            found += (f"; cannot tell {tied.chosen.name} from " + ", ".join(r.name for r in tied.rivals)
                      + "; " + "; ".join(tie.text() for tie in tied.tied_g_s)
                      + f"; to tell them apart, {tied.separating_measurement}")
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


#: A measurement effect fitted together with a model effect (``measurement_with_model``): the
#: model's strength is searched at each measurement value, from three strengths one interval
#: half-width apart, moved downhill at most this many times, then the parabola's minimum.
PROFILE_WALKS = 2
#: Refinement of the measurement value on each side of its best grid value when the model is
#: searched at each (``evaluate_candidate``'s ``refine_evaluations``): each costs a model search.
COMBINED_REFINE = 2


@dataclass
class ModelProfile:
    """The model effect's best strength at each measurement value tried (the measurement's
    profile with the model's strength fitted out), and the batch chi2 there."""

    model: Candidate
    strengths: dict[float, float] = field(default_factory=dict)
    chi2: dict[float, float] = field(default_factory=dict)

    def strength_at(self, value: float) -> float:
        return self.strengths[round(float(value), 12)]

    def predicted(self, value: float, default: float) -> float:
        """Where to centre the model's search at ``value``: the straight line through the
        strengths found so far (the two effects trade off about linearly over the small range
        of a measurement effect), ``default`` before two are known."""
        known = [(m, s) for m, s in self.strengths.items() if math.isfinite(s)]
        if len(known) < 2:
            return default
        m, s = np.array(known).T
        if np.ptp(m) == 0:
            return float(np.mean(s))
        slope, intercept = np.polyfit(m, s, 1)
        return float(slope * value + intercept)

    def interpolated(self, value: float) -> float:
        """The strength at ``value`` straight between those found at the values searched where
        every capsule was fitted (NaN before any): what is only read off at a value between
        them (G_s at an interval's end moves by a fraction of a percent) needs no search of its
        own, which costs 4-6 refits of the batch."""
        known = sorted((m, s) for m, s in self.strengths.items() if math.isfinite(self.chi2.get(m, math.inf)))
        if not known:
            return math.nan
        values, strengths = np.array(known).T
        return float(np.interp(value, values, strengths))


def _best_strength(chi2_at: Callable[[float], float], centre: float, half: float, low: float, high: float) -> float:
    """The strength of lowest batch chi2 near ``centre``: three strengths ``half`` apart, the
    bracket walked downhill (``PROFILE_WALKS``), then the minimum of the parabola through the
    lowest point and its neighbours."""
    clip = lambda x: float(np.clip(x, low, high))   # noqa: E731
    points = {clip(x): 0.0 for x in (centre - half, centre, centre + half)}
    for x in list(points):
        points[x] = chi2_at(x)
    for _ in range(PROFILE_WALKS):
        xs = sorted(points)
        k = int(np.argmin([points[x] for x in xs]))
        if 0 < k < len(xs) - 1:
            break
        beyond = clip(xs[k] - half if k == 0 else xs[k] + half)
        if beyond in points:
            break
        points[beyond] = chi2_at(beyond)
    xs = sorted(points)
    k = int(np.argmin([points[x] for x in xs]))
    if 0 < k < len(xs) - 1 and math.isfinite(points[xs[k - 1]]) and math.isfinite(points[xs[k + 1]]):
        x3, y3 = np.array(xs[k - 1:k + 2]), np.array([points[x] for x in xs[k - 1:k + 2]])
        a, b, _ = np.polyfit(x3, y3, 2)
        if a > 0:
            vertex = clip(-b / (2 * a))
            if vertex not in points:
                points[vertex] = chi2_at(vertex)
    return min(points, key=lambda x: points[x])


def measurement_with_model(measurement: Candidate, model: Candidate, model_result: CandidateResult,
                           database: TubeDatabase | DatabaseSet, sigma: np.ndarray) -> tuple[Candidate, ModelProfile]:
    """A measurement effect fitted together with a model effect that no database needs to hold
    together: the measurement changes the capsules (contour moved along its normals, lengths
    scaled), the model's database gives the shapes, and at each measurement value the model's
    strength is fitted again (``_best_strength``, on the capsules its own fit used). The
    returned candidate has the measurement's name and values; its neutral value is the model
    effect alone at its fitted strength, so that ``diagnose`` on the batch with that law scores
    what the measurement effect adds to the model. The strengths found are kept in the profile.

    Fixing the model at its own best strength and then trying the measurement effect misses
    both when they trade off: pre-stress 0.045 with the contour traced 1 px inside reads as
    alpha 0.054 alone, and at 0.054 the offset's best value is near 0 (-0.19 px, not supported)."""
    assert model_result.after is not None
    usable = np.isfinite(model_result.after.chi2)
    starts = model_result.after
    low, high = extrapolation_range(model)
    centre = model_result.theta
    half = max(centre - model_result.interval[0], model_result.interval[1] - centre, 1e-6)
    profile = ModelProfile(model)
    # The usable capsules in the order they are fitted at a trial strength, the last one left
    # unfitted first: one unfitted capsule makes a strength's chi2 infinite, and away from the
    # model's minimum whole brackets of strengths are so; the other capsules are then not fitted.
    order = [int(i) for i in np.flatnonzero(usable)]

    def apply(capsules: Sequence[Capsule], value: float) -> tuple[list[Capsule], str | BlendedLaw]:
        changed, _ = measurement.apply(capsules, value)
        key = round(float(value), 12)
        if key not in profile.strengths:
            def chi2_at(theta: float) -> float:
                state, law = model.apply(changed, theta)
                chi2 = score_batch(state, database, law, sigma, starts=starts, only=order, stop_on_failure=True).chi2
                failed = [i for i in order if not math.isfinite(chi2[i])]
                if failed:
                    order.remove(failed[0])
                    order.insert(0, failed[0])
                    return math.inf
                return float(chi2[usable].sum())

            if math.isclose(value, measurement.neutral, abs_tol=1e-12):
                profile.strengths[key], profile.chi2[key] = centre, model_result.chi2
            else:
                best = _best_strength(chi2_at, profile.predicted(value, centre), half, low, high)
                profile.strengths[key], profile.chi2[key] = best, chi2_at(best)
        return model.apply(changed, profile.strengths[key])

    def apply_between(capsules: Sequence[Capsule], value: float) -> tuple[list[Capsule], str | BlendedLaw]:
        strength = profile.interpolated(value)
        if not math.isfinite(strength):
            return apply(capsules, value)
        changed, _ = measurement.apply(capsules, value)
        return model.apply(changed, strength)

    return replace(measurement, apply=apply, apply_between=apply_between, neutral=measurement.neutral), profile


def _tied(first: Diagnosis) -> list[CandidateResult]:
    return [first.chosen, *first.rivals] if first.chosen is not None else []


def combine_with_measurement(capsules: Sequence[Capsule], database: TubeDatabase | DatabaseSet, base_law: str,
                             model: Candidate, model_result: CandidateResult, singles: Sequence[CandidateResult],
                             measurements: Sequence[Candidate], sigma: np.ndarray, progress: bool = False
                             ) -> tuple[Diagnosis, ModelProfile | None, str]:
    """A model effect found (``model_result``) and each measurement effect fitted with it
    (``measurement_with_model``): a round of ``diagnose`` on the batch with the model's law, the
    measurement candidates searched with the model refitted at each value. The combination is
    kept (the profile of the chosen measurement returned) when the round supports it and its
    chi2 beats every one-effect result of ``singles`` (those supported) by ``MIN_BIC_DROP`` on
    the capsules both fit: two effects named where one explains the batch would be a guess.
    Returns the round, the profile (None when not kept) and why not."""
    state, law = model.apply(capsules, model_result.theta)
    profiles: dict[str, ModelProfile] = {}
    combined = []
    for measurement in measurements:
        candidate, profiles[measurement.name] = measurement_with_model(measurement, model, model_result, database, sigma)
        combined.append(candidate)
    round_ = diagnose(state, database, law, combined, sigma, screen=False, refine_evaluations=COMBINED_REFINE,
                      progress=progress)
    chosen = round_.chosen
    if chosen is None or chosen.after is None:
        return round_, None, "no measurement effect supported with it"
    for single in singles:
        if single.after is None or not single.supported or single.name == model_result.name:
            continue
        common = np.isfinite(single.after.chi2) & np.isfinite(chosen.after.chi2)
        n_points = max(int(common.sum()), 1) * PROFILE_POINTS
        drop = float(np.sum(single.after.chi2[common] - chosen.after.chi2[common]) - math.log(n_points))
        if common.sum() < 3 or drop <= MIN_BIC_DROP:
            return round_, None, f"{single.name} alone explains the batch as well (BIC drop {drop:.1f})"
    return round_, profiles[chosen.name], ""


def combined_fit(model_result: CandidateResult, measurement: CandidateResult, profile: ModelProfile) -> JointFit:
    """The two strengths of a model effect fitted with a measurement effect: the measurement's
    value and interval from its profile (the model fitted out at each value); the model's
    strength at that value, its interval the strengths fitted across the measurement's interval
    widened by the model's own interval at fixed measurement (its half-widths on each side)."""
    theta = profile.strength_at(measurement.theta)
    lo, hi = measurement.interval
    inside = [s for m, s in profile.strengths.items() if lo - 1e-12 <= m <= hi + 1e-12 and math.isfinite(s)]
    # (the interval's ends are read off between the values searched: ``ModelProfile.interpolated``)
    inside = [*inside, *(s for s in map(profile.interpolated, (lo, hi)) if math.isfinite(s))] or [theta]
    interval = (min(inside) - (model_result.theta - model_result.interval[0]),
                max(inside) + (model_result.interval[1] - model_result.theta))
    points = np.array([(s, m) for m, s in sorted(profile.strengths.items())])
    chi2 = np.array([profile.chi2[m] for m in sorted(profile.strengths)])
    return JointFit((model_result.name, measurement.name), (model_result.theta, 0.0), (theta, measurement.theta),
                    (interval, measurement.interval), model_result.chi2, measurement.chi2, measurement.capsules,
                    points, chi2)


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

    A model effect found first (alone, or tied with a measurement effect) is instead fitted
    with each measurement effect, its strength refitted at every measurement value
    (``combine_with_measurement``); the pair is kept when it beats each effect alone, and then
    resolves such a tie.

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
    joint = None
    tie_resolved = False
    # A model effect found first (alone, or tied with a measurement effect that it may be
    # mimicking together with it): each measurement effect is fitted with it, the model's
    # strength refitted at each measurement value (``combine_with_measurement``).
    model_first = _model_to_combine(rounds[0], library(base_law)) if max_effects >= 2 else None
    if model_first is not None:
        model = next(c for c in library(base_law) if c.name == model_first.name)
        measurements = [c for c in library(base_law) if c.acts_on == "capsules"]
        combined, profile, why = combine_with_measurement(with_contours, database, base_law, model, model_first,
                                                          rounds[0].results, measurements, sigma, progress)
        if profile is not None and combined.chosen is not None:
            joint = combined_fit(model_first, combined.chosen, profile)
            tie_resolved = bool(rounds[0].rivals)
            rounds[0].chosen = model_first
            rounds.append(combined)
            measurement = next(c for c in measurements if c.name == combined.chosen.name)
            fixed = [(model, joint.values[0]), (measurement, joint.values[1])]
            found = ", ".join(f"{name} {value:.3g} [{lo:.3g}, {hi:.3g}]"
                              for name, value, (lo, hi) in zip(joint.names, joint.values, joint.intervals))
            note = (f"fitted together: {found}, {model.name} refitted at each {measurement.name}; chi2 "
                    f"{joint.chi2_start:.0f} -> {joint.chi2:.0f} over {joint.capsules} capsules")
        elif not rounds[0].rivals:
            if combined.chosen is None:
                rounds.append(combined)
            fixed = [(model, model_first.theta)]
            note = (f"measurement effects fitted with {model.name}: {why}; model effects on top of a model "
                    "effect not assessed (no database holds both)")
    # A round whose choice the data cannot make (rivals) ends the sequence: fixing one of two
    # indistinguishable effects would build the next round on a guess.
    while model_first is None and rounds[-1].chosen is not None and not rounds[-1].rivals:
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
    if len(fixed) == 2 and joint is None:
        (first, _), (second, theta_2) = fixed
        state, law = _apply_all(with_contours, base_law, [(second, theta_2)], library)
        rebuilt = [c for c in library(law) if c.name == first.name]
        refit = diagnose(state, database, law, rebuilt, sigma, screen=False, progress=progress)
        result = refit.results[0]
        if math.isfinite(result.theta):
            fixed[0] = (first, result.theta)
            note = (f"{first.name} refitted with {second.name} fixed: {result.theta:.3g}, "
                    f"interval [{result.interval[0]:.3g}, {result.interval[1]:.3g}]")
    if len(fixed) == 2 and joint is None and all(len(c.values) > 2 for c, _ in fixed):
        joint = joint_refine(with_contours, database, base_law, fixed, library, sigma)
        fixed = [(c, value) for (c, _), value in zip(fixed, joint.values)]
        found = ", ".join(f"{name} {value:.3g} [{lo:.3g}, {hi:.3g}]"
                          for name, value, (lo, hi) in zip(joint.names, joint.values, joint.intervals))
        note = (f"fitted together: {found}; chi2 {joint.chi2_start:.0f} -> {joint.chi2:.0f} "
                f"over {joint.capsules} capsules")
    effects = [(c.name, theta) for c, theta in fixed]
    g_s = [rounds[0].chosen.g_s_before if rounds[0].chosen else (math.nan, math.nan)]
    fit, final = rounds[0].fit, None
    lengths, floor = length_g_s_with_systematic(with_contours, lengths_inverter(database, base_law))
    floor = float(np.nan_to_num(floor))
    g_s_lengths, contour_systematic, lengths_systematic = [lengths], [floor], [floor]
    if fixed:
        state, law = _apply_all(with_contours, base_law, fixed, library)
        final = score_batch(state, database, law, sigma)
        keep = np.isfinite(final.g_s)
        g_s.append(_g_s_summary(final, keep)[0])
        lengths, floor = length_g_s_with_systematic(state, lengths_inverter(database, law))
        g_s_lengths.append(lengths)
        # Each round's strength interval carried into G_s: the largest (an approximation for
        # two effects, whose joint interval is not propagated).
        round_choices = [r.chosen for r in rounds if r.chosen is not None]
        floor = float(np.nan_to_num(floor))
        contour_systematic.append(max([floor, *(c.g_s_systematic[1] for c in round_choices)]))
        lengths_systematic.append(max([floor, *(c.g_s_lengths_systematic[1] for c in round_choices)]))
        fit = batch_fit(with_contours, final)
    return SequentialDiagnosis(rounds, effects, g_s, note, joint, fit, g_s_lengths, final=final,
                               g_s_systematic=contour_systematic, g_s_lengths_systematic=lengths_systematic,
                               tie_resolved=tie_resolved)


def _model_to_combine(first: Diagnosis, candidates: Sequence[Candidate]) -> CandidateResult | None:
    """The model effect of the first round to fit measurement effects with: the chosen one when
    it is a model effect with a continuous strength; in a tie, the best such model effect when
    a measurement effect is among the rivals (the two together may be what the batch holds;
    ``combine_with_measurement`` keeps them only if they beat each alone). None otherwise
    (a tie of model effects only: no database holds two)."""
    continuous = {c.name for c in candidates if c.acts_on == "law" and c.continuous}
    tied = _tied(first)
    models = [r for r in tied if r.name in continuous and r.after is not None]
    if not models or (first.rivals and not any(r.acts_on == "capsules" for r in tied)):
        return None
    return max(models, key=lambda r: r.bic_drop_common)

