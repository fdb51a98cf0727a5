"""Measured contours (capsmech.io.contours) and their use in the tube fit: the numerical facts.

- The modified Hausdorff distance between concentric circles is the difference of radii.
- The axis of symmetry of a shifted ellipse is found to 1e-4 of its size; a contour whose
  halves differ is measured as asymmetric by how much they differ.
- A meridian's own profile, moved anywhere in the image, is at distance 0 from it, and the
  axial shift is recovered; traced with uniform +-1 px errors it is at the mean normal
  error, 0.47-0.5 px.
- Contour files in ImageJ's format are read; malformed ones are refused naming file, line
  and field.
- fit-tube on the shipped synthetic batch (made with NH, contours traced to +-1 px): every
  NH fit has H/a below the paper's 0.06 and no asymmetry flag; a capsule 20 % wider than
  its lengths imply, or with one half stretched, is flagged with the reason.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from capsmech.diagnosis.synthetic import noisy_contour
from capsmech.inversion.fitting import fit_tube_rows
from capsmech.io.catalog import database_path
from capsmech.io.contours import (
    ContourError,
    full_profile,
    modified_hausdorff,
    profile_misfit,
    read_contour,
    symmetry_axis,
)
from capsmech.io.database import load_database
from capsmech.io.measurements import Capsule, MeasurementError, read_measurements

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "data" / "examples"
DEV_TUBE = database_path("tube-paper")


def ellipse(cx: float, cy: float, ax: float, ay: float, n: int = 400) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([cx + ax * np.cos(t), cy + ay * np.sin(t)])


def parachute_meridian(n: int = 200) -> np.ndarray:
    """A smooth meridian (r, z) with a concave rear, pole to pole, front at the largest z."""
    s = np.linspace(0, np.pi, n)
    r = 0.8 * np.sin(s)
    z = 1.1 * np.cos(s) + 0.35 * np.sin(s) ** 2 * (s > np.pi / 2) * np.cos(s) ** 2 * 4
    return np.column_stack([r, z])


def test_modified_hausdorff_of_concentric_circles_is_the_radius_difference():
    t = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    circle = lambda r: np.column_stack([r * np.cos(t), r * np.sin(t)])  # noqa: E731
    assert modified_hausdorff(circle(1.0), circle(1.05)) == pytest.approx(0.05, rel=1e-3)
    assert modified_hausdorff(circle(1.0), circle(1.0)) == pytest.approx(0.0, abs=1e-12)


def test_symmetry_axis_of_a_shifted_ellipse_and_asymmetry_of_an_egg():
    axis, distance = symmetry_axis(ellipse(300.0, 187.3, 90.0, 60.0))
    assert axis == pytest.approx(187.3, abs=60e-4)
    assert distance < 1e-3
    # Upper half 10 % taller (6 units at the top): the best axis moves up by about half of the
    # difference and the mirrored halves still differ, most near the sides' top and bottom.
    egg = ellipse(0.0, 0.0, 90.0, 60.0)
    egg[egg[:, 1] > 0, 1] *= 1.1
    axis, distance = symmetry_axis(egg)
    assert 1.0 < axis < 3.0
    assert 0.5 < distance < 3.0


def test_a_meridian_moved_in_the_image_is_at_distance_zero_and_its_shift_is_found():
    meridian = parachute_meridian()
    contour = full_profile(meridian) * 100 + [412.5, 203.0]
    distance, shift = profile_misfit(contour, meridian * 100)
    assert distance < 0.05  # pixels: resampling only
    assert shift == pytest.approx(412.5, abs=0.05)


def test_traced_contour_is_at_the_mean_normal_error_of_plus_minus_one_pixel():
    meridian = parachute_meridian()
    rng = np.random.default_rng(3)
    distances = [profile_misfit(noisy_contour(meridian, 100.0, rng), meridian * 100)[0] for _ in range(5)]
    # e = (u, v) uniform in [-1, 1]^2: E|e.n| is 0.5 px along an axis, 0.47 px diagonally.
    assert 0.40 < np.mean(distances) < 0.55


def test_imagej_contour_file_and_its_errors(tmp_path):
    good = tmp_path / "c.txt"
    points = ellipse(10, 20, 5, 3, n=12)
    good.write_text("X\tY\n" + "".join(f"{x:.4f}\t{y:.4f}\n" for x, y in points))
    assert read_contour(good) == pytest.approx(points, abs=1e-4)
    bad = tmp_path / "bad.txt"
    bad.write_text("X\tY\n1\t2\n3\tfoo\n")
    with pytest.raises(ContourError, match=r"bad.txt:3: .*not two numbers"):
        read_contour(bad)
    short = tmp_path / "short.txt"
    short.write_text("1 2\n3 4\n")
    with pytest.raises(ContourError, match="2 contour points, at least 8"):
        read_contour(short)


def test_measurement_rows_read_their_contours_in_metres(tmp_path):
    points = ellipse(300, 200, 100, 80, n=50)
    np.savetxt(tmp_path / "c01.txt", points, delimiter="\t", header="X\tY", comments="")
    csv = tmp_path / "m.csv"
    csv.write_text("id,L_z [um],L_p [um],tube_radius [um],pixel_size [um],contour [px]\n"
                   "c01,100,10,50,0.5,c01.txt\nc02,100,10,50,0.5,\n")
    first, second = read_measurements(csv, "tube")
    assert first.contour == pytest.approx(points * 0.5e-6)
    assert second.contour is None
    csv.write_text("id,L_z [um],L_p [um],tube_radius [um],contour [px]\nc01,100,10,50,c01.txt\n")
    with pytest.raises(MeasurementError, match=r"m.csv:2: field 'contour' is in px but the row has no pixel_size"):
        read_measurements(csv, "tube")
    csv.write_text("id,L_z [um],L_p [um],tube_radius [um],contour [um]\nc01,100,10,50,missing.txt\n")
    with pytest.raises(MeasurementError, match=r"m.csv:2: field 'contour': .*missing.txt: cannot read"):
        read_measurements(csv, "tube")


@pytest.fixture(scope="module")
def nh_batch():
    return read_measurements(EXAMPLES / "tube_batch_NH.csv", "tube")


@pytest.fixture(scope="module")
def dev_tube():
    return load_database(DEV_TUBE)


def test_synthetic_nh_batch_fits_its_contours(nh_batch, dev_tube):
    rows = fit_tube_rows(nh_batch, dev_tube, ["NH"])
    h_over_a = np.array([row["H_over_a"] for row in rows])
    asymmetry = np.array([row["asymmetry"] for row in rows])
    assert np.all(h_over_a < 0.06), h_over_a
    # +-1 px on a capsule of ~90 px radius: mirrored halves ~0.55 px apart, ~0.006 a.
    assert np.all(asymmetry < 0.008), asymmetry
    assert not any(row["flag"] for row in rows)


def test_wider_or_lopsided_contours_are_flagged(nh_batch, dev_tube):
    capsule = nh_batch[0]
    axis, _ = symmetry_axis(capsule.contour)
    wider = capsule.contour.copy()
    wider[:, 1] = axis + 1.2 * (wider[:, 1] - axis)
    lopsided = capsule.contour.copy()
    upper = lopsided[:, 1] > axis
    lopsided[upper, 1] = axis + 1.15 * (lopsided[upper, 1] - axis)  # one half 15 % wider
    rows = fit_tube_rows([Capsule(capsule.id, capsule.values, capsule.line, wider),
                     Capsule(capsule.id, capsule.values, capsule.line, lopsided)], dev_tube, ["NH"])
    assert rows[0]["H_over_a"] > 0.06 and rows[0]["flag"] == "profile_misfit" and rows[0]["reason"].startswith("profile misfit")
    assert rows[1]["asymmetry"] > 0.0115 and rows[1]["flag"] == "asymmetric" and rows[1]["reason"].startswith("asymmetric contour")
