"""Make data/examples/undeclared/batch_O.csv (and its centred control batch_O0.csv): ten capsules caught off the axis while they
migrate back (issue 7, the fitted off-centre position; the effect is written nowhere in the
data).

Each capsule (NH, batch_A's material: G_s = 0.04 N/m, mu = 1 Pa s, l = 50 um, 0.5 um a pixel)
is released b_r = 0.05-0.1 l off the axis in the 3D tube (level 3, wall 0.28/0.14 l over 6 l,
as the off-centre table) and caught at t = 1.5-3 l/V, by then r_c ~ 0.01-0.06 l; a centred
capsule is run to the same t. What is written is the axisymmetric model's steady capsule plus
the 3D off-centre increment (``capsmech.diagnosis.synthetic.offcentre_hybrid``: the 3D mesh's errors
and the start-up, common to both runs, cancel), with batch_A's noise (2 % on lengths and
velocity, contours traced to +-1 px). The truth (``batch_O_truth.csv``) has r_c. One to three
minutes a run on one core; case files are kept in --cases and reused.

    PYTHONPATH=analysis/src .venv/bin/python scripts/make_offcentre_batch.py [--cases DIR] [--jobs N]
"""
from __future__ import annotations

import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from capsmech.diagnosis.synthetic import offcentre_hybrid, run_tube_3d, simulate_tube, tube_batch, write_tube_csv
from capsmech.diagnosis.undeclared_tube import PIXEL_SIZE_UM, TUBE_RADIUS_UM, write_truth

sys.path.insert(0, str(Path(__file__).resolve().parent))
from make_offcentre_table import SETTINGS, case_path, parse_run_args  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "data" / "examples" / "undeclared"
#: (a/l, Ca_s, released at b [l], caught at t [l/V]); off the table's grid points.
CAPSULES = [(0.72, 0.06, 0.08, 2.0), (0.73, 0.085, 0.1, 2.5), (0.74, 0.055, 0.06, 1.5), (0.76, 0.065, 0.1, 3.0),
            (0.77, 0.09, 0.08, 2.0), (0.78, 0.07, 0.06, 1.5), (0.79, 0.06, 0.1, 2.5), (0.72, 0.095, 0.05, 1.5),
            (0.775, 0.08, 0.1, 2.0), (0.745, 0.07, 0.09, 3.0)]
G_S, SEED = 0.04, 23


def main(argv: list[str] | None = None) -> int:
    args = parse_run_args(__doc__, "offcentre_batch", OUT, argv)
    args.out.mkdir(parents=True, exist_ok=True)
    common = {"level": SETTINGS["level"], "wall": SETTINGS["wall"], "tube_length": SETTINGS["tube_length"],
              "wall_cache": args.cases}
    runs = []
    for a, ca, b, t in CAPSULES:
        runs.append((a, ca, b, t, case_path(args.cases, a, ca, b, "drift", t)))
        runs.append((a, ca, 0.0, t, args.cases / f"a{a:g}_ca{ca:g}_b0_t{t:g}.h5"))

    def run(job) -> Path:
        a, ca, b, t, path = job
        run_tube_3d(a, ca, path, t, offset=b, offset_mode="drift", **common)
        print(path.name, flush=True)
        return path

    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        paths = list(pool.map(run, runs))
    capsules = [offcentre_hybrid(simulate_tube(a, ca, "NH"), paths[2 * k], paths[2 * k + 1])
                for k, (a, ca, _, _) in enumerate(CAPSULES)]
    # "m" for migrating, "c" for centred: the ids stay apart from batch_A's when they are mixed.
    rows = tube_batch(capsules, g_s=G_S, tube_radius_um=TUBE_RADIUS_UM, seed=SEED, pixel_size_um=PIXEL_SIZE_UM,
                      id_prefix="m")
    path = write_tube_csv(rows, args.out / "batch_O.csv",
                          comment="capsules caught off the axis (3D tube kernel increments on the axisymmetric model) "
                                  "by scripts/make_offcentre_batch.py;\n2 % noise on lengths and velocity, contours "
                                  "traced to +-1 pixel")
    truth = [{"id": row["id"], "law": c.law, "a_over_l": c.a_over_l, "Ca_s": c.Ca_s, "G_s": G_S, "released_at": b,
              "caught_at_t": t, "r_c": c.r_c}
             for row, c, (_, _, b, t) in zip(rows, capsules, CAPSULES, strict=True)]
    write_truth(truth, path)
    # The same capsules centred (the axisymmetric model alone, the same noise): a control
    # whose offsets must come out as zero.
    centred = [simulate_tube(a, ca, "NH") for a, ca, _, _ in CAPSULES]
    rows = tube_batch(centred, g_s=G_S, tube_radius_um=TUBE_RADIUS_UM, seed=SEED, pixel_size_um=PIXEL_SIZE_UM,
                      id_prefix="c")
    control = write_tube_csv(rows, args.out / "batch_O0.csv",
                             comment="batch_O's capsules centred (axisymmetric model), the same noise, by "
                                     "scripts/make_offcentre_batch.py")
    write_truth([{"id": row["id"], "law": c.law, "a_over_l": c.a_over_l, "Ca_s": c.Ca_s, "G_s": G_S, "r_c": 0.0}
                 for row, c in zip(rows, centred, strict=True)], control)
    for row in truth:
        print(row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
