"""Make the synthetic square-channel batch in data/examples/ with the kernel (documented there).

Six neo-Hookean capsules of one material (G_s = 0.04 N/m) in a square channel 100 um wide
(half-width w = 50 um), at size ratios a/w and capillary numbers Ca_s between the nodes of the
duct database's grid and below its folds, each simulated by ``capsim`` (3D duct model, level 3,
steady Newton solver) and "measured": 2 % Gaussian noise on L_z, L_p and v_c, mu = 1 Pa s,
V = Ca_s G_s / mu, and a contour traced every 2 pixels with +-1 pixel (uniform) errors at
0.5 um per pixel. The contour is the capsule's section by the mid-plane y = 0 (the plane of
view), cut here from the kernel's membrane mesh, both halves. The truth goes to a separate file.

This script shares no code with the analysis package (``capsmech``): it runs the kernel and
reads its case files with h5py, so that the batch tests the inversion, not its own helpers.

    .venv/bin/python scripts/make_duct_batch.py [--workers 2] [--cases DIR]

The held-out batch (another law, material and capsules; kept out of any tuning and run once):

    .venv/bin/python scripts/make_duct_batch.py --law GH_nu0.5 --g-s 0.05 --seed 4405 \
        --capsules 0.68:0.06,0.63:0.1,0.78:0.055,0.72:0.11,0.88:0.065,0.82:0.085

Each case takes 20 s to several minutes of one core (the smaller Ca_s, the longer); ``--cases``
keeps the case files in DIR and reuses those there.
"""
from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "data" / "examples"
CAPSIM = ROOT / "bin" / "capsim"
#: (a/w, Ca_s) of each capsule: off the grid's a/w nodes (0.6-0.9 by 0.1), below its folds, and at
#: Ca_s 0.045 and above, where the steady solver converges for small capsules (a/w 0.66 at Ca_s
#: 0.035 spent its budget).
CAPSULES = [(0.66, 0.055), (0.64, 0.085), (0.76, 0.045), (0.74, 0.09), (0.86, 0.05), (0.84, 0.07)]
LAW = "NH"
G_S = 0.04              # N/m
MU = 1.0                # Pa s
HALF_WIDTH_UM = 50.0
PIXEL_SIZE_UM = 0.5
NOISE = 0.02            # relative, on L_z, L_p and v_c
TRACE_ERROR_PX = 1.0
TRACE_SPACING_PX = 2.0
SEED = 44
#: The database's kernel settings (duct-dev): mesh level, channel length and wall spacing [w].
KERNEL = ["--flow", "tube", "--model", "3d", "--channel", "square", "--integrator", "newton", "--level", "3",
          "--tube-length", "6", "--wall-h-centre", "0.1", "--wall-h-far", "0.2", "--threads", "1", "--quiet"]
#: The kernel's flags of each law key this script makes batches of.
LAW_FLAGS = {"NH": ["--law", "NH"], "GH_nu0.5": ["--law", "GH", "--nu-s", "0.5"]}


def simulate(law: str, a_over_w: float, ca: float, out: Path) -> dict:
    """One kernel case (``out``, run unless it exists): its status, steady L_z, L_p, v_c/V [w, V]
    and mid-plane section (z, x) [w]."""
    if not out.exists():
        partial = out.with_suffix(".partial.h5")
        subprocess.run([str(CAPSIM), *KERNEL, *LAW_FLAGS[law], "--a-over-l", repr(a_over_w), "--ca", repr(ca), "--out", str(partial)],
                       check=True, capture_output=True, text=True)
        partial.rename(out)
    with h5py.File(out, "r") as case:
        status = case.attrs["status"].decode()
        if status != "steady":
            return {"status": status}
        steady = {name: float(case["steady"][name][()]) for name in ("L_z", "L_p", "v_c")}
        section = mid_plane_section(case["mesh/nodes"][()], case["mesh/triangles"][()])
    return {"status": status, **steady, "section": section}


def mid_plane_section(nodes: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The closed section (z, x) of a triangulated membrane by the plane y = 0, ordered by its
    angle about the section's centre (the capsule's sections are star-shaped about it)."""
    points = []
    for triangle in triangles:
        corners = nodes[triangle]
        y = corners[:, 1]
        for i, j in ((0, 1), (1, 2), (2, 0)):
            if (y[i] < 0) != (y[j] < 0):
                s = y[i] / (y[i] - y[j])
                points.append(corners[i] + s * (corners[j] - corners[i]))
    cut = np.unique(np.round(np.array(points)[:, [2, 0]], 12), axis=0)
    centre = 0.5 * (cut.max(axis=0) + cut.min(axis=0))
    order = np.argsort(np.arctan2(cut[:, 1] - centre[1], cut[:, 0] - centre[0]))
    return cut[order]


def traced(section: np.ndarray, pixels_per_w: float, rng: np.random.Generator) -> np.ndarray:
    """A hand-traced contour [px] of a closed section [w]: placed at random in the image, points
    every TRACE_SPACING_PX along it, each coordinate off by a uniform error of +-TRACE_ERROR_PX."""
    closed = np.vstack([section, section[:1]]) * pixels_per_w
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(closed, axis=0).T))])
    s = np.linspace(0.0, arc[-1], max(int(arc[-1] / TRACE_SPACING_PX), 16), endpoint=False)
    points = np.column_stack([np.interp(s, arc, closed[:, 0]), np.interp(s, arc, closed[:, 1])])
    origin = np.array([rng.uniform(200, 400), rng.uniform(150, 250)])
    return points + origin + rng.uniform(-TRACE_ERROR_PX, TRACE_ERROR_PX, points.shape)


def parse_capsules(text: str) -> list[tuple[float, float]]:
    """``0.68:0.06,0.63:0.1`` -> [(0.68, 0.06), (0.63, 0.1)] (a/w, Ca_s of each capsule)."""
    try:
        pairs = [tuple(float(v) for v in item.split(":")) for item in text.split(",")]
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"--capsules: {error}") from None
    if not pairs or any(len(p) != 2 for p in pairs):
        raise argparse.ArgumentTypeError("--capsules: a/w:Ca_s pairs separated by commas")
    return [(a, ca) for a, ca in pairs]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=1, help="kernel runs at once (each on one thread)")
    parser.add_argument("--cases", type=Path, help="keep the case files here, and reuse those there")
    parser.add_argument("--law", default=LAW, choices=sorted(LAW_FLAGS), help=f"membrane law (default {LAW})")
    parser.add_argument("--g-s", type=float, default=G_S, help=f"the material's G_s [N/m] (default {G_S})")
    parser.add_argument("--seed", type=int, default=SEED, help=f"noise and tracing seed (default {SEED})")
    parser.add_argument("--capsules", type=parse_capsules, default=CAPSULES,
                        help="a/w:Ca_s of each capsule, comma-separated (default: the NH batch's six)")
    args = parser.parse_args()
    name = f"duct_batch_{args.law}"
    if not CAPSIM.exists():
        print(f"make_duct_batch: no kernel at {CAPSIM} (make build)", file=sys.stderr)
        return 1
    rng = np.random.default_rng(args.seed)
    trace_rng = np.random.default_rng(args.seed + 1000)
    folder = OUT / f"{name}_contours"
    folder.mkdir(parents=True, exist_ok=True)
    rows, truth = [], []
    with tempfile.TemporaryDirectory() as tmp:
        cases = args.cases or Path(tmp)
        cases.mkdir(parents=True, exist_ok=True)
        ids = [f"d{k + 1:03d}" for k in range(len(args.capsules))]
        with ThreadPoolExecutor(max_workers=max(1, args.workers)) as pool:
            results = list(pool.map(lambda i, p: simulate(args.law, *p, cases / f"{i}.h5"), ids, args.capsules))
        for capsule_id, (a_over_w, ca), case in zip(ids, args.capsules, results):
            truth.append([capsule_id, args.law, f"{a_over_w:.6g}", f"{ca:.6g}", f"{args.g_s:.6g}", case["status"],
                          *(f"{case[q]:.6g}" if q in case else "nan" for q in ("L_z", "L_p", "v_c"))])
            print(f"{capsule_id}: a/w {a_over_w}, Ca_s {ca}: {case['status']}", flush=True)
            if case["status"] != "steady":
                continue
            scale = 1 + NOISE * rng.standard_normal(3)
            mean_velocity_mm_s = ca * args.g_s / MU * 1e3
            contour = traced(case["section"], HALF_WIDTH_UM / PIXEL_SIZE_UM, trace_rng)
            np.savetxt(folder / f"{capsule_id}.txt", contour, fmt="%.3f", delimiter="\t", header="X\tY", comments="")
            rows.append([capsule_id, f"{case['L_z'] * HALF_WIDTH_UM * scale[0]:.6g}",
                         f"{case['L_p'] * HALF_WIDTH_UM * scale[1]:.6g}",
                         f"{case['v_c'] * mean_velocity_mm_s * scale[2]:.6g}", f"{HALF_WIDTH_UM:.6g}", f"{MU:.6g}",
                         f"{PIXEL_SIZE_UM:.6g}", f"{folder.name}/{capsule_id}.txt"])
    with open(OUT / f"{name}.csv", "w", newline="", encoding="utf-8") as stream:
        stream.write(f"# synthetic batch made by scripts/make_duct_batch.py with the kernel ({args.law}, 3D square duct,\n"
                     "# level 3): a 100 um square channel, 2 % noise on lengths and velocity, contours traced to\n"
                     "# +-1 pixel; the truth is in the _truth file\n")
        writer = csv.writer(stream)
        writer.writerow(["id", "L_z [um]", "L_p [um]", "v_c [mm/s]", "half_width [um]", "mu [Pa s]",
                         "pixel_size [um]", "contour [px]"])
        writer.writerows(rows)
    with open(OUT / f"{name}_truth.csv", "w", newline="", encoding="utf-8") as stream:
        writer = csv.writer(stream)
        writer.writerow(["id", "law", "a_over_w", "Ca_s", "G_s [N/m]", "status", "L_z [w]", "L_p [w]", "vc_over_V"])
        writer.writerows(truth)
    print(f"{name}: {len(rows)} of {len(args.capsules)} capsules steady")
    return 0


if __name__ == "__main__":
    sys.exit(main())
