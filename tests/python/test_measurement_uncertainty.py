"""The measurement uncertainties the image front ends write, carried into G_s's interval.

- **Tube radius** (``tube_radius_sigma``, what ``capsmech extract`` writes per capsule): the
  lengths are measured in l, so an error of l moves L_z/l and L_p/l together. fit-tube adds
  what l +- sigma_l moves G_s by to ``G_s_spread`` in quadrature; checked here against refits of
  the same capsules with the tube radius written (1 +- sigma/l) times larger in the file, on
  the shipped NH example batch (kernel shapes, G_s = 0.04 N/m). The change grows in proportion
  to sigma_l (a smooth inversion), G_s itself does not move, and a row without the column is
  fitted exactly as before.
- **Couette D12** (``D12_err``, what ``capsmech extract-shear`` writes at two standard
  deviations): fit-shear's ``G_s_spread`` makes G_s +- G_s_spread hold the G_s of the capsule
  refitted at D12 - D12_err and D12 + D12_err (ellipse area kept), computed here from rows
  written with those semi-axes; it widens with the error; without the column nothing changes.
- **Round trip**: extract-shear on a frame drawn by the tests (``shear_frames``: their own
  optics) of the kernel's shear-plane shape writes D12_err in the CSV fit-shear reads, the
  report's value, and fit-shear's interval holds the truth G_s = mu gamma_dot a / Ca_s.
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest
from shear_frames import draw_frame, shear_outline
from skimage.io import imsave

from capsmech.cli.main import main
from capsmech.inversion.fitting import fit_shear_rows, fit_tube_rows
from capsmech.io.catalog import database_path
from capsmech.io.database import load_database
from capsmech.io.measurements import read_measurements

ROOT = Path(__file__).resolve().parents[2]
BATCH = ROOT / "data" / "examples" / "tube_batch_NH.csv"
#: The tube radius's standard uncertainty given to the capsules [um] (1 % of the 50 um radius).
SIGMA_UM = 0.5
#: The Couette set-up (the paper's section 4.3 example) and the drawn capsule's radius [px].
SHEAR_RATE, MU, PIXEL_UM, A_PX = 350.0, 0.756, 1.5, 30.0


def batch_rows() -> list[dict[str, str]]:
    lines = [line for line in BATCH.read_text().splitlines() if not line.startswith("#")]
    return list(csv.DictReader(lines))


def write_tube(path: Path, rows: list[dict[str, str]], radius_scale: float = 1.0,
               sigmas: list[float | None] | None = None) -> Path:
    """The batch's lengths and velocities (no contours: the lengths' fits are what l moves),
    the tube radius times ``radius_scale``, and a ``tube_radius_sigma`` column where given
    (None: an empty cell)."""
    header = "id,L_z [um],L_p [um],v_c [mm/s],tube_radius [um],mu [Pa s]"
    lines = [header + (",tube_radius_sigma [um]" if sigmas is not None else "")]
    for k, r in enumerate(rows):
        cells = [r["id"], r["L_z [um]"], r["L_p [um]"], r["v_c [mm/s]"],
                 repr(float(r["tube_radius [um]"]) * radius_scale), r["mu [Pa s]"]]
        if sigmas is not None:
            cells.append("" if sigmas[k] is None else repr(sigmas[k]))
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")
    return path


def same(a: object, b: object) -> bool:
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


@pytest.fixture(scope="module")
def tube_fits(tmp_path_factory):
    """fit-tube's NH rows: plain; with sigma_l on every other capsule; with 2 sigma_l on all;
    and plain with the tube radius moved by +-sigma_l."""
    folder = tmp_path_factory.mktemp("tube")
    database = load_database(database_path("tube-paper"))
    rows = batch_rows()
    radius = float(rows[0]["tube_radius [um]"])
    assert all(float(r["tube_radius [um]"]) == radius for r in rows)

    def fit(name: str, **kwargs: object) -> list[dict]:
        return fit_tube_rows(read_measurements(write_tube(folder / name, rows, **kwargs)), database, ["NH"])

    every_other = [SIGMA_UM if k % 2 == 0 else None for k in range(len(rows))]
    return {"plain": fit("plain.csv"), "mixed": fit("mixed.csv", sigmas=every_other),
            "double": fit("double.csv", sigmas=[2 * SIGMA_UM] * len(rows)),
            "wider": fit("wider.csv", radius_scale=1 + SIGMA_UM / radius),
            "narrower": fit("narrower.csv", radius_scale=1 - SIGMA_UM / radius)}


def test_tube_radius_uncertainty_matches_refits_with_the_radius_moved(tube_fits):
    plain, mixed = tube_fits["plain"], tube_fits["mixed"]
    checked = 0
    for k, (before, after, wider, narrower) in enumerate(zip(plain, mixed, tube_fits["wider"],
                                                             tube_fits["narrower"])):
        if k % 2:
            continue
        assert not before["flag"], before["reason"]
        refit_change = 0.5 * abs(wider["G_s"] - narrower["G_s"])
        # G_s moves by a few tenths of a percent for a 1 % radius error: far from nothing.
        assert refit_change > 1e-4 * before["G_s"]
        assert after["G_s_tube_radius_error"] == pytest.approx(refit_change, rel=1e-9)
        # Added in quadrature to the five fits' spread; the fitted values themselves unchanged.
        assert after["G_s_spread"] == pytest.approx(math.hypot(before["G_s_spread"], refit_change), rel=1e-12)
        assert after["G_s"] == before["G_s"] and after["a_over_l"] == before["a_over_l"]
        for name in ("a_over_l", "Ca_s"):
            change = 0.5 * abs(wider[name] - narrower[name])
            assert after[f"{name}_spread"] == pytest.approx(math.hypot(before[f"{name}_spread"], change), rel=1e-9)
        checked += 1
    assert checked == (len(plain) + 1) // 2


def test_rows_without_the_column_are_fitted_exactly_as_before(tube_fits):
    for k, (before, after) in enumerate(zip(tube_fits["plain"], tube_fits["mixed"])):
        if k % 2:
            assert all(same(before[key], after[key]) for key in before), before["id"]
        assert math.isnan(before["G_s_tube_radius_error"])


def test_the_spread_grows_with_the_tube_radius_uncertainty(tube_fits):
    ratios = []
    for k, (before, single, double) in enumerate(zip(tube_fits["plain"], tube_fits["mixed"], tube_fits["double"])):
        if k % 2:
            continue
        assert before["G_s_spread"] < single["G_s_spread"] < double["G_s_spread"]
        ratios.append(double["G_s_tube_radius_error"] / single["G_s_tube_radius_error"])
    # A smooth inversion: the change is linear in sigma_l to first order (doubling it doubles it).
    assert np.allclose(ratios, 2.0, rtol=0.15), ratios


def write_shear(path: Path, capsules: list[tuple[str, float, float, float | None]]) -> Path:
    """Shear rows (id, L1 [um], L2 [um], D12_err or None: no such column in the file)."""
    with_error = any(c[3] is not None for c in capsules)
    lines = ["id,L1 [um],L2 [um],shear_rate [1/s],mu [Pa s]" + (",D12_err" if with_error else "")]
    for name, l1, l2, err in capsules:
        lines.append(f"{name},{l1!r},{l2!r},{SHEAR_RATE},{MU}" + (f",{'' if err is None else repr(err)}"
                                                                    if with_error else ""))
    path.write_text("\n".join(lines) + "\n")
    return path


def semi_axes(size_um: float, d12: float) -> tuple[float, float]:
    """Semi-axes [um] of an ellipse of area-equivalent radius ``size_um`` and deformation d12."""
    ratio = math.sqrt((1 + d12) / (1 - d12))
    return size_um * ratio, size_um / ratio


@pytest.fixture(scope="module")
def shear_db():
    return load_database(database_path("shear-paper"))


def refit_ends(shear_db, tmp_path: Path, size_um: float, d12: float, err: float) -> list[float]:
    """G_s [N/m] of capsules written with D12 -+ err (same ellipse area), fitted on their own."""
    ends = [("low", *semi_axes(size_um, d12 - err), None), ("high", *semi_axes(size_um, d12 + err), None)]
    rows = fit_shear_rows(read_measurements(write_shear(tmp_path / "ends.csv", ends)), shear_db, ["NH"])
    return [r["G_s"] for r in rows]


def test_shear_interval_holds_the_refits_at_the_d12_extremes_and_widens(shear_db, tmp_path):
    size, d12 = 45.0, 0.45
    l1, l2 = semi_axes(size, d12)
    capsules = [("none", l1, l2, None), ("small", l1, l2, 0.01), ("large", l1, l2, 0.03)]
    rows = {r["id"]: r for r in fit_shear_rows(read_measurements(write_shear(tmp_path / "s.csv", capsules)),
                                               shear_db, ["NH"])}
    plain = fit_shear_rows(read_measurements(write_shear(tmp_path / "p.csv", capsules[:1])), shear_db, ["NH"])[0]
    # Without an error: the fit as before, no interval.
    assert all(same(plain[key], rows["none"][key]) for key in plain)
    assert math.isnan(plain["G_s_spread"]) and math.isnan(plain["D12_err"])
    for name, err in (("small", 0.01), ("large", 0.03)):
        row = rows[name]
        assert row["G_s"] == plain["G_s"] and row["D12_err"] == err
        ends = refit_ends(shear_db, tmp_path, size, d12, err)
        # (to the rounding of the semi-axes written in um and read back in m)
        assert all(abs(g - row["G_s"]) <= row["G_s_spread"] * (1 + 1e-9) for g in ends)
        # The spread is the farther end, not more.
        assert row["G_s_spread"] == pytest.approx(max(abs(g - row["G_s"]) for g in ends), rel=1e-9)
    # G_s ~ 1/Ca_s, and Ca_s climbs steeply with D12: a 0.01 error is several percent of G_s.
    assert 0.02 * plain["G_s"] < rows["small"]["G_s_spread"] < rows["large"]["G_s_spread"]


def read_rows(path: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(line for line in path.read_text().splitlines() if not line.startswith("#")))


def test_extract_shear_writes_d12_err_and_fit_shear_carries_it(shear_db, tmp_path, capsys):
    outline, truth = shear_outline("NH", 9)                      # D12 0.45
    frame = draw_frame([(outline * A_PX, (105.0, 95.0))], (190, 220), seed=3)
    image = tmp_path / "couette.png"
    imsave(image, frame, check_contrast=False)
    out = tmp_path / "couette.csv"
    assert main(["extract-shear", str(image), "--pixel-size", f"{PIXEL_UM}um", "--shear-rate", str(SHEAR_RATE),
                 "--mu", str(MU), "--out", str(out), "--id", "c"]) == 0, capsys.readouterr().err
    measured = read_rows(out)[0]
    report = read_rows(tmp_path / "couette_ellipses.csv")[-1]
    assert float(measured["D12_err [1]"]) == pytest.approx(float(report["D12_err [1]"]), rel=1e-5)
    results = tmp_path / "fit.csv"
    assert main(["fit-shear", str(out), "--law", "NH", "--out", str(results)]) == 0
    fitted = read_rows(results)[0]
    g_s, spread = float(fitted["G_s [N/m]"]), float(fitted["G_s_spread [N/m]"])
    assert float(fitted["D12_err [1]"]) == pytest.approx(float(measured["D12_err [1]"]), rel=1e-5)
    l1, l2 = float(measured["L1 [um]"]), float(measured["L2 [um]"])
    ends = refit_ends(shear_db, tmp_path, math.sqrt(l1 * l2), (l1 - l2) / (l1 + l2), float(measured["D12_err [1]"]))
    # (to the 6 digits the files are written with)
    assert all(abs(g - g_s) <= spread * (1 + 1e-4) for g in ends)
    g_s_truth = MU * SHEAR_RATE * A_PX * PIXEL_UM * 1e-6 / truth["Ca_s"]
    assert g_s - spread <= g_s_truth <= g_s + spread, (g_s, spread, g_s_truth)
