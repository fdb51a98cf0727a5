"""Continuous law parameters as candidate effects: Skalak's area-dilatation ratio C and
Evans-Skalak/GH's ν_s (issue 22, item 4).

A database holds a law family at a few parameter values only (law keys ``SK_C<C>``,
``GH_nu<nu_s>``). A batch made with a value between them (SK with C = 3) is neither law
group; the family candidate fits the parameter between the family's levels, the law being
the linear blend of the two bracketing groups (as pre-stress and bending are blended between
their levels, ``capsmech.diagnosis.candidates.BlendedLaw``). Levels no database holds make
the candidate "not assessed: needs simulations", with the grid of exactly those groups around
the batch (``capsmech.diagnosis.effect_grid``); ``diagnose --simulate`` computes them.

The base law is not a member of a family unless its key is one (base ``SK_C1`` in the
family ``SK_C``: C = 1 is the base). For base NH the family's neutral value is NaN: no value
of the family is the base law, every level is refitted, and the criteria compare the family's
best blend with NH.
"""
from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence

from capsmech.diagnosis.candidates import BlendedLaw, Candidate, interpolation_weights
from capsmech.io.measurements import Capsule

#: family -> (parameter, default levels). SK's C: 1 is the paper's group; 2, 4 and 8 span the
#: membranes whose area resists 3-9 times more than their shear (C = 3 lies between 2 and 4,
#: where the linear blend of two groups holds). GH's ν_s: the paper's three groups.
LAW_FAMILIES: dict[str, tuple[str, tuple[float, ...]]] = {
    "SK_C": ("C", (1.0, 2.0, 4.0, 8.0)),
    "GH_nu": ("nu_s", (0.0, 0.2, 0.5)),
}

_MEMBER = re.compile(r"^(?P<family>SK_C|GH_nu)(?P<value>[0-9.eE+-]+)$")


def family_key(family: str, value: float) -> str:
    """The law key of a family member: ``family_key("SK_C", 2)`` is ``"SK_C2"``."""
    return f"{family}{value:g}"


def family_member(key: str) -> tuple[str, float] | None:
    """``(family, value)`` of a plain law key of a family (``"GH_nu0.2"`` -> ``("GH_nu", 0.2)``),
    None for any other key (NH, or a key with an effect such as ``SK_C1+prestress0.05``)."""
    match = _MEMBER.match(key)
    if match is None:
        return None
    try:
        return match["family"], float(match["value"])
    except ValueError:
        return None


def law_family_candidate(base_law: str, family: str, levels: Sequence[float] | None = None) -> Candidate:
    """The family's parameter as a candidate on ``base_law``: the law at a value between two
    levels is their blend; at a level, that group. Its ``laws`` are the groups it needs."""
    parameter, default_levels = LAW_FAMILIES[family]
    values = tuple(sorted({float(v) for v in (default_levels if levels is None else levels)}))
    if len(values) < 2:
        raise ValueError(f"law family {family}: needs at least two levels, got {list(values)}")
    member = family_member(base_law)
    neutral = member[1] if member is not None and member[0] == family else math.nan
    if member is not None and member[0] == family and neutral not in values:
        values = tuple(sorted((*values, neutral)))

    def apply(capsules: Sequence[Capsule], theta: float) -> tuple[list[Capsule], str | BlendedLaw]:
        at = [v for v in values if math.isclose(v, theta, rel_tol=0, abs_tol=1e-12)]
        if at:
            key = family_key(family, at[0])
            return list(capsules), base_law if at[0] == neutral else key
        weights = interpolation_weights(values, theta)
        return list(capsules), BlendedLaw([family_key(family, values[k]) for k, _ in weights],
                                          [w for _, w in weights])

    laws = tuple(family_key(family, v) for v in values if v != neutral)
    return Candidate(family, parameter, "", values, neutral, apply, laws=laws)


def law_family_candidates(base_law: str | BlendedLaw, levels: Mapping[str, Sequence[float]] | None = None
                          ) -> list[Candidate]:
    """A candidate per family (``LAW_FAMILIES``; ``levels`` overrides a family's levels, an empty
    list drops it). None for a blended base (a later round of a sequential diagnosis after a
    blended law was chosen): the family's members are defined on plain law keys only."""
    if not isinstance(base_law, str) or "+" in base_law:
        return []
    out = []
    for family in LAW_FAMILIES:
        chosen = None if levels is None else levels.get(family)
        if chosen is not None and len(chosen) == 0:
            continue
        out.append(law_family_candidate(base_law, family, chosen))
    return out
