"""Couette images: capsules in the shear plane -> ellipse -> D12, theta -> fit-shear (paper §4.3).

The images are drawn by the tests (``shear_frames``: their own ring, interior, blur, noise and
illumination; not the package's renderer) from exact ellipses and from the kernel's steady
shear-plane contours of the shipped ``shear-paper`` database. Facts checked:

- the least-squares ellipse of exact points is exact, and its stated uncertainty (two standard
  deviations) covers the truth about 95 % of the time on noisy points (Monte Carlo);
- on drawn ellipses of known axes (three orientations, a flow given as vertical), L1, L2, D12
  and theta lie within their stated uncertainties;
- on the kernel's shapes, D12 from 0.08 to 0.49 with a thin clean ring and with a fuzzy one on
  a darker interior, D12 and theta lie within their stated uncertainties of the outline's own
  inertia ellipse;
- the CSV that ``extract-shear`` writes is read by ``fit-shear``, whose G_s for each capsule
  (D12 >= 0.35) lies, with D12's stated uncertainty carried through the same database, around
  the truth G_s = mu gamma_dot a / Ca_s used to make the shapes;
- frames of one capsule combine into one row whose uncertainty still covers the truth;
- noise-only frames give no capsule; a capsule cut by the frame's edge, a solid speck and two
  capsules in contact are reported with their reasons and never measured; a stack without a
  pixel size is an error that names the option.
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest
from shear_frames import Optics, draw_frame, ellipse_outline, inertia_ellipse, shear_outline
from skimage.io import imsave

from capsmech.api import fit_shear
from capsmech.cli.main import main
from capsmech.imaging.shear_plane import ShearSettings, fit_ellipse, measure_frame
from capsmech.io.measurements import Capsule

#: The capsule's radius in the drawn images [px].
A_PX = 30.0
#: What the rheometer's images are recorded with (the paper's §4.3 example).
PIXEL_UM, SHEAR_RATE, MU = 1.5, 350.0, 0.756


def angle_difference(a: float, b: float) -> float:
    """a - b for axis angles [deg], folded into (-90, 90]."""
    return (a - b + 90.0) % 180.0 - 90.0


def write_frames(folder: Path, frames: list[np.ndarray]) -> list[str]:
    paths = []
    for k, frame in enumerate(frames):
        path = folder / f"couette_{k}.png"
        imsave(path, frame, check_contrast=False)
        paths.append(str(path))
    return paths


def read_rows(path: Path) -> list[dict[str, str]]:
    lines = [line for line in path.read_text().splitlines() if not line.startswith("#")]
    return list(csv.DictReader(lines))


def test_exact_points_give_the_exact_ellipse_and_noisy_ones_an_honest_uncertainty():
    truth = (41.0, 23.0, 35.0)                 # L1, L2 [px], angle [deg]
    points = ellipse_outline(*truth, count=240)
    points[:, 1] *= -1                         # to image rows (y down)
    fit = fit_ellipse(points + [120.0, 80.0])
    assert (fit.L1_px, fit.L2_px, fit.theta_deg) == pytest.approx(truth, abs=1e-7)
    assert fit.D12 == pytest.approx((41 - 23) / (41 + 23), abs=1e-10)
    assert (fit.x_px, fit.y_px) == pytest.approx((120.0, 80.0), abs=1e-7)
    # White noise along the rays (what a tracing of independent rays makes): the stated 2-sigma
    # interval holds the truth about 95 % of the time.
    rng = np.random.default_rng(7)
    covered = {"D12": 0, "theta": 0}
    trials = 150
    radial = points / np.hypot(points[:, 0], points[:, 1])[:, None]
    for _ in range(trials):
        noisy = points + radial * rng.normal(0.0, 0.3, len(points))[:, None]
        fit = fit_ellipse(noisy)
        covered["D12"] += abs(fit.D12 - (41 - 23) / 64) <= fit.D12_err
        covered["theta"] += abs(angle_difference(fit.theta_deg, 35.0)) <= fit.theta_err_deg
    for name, count in covered.items():
        assert 0.88 <= count / trials <= 0.995, (name, count)


@pytest.mark.parametrize(("a", "b", "angle", "flow_angle"), [(40.0, 25.0, 30.0, 0.0), (35.0, 30.0, -55.0, 0.0),
                                                             (48.0, 20.0, 80.0, 90.0)])
def test_a_drawn_ellipse_of_known_axes(a, b, angle, flow_angle):
    frame = draw_frame([(ellipse_outline(a, b, angle), (110.0, 85.0))], (170, 220), Optics(noise=3.0), seed=11)
    (obj,) = measure_frame(frame, ShearSettings(flow_angle_deg=flow_angle))
    fit = obj.fit
    assert fit is not None, obj.flag
    assert abs(fit.L1_px - a) <= fit.L1_err_px and abs(fit.L2_px - b) <= fit.L2_err_px
    assert abs(fit.D12 - (a - b) / (a + b)) <= fit.D12_err
    # theta is measured from the flow's direction on the screen.
    assert abs(angle_difference(fit.theta_deg, angle - flow_angle)) <= fit.theta_err_deg
    assert (fit.x_px, fit.y_px) == pytest.approx((110.0, 85.0), abs=0.1)
    # A sub-pixel tracing: the uncertainty is a fraction of a pixel, D12 to a few thousandths.
    assert fit.L1_err_px < 0.3 and fit.D12_err < 0.004


#: Rows of the NH branch (Ca_s 0.04 ... 0.5: D12 0.08 ... 0.49), each with two optics.
KERNEL_ROWS = [2, 4, 6, 8, 10]
OPTICS = {"thin": Optics(), "fuzzy": Optics(ring_sigma_px=1.8, blur_px=1.6, noise=4.0, gradient=0.25, interior=-0.05)}


@pytest.mark.parametrize("optics", list(OPTICS))
@pytest.mark.parametrize("row", KERNEL_ROWS)
def test_kernel_shapes_give_d12_and_theta_within_their_uncertainty(row, optics):
    outline, truth = shear_outline("NH", row)
    l1, l2, angle = inertia_ellipse(outline * A_PX)
    frame = draw_frame([(outline * A_PX, (105.0, 95.0))], (190, 220), OPTICS[optics], seed=row)
    (obj,) = measure_frame(frame)
    fit = obj.fit
    assert fit is not None, obj.flag
    assert abs(fit.D12 - (l1 - l2) / (l1 + l2)) <= fit.D12_err
    assert abs(angle_difference(fit.theta_deg, angle)) <= fit.theta_err_deg
    # The outline's inertia ellipse is the kernel's shape: its D12 is the database's to 2 %.
    assert (l1 - l2) / (l1 + l2) == pytest.approx(truth["D12"], rel=0.02)
    # Stated, the uncertainty is small next to the paper's +-20 % by hand.
    assert fit.D12_err < 0.1 * truth["D12"]


def d12_interval_g_s(row: dict[str, str], d12_err: float) -> tuple[float, float]:
    """G_s [N/m] at D12 -+ its uncertainty, the capsule's area-equivalent size sqrt(L1 L2) kept."""
    l1, l2 = float(row["L1 [um]"]) * 1e-6, float(row["L2 [um]"]) * 1e-6
    size, d12 = math.sqrt(l1 * l2), (l1 - l2) / (l1 + l2)
    ends = []
    for d in (d12 - d12_err, d12 + d12_err):
        ratio = math.sqrt((1 + d) / (1 - d))
        capsule = Capsule(row["id"], {"L1": size * ratio, "L2": size / ratio, "shear_rate": SHEAR_RATE, "mu": MU}, 0)
        ends.append(float(fit_shear([capsule], "shear-paper", "NH")["G_s"].iloc[0]))
    return min(ends), max(ends)


def test_extract_shear_writes_what_fit_shear_reads_and_its_g_s_holds_the_truth(tmp_path, capsys):
    rows = [8, 9, 10]                          # D12 0.40, 0.45, 0.49: fit-shear fits D12 >= 0.35
    truths = [shear_outline("NH", row)[1] for row in rows]
    frames = [draw_frame([(shear_outline("NH", row)[0] * A_PX, (105.0, 95.0))], (190, 220), seed=row)
              for row in rows]
    out = tmp_path / "couette.csv"
    status = main(["extract-shear", *write_frames(tmp_path, frames), "--pixel-size", f"{PIXEL_UM}um",
                   "--shear-rate", str(SHEAR_RATE), "--mu", str(MU), "--out", str(out), "--id", "c"])
    assert status == 0, capsys.readouterr().err
    report = {r["id"]: r for r in read_rows(tmp_path / "couette_ellipses.csv")}
    results = tmp_path / "fit.csv"
    assert main(["fit-shear", str(out), "--law", "NH", "--out", str(results)]) == 0
    fitted = {r["id"]: r for r in read_rows(results)}
    measured = read_rows(out)
    assert [r["id"] for r in measured] == ["c-1", "c-2", "c-3"]
    for row, truth in zip(measured, truths):
        g_s_truth = MU * SHEAR_RATE * A_PX * PIXEL_UM * 1e-6 / truth["Ca_s"]
        g_s = float(fitted[row["id"]]["G_s [N/m]"])
        low, high = d12_interval_g_s(row, float(report[row["id"]]["D12_err [1]"]))
        assert low <= g_s <= high
        assert low <= g_s_truth <= high, (row["id"], low, g_s_truth, high)
        # theta goes to fit-shear's CSV as the inclination (the kernel's, to its uncertainty).
        assert abs(float(row["theta [deg]"]) - truth["theta_deg"]) <= float(report[row["id"]]["theta_err [deg]"]) + 0.5


def test_frames_of_one_capsule_are_combined(tmp_path):
    outline, _ = shear_outline("NH", 6)
    l1, l2, _ = inertia_ellipse(outline * A_PX)
    frames = [draw_frame([(outline * A_PX, (100.0 + 3 * k, 90.0))], (180, 220), Optics(noise=4.0), seed=20 + k)
              for k in range(3)]
    out = tmp_path / "one.csv"
    assert main(["extract-shear", *write_frames(tmp_path, frames), "--pixel-size", "1", "--shear-rate", "100",
                 "--mu", "1", "--out", str(out), "--one-capsule", "--id", "cap"]) == 0
    (row,) = read_rows(out)
    assert row["id"] == "cap"
    report = read_rows(tmp_path / "one_ellipses.csv")
    assert [(r["frame"], r["id"]) for r in report] == [("0", "cap"), ("1", "cap"), ("2", "cap"), ("combined", "cap")]
    combined = report[-1]
    assert float(row["L1 [um]"]) == pytest.approx(float(combined["L1 [px]"]), rel=1e-5)
    assert abs(float(combined["L1 [px]"]) - l1) <= float(combined["L1_err [px]"])
    assert abs(float(combined["L2 [px]"]) - l2) <= float(combined["L2_err [px]"])
    assert abs(float(combined["D12 [1]"]) - (l1 - l2) / (l1 + l2)) <= float(combined["D12_err [1]"])
    # The frames are independent tracings: together they know D12 better than any one of them,
    # but not better than their random parts averaged.
    own = [float(r["D12_err [1]"]) for r in report[:3]]
    assert float(combined["D12_err [1]"]) < min(own)
    assert float(combined["D12_err [1]"]) >= math.sqrt(sum(e ** 2 for e in own)) / 3


def test_only_closed_outlines_inside_the_frame_are_capsules(tmp_path, capsys):
    # Noise on a strong illumination gradient: nothing to find.
    noise = [draw_frame([], (180, 240), Optics(noise=4.0, gradient=0.25), seed=k) for k in range(4)]
    assert all(measure_frame(frame) == [] for frame in noise)
    assert main(["extract-shear", *write_frames(tmp_path, noise), "--pixel-size", "1", "--shear-rate", "100",
                 "--mu", "1", "--out", str(tmp_path / "none.csv")]) == 1
    assert "nothing measured" in capsys.readouterr().err
    assert not (tmp_path / "none.csv").exists()
    # A capsule cut by the edge, a solid speck of dirt, and one capsule whole.
    frame = draw_frame([(ellipse_outline(30, 20, 10), (18.0, 100.0)), (ellipse_outline(25, 18, -20), (150.0, 100.0))],
                       (200, 260), seed=3).astype(float)
    rows, cols = np.mgrid[0:200, 0:260]
    frame[(rows - 40) ** 2 + (cols - 220) ** 2 < 12 ** 2] -= 50
    found = sorted(measure_frame(frame.astype(np.uint8)), key=lambda o: o.x_px)
    assert [o.flag.split(":")[0] for o in found] == ["cut by the image edge", "",
                                                      "no interior"]
    assert [o.fit is not None for o in found] == [False, True, False]
    # Two capsules in contact: one ring with two interiors is no ellipse to fit.
    pair = draw_frame([(ellipse_outline(30, 20, 0), (60.0, 100.0)), (ellipse_outline(30, 20, 0), (122.0, 100.0))],
                      (200, 200), seed=3)
    (touching,) = measure_frame(pair)
    assert touching.fit is None and touching.flag.startswith("touching outlines: 2 interiors")
    # Without a pixel size (PNG carries none) the command names its option.
    assert main(["extract-shear", *write_frames(tmp_path, [frame.astype(np.uint8)]), "--shear-rate", "100",
                 "--mu", "1", "--out", str(tmp_path / "x.csv")]) == 2
    assert "--pixel-size" in capsys.readouterr().err
