"""Candidate effects of the diagnosis: each adds one parameter to the forward model of a tube
batch (a contour offset, a tube-radius error, another law group, a scalar kernel effect such as
pre-stress or bending blended between database levels)."""
from __future__ import annotations

import math
import weakref
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from capsmech.inversion.fitting import tube_inverter
from capsmech.inversion.inverters import N_NEIGHBOURS, TubeFit, TubeInverter, TubeTable
from capsmech.io.database import TubeDatabase
from capsmech.io.measurements import Capsule


def offset_contour(contour: np.ndarray, delta: float) -> np.ndarray:
    """The closed contour moved outward by delta along its normals (inward for delta < 0).

    The normals come from the contour smoothed over 5 neighbouring points, so that tracing
    noise does not turn them; the traced points themselves are moved."""
    kernel = np.ones(5) / 5
    padded = np.vstack([contour[-2:], contour, contour[:2]])
    smooth = np.column_stack([np.convolve(padded[:, k], kernel, mode="valid") for k in range(2)])
    tangent = np.roll(smooth, -1, axis=0) - np.roll(smooth, 1, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1)[:, None]
    normal = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    if np.mean(np.sum((smooth - smooth.mean(axis=0)) * normal, axis=1)) < 0:
        normal = -normal
    return contour + delta * normal


@dataclass(frozen=True)
class Candidate:
    """One effect: a name, its parameter's name and unit, the grid of values to try, the
    neutral value (the base model), and how a value changes the capsules or the law."""

    name: str
    parameter: str
    unit: str
    values: tuple[float, ...]
    neutral: float
    #: (capsules, value) -> (capsules, law): the law a key, or a BlendedLaw between keys.
    apply: Callable[[Sequence[Capsule], float], tuple[list[Capsule], str | BlendedLaw]]
    #: Law groups the candidate needs from the databases (beyond the base law).
    laws: tuple[str, ...] = ()
    #: "capsules" (a measurement effect: changes the data, keeps the law it was built on) or
    #: "law" (a model effect: changes the law, keeps the data); what makes two effects compose.
    acts_on: str = "law"
    #: The strengths that have a physical meaning (pre-stress and bending are >= 0): the fit
    #: never extrapolates beyond them (``extrapolation_range``).
    limits: tuple[float, float] = (-math.inf, math.inf)
    #: A model effect whose lowest value is the base law: the same effect with another law
    #: between the base law and the lowest level (the quadratic through the base law and the
    #: two lowest levels; elsewhere the same blend), whose estimate's difference from this one's
    #: measures the interpolation error there (``capsmech.diagnosis.scoring.evaluate_candidate``).
    near_base_alternative: Candidate | None = None
    #: ``apply`` where the law need not be fitted again, for what is only read off at a value
    #: (the G_s at the ends of the strength's interval, ``scoring._g_s_systematic``); None: ``apply``.
    #: A measurement effect fitted with a model effect (``sequential.measurement_with_model``)
    #: refits the model's strength at every new value; here it interpolates the strengths found.
    apply_between: Callable[[Sequence[Capsule], float], tuple[list[Capsule], str | BlendedLaw]] | None = None

    @property
    def continuous(self) -> bool:
        """A strength fitted between its values (not a yes/no law group)."""
        return self.parameter != "group" and len(self.values) > 2


#: How far beyond its outermost values a continuous strength is fitted, as a fraction of the
#: spacing of the two outermost values: the blend of the last two levels (or the measurement
#: effect's formula) extended linearly. Half a spacing: far enough that a strength just beyond
#: the levels (Skalak C = 10 above the levels 1-8) is no longer pinned at the last one, near
#: enough that the linear extension stays close to the kernel's shapes (the blend's own error
#: between two levels is largest halfway).
EXTRAPOLATION = 0.5
#: How far beyond its values a measurement effect is searched, in spacings: it is exact at any
#: value (the data are changed, not a law extrapolated), so its values only say where to start.
MEASUREMENT_REACH = 2.0


def extrapolation_range(candidate: Candidate) -> tuple[float, float]:
    """The strengths a continuous candidate is fitted over: its values' range extended by
    ``EXTRAPOLATION`` of the outermost spacing on each side (``MEASUREMENT_REACH`` spacings for
    a measurement effect), within its ``limits``."""
    values = sorted(candidate.values)
    reach = MEASUREMENT_REACH if candidate.acts_on == "capsules" else EXTRAPOLATION
    low = values[0] - reach * (values[1] - values[0])
    high = values[-1] + reach * (values[-1] - values[-2])
    return max(low, candidate.limits[0]), min(high, candidate.limits[1])


def contour_offset_candidate(base_law: str | BlendedLaw, max_px: float = 3.0, step_px: float = 0.75) -> Candidate:
    """Traced contour offset outward by delta pixels (needs a ``pixel_size`` column)."""

    def apply(capsules: Sequence[Capsule], delta: float) -> tuple[list[Capsule], str | BlendedLaw]:
        out = []
        for c in capsules:
            pixel = c["pixel_size"]
            if c.contour is None or not math.isfinite(pixel):
                out.append(c)
                continue
            values = dict(c.values)
            values["L_z"] = c["L_z"] - 2 * delta * pixel
            out.append(replace(c, values=values, contour=offset_contour(c.contour, -delta * pixel)))
        return out, base_law

    values = tuple(np.round(np.arange(-2 * step_px, max_px + 1e-9, step_px), 6))
    return Candidate("contour_offset", "delta", "px", values, 0.0, apply, acts_on="capsules")


def tube_radius_candidate(base_law: str | BlendedLaw, max_rel: float = 0.045, step: float = 0.015) -> Candidate:
    """The capillary radius is l (1 + eps) instead of the nominal l."""

    def apply(capsules: Sequence[Capsule], eps: float) -> tuple[list[Capsule], str | BlendedLaw]:
        out = []
        for c in capsules:
            values = dict(c.values)
            values["tube_radius"] = c["tube_radius"] * (1 + eps)
            out.append(replace(c, values=values))
        return out, base_law

    values = tuple(np.round(np.arange(-max_rel, max_rel + 1e-9, step), 6))
    return Candidate("tube_radius", "eps", "1", values, 0.0, apply, acts_on="capsules")


def law_candidate(base_law: str, other_law: str) -> Candidate:
    """Another database group (law, nu_s, or a law key with an effect) instead of the base:
    one discrete parameter, 0 = base, 1 = the other group."""

    def apply(capsules: Sequence[Capsule], which: float) -> tuple[list[Capsule], str | BlendedLaw]:
        return list(capsules), other_law if which >= 0.5 else base_law

    return Candidate(f"law {other_law}", "group", "", (0.0, 1.0), 0.0, apply, laws=(other_law,))


#: Kernel effects with one scalar strength that an effect database holds at a few levels
#: (law keys ``<base>+<effect><value>``): effect -> (parameter name, default levels).
SCALAR_EFFECTS: dict[str, tuple[str, tuple[float, ...]]] = {
    "prestress": ("alpha", (0.04, 0.06, 0.08)),
    "kb": ("k_b", (0.0025, 0.005, 0.01)),
}


def effect_key(base_law: str, effect: str, value: float) -> str:
    """The database law key of the base law with a scalar effect (``NH+prestress0.05``,
    ``NH+kb0.01``); the base law itself at value 0."""
    return base_law if value == 0 else f"{base_law}+{effect}{value:g}"


def prestress_key(base_law: str, alpha: float) -> str:
    """The database law key of the base law with pre-stress alpha (``NH+prestress0.05``)."""
    return effect_key(base_law, "prestress", alpha)


def interpolation_weights(levels: Sequence[float], value: float) -> list[tuple[int, float]]:
    """Weights of the levels whose blend is the law at ``value``: linear between the two
    levels that bracket it, [(level index, weight)]; beyond the levels, the outermost two
    extended linearly (a weight above 1 and one below 0: ``EXTRAPOLATION``).

    Linear, not a quadratic through three levels: an effect can change a shape abruptly
    between two levels (pre-stress removes the parachute between alpha = 0 and 0.04), and a
    quadratic carries that into the next interval (measured on the pre-stress batch: alpha
    0.0482 [0.0474, 0.0490] and chi2 418 against the linear blend's 0.0508 and 366, truth 0.05)."""
    grid = np.asarray(levels, dtype=float)
    k = int(np.clip(np.searchsorted(grid, value) - 1, 0, len(grid) - 2))
    w = (value - grid[k]) / (grid[k + 1] - grid[k])
    return [(k, 1 - w), (k + 1, w)]


def quadratic_weights(levels: Sequence[float], value: float) -> list[tuple[int, float]]:
    """Weights of the three lowest levels whose blend is the law at ``value`` by quadratic
    (Lagrange) interpolation through them: the second interpolant between the base law and the
    lowest level (``near_base_alternative``), where the linear blend is the least accurate."""
    nodes = [float(v) for v in levels[:3]]
    weights = []
    for j, node in enumerate(nodes):
        others = [other for m, other in enumerate(nodes) if m != j]
        weights.append((j, float(np.prod([(value - other) / (node - other) for other in others]))))
    return weights


class BlendedLaw:
    """A law between database groups (a scalar effect between its levels): its profiles and
    velocity ratio are the weighted sum of the groups', at the same (a/l, Ca_s); its length
    fit is that of the group with the largest weight (a contour fit's start only)."""

    def __init__(self, keys: Sequence[str], weights: Sequence[float]) -> None:
        self.keys, self.weights = list(keys), [float(w) for w in weights]

    def __str__(self) -> str:
        return " + ".join(f"{w:.3g} {key}" for key, w in zip(self.keys, self.weights))

    def inverter(self, database) -> BlendedInverter:
        return BlendedInverter([level_inverter(database, key) for key in self.keys], self.weights)

    def lengths_inverter(self, database) -> TubeInverter | None:
        """The inverter of the blend's own lengths (``blended_table``), made once per database
        and blend; None where the levels share too few nodes."""
        inverters = _LEVEL_INVERTERS.setdefault(database, {})
        key = ("lengths", tuple(self.keys), tuple(self.weights))
        if key not in inverters:
            table = blended_table([level_inverter(database, k).table for k in self.keys], self.weights)
            inverters[key] = _CachedFits(TubeInverter(table)) if table is not None else None
        return inverters[key]


#: Nodes the levels of a blend must share for its lengths to be inverted (the inversion's local
#: fits take that many neighbours).
MIN_SHARED_NODES = N_NEIGHBOURS


def blended_table(tables: Sequence[TubeTable], weights: Sequence[float]) -> TubeTable | None:
    """The blend's own rows: at each (a/l, Ca_s) node every level has, the levels' L_z, L_p,
    v_c/V (and profiles, where the levels have them on the same points) summed with the blend's
    weights, as ``BlendedInverter.profile`` sums profiles. None with fewer than
    ``MIN_SHARED_NODES`` such nodes.

    Inverting these rows gives G_s by lengths under the law the contour fits use. Blending each
    level's own lengths fit instead (``BlendedInverter.fit``) averages G_s values found at
    different (a/l, Ca_s), and needs every level to reproduce the lengths: on the independent
    generator's GH nu_s = 0.35 capsules (12, seed 11; truth 0.025 N/m) at the blend
    0.5 GH_nu0.2 + 0.5 GH_nu0.5 that gave 0.0292 from 9 capsules, these rows 0.0254 from 11
    (the levels' own fits: 0.044 and 0.014)."""
    indices = []
    for table in tables:
        indices.append({(round(float(a), 9), round(float(c), 9)): i
                        for i, (a, c) in enumerate(zip(table.a_over_l, table.Ca_s))})
    shared = sorted(set.intersection(*(set(index) for index in indices)))
    if len(shared) < MIN_SHARED_NODES:
        return None
    rows = [np.array([index[node] for node in shared]) for index in indices]

    def blend(name: str) -> np.ndarray:
        return sum(w * np.asarray(getattr(t, name), dtype=float)[r] for w, t, r in zip(weights, tables, rows))

    points = {np.shape(t.profile_r)[1] if t.profile_r is not None and t.profile_z is not None else -1 for t in tables}
    same_points = len(points) == 1 and -1 not in points
    root = np.ones(len(shared), dtype=bool)
    for t, r in zip(tables, rows):
        if t.root is not None:
            root &= np.asarray(t.root, dtype=bool)[r]
    return TubeTable(a_over_l=np.array([node[0] for node in shared]), Ca_s=np.array([node[1] for node in shared]),
                     L_z=blend("L_z"), L_p=blend("L_p"), vc_over_V=blend("vc_over_V"),
                     profile_r=blend("profile_r") if same_points else None,
                     profile_z=blend("profile_z") if same_points else None, root=root)


#: Each database's level inverters, kept while the database lives (``level_inverter``).
_LEVEL_INVERTERS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def level_inverter(database, key: str) -> TubeInverter:
    """The inverter of one level of a blend, made once per database: a diagnosis refits the
    batch at some 15 strengths of each model effect, every one a blend of the same levels
    whose lengths fits (``BlendedInverter.fit``) are then made once per capsule
    (``_CachedFits``), not once per strength."""
    inverters = _LEVEL_INVERTERS.setdefault(database, {})
    if key not in inverters:
        inverters[key] = _CachedFits(tube_inverter(database, key))
    return inverters[key]


class _CachedFits(TubeInverter):
    """A TubeInverter whose ``fit`` remembers its answers (the same lengths, the same fit)."""

    def __init__(self, inverter: TubeInverter) -> None:
        self.__dict__.update(inverter.__dict__)
        self._fits: dict[tuple[float, float, float | None, float | None], TubeFit] = {}

    def fit(self, L_z: float, L_p: float, v_c: float | None = None, mu: float | None = None) -> TubeFit:
        key = (L_z, L_p, v_c, mu)
        if key not in self._fits:
            self._fits[key] = super().fit(L_z, L_p, v_c, mu)
        return self._fits[key]


class BlendedInverter:
    """The TubeInverter interface diagnose uses, for a BlendedLaw."""

    def __init__(self, inverters: Sequence[TubeInverter], weights: Sequence[float]) -> None:
        self.inverters, self.weights = list(inverters), list(weights)
        self.nearer = self.inverters[int(np.argmax(self.weights))]
        self.table = self.nearer.table

    def fit(self, L_z: float, L_p: float, v_c: float | None = None, mu: float | None = None) -> TubeFit:
        """Fit one capsule's lengths [l] at each level (``TubeInverter.fit``) and blend the fits
        with the levels' weights, as the law blends their profiles: fit-tube's estimator at a
        strength between two levels. Flagged where a level reproduces no such lengths."""
        fits = [inverter.fit(L_z, L_p, v_c, mu) for inverter in self.inverters]
        failed = [f for f in fits if not f.ok]
        if failed:
            return TubeFit(flag=failed[0].flag)

        def blend(name: str) -> float:
            return float(sum(w * getattr(f, name) for w, f in zip(self.weights, fits)))

        return TubeFit(G_s=blend("G_s"), a_over_l=blend("a_over_l"), Ca_s=blend("Ca_s"), vc_over_V=blend("vc_over_V"))

    def start_fit(self, L_z: float, L_p: float) -> TubeFit:
        """Where a contour fit of the blend starts: the blend's lengths fit, else the fit of the
        first level (by weight) that reproduces the lengths at a point every level covers.

        The blend's own fit needs every level to reproduce the lengths, and the base law (the
        level at strength 0) cannot for the very capsules an effect changes; a start elsewhere
        (the base fit, the nearest row of one level) can lie outside another level's nodes,
        where the contour fit finds nothing and the strength was pinned at a level."""
        blended = self.fit(L_z, L_p)
        if blended.ok:
            return blended
        for k in np.argsort(self.weights)[::-1]:
            fit = self.inverters[int(k)].fit(L_z, L_p)
            if fit.ok and self.profile(fit.a_over_l, fit.Ca_s) is not None:
                return fit
        return blended

    def profile(self, a_over_l: float, Ca_s: float) -> np.ndarray | None:
        profiles = [p for p in (inverter.profile(a_over_l, Ca_s) for inverter in self.inverters) if p is not None]
        if len(profiles) < len(self.inverters):
            return None
        blend = self.weights[0] * profiles[0]
        for w, p in zip(self.weights[1:], profiles[1:]):
            blend = blend + w * p
        return blend

    def velocity_ratio(self, a_over_l: float, Ca_s: float) -> float:
        return sum(w * inverter.velocity_ratio(a_over_l, Ca_s) for w, inverter in zip(self.weights, self.inverters))

    def triangle_turns(self, a_over_l: float, Ca_s: float
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """Every level's rows behind (a/l, Ca_s) (``TubeInverter.triangle_turns``), their weights
        times the level's: the blend's values are interpolated from all of them."""
        found = [inverter.triangle_turns(a_over_l, Ca_s) for inverter in self.inverters]
        parts = [part for part in found if part is not None]
        if len(parts) < len(found):
            return None
        return (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
                np.concatenate([w * p[2] for w, p in zip(self.weights, parts)]),
                np.concatenate([p[3] for p in parts]))


def scalar_effect_candidate(base_law: str, effect: str, levels: Sequence[float] | None = None) -> Candidate:
    """A kernel effect with one scalar strength (``SCALAR_EFFECTS``: pre-stress alpha, bending
    stiffness k_b), fitted between the effect database's levels: between levels the law is
    their blend (``BlendedLaw``, ``interpolation_weights``), so that the batch is refitted at
    any strength, not only at the levels."""
    parameter, default_levels = SCALAR_EFFECTS[effect]
    values = (0.0, *sorted(float(v) for v in (default_levels if levels is None else levels)))

    def blend(theta: float, quadratic_near_base: bool) -> str | BlendedLaw:
        at = [v for v in values if math.isclose(v, theta, rel_tol=0, abs_tol=1e-12)]
        if at:
            return effect_key(base_law, effect, at[0])
        near_base = quadratic_near_base and len(values) >= 3 and values[0] < theta < values[1]
        weights = quadratic_weights(values, theta) if near_base else interpolation_weights(values, theta)
        return BlendedLaw([effect_key(base_law, effect, values[k]) for k, _ in weights], [w for _, w in weights])

    def apply(capsules: Sequence[Capsule], theta: float) -> tuple[list[Capsule], str | BlendedLaw]:
        return list(capsules), blend(theta, False)

    def apply_quadratic_near_base(capsules: Sequence[Capsule], theta: float) -> tuple[list[Capsule], str | BlendedLaw]:
        return list(capsules), blend(theta, True)

    # (the base law is the level at 0; a negative pre-stress or bending stiffness is no membrane)
    laws = tuple(effect_key(base_law, effect, v) for v in values[1:])
    alternative = (Candidate(effect, parameter, "", values, 0.0, apply_quadratic_near_base, laws=laws,
                             limits=(0.0, math.inf)) if len(values) >= 3 else None)
    return Candidate(effect, parameter, "", values, 0.0, apply, laws=laws, limits=(0.0, math.inf),
                     near_base_alternative=alternative)


def prestress_candidate(base_law: str, levels: Sequence[float] = SCALAR_EFFECTS["prestress"][1]) -> Candidate:
    """Membrane pre-stress alpha (``--prestress``) between the database's levels."""
    return scalar_effect_candidate(base_law, "prestress", levels)


def bending_candidate(base_law: str, levels: Sequence[float] = SCALAR_EFFECTS["kb"][1]) -> Candidate:
    """Bending stiffness k_b = K_B/(G_s a^2) (``--kb``) between the database's levels."""
    return scalar_effect_candidate(base_law, "kb", levels)


def candidate_library(base_law: str, database_laws: Sequence[str], prestress_levels: Sequence[float] | None = None,
                      other_laws: Sequence[str] | None = None, kb_levels: Sequence[float] | None = None
                      ) -> list[Candidate]:
    """The effect library (issue 7): contour offset, tube radius, pre-stress, bending
    stiffness, and every other law group of the databases without an effect (another law,
    nu_s or C) unless ``other_laws`` names them. Levels None: the defaults of
    ``SCALAR_EFFECTS``; empty: no such candidate."""
    candidates = [contour_offset_candidate(base_law), tube_radius_candidate(base_law)]
    for effect, levels in (("prestress", prestress_levels), ("kb", kb_levels)):
        if levels is None or len(levels):
            candidates.append(scalar_effect_candidate(base_law, effect, levels))
    if other_laws is None:
        other_laws = [key for key in database_laws if key != base_law and "+" not in key]
    return candidates + [law_candidate(base_law, key) for key in other_laws]


class DatabaseSet:
    """Several tube databases seen as one: a law key is taken from the first that has it
    (the base database, then effect databases such as the shipped tube-prestress and tube-kb)."""

    flow = "tube"

    def __init__(self, databases: Sequence[TubeDatabase]) -> None:
        self.databases = list(databases)

    @property
    def laws(self) -> list[str]:
        return list(dict.fromkeys(key for d in self.databases for key in d.laws))

    def law(self, key: str):
        for database in self.databases:
            if key in database.laws:
                return database.law(key)
        raise KeyError(f"no database has law {key!r}")

