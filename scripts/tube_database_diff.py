"""Two fillings of the same tube grid, row by row: status changes, and the largest differences
of L_z, L_p and v_c/V per accuracy class of ``capsmech.inversion.sharp_edge``.

Why: a tube database row is the steady shape reached from a sphere at rest by the kernel's time
steps, and near a fold of the steady branch (the rear's buckling at Ca_s ~ 0.01) or at a corner
of the rim (large Ca_s) another sequence of steps can end elsewhere. Two fillings by kernels
whose steps differ (e.g. the database of an older release, ``git show REV:PATH > old.h5``)
measure that spread; ``sharp_edge``'s stated accuracy is the larger of it and the mesh's
(``scripts/tube_mesh_accuracy.py``).

    python scripts/tube_database_diff.py OLD.h5 NEW.h5
"""
from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

import h5py
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "analysis" / "src"))
from capsmech.inversion.sharp_edge import ACCURACY_BY_TURN, BUCKLING_CA_S, NEAR_FOLD_CA_S, largest_turn  # noqa: E402

CLASSES = ("Ca_s <= 0.011 (buckling)", "Ca_s <= 0.035 (near the fold)", "turn < 30", "turn 30-90", "turn >= 90")


def row_class(ca_s: float, turn: float) -> str:
    """The accuracy class of a row, as ``sharp_edge.row_accuracy`` chooses it."""
    if ca_s <= BUCKLING_CA_S:
        return CLASSES[0]
    if ca_s <= NEAR_FOLD_CA_S:
        return CLASSES[1]
    smooth_below, corner_from = ACCURACY_BY_TURN[0][0], ACCURACY_BY_TURN[1][0]
    if not turn >= smooth_below:
        return CLASSES[2]
    return CLASSES[3] if turn < corner_from else CLASSES[4]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("old", type=Path)
    parser.add_argument("new", type=Path)
    args = parser.parse_args(argv)
    spread: dict[str, list[tuple[float, float, float, float, str]]] = {name: [] for name in CLASSES}
    with h5py.File(args.old, "r") as old, h5py.File(args.new, "r") as new:
        print(f"kernel {old.attrs['code_version']} -> {new.attrs['code_version']}")
        totals_old: Counter[str] = Counter()
        totals_new: Counter[str] = Counter()
        for law in old:
            a, b = old[law], new[law]
            if not (np.array_equal(a["a_over_l"][:], b["a_over_l"][:]) and np.array_equal(a["Ca_s"][:], b["Ca_s"][:])):
                raise SystemExit(f"{law}: the two files do not hold the same grid")
            status_a, status_b = a["status"][:].astype(str), b["status"][:].astype(str)
            totals_old.update(map(str, status_a))
            totals_new.update(map(str, status_b))
            a_over_l, ca_s = a["a_over_l"][:], a["Ca_s"][:]
            for i in np.flatnonzero(status_a != status_b):
                print(f"  {law} a/l {a_over_l[i]:g} Ca_s {ca_s[i]:g}: {status_a[i]} -> {status_b[i]}")
            for i in np.flatnonzero((status_a == "steady") & (status_b == "steady")):
                turn = largest_turn(b["profile_r"][i], b["profile_z"][i])
                d_lp = abs(b["L_p"][i] - a["L_p"][i])
                spread[row_class(float(ca_s[i]), turn)].append((
                    abs(b["L_z"][i] / a["L_z"][i] - 1), d_lp, d_lp / max(abs(a["L_p"][i]), 1e-12),
                    abs(b["vc_over_V"][i] / a["vc_over_V"][i] - 1), f"{law} a/l {a_over_l[i]:g} Ca_s {ca_s[i]:g}"))
        print(f"statuses: {dict(totals_old)} -> {dict(totals_new)}")
    print("| class | rows steady in both | L_z | L_p | L_p / L_p | v_c/V | largest L_z at |")
    print("|---|---|---|---|---|---|---|")
    for name, rows in spread.items():
        if not rows:
            continue
        values = np.array([r[:4] for r in rows])
        worst = rows[int(np.argmax(values[:, 0]))][4]
        print(f"| {name} | {len(rows)} | {100 * values[:, 0].max():.2f} % | {values[:, 1].max():.4f} l "
              f"| {100 * values[:, 2].max():.1f} % | {100 * values[:, 3].max():.3f} % | {worst} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
