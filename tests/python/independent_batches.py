"""A second, independent generator of tube batches (issue 19, item 6).

``capsmech`` ships its own batch generator (``capsmech.diagnosis.undeclared_tube``), and the
diagnosis was tuned on what it makes. A method tested only on its own generator's data can be
right for the wrong reasons (the same noise model in the data and in the method's
assumptions), so this module makes batches with **none of capsmech's code** (numpy, h5py and
the ``capsim`` executable only) and with its own choices throughout:

- **capsules**: a/l in [0.86, 0.99] and Ca_s in [0.022, 0.07] (log), drawn by Latin hypercube
  (the other generator: 0.87-1.03, 0.03-0.10, independent uniform draws); the kernel at 96
  meridian elements (the databases: 64), so the batches carry the databases' own
  discretisation error as real capsules would;
- **material and optics**: G_s = 0.025 N/m, mu = 0.6 Pa s, a 40 um capillary, 0.4 um pixels;
- **contour sampling and noise**: points at jittered arclength steps of 2.5 px, each moved
  along the normal by correlated Gaussian noise (AR(1) along the contour, rho 0.5,
  sigma 0.45 px) and written to 0.1 px (the other generator: uniform 2 px steps and
  independent uniform +-1 px errors on each coordinate);
- **lengths measured on the noisy contour** as a lab measures them (L_z its extent along the
  axis, L_p from the rear crossing of the axis to the rear-most point), not drawn with their
  own noise; v_c with a 1.5 % Gaussian error.

The kernel runs are done once into a *pool* (``python tests/python/independent_batches.py
pool OUT.npz``: 24 capsules per law key, ``POOL_KEYS``), kept in ``tests/data/independent_pool``;
batches are drawn from it at test time with fresh noise (``draw_batch``), so that many batches
(the interval coverage study) cost no new simulation.

Effects (``draw_batch``'s arguments): the membrane (any pool key: a law, a law with pre-stress
or bending), ``contour_offset_px`` (the traced line outside the membrane by that many pixels),
``tube_radius_rel`` (the capillary's true radius is (1 + eps) times the one written in the
file), ``ripple_px`` (a cos(4 phi) distortion of the contour about its centre: what no
candidate of the library describes, e.g. an optical aberration).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
POOL = ROOT / "tests" / "data" / "independent_pool" / "pool.npz"
#: Deep parachutes (``DEEP_*``): where the rear rim is a corner and the 64-element databases are
#: least accurate (docs/validation/databases.md). Made by ``python
#: tests/python/independent_batches.py pool tests/data/independent_pool/deep_pool.npz --deep``.
DEEP_POOL = ROOT / "tests" / "data" / "independent_pool" / "deep_pool.npz"

#: Membranes of the pool: the law key (as the databases name them) -> the kernel's options.
POOL_KEYS: dict[str, list[str]] = {
    "NH": ["--law", "NH"],
    "NH+prestress0.045": ["--law", "NH", "--prestress", "0.045"],
    "NH+prestress0.07": ["--law", "NH", "--prestress", "0.07"],
    "NH+kb0.003": ["--law", "NH", "--kb", "0.003"],
    "NH+kb0.007": ["--law", "NH", "--kb", "0.007"],
    "GH_nu0.5": ["--law", "GH", "--nu-s", "0.5"],
    "SK_C1": ["--law", "SK", "--C", "1"],
    # Outside every shipped database: no law group, no effect database.
    "SK_C3": ["--law", "SK", "--C", "3"],
    "GH_nu0.35": ["--law", "GH", "--nu-s", "0.35"],
}
#: Membranes at strengths between or below the shipped effect levels (pre-stress 0.04-0.08):
#: a pool of their own (``STRENGTH_POOL``), so that the main pool's keys stay those above.
STRENGTH_KEYS: dict[str, list[str]] = {
    "NH+prestress0.03": ["--law", "NH", "--prestress", "0.03"],
}
#: Made by ``python tests/python/independent_batches.py pool
#: tests/data/independent_pool/strength_pool.npz --strengths``.
STRENGTH_POOL = ROOT / "tests" / "data" / "independent_pool" / "strength_pool.npz"
#: A membrane stiffer in area than every shipped or default family level (Skalak C 1-8): what
#: ``diagnose --simulate`` must extend the levels for. Made by ``python
#: tests/python/independent_batches.py pool tests/data/independent_pool/stiff_pool.npz --stiff``.
STIFF_KEYS: dict[str, list[str]] = {
    "SK_C10": ["--law", "SK", "--C", "10"],
}
STIFF_POOL = ROOT / "tests" / "data" / "independent_pool" / "stiff_pool.npz"
STIFF_CAPSULES = 12
POOL_CAPSULES = 24
N_MERIDIAN = 96
A_OVER_L = (0.86, 0.99)
CA_S = (0.022, 0.07)
DEEP_KEYS = ["GH_nu0.5", "SK_C1"]
DEEP_CAPSULES, DEEP_SEED = 12, 2612
DEEP_A_OVER_L = (0.8, 0.95)
DEEP_CA_S = (0.2, 1.0)

G_S = 0.025            # N/m
MU = 0.6               # Pa s
TUBE_RADIUS_UM = 40.0
PIXEL_SIZE_UM = 0.4
STEP_PX = 2.5
NOISE_PX = 0.45
NOISE_RHO = 0.5
VELOCITY_NOISE = 0.015


def latin_hypercube(n: int, seed: int, a_range: tuple[float, float] = A_OVER_L,
                    ca_range: tuple[float, float] = CA_S) -> tuple[np.ndarray, np.ndarray]:
    """(a/l, Ca_s) of n capsules: one per row and column of an n x n grid of the region."""
    rng = np.random.default_rng(seed)
    u = (rng.permutation(n) + rng.uniform(size=n)) / n
    v = (rng.permutation(n) + rng.uniform(size=n)) / n
    a = a_range[0] + u * (a_range[1] - a_range[0])
    ca = np.exp(np.log(ca_range[0]) + v * np.log(ca_range[1] / ca_range[0]))
    return a, ca


def simulate(capsim: Path, key: str, a_over_l: float, ca: float, folder: Path) -> dict:
    """One steady capsule from the kernel: status, meridian (r, z) [l], L_z, L_p [l], v_c/V."""
    out = folder / f"{key}_{a_over_l:.6f}_{ca:.6f}.h5"
    subprocess.run([str(capsim), "--flow", "tube", *{**POOL_KEYS, **STRENGTH_KEYS, **STIFF_KEYS}[key], "--ca", repr(ca), "--a-over-l", repr(a_over_l),
                    "--n-meridian", str(N_MERIDIAN), "--threads", "1", "--quiet", "--out", str(out)],
                   check=True, timeout=3600)
    with h5py.File(out) as f:
        status = f.attrs["status"].decode() if isinstance(f.attrs["status"], bytes) else str(f.attrs["status"])
        steady = "steady" in f
        result = {"status": status, "r": f["profile/r"][:], "z": f["profile/z"][:],
                  **{name: float(f["steady/" + key][()]) if steady else math.nan
                     for name, key in (("L_z", "L_z"), ("L_p", "L_p"), ("vc_over_V", "v_c"))}}
    out.unlink()
    return result


def make_pool(capsim: Path, out: Path, workers: int, n: int = POOL_CAPSULES, seed: int = 2611,
              keys: list[str] | None = None, a_range: tuple[float, float] = A_OVER_L,
              ca_range: tuple[float, float] = CA_S) -> Path:
    """Run every (key, capsule) of the pool with the kernel and save it (numpy .npz)."""
    keys = list(POOL_KEYS) if keys is None else keys
    a, ca = latin_hypercube(n, seed, a_range, ca_range)
    jobs = [(key, i) for key in keys for i in range(n)]
    with tempfile.TemporaryDirectory() as tmp, ThreadPoolExecutor(workers) as pool:
        results = list(pool.map(lambda job: simulate(capsim, job[0], float(a[job[1]]), float(ca[job[1]]), Path(tmp)),
                                jobs))
    points = N_MERIDIAN + 1
    shape = (len(keys), n)
    arrays = {"keys": np.array(keys), "a_over_l": a, "Ca_s": ca,
              "status": np.empty(shape, dtype="U32"), "r": np.full(shape + (points,), np.nan),
              "z": np.full(shape + (points,), np.nan), "L_z": np.full(shape, np.nan), "L_p": np.full(shape, np.nan),
              "vc_over_V": np.full(shape, np.nan)}
    for (key, i), res in zip(jobs, results):
        k = keys.index(key)
        arrays["status"][k, i] = res["status"]
        for name in ("L_z", "L_p", "vc_over_V"):
            arrays[name][k, i] = res[name]
        if len(res["r"]) == points:
            arrays["r"][k, i], arrays["z"][k, i] = res["r"], res["z"]
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out, **arrays)
    return out


@dataclass
class Pool:
    keys: list[str]
    a_over_l: np.ndarray
    Ca_s: np.ndarray
    status: np.ndarray
    r: np.ndarray
    z: np.ndarray
    vc_over_V: np.ndarray

    def steady(self, key: str) -> np.ndarray:
        return np.flatnonzero(self.status[self.keys.index(key)] == "steady")


def load_pool(path: Path = POOL) -> Pool:
    with np.load(path) as f:
        return Pool([str(k) for k in f["keys"]], f["a_over_l"], f["Ca_s"], f["status"], f["r"], f["z"],
                    f["vc_over_V"])


def _closed_section(r: np.ndarray, z: np.ndarray) -> np.ndarray:
    """The capsule's section through the axis, (x along the flow, y across) [l], closed, both
    halves: the meridian runs from the front pole (r = 0) to the rear pole (r = 0)."""
    upper = np.column_stack([z, r])
    lower = np.column_stack([z[::-1], -r[::-1]])[1:-1]
    return np.vstack([upper, lower])


def _resample(curve: np.ndarray, s_new: np.ndarray) -> np.ndarray:
    """Points of the closed polyline ``curve`` at arclengths ``s_new`` (wrapped)."""
    closed = np.vstack([curve, curve[:1]])
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(closed, axis=0).T))])
    s_new = np.mod(s_new, s[-1])
    return np.column_stack([np.interp(s_new, s, closed[:, 0]), np.interp(s_new, s, closed[:, 1])])


def _normals(curve: np.ndarray) -> np.ndarray:
    """Outward unit normals of a closed, counter-clockwise curve (central differences)."""
    tangent = np.roll(curve, -1, axis=0) - np.roll(curve, 1, axis=0)
    tangent /= np.hypot(*tangent.T)[:, None]
    return np.column_stack([tangent[:, 1], -tangent[:, 0]])


def _counter_clockwise(curve: np.ndarray) -> np.ndarray:
    x, y = curve.T
    area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    return curve if area > 0 else curve[::-1]


def traced(section_px: np.ndarray, rng: np.random.Generator, contour_offset_px: float = 0.0,
           ripple_px: float = 0.0, noise_px: float | None = None) -> np.ndarray:
    """A traced contour [px] of an exact section [px]: sampled, distorted and noisy (module;
    ``noise_px``, the noise's sigma, ``NOISE_PX`` by default)."""
    fine = _counter_clockwise(_resample(section_px, np.linspace(0, 1, 2000, endpoint=False)
                                        * np.sum(np.hypot(*np.diff(np.vstack([section_px, section_px[:1]]),
                                                                   axis=0).T))))
    if contour_offset_px:
        fine = fine + contour_offset_px * _normals(fine)
    if ripple_px:
        centre = 0.5 * (fine.min(axis=0) + fine.max(axis=0))
        rel = fine - centre
        phi = np.arctan2(rel[:, 1], rel[:, 0])
        fine = fine + ripple_px * np.cos(4 * phi)[:, None] * rel / np.hypot(*rel.T)[:, None]
    length = np.sum(np.hypot(*np.diff(np.vstack([fine, fine[:1]]), axis=0).T))
    count = int(length / STEP_PX)
    s = (np.arange(count) + rng.uniform(-0.3, 0.3, count)) * length / count + rng.uniform(0, length)
    points = _resample(fine, np.sort(s))
    noise = np.empty(count)
    noise[0] = rng.standard_normal()
    for k in range(1, count):
        noise[k] = NOISE_RHO * noise[k - 1] + math.sqrt(1 - NOISE_RHO ** 2) * rng.standard_normal()
    points = points + (NOISE_PX if noise_px is None else noise_px) * noise[:, None] * _normals(points)
    return np.round(points, 1)


def measured_lengths(contour: np.ndarray) -> tuple[float, float]:
    """(L_z, L_p) [px] read off a traced contour as a lab would: the extent along the axis, and
    the parachute depth from where the contour crosses the axis at the rear to its rear-most
    point (0 for a convex rear)."""
    x, y = contour.T
    axis = 0.5 * (y.min() + y.max())
    closed = np.vstack([contour, contour[:1]])
    crossings = []
    for (x0, y0), (x1, y1) in zip(closed[:-1], closed[1:]):
        if (y0 - axis) * (y1 - axis) <= 0 and y0 != y1:
            crossings.append(x0 + (axis - y0) * (x1 - x0) / (y1 - y0))
    rear_on_axis = min(crossings) if crossings else x.min()
    return float(x.max() - x.min()), float(max(rear_on_axis - x.min(), 0.0))


@dataclass
class DrawnBatch:
    csv: Path
    truth: dict


def draw_batch(pool: Pool, key: str, folder: Path, name: str, seed: int, n: int = 16,
               contour_offset_px: float = 0.0, tube_radius_rel: float = 0.0, ripple_px: float = 0.0,
               noise_px: float | None = None, g_s: list[float] | None = None) -> DrawnBatch:
    """Draw n steady capsules of membrane ``key`` from the pool, trace and measure them with
    fresh noise, write ``folder/name.csv`` and its contours; return it with the truth.
    ``noise_px``: the tracing noise's sigma (``NOISE_PX`` by default); ``g_s``: each capsule's
    G_s [N/m] in the drawn order (a batch of several materials; ``G_S`` for all by default)."""
    rng = np.random.default_rng(seed)
    k = pool.keys.index(key)
    chosen = rng.choice(pool.steady(key), size=min(n, len(pool.steady(key))), replace=False)
    true_l_px = TUBE_RADIUS_UM * (1 + tube_radius_rel) / PIXEL_SIZE_UM
    contours = folder / f"{name}_contours"
    contours.mkdir(parents=True, exist_ok=True)
    rows = []
    for j, i in enumerate(sorted(chosen)):
        section = _closed_section(pool.r[k, i], pool.z[k, i]) * true_l_px
        section = section + [rng.uniform(150, 450), rng.uniform(100, 200)]
        contour = traced(section, rng, contour_offset_px, ripple_px, noise_px)
        L_z, L_p = measured_lengths(contour)
        mean_velocity = pool.Ca_s[i] * (G_S if g_s is None else g_s[j]) / MU           # m/s
        v_c = pool.vc_over_V[k, i] * mean_velocity * (1 + VELOCITY_NOISE * rng.standard_normal())
        capsule = f"c{j + 1:02d}"
        path = contours / f"{capsule}.txt"
        path.write_text("X\tY\n" + "".join(f"{x:.1f}\t{y:.1f}\n" for x, y in contour))
        rows.append([capsule, f"{L_z * PIXEL_SIZE_UM:.3f}", f"{L_p * PIXEL_SIZE_UM:.3f}", f"{v_c * 1e3:.5f}",
                     f"{TUBE_RADIUS_UM}", f"{MU}", f"{PIXEL_SIZE_UM}", f"{contours.name}/{path.name}"])
    out = folder / f"{name}.csv"
    with out.open("w", newline="") as f:
        f.write("# tube batch from tests/python/independent_batches.py (not capsmech's generator)\n")
        writer = csv.writer(f)
        writer.writerow(["id", "L_z [um]", "L_p [um]", "v_c [mm/s]", "tube_radius [um]", "mu [Pa s]",
                         "pixel_size [um]", "contour [px]"])
        writer.writerows(rows)
    truth = {"membrane": key, "contour_offset_px": contour_offset_px, "tube_radius_rel": tube_radius_rel,
             "ripple_px": ripple_px, "G_s": G_S if g_s is None else list(g_s[:len(rows)]),
             "noise_px": NOISE_PX if noise_px is None else noise_px, "capsules": len(rows),
             "a_over_l": [float(pool.a_over_l[i]) for i in sorted(chosen)],
             "Ca_s": [float(pool.Ca_s[i]) for i in sorted(chosen)]}
    (folder / f"{name}_truth.json").write_text(json.dumps(truth, indent=1))
    return DrawnBatch(out, truth)


#: The confusion study's batches (issue 19, item 6): name -> (membrane, draw_batch keywords, the
#: answer that is right: a candidate name of capsmech's diagnosis, None for "no effect", or
#: "unexplained" for what no candidate of the library describes).
CONFUSION_BATCHES: dict[str, tuple[str, dict, str | None]] = {
    "control": ("NH", {}, None),
    "offset_1.0px": ("NH", {"contour_offset_px": 1.0}, "contour_offset"),
    "offset_2.2px": ("NH", {"contour_offset_px": 2.2}, "contour_offset"),
    "radius_+0.02": ("NH", {"tube_radius_rel": 0.02}, "tube_radius"),
    "radius_-0.035": ("NH", {"tube_radius_rel": -0.035}, "tube_radius"),
    "prestress_0.045": ("NH+prestress0.045", {}, "prestress"),
    "prestress_0.07": ("NH+prestress0.07", {}, "prestress"),
    "kb_0.003": ("NH+kb0.003", {}, "kb"),
    "kb_0.007": ("NH+kb0.007", {}, "kb"),
    # GH's nu_s is a continuous candidate over the shipped groups 0, 0.2, 0.5 (law_family): a GH
    # batch, at a group or between two, is that family's; Skalak's C = 3 needs simulations.
    "law_GH_nu0.5": ("GH_nu0.5", {}, "GH_nu"),
    "law_SK_C1": ("SK_C1", {}, "law SK_C1"),
    "outside_SK_C3": ("SK_C3", {}, "unexplained"),
    "between_GH_nu0.35": ("GH_nu0.35", {}, "GH_nu"),
    "outside_ripple_1.5px": ("NH", {"ripple_px": 1.5}, "unexplained"),
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    make = sub.add_parser("pool", help="run the kernel for every capsule of the pool")
    make.add_argument("out", type=Path)
    make.add_argument("--capsim", type=Path, default=ROOT / "bin" / "capsim")
    make.add_argument("--workers", type=int, default=2)
    make.add_argument("--capsules", type=int, default=POOL_CAPSULES)
    make.add_argument("--deep", action="store_true", help="the deep parachutes' pool (DEEP_*) instead")
    make.add_argument("--strengths", action="store_true", help="the off-level strengths' pool (STRENGTH_KEYS) instead")
    make.add_argument("--stiff", action="store_true", help="the stiff membranes' pool (STIFF_KEYS) instead")
    args = parser.parse_args(argv)
    if args.stiff:
        make_pool(args.capsim, args.out, args.workers, STIFF_CAPSULES, keys=list(STIFF_KEYS))
    elif args.strengths:
        make_pool(args.capsim, args.out, args.workers, args.capsules, keys=list(STRENGTH_KEYS))
    elif args.deep:
        make_pool(args.capsim, args.out, args.workers, DEEP_CAPSULES, DEEP_SEED, DEEP_KEYS, DEEP_A_OVER_L, DEEP_CA_S)
    else:
        make_pool(args.capsim, args.out, args.workers, args.capsules)
    return 0


if __name__ == "__main__":
    sys.exit(main())
