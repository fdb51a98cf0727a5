"""Make the example frame stack data/examples/frames/capsule_NH.tif and its overlay picture.

A kernel capsule off the database grid (NH, a/l = 0.93, Ca_s = 0.07, axisymmetric tube model)
of a material with G_s = 0.04 N/m in a liquid of mu = 1 Pa s, rendered by capsmech.imaging.rendering
as a 1500 frames/s bright-field film with 0.6 um pixels in a 60 um capillary (l = 50 px):
two frames entering at the left border, then 18 measurable frames, one of them out of focus.
The truth goes to data/examples/frames/truth.csv. Then ``capsmech extract`` runs on it and
its overlay is copied to docs/extract_overlay.png (the picture in the README).

    .venv/bin/python scripts/make_example_frames.py      # about 20 s
"""
from __future__ import annotations

import csv
import shutil
import tempfile
from pathlib import Path

import numpy as np

from capsmech.cli.main import main as capsmech
from capsmech.diagnosis.synthetic import simulate_tube
from capsmech.imaging.rendering import (
    FrameStyle,
    blurred,
    drawn_lengths,
    outline_from_meridian,
    render_frame,
    write_tiff_stack,
)

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "data" / "examples" / "frames"
LAW, A_OVER_L, CA_S = "NH", 0.93, 0.07
G_S, MU, PIXEL_UM, RATE, RADIUS_PX = 0.04, 1.0, 0.6, 1500.0, 50.0


def main() -> int:
    capsule = simulate_tube(A_OVER_L, CA_S, LAW)
    v_c = capsule.vc_over_V * CA_S * G_S / MU                      # m/s, V = Ca_s G_s / mu
    step = v_c / (PIXEL_UM * 1e-6) / RATE                          # px per frame
    outline = outline_from_meridian(capsule.meridian[:, 0], capsule.meridian[:, 1])
    style = FrameStyle(shape=(160, 320), tube_radius_px=RADIUS_PX, axis_row=79.4)
    rng = np.random.default_rng(8)
    x0 = -8.0 - outline[:, 0].min() * RADIUS_PX                    # rear 8 px beyond the left edge
    frames = [render_frame([(outline, x0 + k * step)], blurred(style, 5.0) if k == 12 else style, rng)
              for k in range(20)]
    OUT.mkdir(parents=True, exist_ok=True)
    stack = OUT / "capsule_NH.tif"
    write_tiff_stack(stack, np.stack(frames), pixel_size_um=PIXEL_UM, frame_rate=RATE)
    L_z, L_p = drawn_lengths(outline)
    with open(OUT / "truth.csv", "w", newline="", encoding="utf-8") as stream:
        writer = csv.writer(stream)
        writer.writerow(["# the parameters capsule_NH.tif was made with (scripts/make_example_frames.py)"])
        writer.writerow(["law", "a_over_l", "Ca_s", "G_s [N/m]", "mu [Pa s]", "L_z [um]", "L_p [um]",
                         "v_c [mm/s]", "tube_radius [um]", "pixel_size [um]", "frame_rate [1/s]"])
        writer.writerow([LAW, A_OVER_L, CA_S, G_S, MU, f"{L_z * RADIUS_PX * PIXEL_UM:.4f}",
                         f"{L_p * RADIUS_PX * PIXEL_UM:.4f}", f"{v_c * 1e3:.5f}", RADIUS_PX * PIXEL_UM,
                         PIXEL_UM, RATE])
    with tempfile.TemporaryDirectory() as tmp:
        code = capsmech(["extract", str(stack), "--mu", str(MU), "--out", str(Path(tmp) / "m.csv"),
                         "--overlay", tmp])
        if code == 0:
            (REPO / "docs").mkdir(exist_ok=True)
            shutil.copy(Path(tmp) / "capsule_NH.png", REPO / "docs" / "extract_overlay.png")
    return code


if __name__ == "__main__":
    raise SystemExit(main())
