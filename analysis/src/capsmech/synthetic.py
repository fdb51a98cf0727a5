"""Synthetic measurements made by the kernel at known parameters, for tests and examples.

``simulate_tube(a_over_l, Ca_s, law)`` runs ``capsim`` (axisymmetric tube) and returns its
steady L_z, L_p, v_c/V and meridian; ``tube_batch(...)`` turns a list of such capsules into
rows of the tube measurement format (``capsmech.measurements``) in micrometres for one
material (one G_s; each capsule's Ca_s set by its flow rate), with realistic noise: each
length off by a relative Gaussian error (2 % by default, the paper's estimate), the
velocity likewise. The truth is kept beside the rows, never written into them.
"""
from __future__ import annotations

import csv
import math
import subprocess
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capsmech.grid import parse_law
from capsmech.io import read_case
from capsmech.paths import capsim_executable


@dataclass(frozen=True)
class SimulatedCapsule:
    """Steady state of one simulated tube case (lengths in l)."""

    a_over_l: float
    Ca_s: float
    law: str
    L_z: float
    L_p: float
    vc_over_V: float
    meridian: np.ndarray
    status: str


def simulate_tube(a_over_l: float, Ca_s: float, law: str, n_meridian: int = 64, threads: int = 1,
                  capsim: str | Path | None = None) -> SimulatedCapsule:
    """Run the kernel for one centred capsule in the tube; NaN results when not steady."""
    kernel = Path(capsim) if capsim else capsim_executable()
    flags = parse_law(law).kernel_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "case.h5"
        subprocess.run([str(kernel), "--flow", "tube", *flags, "--a-over-l", repr(float(a_over_l)), "--ca", repr(float(Ca_s)),
                        "--n-meridian", str(n_meridian), "--threads", str(threads), "--quiet", "--out", str(out)],
                       check=True, capture_output=True, text=True)
        case = read_case(out)
    if case.status != "steady":
        nan = math.nan
        return SimulatedCapsule(float(a_over_l), float(Ca_s), law, nan, nan, nan, np.empty((0, 2)), case.status)
    meridian = np.column_stack([case.profile["r"], case.profile["z"]])
    return SimulatedCapsule(float(a_over_l), float(Ca_s), law, case.steady_value("L_z"), case.steady_value("L_p"),
                            case.steady_value("v_c"), meridian, case.status)


def tube_batch(capsules: Sequence[SimulatedCapsule], g_s: float = 0.04, tube_radius_um: float = 50.0,
               mu_pa_s: float = 1.0, noise: float = 0.02, seed: int = 0) -> list[dict[str, float | str]]:
    """Measurement rows (L_z, L_p [um], v_c [mm/s], tube_radius [um], mu [Pa s]) with noise.

    The batch is one material: every capsule has the modulus g_s [N/m], and its Ca_s was
    reached by its flow rate, V = Ca_s g_s / mu (so v_c = (v_c/V) V).
    """
    rng = np.random.default_rng(seed)
    rows = []
    for k, capsule in enumerate(capsules):
        if capsule.status != "steady":
            continue
        scale = 1 + noise * rng.standard_normal(3)
        mean_velocity_mm_s = capsule.Ca_s * g_s / mu_pa_s * 1e3
        rows.append({"id": f"s{k + 1:03d}",
                     "L_z": capsule.L_z * tube_radius_um * scale[0],
                     "L_p": capsule.L_p * tube_radius_um * scale[1],
                     "v_c": capsule.vc_over_V * mean_velocity_mm_s * scale[2],
                     "tube_radius": tube_radius_um, "mu": mu_pa_s})
    return rows


def write_tube_csv(rows: Sequence[dict[str, float | str]], path: str | Path, comment: str = "") -> Path:
    """Write rows in the tube measurement format."""
    path = Path(path)
    with open(path, "w", newline="", encoding="utf-8") as stream:
        for line in comment.splitlines():
            stream.write(f"# {line}\n")
        writer = csv.writer(stream)
        writer.writerow(["id", "L_z [um]", "L_p [um]", "v_c [mm/s]", "tube_radius [um]", "mu [Pa s]"])
        for row in rows:
            writer.writerow([row["id"], *(f"{row[k]:.6g}" for k in ("L_z", "L_p", "v_c", "tube_radius", "mu"))])
    return path
