"""The small-deformation limit of a capsule in simple shear (Barthes-Biesel & Rallison 1981):
the published value the shear kernel and the shear databases are checked against."""
from __future__ import annotations

#: NH's area dilatation modulus is 3 G_s, that of a Hookean membrane with nu_s = 1/2.
NH_NU_S = 0.5


def d12_slope(nu_s: float) -> float:
    """D12 / Ca_s as Ca_s -> 0 for K_s/G_s = (1 + nu_s)/(1 - nu_s): 5/4 (2 + nu_s)/(1 + nu_s)
    (25/12 for NH)."""
    return 1.25 * (2.0 + nu_s) / (1.0 + nu_s)


def law_d12_slope(law_key: str) -> float:
    """:func:`d12_slope` of a database law key (``NH``, ``GH_nu0.2``, ...); NH as nu_s = 1/2."""
    from capsmech.io.laws import parse_law

    nu_s = parse_law(law_key).nu_s
    return d12_slope(NH_NU_S if nu_s is None else nu_s)
