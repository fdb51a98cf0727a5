"""On dclab's real RT-DC recordings, the walls ``extract`` finds are the liquid-side edges of the
wall lines seen in the levelled median image.

The edges are located here, apart from the package's wall finder: the recording's median frame
is sheared level along the survey's wall tilts (tests/data/real_frames/*/meta.json, fitted by
scripts/fetch_real_frames.py), its illumination divided by a plane fitted to the channel's
inside, and averaged over the straight columns into one row profile. Each inner wall line is the
darkest row within 2 px of the survey's line; its liquid-side edge is where the profile rises
fastest from it towards the channel (the top line) or falls fastest into it (the bottom line),
within 4 rows, placed to a fraction of a pixel by a parabola through the three differences around
the steepest. The channel width between those edges is the reference: ``extract``'s width lies
within 2 px of it, and each wall within 1.5 px of its edge. On the recording whose top wall is
cut by the image's edge, the bottom wall is compared alone.

    .venv/bin/python tests/python/test_walls_real_edges.py      # the per-recording table
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from capsmech.imaging.extraction import prepare, read_frames

DATA = Path(__file__).resolve().parents[1] / "data" / "real_frames"
#: The recordings that show the channel's walls (the survey found at least one wall line).
RECORDINGS = sorted(p.name for p in DATA.iterdir() if p.is_dir()
                    and json.loads((p / "meta.json").read_text())["survey"].get("dark_lines")) if DATA.is_dir() else []

pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason="tests/data/real_frames/ is not there")


def levelled_profile(name: str) -> tuple[np.ndarray, dict]:
    """The recording's median frame, sheared level along the survey's wall tilt and divided by a
    plane fitted to the channel's inside, averaged over the straight columns: one row profile."""
    folder = DATA / name
    survey = json.loads((folder / "meta.json").read_text())["survey"]
    stack = np.stack([np.asarray(f, dtype=float) for f in read_frames([folder / "frames.tif"]).frames])
    median = np.median(stack, axis=0)
    rows, cols = median.shape
    tilts = survey.get("wall_tilt_deg") or [line["tilt_deg"] for line in survey["dark_lines"]]
    slope = math.tan(math.radians(float(np.mean(tilts))))
    y, x = np.mgrid[0:rows, 0:cols].astype(float)
    # Row r of the sheared image holds, in every column, the row that the wall line through
    # row r at the centre column crosses there.
    sheared = ndimage.map_coordinates(median, [y + (x - (cols - 1) / 2) * slope, x], order=1, mode="nearest")
    lines = [line["row_at_centre"] for line in survey["dark_lines"]]
    inside = np.zeros((rows, cols), dtype=bool)
    inner = survey.get("inner_walls_rows") or ([-1.0, lines[0]] if lines[0] > rows / 2 else [lines[0], rows])
    inside[int(inner[0]) + 5:int(inner[1]) - 4] = True
    inside &= sheared > 0.05 * sheared.max()          # black padding rows are no light
    design = np.column_stack([np.ones(inside.sum()), x[inside], y[inside]])
    coefficients, *_ = np.linalg.lstsq(design, sheared[inside], rcond=None)
    plane = coefficients[0] + coefficients[1] * x + coefficients[2] * y
    flat = sheared / plane
    first, last = survey.get("straight_columns") or [0, cols - 1]
    usable = np.ones(cols, dtype=bool)
    usable[:first] = usable[last + 1:] = False
    profile = np.empty(rows)
    for r in range(rows):
        # Only the columns whose sheared row lies inside the frame (none repeated from its edge).
        ok = usable & (y[r] + (x[r] - (cols - 1) / 2) * slope >= 0) & (y[r] + (x[r] - (cols - 1) / 2) * slope <= rows - 1)
        profile[r] = float(np.mean(flat[r, ok])) if ok.sum() > 0.3 * cols else math.nan
    return profile, survey


def liquid_side_edge(profile: np.ndarray, line_row: float, towards: int) -> float:
    """The liquid-side edge of the dark line near ``line_row``: from its darkest row (within 2 px),
    where the profile changes fastest towards the liquid (``towards`` +1: the liquid is below)."""
    lo = max(0, int(round(line_row)) - 2)
    darkest = lo + int(np.nanargmin(profile[lo:int(round(line_row)) + 3]))
    # The brightening of each step towards the liquid, from row darkest + towards k to the next.
    steps = [profile[darkest + towards * (k + 1)] - profile[darkest + towards * k] for k in range(4)]
    k = int(np.argmax(steps))
    shift = 0.0
    if 0 < k < len(steps) - 1:
        a, b, c = steps[k - 1], steps[k], steps[k + 1]
        if a - 2 * b + c < 0:
            shift = float(np.clip(0.5 * (a - c) / (a - 2 * b + c), -0.5, 0.5))
    return darkest + towards * (k + 0.5 + shift)


def reference_edges(name: str) -> tuple[float | None, float | None]:
    """The liquid-side edges (top, bottom) of the inner wall lines; None for a wall out of view."""
    profile, survey = levelled_profile(name)
    if survey.get("inner_walls_rows"):
        top, bottom = survey["inner_walls_rows"]
        return liquid_side_edge(profile, top, +1), liquid_side_edge(profile, bottom, -1)
    (line,) = [d["row_at_centre"] for d in survey["dark_lines"]]
    if line > profile.size / 2:
        return None, liquid_side_edge(profile, line, -1)
    return liquid_side_edge(profile, line, +1), None


def found_walls(name: str):
    """The walls ``extract`` finds, as a user runs it: the recording's own background where it has
    one, the nominal channel width."""
    folder = DATA / name
    survey = json.loads((folder / "meta.json").read_text())["survey"]
    stack = read_frames([folder / "frames.tif"])
    background = read_frames([folder / "background.png"]).frames[0] if (folder / "background.png").exists() else None
    return prepare(stack, background=background, channel_width_px=survey["channel_width_nominal_px"]).walls


@pytest.mark.parametrize("name", RECORDINGS)
def test_the_walls_are_the_liquid_side_edges_of_the_levelled_median_image(name):
    top, bottom = reference_edges(name)
    walls = found_walls(name)
    if top is not None and bottom is not None:
        assert abs(walls.width_px - (bottom - top)) <= 2.0, (walls, top, bottom)
    if top is not None:
        assert abs(walls.top_row - top) <= 1.5, (walls.top_row, top)
    if bottom is not None:
        assert abs(walls.bottom_row - bottom) <= 1.5, (walls.bottom_row, bottom)


if __name__ == "__main__":
    print("| recording | edges (this test) | walls found | width edges | width found | difference |")
    print("|---|---|---|---|---|---|")
    for name in RECORDINGS:
        top, bottom = reference_edges(name)
        walls = found_walls(name)
        width = bottom - top if top is not None and bottom is not None else math.nan
        print(f"| {name} | {top if top is None else round(top, 2)}, {bottom if bottom is None else round(bottom, 2)} | "
              f"{walls.top_row:.2f}, {walls.bottom_row:.2f} | {width:.2f} | {walls.width_px:.2f} | "
              f"{walls.width_px - width:+.2f} |")
