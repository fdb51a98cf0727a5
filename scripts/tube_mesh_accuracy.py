"""How close the shipped tube database's rows (64 meridian elements) are to the same cases on
a finer meridian, split by whether the steady profile has a sharp parachute edge.

Why: the database states one accuracy for every row ("L_p within 0.6 % of 128 elements"),
measured on smooth shapes. At large Ca_s the rear rim of a membrane without bending stiffness
becomes a corner: the meridian turns by 90-135 degrees at one node, where the meridional
tension is about zero, and the corner sits at a material node. Its position moves by whole
elements, so L_p there carries an error of the order of an element; this script measures it.

Each sampled row is run again from a sphere, as the database was (one thread a case), at
--n-meridian elements; the table gives the largest relative difference of L_z, L_p and v_c/V
per class and law. Rows are classed by the largest turning angle of the database's own
resampled profile (capsmech.inversion.sharp_edge.largest_turn), so that the class is known for
every row without a rerun.

    python scripts/tube_mesh_accuracy.py [--n-meridian 128] [--per-class 2] [--workers 2] [--laws NH SK_C1 ...]
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import h5py
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "analysis" / "src"))
from capsmech.inversion.sharp_edge import largest_turn  # noqa: E402

CAPSIM = REPO / "bin" / "capsim"
DATABASE = REPO / "analysis" / "src" / "capsmech" / "databases" / "tube.h5"
LAW_FLAGS = {"NH": ["--law", "NH"], "SK_C1": ["--law", "SK", "--C", "1"],
             "GH_nu0.5": ["--law", "GH", "--nu-s", "0.5"], "GH_nu0.2": ["--law", "GH", "--nu-s", "0.2"],
             "GH_nu0": ["--law", "GH", "--nu-s", "0"]}
#: Classes of the largest turn over two resampled segments [degrees].
TURN_CLASSES = (("<30", 0.0, 30.0), ("30-60", 30.0, 60.0), ("60-90", 60.0, 90.0), (">=90", 90.0, 360.0))


def sample_rows(group: h5py.Group, per_class: int) -> list[tuple[int, str, float]]:
    """Evenly spread steady rows, per_class of each class of TURN_CLASSES."""
    status = group["status"][:].astype(str)
    turns = np.array([largest_turn(r, z) if s == "steady" else np.nan
                      for r, z, s in zip(group["profile_r"][:], group["profile_z"][:], status)])
    picks = []
    for name, low, high in TURN_CLASSES:
        rows = np.flatnonzero((turns >= low) & (turns < high))
        if rows.size:
            chosen = rows[np.unique(np.linspace(0, rows.size - 1, min(per_class, rows.size)).round().astype(int))]
            picks += [(int(i), name, float(turns[i])) for i in chosen]
    return picks


def run(law: str, a_over_l: float, ca: float, n_meridian: int, out: Path) -> dict:
    subprocess.run([str(CAPSIM), "--flow", "tube", *LAW_FLAGS[law], "--a-over-l", repr(a_over_l), "--ca", repr(ca),
                    "--n-meridian", str(n_meridian), "--threads", "1", "--quiet", "--out", str(out)], check=True)
    with h5py.File(out) as f:
        status = f.attrs["status"]
        status = status.decode() if isinstance(status, bytes) else str(status)
        if "steady" not in f or status != "steady":
            return {"status": status}
        return {"status": status, **{k: float(f["steady/" + k][()]) for k in ("L_z", "L_p", "v_c")}}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-meridian", type=int, default=128)
    parser.add_argument("--per-class", type=int, default=2)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--laws", nargs="+", default=list(LAW_FLAGS))
    args = parser.parse_args()
    jobs = []
    with h5py.File(DATABASE) as db:
        for law in args.laws:
            g = db[law]
            for i, cls, turn in sample_rows(g, args.per_class):
                jobs.append((law, i, cls, turn, float(g["a_over_l"][i]), float(g["Ca_s"][i]),
                             {"L_z": float(g["L_z"][i]), "L_p": float(g["L_p"][i]), "v_c": float(g["vc_over_V"][i])}))
    with tempfile.TemporaryDirectory() as tmp, ThreadPoolExecutor(args.workers) as pool:
        finer = list(pool.map(lambda j: run(j[0], j[4], j[5], args.n_meridian, Path(tmp) / f"{j[0]}_{j[1]}.h5"), jobs))
    print(f"law       a/l   Ca_s   class  turn  n={args.n_meridian}   dL_z [l]  dL_p [l]  dL_z/L_z  dv_c/v_c")
    worst: dict[tuple[str, str], np.ndarray] = {}
    for (law, _, cls, turn, a, ca, coarse), fine in zip(jobs, finer):
        if fine["status"] != "steady":
            print(f"{law:9s} {a:4.2f} {ca:6.3f} {cls:6s} {turn:5.1f}  {fine['status']}")
            continue
        diff = np.array([abs(coarse["L_z"] - fine["L_z"]), abs(coarse["L_p"] - fine["L_p"]),
                         abs(coarse["L_z"] - fine["L_z"]) / fine["L_z"], abs(coarse["v_c"] - fine["v_c"]) / fine["v_c"]])
        print(f"{law:9s} {a:4.2f} {ca:6.3f} {cls:6s} {turn:5.1f}  steady   " + "  ".join(f"{x:8.2e}" for x in diff))
        for key in ((law, cls), ("all", cls)):
            worst[key] = np.fmax(worst.get(key, np.zeros(4)), diff)
    print("\nlargest difference, 64 elements (database) against", args.n_meridian)
    for (law, cls), d in sorted(worst.items()):
        print(f"{law:9s} {cls:6s} L_z {d[0]:.4f} l ({d[2]:.2%})  L_p {d[1]:.4f} l  v_c {d[3]:.2%}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
