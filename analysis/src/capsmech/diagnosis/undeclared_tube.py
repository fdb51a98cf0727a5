"""Synthetic tube batches with an effect the data do not declare (issue 7, test data for diagnose).

``make_batch({"prestress": 0.05})`` draws capsules of one material at random between the
database nodes (a/l uniform in ``A_OVER_L``, Ca_s log-uniform in ``CA_S``: the region where the
NH tube database is steady), simulates each with the kernel with the effect switched on, and
turns them into measurement rows with realistic noise (``capsmech.diagnosis.synthetic.tube_batch``: 2 %
on lengths and velocity, contours traced to +-1 px). The rows say nothing about the effect;
the truth is returned apart (and written to a separate ``_truth.csv``).

Effects (name: strength, its unit)
----------------------------------
- ``contour_offset`` (px): the traced line lies delta outside the membrane: every contour
  point moves out by delta along the normal and L_z grows by 2 delta.
- ``tube_radius`` (relative): the capillary radius is l (1 + eps). Capsules are simulated at
  their true a/l; lengths and contours are scaled with the true l, the nominal l is written.
- ``prestress`` (alpha): the kernel's ``--prestress alpha``, law key ``<law>+prestress<alpha>``.
- ``kb`` (k_b = K_B/(G_s a^2)): the kernel's ``--kb k_b``, law key ``<law>+kb<k_b>``.
- ``GH_nu`` (nu_s): the membrane is GH with this nu_s (``GH_nu0.5``) while the user fits ``law``.
- ``SK_C`` (C): the membrane is Skalak with this C (``SK_C1``) while the user fits ``law``.
Several effects at once combine (e.g. ``{"prestress": 0.05, "contour_offset": 1.5}``).
"""
from __future__ import annotations

import csv
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capsmech.diagnosis.candidates import offset_contour
from capsmech.diagnosis.synthetic import (
    SimulatedCapsule,
    simulate_tube,
    tube_batch,
    write_tube_csv,
)

#: Where capsules are drawn (NH tube database steady and well inside its nodes).
A_OVER_L = (0.87, 1.03)
CA_S = (0.03, 0.10)
#: Nominal capillary radius [um] and image scale [um per pixel] (a 100 um tube is 200 px wide).
TUBE_RADIUS_UM = 50.0
PIXEL_SIZE_UM = 0.5
EFFECT_UNITS = {"contour_offset": "px", "tube_radius": "1", "prestress": "1", "kb": "1", "GH_nu": "1", "SK_C": "1"}

Simulator = Callable[[float, float, str], SimulatedCapsule]


@dataclass
class Batch:
    """Measurement rows (as ``tube_batch`` makes them) and the truth kept apart."""

    rows: list[dict]
    truth: list[dict]
    effects: dict[str, float]


def simulated_law(effects: Mapping[str, float], law: str = "NH") -> str:
    """The law key the kernel runs for these effects (``NH+prestress0.05``, ``GH_nu0.5`` ...)."""
    if "GH_nu" in effects and "SK_C" in effects:
        raise ValueError("GH_nu and SK_C are two membrane laws: switch on one")
    key = f"GH_nu{effects['GH_nu']:g}" if "GH_nu" in effects else f"SK_C{effects['SK_C']:g}" if "SK_C" in effects else law
    for effect in ("prestress", "kb"):
        if effects.get(effect, 0.0):
            key += f"+{effect}{effects[effect]:g}"
    return key


def draw_capsules(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(a/l, Ca_s) of n capsules at random between the nodes (true a/l: the true tube radius)."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(*A_OVER_L, n)
    ca = np.exp(rng.uniform(np.log(CA_S[0]), np.log(CA_S[1]), n))
    return a, ca


def make_batch(effects: str | Mapping[str, float], strength: float | None = None, n_capsules: int = 24,
               law: str = "NH", g_s: float = 0.04, seed: int = 0, draw_seed: int | None = None,
               simulate: Simulator | None = None, workers: int = 1) -> Batch:
    """A synthetic batch with ``effects`` switched on (see the module).

    Parameters
    ----------
    effects : str or mapping
        One effect name (with ``strength``) or {name: strength}; ``"none"`` or {} for none.
    n_capsules : int
        Capsules drawn (those that reach no steady state are left out of the rows).
    law : str
        The base law the user will fit (the membrane's law unless ``GH_nu`` is on).
    g_s : float
        The material's G_s [N/m].
    seed : int
        Seed of the noise; ``draw_seed`` (default ``seed``) that of the capsules' (a/l, Ca_s),
        so that batches can share their capsules and differ only in effect and noise.
    simulate : callable, optional
        ``(a_over_l, Ca_s, law_key) -> SimulatedCapsule`` (default ``simulate_tube``; pass a
        caching one to reuse kernel runs across batches).
    """
    if isinstance(effects, str):
        effects = {} if effects == "none" else {effects: float(strength if strength is not None else 0.0)}
    effects = {k: float(v) for k, v in effects.items()}
    unknown = set(effects) - set(EFFECT_UNITS)
    if unknown:
        raise ValueError(f"unknown effect(s) {sorted(unknown)}: known are {', '.join(EFFECT_UNITS)}")
    simulate = simulate or (lambda a, ca, key: simulate_tube(a, ca, key))
    key = simulated_law(effects, law)
    a, ca = draw_capsules(n_capsules, seed if draw_seed is None else draw_seed)
    with ThreadPoolExecutor(max_workers=workers) as pool:
        capsules = list(pool.map(lambda p: simulate(float(p[0]), float(p[1]), key), zip(a, ca)))
    true_l = TUBE_RADIUS_UM * (1 + effects.get("tube_radius", 0.0))
    rows = tube_batch(capsules, g_s=g_s, tube_radius_um=true_l, seed=seed, pixel_size_um=PIXEL_SIZE_UM)
    delta_px = effects.get("contour_offset", 0.0)
    for row in rows:
        row["tube_radius"] = TUBE_RADIUS_UM
        if delta_px:
            contour, length = row["contour"], row["L_z"]
            assert isinstance(contour, np.ndarray) and isinstance(length, float)  # rows with contours
            row["contour"] = offset_contour(contour, delta_px)
            row["L_z"] = length + 2 * delta_px * PIXEL_SIZE_UM
    truth, k = [], 0
    for j, capsule in enumerate(capsules):
        truth.append({"id": f"s{j + 1:03d}", "law": key, "a_over_l": capsule.a_over_l, "Ca_s": capsule.Ca_s,
                      "G_s": g_s, "status": capsule.status,
                      **{f"effect_{name}": effects.get(name, 0.0) for name in EFFECT_UNITS}})
        k += capsule.status == "steady"
    return Batch(rows, truth, effects)


def write_batch(batch: Batch, path: str | Path) -> tuple[Path, Path]:
    """The measurement CSV (and contour files) at ``path``; the truth beside it, ``<stem>_truth.csv``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_tube_csv(batch.rows, path, comment="synthetic tube batch made with the kernel by capsmech.diagnosis.undeclared_tube;\n"
                                             "2 % noise on lengths and velocity, contours traced to +-1 pixel")
    return path, write_truth(batch.truth, path)


def write_truth(truth: list[dict], path: Path) -> Path:
    """The truth of a synthetic batch beside its measurement file ``path``: ``<stem>_truth.csv``,
    one row per capsule, floats to 6 significant digits."""
    truth_path = path.with_name(f"{path.stem}_truth.csv")
    columns = list(truth[0])
    with open(truth_path, "w", newline="", encoding="utf-8") as stream:
        writer = csv.writer(stream)
        writer.writerow(columns)
        for row in truth:
            writer.writerow([f"{row[c]:.6g}" if isinstance(row[c], float) else row[c] for c in columns])
    return truth_path


def read_truth(path: str | Path) -> dict[str, float | str]:
    """The batch-level truth of a ``_truth.csv``: law key, G_s and every effect's strength."""
    with open(path, newline="", encoding="utf-8") as stream:
        rows = list(csv.DictReader(stream))
    first = rows[0]
    out: dict[str, float | str] = {"law": first["law"], "G_s": float(first["G_s"])}
    out.update({k[len("effect_"):]: float(v) for k, v in first.items() if k.startswith("effect_")})
    return out


def expected_candidates(truth: Mapping[str, float | str], base_law: str = "NH") -> dict[str, float]:
    """The diagnose candidates (``capsmech.diagnose`` names) that undo a batch's true effects,
    with the parameter value each should find: {candidate name: theta}."""
    out: dict[str, float] = {}
    if truth.get("contour_offset", 0.0):
        out["contour_offset"] = float(truth["contour_offset"])
    if truth.get("tube_radius", 0.0):
        out["tube_radius"] = float(truth["tube_radius"])
    for effect in ("prestress", "kb"):
        if truth.get(effect, 0.0):
            out[effect] = float(truth[effect])
    law = str(truth["law"]).split("+")[0]
    if law != base_law:
        out[f"law {law}"] = 1.0
    return out
