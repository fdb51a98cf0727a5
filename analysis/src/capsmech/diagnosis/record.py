"""A diagnosis as plain data (``capsmech diagnose --json``, issue 19 item 5): the verdict's kind,
the effects with their strengths and intervals, G_s before and after by both estimators, the
goodness of fit, and the capsules used and left out. The console and the Markdown report say
the same in words.

A number the verdict does not support is not written: an ``unexplained`` batch has no
``g_s_after`` (null, with the reason); a yes/no candidate (another law group) has no strength
and no interval.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from capsmech.diagnosis.diagnose import Diagnosis, TiedGs
from capsmech.diagnosis.goodness import GoodnessOfFit
from capsmech.diagnosis.report import batch_heterogeneity
from capsmech.diagnosis.scoring import G_S_LEVEL, CandidateResult, g_s_half_width
from capsmech.diagnosis.sequential import SequentialDiagnosis
from capsmech.io.atomic import write_text_atomically


def _number(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _summary(values: np.ndarray) -> tuple[float, float, int]:
    """(mean, sd, count) of the finite values."""
    g = values[np.isfinite(values)]
    return (float(g.mean()), float(g.std(ddof=1)), len(g)) if len(g) > 1 else (math.nan, math.nan, len(g))


def g_s_interval(mean: float, sd: float, n: int, systematic: float = 0.0, level: float = G_S_LEVEL) -> dict[str, Any]:
    """G_s [N/m] with the interval of its mean over n capsules: the Student-t half-width of the
    capsules' scatter and the ``systematic`` half-width [N/m] (the databases' accuracy, and the
    uncertainty of an effect's strength G_s was computed at; ``capsmech.diagnosis.scoring``),
    added in quadrature as for the strengths' intervals."""
    if n < 2 or not (math.isfinite(mean) and math.isfinite(sd)):
        return {"value": None, "interval": None, "capsules": n}
    systematic = float(systematic) if math.isfinite(systematic) else 0.0
    half = g_s_half_width(sd, n, systematic, level)
    return {"value": mean, "interval": [mean - half, mean + half], "sd": sd, "systematic": systematic,
            "capsules": n, "level": level}


#: Fewer of the contour fits' capsules than this fraction inverted by lengths: G_s by lengths
#: is that of a subset the law happens to reach, not the batch's.
LENGTHS_MIN_SHARE = 0.5


def lengths_left_out(lengths: dict[str, Any] | None, contour: dict[str, Any] | None) -> str:
    """Why G_s by lengths after an effect is not an answer beside the contour fits' (both as
    ``g_s_interval`` makes them), or "" when it is: the law reproduces the lengths of fewer than
    ``LENGTHS_MIN_SHARE`` of the capsules the contour fits use, its interval reaches 0 (no
    modulus at all is excluded), or the two intervals do not overlap. The contour fits use each
    capsule's whole contour; the lengths are two numbers a capsule, and under a law whose
    lengths hardly change with Ca_s (pre-stress, a stiff Skalak membrane's nearly
    parachute-free shapes) they barely constrain it: on the independent generator's Skalak
    C = 10 capsules at the level C = 8, G_s by lengths scattered by 79 % a capsule, its interval
    [-0.0016, 0.068] N/m. (Its scatter alone is no criterion: on one-material batches the
    lengths scatter 3-8 times more than the contour fits, 6-18 % against 2-3 %.)"""
    if not contour or contour.get("value") is None or not lengths or lengths.get("value") is None:
        return ""
    if lengths["capsules"] < LENGTHS_MIN_SHARE * contour["capsules"]:
        return (f"the law reproduces the lengths of {lengths['capsules']} of the {contour['capsules']} capsules the "
                "contour fits use: G_s by lengths would be that subset's; use the contour fits' G_s")
    (low, high), (c_low, c_high) = lengths["interval"], contour["interval"]
    if low <= 0:
        return (f"G_s by lengths {lengths['value']:.4g} [{low:.4g}, {high:.4g}] N/m: its capsules scatter by "
                f"{100 * lengths['sd'] / lengths['value']:.0f} % and the interval reaches 0: under this law the lengths "
                "(two numbers a capsule) hardly constrain Ca_s where the whole contour does; use the contour fits' G_s")
    if high < c_low or low > c_high:
        return (f"G_s by lengths {lengths['value']:.4g} [{low:.4g}, {high:.4g}] N/m disagrees with the contour fits' "
                f"{contour['value']:.4g} [{c_low:.4g}, {c_high:.4g}] N/m: under this law the lengths (two numbers a "
                "capsule) hardly constrain Ca_s where the whole contour does; use the contour fits' G_s")
    return ""


def candidate_record(result: CandidateResult) -> dict[str, Any]:
    """One candidate's evidence."""
    record: dict[str, Any] = {"name": result.name, "supported": result.supported, "note": result.note or None}
    if result.note:
        return record
    record.update({
        "parameter": None if result.discrete else result.parameter,
        "unit": None if result.discrete else result.unit,
        "strength": None if result.discrete else _number(result.theta),
        "interval": None if result.discrete else [_number(v) for v in result.interval],
        "interval_systematic": None if result.discrete else _number(result.systematic),
        # Between the base law and the lowest level: how far the other interpolant moves the strength.
        "interval_interpolation": _number(result.interpolation) if result.interpolation > 0 else None,
        "levels": None if result.discrete else [_number(v) for v in result.levels],
        "at_edge": (result.edge or None) if not result.discrete else None,
        "capsules": result.capsules, "chi2_base": _number(result.chi2_base), "chi2": _number(result.chi2),
        "bic_drop": _number(result.bic_drop), "cv_gain": _number(result.cv_gain),
        "cv_p_value": _number(result.cv_p_value),
        "g_s_contour_fits": {"before": g_s_interval(*result.g_s_before, result.capsules, result.g_s_systematic[0]),
                             "after": g_s_interval(*result.g_s_after, result.capsules, result.g_s_systematic[1])},
        "g_s_lengths": {"before": g_s_interval(*result.g_s_lengths_before, result.g_s_lengths_systematic[0]),
                        "after": g_s_interval(*result.g_s_lengths_after, result.g_s_lengths_systematic[1]),
                        # (the evidence keeps the number; why it is no answer beside the contour fits')
                        "after_left_out": lengths_left_out(
                            g_s_interval(*result.g_s_lengths_after, result.g_s_lengths_systematic[1]),
                            g_s_interval(*result.g_s_after, result.capsules, result.g_s_systematic[1])) or None},
        "goodness_of_fit": result.fit.as_dict() if result.fit is not None else None,
    })
    return record


def _effect(result: CandidateResult, theta: float, interval: tuple[float, float]) -> dict[str, Any]:
    """An effect found: its name, strength and interval (none for a yes/no candidate)."""
    if result.discrete:
        return {"name": result.name, "strength": None, "interval": None, "unit": None}
    return {"name": result.name, "parameter": result.parameter, "strength": _number(theta),
            "interval": [_number(v) for v in interval], "unit": result.unit, "at_edge": result.edge or None}


def _tie(tie: TiedGs) -> dict[str, Any]:
    """G_s after under each tied candidate and the interval covering them all."""
    low, high = tie.interval
    return {"interval": [_number(low), _number(high)] if math.isfinite(low) else None,
            "level": G_S_LEVEL, "spread": _number(tie.spread),
            "candidates": [{"name": n, "value": _number(v), "interval": [_number(lo), _number(hi)]}
                           for n, v, (lo, hi) in zip(tie.names, tie.values, tie.intervals)]}


def _fit(fit: GoodnessOfFit | None) -> dict[str, Any] | None:
    return fit.as_dict() if fit is not None else None


def _tied_rounds(outcome: Diagnosis | SequentialDiagnosis, first: Diagnosis) -> list[Diagnosis]:
    """The rounds that end in a tie; a first-round tie that a model and a measurement effect
    fitted together resolved (``tie_resolved``) is not one."""
    if not isinstance(outcome, SequentialDiagnosis):
        return [first] if first.rivals else []
    return [r for k, r in enumerate(outcome.rounds) if r.rivals and not (k == 0 and outcome.tie_resolved)]


def diagnosis_record(outcome: Diagnosis | SequentialDiagnosis, batch: str = "") -> dict[str, Any]:
    """The whole diagnosis as a JSON-ready dict (see the module)."""
    first = outcome.rounds[0] if isinstance(outcome, SequentialDiagnosis) else outcome
    kind = outcome.kind
    record: dict[str, Any] = {"batch": batch, "base_law": str(first.base_law), "verdict": kind,
                              "verdict_text": outcome.verdict, "goodness_of_fit": _fit(outcome.fit)}
    effects = []
    if isinstance(outcome, SequentialDiagnosis):
        chosen = [r.chosen for r in outcome.rounds if r.chosen is not None]
        for k, ((_, theta), result) in enumerate(zip(outcome.effects, chosen)):
            # Two strengths fitted together carry the joint fit's intervals.
            interval = outcome.joint.intervals[k] if outcome.joint is not None else result.interval
            effects.append(_effect(result, theta, interval))
    elif first.chosen is not None:
        effects.append(_effect(first.chosen, first.chosen.theta, first.chosen.interval))
    record["effects"] = effects if kind == "effect" else []
    # Candidates the data cannot tell apart (verdict cannot_tell): the chosen one and its rivals.
    tied = _tied_rounds(outcome, first)
    record["cannot_tell"] = ([r.name for r in [tied[0].chosen, *tied[0].rivals] if r is not None]
                             if kind == "cannot_tell" and tied else [])
    closest = first.closest
    record["closest"] = candidate_record(closest) if closest is not None else None
    # G_s by two estimators, each the same before and after (issue 19, item 3): by lengths
    # (measured on the contour, inverted) and by the contour fits. "After" only where the
    # verdict supports it. Each with its systematic part (``g_s_interval``).
    if isinstance(outcome, SequentialDiagnosis):
        lengths_systematic = [*outcome.g_s_lengths_systematic, 0.0, 0.0]
        contour_systematic = [*outcome.g_s_systematic, 0.0, 0.0]
        lengths = [(*v, systematic) for v, systematic in zip(outcome.g_s_lengths, lengths_systematic)]
        contour = [(m, s, outcome.fit.capsules if outcome.fit is not None else 0, systematic)
                   for (m, s), systematic in zip(outcome.g_s, contour_systematic)]
        if not outcome.effects:
            contour = [(*_summary(first.base.g_s), contour_systematic[0])] if first.base is not None else []
    else:
        c = first.chosen
        lengths = ([(*c.g_s_lengths_before, c.g_s_lengths_systematic[0]),
                    (*c.g_s_lengths_after, c.g_s_lengths_systematic[1])] if c is not None else [])
        contour = ([(*c.g_s_before, c.capsules, c.g_s_systematic[0]), (*c.g_s_after, c.capsules, c.g_s_systematic[1])]
                   if c is not None else
                   [(*_summary(first.base.g_s), closest.g_s_systematic[0] if closest is not None else 0.0)]
                   if first.base is not None else [])
    if not lengths and closest is not None:
        lengths = [(*closest.g_s_lengths_before, closest.g_s_lengths_systematic[0])]
    g_s: dict[str, Any] = {}
    for name, values in (("lengths", lengths), ("contour_fits", contour)):
        before = g_s_interval(*values[0]) if values and math.isfinite(values[0][0]) else None
        after = g_s_interval(*values[1]) if kind == "effect" and len(values) > 1 else None
        g_s[name] = {"before": before, "after": after}
    # The two estimators agree, or G_s by lengths after is left out with the reason.
    excluded = lengths_left_out(g_s["lengths"]["after"], g_s["contour_fits"]["after"])
    if excluded:
        g_s["lengths"]["after"] = None
        g_s["lengths"]["after_left_out"] = excluded
    # A tie still answers: G_s after under each tied candidate, and one interval covering them.
    tied_round = next(iter(_tied_rounds(outcome, first)), None)
    if kind == "cannot_tell" and tied_round is not None:
        for tie in tied_round.tied_g_s:
            g_s[tie.estimator]["tied"] = _tie(tie)
        record["separating_measurement"] = tied_round.separating_measurement
    record["g_s"] = g_s
    if kind != "effect":
        record["g_s_after_reason"] = (
            "no effect found: G_s is the base law's (before)" if kind == "none" else
            "cannot_tell: G_s after depends on which of the tied candidates is right: under each, and one "
            "interval covering them all, in g_s.<estimator>.tied" if kind == "cannot_tell" else
            f"{kind}: no candidate leaves the batch consistent with its noise, so no G_s after is supported")
    # One material or several, on the contour fits' per-capsule G_s (capsmech.diagnosis.report).
    mixture = batch_heterogeneity(first)
    record["heterogeneity"] = mixture.as_dict() if mixture is not None else None
    record["candidates"] = [candidate_record(r) for r in first.results]
    record["left_out"] = [{"id": capsule, "reason": why} for capsule, why in first.excluded]
    if first.base is not None:
        record["capsules_fitted_by_base"] = int(sum(1 for v in first.base.chi2 if math.isfinite(v)))
    return record


def write_json(outcome: Diagnosis | SequentialDiagnosis, path: str | Path, batch: str = "") -> Path:
    """Write ``diagnosis_record`` to ``path`` whole (temporary name, then renamed)."""
    return write_text_atomically(path, json.dumps(diagnosis_record(outcome, batch), indent=1) + "\n")
