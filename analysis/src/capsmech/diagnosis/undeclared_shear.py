"""Synthetic shear (Couette) batches with an undeclared viscosity ratio (issue 7, test data
for ``capsmech diagnose-shear``).

``make_shear_batch(viscosity_ratio=0.001)`` draws capsules of one material (one G_s) at random:
Ca_s log-uniform in ``CA_S`` and radius a uniform in ``RADIUS_UM``. Each capsule is a kernel
run (``capsim --flow shear --lambda X``, level 3 and t_max 60 as the shear databases, one
thread), never an interpolation of a database. The capsule's shear rate is the one that gives
its Ca_s at the outer viscosity ``MU_PA_S`` (Ca_s = mu gamma_dot a / G_s). The measured
semi-axes L1, L2 [um] are the steady ones times a, each off by a uniform error in
[-1, 1] pixel (0.5 um pixels, written in the ``pixel_size`` column); the shear rate and mu are
exact. With ``theta_error_deg`` the rows also carry the inclination theta [deg], off by a
Gaussian error of that standard deviation (its own generator: the semi-axes stay the same). The rows say nothing about lambda; the truth is returned apart
and written to ``<stem>_truth.csv`` (conventions of ``capsmech.diagnosis.undeclared_tube.write_batch``).

``CA_S`` is where both shear databases (lambda = 1 and 0.001, NH) give D12 >= 0.35 (the paper's
lower limit) and the lambda = 0.001 capsule's D12 stays inside the lambda = 1 database
(D12 <= 0.605 there): every capsule can be read with either database.
"""
from __future__ import annotations

import csv
import json
import math
import subprocess
import tempfile
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from capsmech.diagnosis.undeclared_tube import write_truth
from capsmech.io.case import read_case
from capsmech.io.laws import parse_law
from capsmech.workflow.paths import capsim_executable

CA_S = (0.25, 0.62)
RADIUS_UM = (40.0, 50.0)
#: Outer viscosity [Pa s]: the paper's glycerol (section 4.3).
MU_PA_S = 0.756
PIXEL_SIZE_UM = 0.5
ERROR_PX = 1.0
#: Standard deviation of a measured inclination angle [deg] when the batch carries one.
THETA_ERROR_DEG = 1.0
#: Kernel settings of the shear databases (config/paper.yaml, config/microrheometry.yaml).
LEVEL = 3
T_MAX = 60.0


@dataclass(frozen=True)
class ShearCapsule:
    """Steady state of one simulated shear case (lengths in a, theta in rad)."""

    Ca_s: float
    law: str
    D12: float
    L1_over_a: float
    L2_over_a: float
    L3_over_a: float
    theta: float
    status: str
    message: str


Simulator = Callable[[float, str], ShearCapsule]


def law_key(law: str, viscosity_ratio: float) -> str:
    """The database law key of ``law`` at this viscosity ratio (``NH``, ``NH+lambda0.001``)."""
    return law if viscosity_ratio == 1.0 else f"{law}+lambda{viscosity_ratio:g}"


def simulate_shear(Ca_s: float, key: str, threads: int = 1, capsim: str | Path | None = None) -> ShearCapsule:
    """Run the kernel for one capsule in simple shear (law key may carry ``+lambda<X>``), the
    base model (no bending stiffness, whatever the kernel's default); NaN shape measures when
    the run is not steady."""
    kernel = Path(capsim) if capsim else capsim_executable()
    with tempfile.TemporaryDirectory(prefix="capsim-shear-") as tmp:
        out = Path(tmp) / "case.h5"
        subprocess.run([str(kernel), "--flow", "shear", *parse_law(key).kernel_args(), "--ca", repr(float(Ca_s)),
                        "--kb", "0", "--level", str(LEVEL), "--t-max", f"{T_MAX:g}", "--threads", str(threads), "--quiet",
                        "--out", str(out)], check=True, capture_output=True, text=True)
        case = read_case(out)
    if case.status != "steady":
        nan = math.nan
        return ShearCapsule(float(Ca_s), key, nan, nan, nan, nan, nan, case.status, case.message)
    d12, l1, l2, l3, theta = (case.steady_value(k) for k in ("D12", "L1", "L2", "L3", "theta"))
    return ShearCapsule(float(Ca_s), key, d12, l1, l2, l3, theta, case.status, case.message)


def cached_simulator(folder: str | Path, simulate: Simulator | None = None) -> Simulator:
    """``simulate_shear`` whose results are kept as JSON files in ``folder``: batches sharing
    capsules run the kernel once, and an interrupted generation resumes where it stopped."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    simulate = simulate or simulate_shear

    def cached(Ca_s: float, key: str) -> ShearCapsule:
        path = folder / f"{key}_Ca{float(Ca_s)!r}.json"
        if path.exists():
            return ShearCapsule(**json.loads(path.read_text()))
        capsule = simulate(Ca_s, key)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(asdict(capsule)))
        tmp.replace(path)
        return capsule
    return cached


@dataclass
class ShearBatch:
    """Measurement rows (shear format, micrometres) and the truth kept apart."""

    rows: list[dict]
    truth: list[dict]
    viscosity_ratio: float
    theta_error_deg: float | None = None


def draw_capsules(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(Ca_s, a [um]) of n capsules drawn at random (see the module)."""
    rng = np.random.default_rng(seed)
    ca = np.exp(rng.uniform(np.log(CA_S[0]), np.log(CA_S[1]), n))
    a = rng.uniform(*RADIUS_UM, n)
    return ca, a


def make_shear_batch(viscosity_ratio: float = 1.0, n_capsules: int = 14, law: str = "NH", g_s: float = 0.04,
                     seed: int = 0, draw_seed: int | None = None, simulate: Simulator | None = None,
                     theta_error_deg: float | None = None) -> ShearBatch:
    """A synthetic shear batch of one material simulated at ``viscosity_ratio`` (see the module).

    Parameters
    ----------
    viscosity_ratio : float
        lambda, inner over outer viscosity, of every capsule (1 is the databases' base).
    n_capsules : int
        Capsules drawn (those that reach no steady state are left out of the rows).
    law : str
        The membrane law (``NH``, ``GH_nu0.5`` ...).
    g_s : float
        The material's G_s [N/m].
    seed : int
        Seed of the measurement noise; ``draw_seed`` (default ``seed``) that of the capsules'
        (Ca_s, a), so that batches share their capsules and differ in lambda and noise.
    simulate : callable, optional
        ``(Ca_s, law_key) -> ShearCapsule`` (default :func:`simulate_shear`, one kernel run
        per capsule, one at a time).
    theta_error_deg : float, optional
        When given, each row carries the measured inclination theta [deg] with this error.
    """
    simulate = simulate or simulate_shear
    key = law_key(law, float(viscosity_ratio))
    ca, a_um = draw_capsules(n_capsules, seed if draw_seed is None else draw_seed)
    rng = np.random.default_rng(seed)
    theta_rng = np.random.default_rng(seed + 1000)
    error_um = ERROR_PX * PIXEL_SIZE_UM
    rows, truth = [], []
    for k, (ca_k, a_k) in enumerate(zip(ca, a_um)):
        capsule = simulate(float(ca_k), key)
        capsule_id = f"c{k + 1:03d}"
        shear_rate = float(ca_k) * g_s / (MU_PA_S * a_k * 1e-6)
        noise = rng.uniform(-error_um, error_um, 2)
        theta_noise = theta_rng.standard_normal()
        truth.append({"id": capsule_id, "law": key, "viscosity_ratio": float(viscosity_ratio), "Ca_s": float(ca_k),
                      "a": float(a_k), "G_s": float(g_s), "D12": capsule.D12, "L1": capsule.L1_over_a * a_k,
                      "L2": capsule.L2_over_a * a_k, "theta": capsule.theta, "status": capsule.status})
        if capsule.status != "steady":
            continue
        l1, l2 = capsule.L1_over_a * a_k + noise[0], capsule.L2_over_a * a_k + noise[1]
        rows.append({"id": capsule_id, "L1": max(l1, l2), "L2": min(l1, l2), "shear_rate": shear_rate,
                     "mu": MU_PA_S, "pixel_size": PIXEL_SIZE_UM})
        if theta_error_deg is not None:
            rows[-1]["theta"] = math.degrees(capsule.theta) + theta_error_deg * theta_noise
    return ShearBatch(rows, truth, float(viscosity_ratio), theta_error_deg)


def write_shear_batch(batch: ShearBatch, path: str | Path) -> tuple[Path, Path]:
    """The measurement CSV at ``path`` (shear format) and the truth beside it, ``<stem>_truth.csv``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    columns = ["L1", "L2", "shear_rate", "mu", "pixel_size"]
    header = ["id", "L1 [um]", "L2 [um]", "shear_rate [1/s]", "mu [Pa s]", "pixel_size [um]"]
    if batch.rows and "theta" in batch.rows[0]:
        columns.append("theta")
        header.append("theta [deg]")
    with open(path, "w", newline="", encoding="utf-8") as stream:
        stream.write("# synthetic shear batch made with the kernel by capsmech.diagnosis.undeclared_shear;\n"
                     f"# semi-axes off by a uniform error in [-{ERROR_PX:g}, {ERROR_PX:g}] pixel "
                     f"({PIXEL_SIZE_UM:g} um pixels)\n")
        if "theta" in columns:
            stream.write(f"# theta off by a Gaussian error of {batch.theta_error_deg:g} deg\n")
        writer = csv.writer(stream)
        writer.writerow(header)
        for row in batch.rows:
            writer.writerow([row["id"], *(f"{row[k]:.6g}" for k in columns)])
    return path, write_truth(batch.truth, path)


def read_shear_truth(path: str | Path) -> dict[str, float | str]:
    """The batch-level truth of a shear ``_truth.csv``: law key, G_s and viscosity ratio."""
    with open(path, newline="", encoding="utf-8") as stream:
        first = next(csv.DictReader(stream))
    return {"law": first["law"], "G_s": float(first["G_s"]), "viscosity_ratio": float(first["viscosity_ratio"])}

