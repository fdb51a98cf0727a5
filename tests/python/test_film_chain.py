"""Film in, the right numbers out: film -> ``capsmech extract`` -> ``fit-tube`` -> ``population``.

The films are drawn by tests/python/capillary_films.py, apart from the package's renderer and
databases: the kernel's steady NH capsules of the independent pool (96 meridian elements, a/l
0.87-0.99, Ca_s 0.043-0.067, parachutes 0.15-0.24 l deep), G_s = 0.04 N/m, mu = 1 Pa s, a
capillary of radius 30 um seen at 0.5 um a pixel (l = 60 px, films of 480 x 160 px, 22 frames,
the capsule moving ~16 px a frame and entering through the image's edge); glass walls as
tests/python/glass_walls.py draws them (thin dark bands of 6-10 px with or without a refraction
line on either side, thick 15 px bands), tilt up to 2 deg, illumination gradients up to 25 %,
static dirt, noise 2-4 grey levels of ~200; the capsule a dark line centred on its outline
around a 4 % brighter interior (tests/python/event_frames.py's optics), the image sometimes
upside down.

Each film goes through the command line as a user would run it (``extract`` with the pixel
size, frame rate and viscosity; the measurement files put together; ``fit-tube --law NH --law
GH_nu0.5 --law SK_C1``; ``population --json``), and what comes out is held against the truth:

- the tube radius within 1 % on every film;
- each capsule's L_z and L_p within 0.5 px (0.25 um) of the kernel's, v_c within 0.5 %;
- each capsule's NH G_s (length fit) within 3 of its stated spreads of 0.04 N/m;
- the batch's verdict names NH, and its G_s interval holds 0.04 N/m;
- each film one capsule and nothing else, the flow's direction from the motion; L_z without
  the ring's tracing bias.

Held out (run only once the thresholds above were set, never looked at while writing them):
``HELD_OUT``, a 7 px band with a glass-side refraction line tilted by -1.9 deg under a 23 %
gradient, upside down, and a 15 px band tilted by +1.6 deg under a 20 % gradient, each with a
capsule the batch does not have.
"""
from __future__ import annotations

import contextlib
import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import tifffile
from capillary_films import G_S, PIXEL_SIZE_UM, TUBE_RADIUS_UM, Capsule, film_batch, passage, pool_capsules
from glass_walls import Glass

from capsmech.cli.main import main

#: The batch: pool capsules (by index), the glass of their films and whether each image is upside down.
BATCH = film_batch([1, 7, 9, 10, 11, 14, 19, 20, 22])
HELD_OUT: list[tuple[int, Glass, bool]] = [
    (12, Glass(7.0, "glass", darkness=0.45, tilt_deg=-1.9, gradient=0.23, noise=3.4), True),
    (23, Glass(15.0, "none", darkness=0.55, blur_px=1.1, tilt_deg=1.6, gradient=0.2, noise=2.6), False),
]
LAWS = ["NH", "GH_nu0.5", "SK_C1"]
LENGTH_TOLERANCE_UM = 0.5 * PIXEL_SIZE_UM


@dataclass
class Passage:
    """One film through ``extract``: its truth, the capsules it wrote and what it printed."""

    capsule: Capsule
    glass: Glass
    measured: pd.DataFrame
    printed: str


def _run(argv: list[str]) -> str:
    """The command line, as a user runs it: what it printed (its exit status must be 0)."""
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert main(argv) == 0, printed.getvalue()
    return printed.getvalue()


def _extract(folder: Path, name: str, index: int, glass: Glass, flip: bool, seed: int) -> Passage:
    capsule = {c.index: c for c in pool_capsules("NH")}[index]
    film = passage(capsule, glass, seed=seed, flip=flip)
    tiff = folder / f"{name}.tif"
    tifffile.imwrite(tiff, film.frames)
    printed = _run(["extract", str(tiff), "--pixel-size", f"{PIXEL_SIZE_UM}um", "--frame-rate", str(film.frame_rate),
                    "--mu", "1", "--id", name, "--out", str(folder / f"{name}.csv")])
    return Passage(capsule, glass, pd.read_csv(folder / f"{name}.csv", comment="#"), printed)


def _chain(folder: Path, films: list[tuple[int, Glass, bool]], seed: int) -> tuple[list[Passage], pd.DataFrame, dict]:
    """Every film through ``extract``, the measurements together through ``fit-tube`` and
    ``population``."""
    passages = [_extract(folder, f"film{n}", index, glass, flip, seed + n)
                for n, (index, glass, flip) in enumerate(films)]
    pd.concat([p.measured for p in passages]).to_csv(folder / "batch.csv", index=False)
    _run(["fit-tube", str(folder / "batch.csv"), *[a for law in LAWS for a in ("--law", law)],
          "--out", str(folder / "results.csv")])
    verdict: dict = {}
    if len(films) >= 5:
        _run(["population", str(folder / "results.csv"), "--json", str(folder / "population.json")])
        verdict = json.loads((folder / "population.json").read_text())
    return passages, pd.read_csv(folder / "results.csv"), verdict


@pytest.fixture(scope="module")
def batch(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[Passage], pd.DataFrame, dict]:
    return _chain(tmp_path_factory.mktemp("films"), BATCH, 100)


def _true_lengths_um(capsule: Capsule) -> tuple[float, float]:
    return capsule.L_z * TUBE_RADIUS_UM, capsule.L_p * TUBE_RADIUS_UM


def _check_front_end(passages: list[Passage]) -> None:
    """Tube radius within 1 %, the measured capsule's L_z and L_p within half a pixel, v_c within 0.5 %."""
    for p in passages:
        assert len(p.measured) == 1, p.printed
        row = p.measured.iloc[0]
        assert row["tube_radius [um]"] == pytest.approx(TUBE_RADIUS_UM, rel=0.01), p.glass
        L_z, L_p = _true_lengths_um(p.capsule)
        assert row["L_z [um]"] == pytest.approx(L_z, abs=LENGTH_TOLERANCE_UM), p.glass
        assert row["L_p [um]"] == pytest.approx(L_p, abs=LENGTH_TOLERANCE_UM), p.glass
        assert row["v_c [mm/s]"] == pytest.approx(p.capsule.v_c_mm_s, rel=0.005), p.glass


def _check_length_fits(results: pd.DataFrame) -> None:
    nh = results[results["law"] == "NH"]
    assert nh["G_s [N/m]"].notna().all()
    pulls = (nh["G_s [N/m]"] - G_S) / nh["G_s_spread [N/m]"]
    assert (pulls.abs() < 3).all(), nh[["id", "G_s [N/m]", "G_s_spread [N/m]"]]


def test_every_film_gives_the_tube_radius_within_1_percent_and_the_capsule_lengths(batch):
    """Measured: tube radius -0.22 to 0.00 %; L_z -0.04 to +0.01 um, L_p -0.02 to +0.03 um."""
    passages, _, _ = batch
    _check_front_end(passages)


def test_each_capsule_gives_the_true_G_s_with_the_law_it_was_made_with(batch):
    """NH length fits: 0.0394-0.0402 N/m, each within 1 of its spread (~0.001 N/m)."""
    _, results, _ = batch
    _check_length_fits(results)


def test_the_batch_names_NH_and_its_interval_holds_the_true_G_s(batch):
    """Measured: NH, 0.0404 [0.0390, 0.0417] N/m (contour fits; 0.0411 [0.0398, 0.0424], +2.8 %,
    before the ring's tracing bias was corrected); GH_nu0.5 and SK_C1 drift (p < 1e-5)
    and miss the contours (chi2/dof 11 and 17 against the 1.6 noise reaches)."""
    _, _, verdict = batch
    assert verdict["verdict"] == "law" and verdict["law"] == "NH", verdict["reason"]
    low, high = verdict["G_s_interval"]
    assert low <= G_S <= high, (low, high)
    # The other laws are told apart, not only outranked.
    for law in ("GH_nu0.5", "SK_C1"):
        low, high = verdict["laws"][law]["G_s_interval"]
        assert not low <= G_S <= high


def test_each_film_is_one_capsule_and_nothing_else(batch):
    """One passage, one capsule: no other object named, the capsule keeps its id, the flow's
    direction found from its motion. (Before the background's lamp trend and the capsules'
    interiors were accounted for, 2 films with 15 px bands showed static 'silhouettes' where
    a dirt speck had been seen through the capsule's brighter interior.)"""
    passages, _, _ = batch
    for p in passages:
        assert list(p.measured["id"]) == [p.measured["id"].iloc[0].split("-")[0]], p.printed
        assert "capsule " not in p.printed and "from the motion" in p.printed, p.printed


def test_the_traced_length_carries_no_bias(batch):
    """The ring is centred on the outline: L_z on average within 0.1 px of the truth.
    Measured: -0.05 px (-0.08 to +0.01 px; +0.25 px before the correction)."""
    passages, _, _ = batch
    errors = [p.measured["L_z [um]"].iloc[0] - _true_lengths_um(p.capsule)[0] for p in passages]
    assert abs(np.mean(errors)) < 0.1 * PIXEL_SIZE_UM, errors


def test_held_out_films(tmp_path):
    """Two films never run while the thresholds were chosen (see the module's docstring)."""
    passages, results, _ = _chain(tmp_path, HELD_OUT, 900)
    _check_front_end(passages)
    _check_length_fits(results)
