"""Make the off-centre capsules of data/examples/undeclared/offcentre.csv (issue 7, the
off-centre position).

Five NH capsules of the undeclared batches' material (G_s = 0.04 N/m, mu = 1 Pa s, l = 50 um,
0.5 um a pixel), small enough to have room off the axis (a/l 0.7-0.8), released at b = 0.08-0.1
l in the 3D tube (level 2, wall 0.28/0.14 l over 6 l, the vertex self rule) and caught while they migrate back
(r_c 0.009-0.07 l): lengths and velocity of the last history row, contour traced on the
section through the tube axis and the centroid (``capsmech.diagnosis.synthetic.simulate_offcentre_tube``).
Tests add them to batch_A: ``diagnose`` must leave them out. 3-10 minutes a capsule on one
core; case files are kept in --cases (and reused when present).

    PYTHONPATH=analysis/src .venv/bin/python scripts/make_offcentre.py [--cases DIR] [--out DIR]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from capsmech.diagnosis.synthetic import simulate_offcentre_tube, tube_batch, write_tube_csv
from capsmech.diagnosis.undeclared_tube import PIXEL_SIZE_UM, TUBE_RADIUS_UM, write_truth

OUT = Path(__file__).resolve().parents[1] / "data" / "examples" / "undeclared"
#: (a/l, Ca_s, released at b [l], caught at t [l/V]).
CAPSULES = [(0.7, 0.05, 0.1, 3.0), (0.7, 0.05, 0.1, 15.0), (0.7, 0.1, 0.1, 15.0), (0.75, 0.06, 0.1, 3.0),
            (0.8, 0.08, 0.08, 2.5)]
G_S, SEED = 0.04, 11


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=Path, default=Path("results/offcentre"), help="kernel case files")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    args.cases.mkdir(parents=True, exist_ok=True)
    args.out.mkdir(parents=True, exist_ok=True)
    capsules = []
    for a, ca, b, t in CAPSULES:
        out = args.cases / f"a{a:g}_Ca{ca:g}_b{b:g}_t{t:g}.h5"
        print(f"{out.name} ...", flush=True)
        # The shipped capsules were made before the accurate self term became the default.
        capsules.append(simulate_offcentre_tube(a, ca, b, t, self_quadrature="vertex", out=out))
    rows = tube_batch(capsules, g_s=G_S, tube_radius_um=TUBE_RADIUS_UM, seed=SEED, pixel_size_um=PIXEL_SIZE_UM,
                      id_prefix="o")
    path = write_tube_csv(rows, args.out / "offcentre.csv",
                          comment="off-centre capsules made with the 3D tube kernel by scripts/make_offcentre.py;\n"
                                  "2 % noise on lengths and velocity, contours traced to +-1 pixel")
    truth = [{"id": row["id"], "law": c.law, "a_over_l": c.a_over_l, "Ca_s": c.Ca_s, "G_s": G_S,
              "released_at": b, "caught_at_t": t, "r_c": c.r_c, "status": c.status}
             for row, c, (_, _, b, t) in zip(rows, capsules, CAPSULES, strict=True)]
    write_truth(truth, path)
    for row in truth:
        print(row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
