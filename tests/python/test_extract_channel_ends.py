"""Where the channel ends in view (issue 20, "real recordings in"): a frame that shows the
constriction's inlet or outlet, where the walls leave their rows, is searched for capsules only
in the straight channel, and a capsule reaching its end is flagged, not measured.

Rendered frames whose walls stop at a known column (the inlet: no wall lines before it), and the
real recording that shows a whole constriction (dclab's fmt-tdms_fl-image-large-fov_2017, whose
walls widen within 96 px and 40 px of the frame's ends, as the fixture's survey measured them).
"""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from capsmech.imaging.extraction import FrameStack, extract_stack, read_frames
from capsmech.imaging.rendering import FrameStyle, drawn_lengths, outline_from_meridian, render_frame, render_stack

REAL = Path(__file__).resolve().parents[1] / "data" / "real_frames"
STYLE = FrameStyle(shape=(160, 480), tube_radius_px=50.0, axis_row=79.6)
#: The inlet: no wall lines in the columns before this one.
INLET_END = 70


def capsule_outline() -> np.ndarray:
    # A slightly elongated capsule (an ellipse of semi-axes 0.75 l and 0.6 l): no database needed.
    t = np.linspace(0, np.pi, 121)
    return outline_from_meridian(0.6 * np.sin(t), 0.75 * np.cos(t))


def with_inlet(frames: np.ndarray, seed: int) -> np.ndarray:
    """The frames with the inlet drawn: their first INLET_END columns replaced by the empty,
    wall-less view (the same noise level)."""
    open_view = render_frame([], replace(STYLE, wall_darkness=1e-9), np.random.default_rng(seed))
    out = frames.copy()
    out[:, :, :INLET_END] = open_view[:, :INLET_END]
    return out


def test_the_straight_channel_starts_where_the_walls_do_and_capsules_there_are_measured_as_without_inlet():
    outline = capsule_outline()
    frames = render_stack(outline, 14, 20.0, 30.0, STYLE, seed=3)
    channel, results = extract_stack(FrameStack(list(with_inlet(frames, 11)), [f"f{k}" for k in range(14)]))
    plain_channel, plain = extract_stack(FrameStack(list(frames), [f"f{k}" for k in range(14)]))
    first, last = channel.walls.columns
    # Where the walls start, to 2 px (measured: to the column); the far end is the image's.
    assert INLET_END <= first <= INLET_END + 2 and last == STYLE.shape[1] - 1
    assert plain_channel.walls.columns is None
    assert "straight channel: columns" in channel.geometry_check
    L_z = drawn_lengths(outline)[0] * STYLE.tube_radius_px
    reach = L_z / 2 + 3          # the capsule's half length, its line and blur
    for r, p, k in zip(results, plain, range(14)):
        centre = 20.0 + 30.0 * k
        if centre - reach > first + 1 and centre + reach < STYLE.shape[1] - 2:
            # Fully in the straight channel: as measured without the inlet (the same background there;
            # the tilt and the frame-to-background gain are taken over another area: 0.024 px apart).
            assert r.good and p.good, (k, r.flag, p.flag)
            assert r.L_z_px == pytest.approx(p.L_z_px, abs=0.05) and abs(r.L_z_px - L_z) < 0.5
        elif centre + reach > first and centre - reach < first:
            # Across the channel's end: cut, flagged with the column; never measured.
            assert r.flag.startswith("touches the end of the straight channel"), (k, r.flag)
            assert not r.good
        else:
            assert not r.good, (k, r.flag)      # in the inlet: not looked for


def test_a_gap_in_the_walls_away_from_the_ends_cuts_nothing():
    """A notch: both wall lines missing over 40 columns in the middle of the view (and a capsule
    beside it). Only the ends of the view are cut, so the channel stays whole."""
    outline = capsule_outline()
    frames = render_stack(outline, 8, 60.0, 40.0, STYLE, seed=8)
    open_view = render_frame([], replace(STYLE, wall_darkness=1e-9), np.random.default_rng(9))
    for rows in (slice(0, 40), slice(120, 160)):      # the walls' rows only: the capsules stay
        frames[:, rows, 220:260] = open_view[rows, 220:260]
    channel, results = extract_stack(FrameStack(list(frames), [f"f{k}" for k in range(8)]))
    assert channel.walls.columns is None and channel.geometry_check == ""
    assert sum(r.good for r in results) >= 6, [r.flag for r in results]


def test_a_single_frame_is_levelled_against_the_straight_channel_only():
    outline = capsule_outline()
    frame = with_inlet(render_stack(outline, 1, 260.0, 0.0, STYLE, seed=5), 13)
    channel, (result,) = extract_stack(FrameStack([frame[0]], ["single"]))
    assert channel.background_source.startswith("per-row median")
    assert "give the empty channel's image (--background)" in channel.background_check
    assert INLET_END <= channel.walls.columns[0] <= INLET_END + 2
    L_z, L_p = (length * STYLE.tube_radius_px for length in drawn_lengths(outline))
    assert result.good, result.flag
    # The rendered-frame accuracy: within 0.25 px.
    assert abs(result.L_z_px - L_z) < 0.25 and abs(result.L_p_px - L_p) < 0.25


@pytest.mark.skipif(not (REAL / "fmt-tdms_fl-image-large-fov_2017").is_dir(), reason="real frames not there")
def test_the_whole_constriction_real_frame_says_what_it_cannot_see():
    """The one frame of the whole constriction: its walls leave their rows at both ends, where
    the survey's straight wall lines end; nothing there is taken for a capsule; its faint cell is
    not seen against the frame's own per-row median, and the frame and the stack say so -
    no length is measured."""
    folder = REAL / "fmt-tdms_fl-image-large-fov_2017"
    survey = json.loads((folder / "meta.json").read_text())["survey"]
    channel, (result,) = extract_stack(read_frames([folder / "frames.tif"]),
                                       channel_width_px=survey["channel_width_nominal_px"])
    first, last = channel.walls.columns
    s_first, s_last = survey["straight_columns"]
    assert abs(first - s_first) <= 8 and abs(last - s_last) <= 8, (channel.walls.columns, survey["straight_columns"])
    assert result.flag == "no capsule" and not result.traces and not result.good
    assert "(--background)" in channel.background_check


def surveyed_both_walls() -> list[str]:
    """The recordings whose survey finds both inner wall lines (the others show one wall or none)."""
    if not REAL.is_dir():
        return []
    return sorted(p.name for p in REAL.iterdir() if p.is_dir()
                  and json.loads((p / "meta.json").read_text())["survey"].get("straight_columns"))


@pytest.mark.parametrize("name", surveyed_both_walls())
def test_the_channel_is_cut_only_where_the_survey_finds_no_whole_wall_line(name):
    """On every recording with both walls in view: the straight channel found holds every column
    where the survey finds both inner wall lines whole on their rows, and cuts none of them."""
    folder = REAL / name
    survey = json.loads((folder / "meta.json").read_text())["survey"]
    background = read_frames([folder / "background.png"]).frames[0] if (folder / "background.png").exists() else None
    stack = read_frames([folder / "frames.tif"])
    channel, _ = extract_stack(stack, background=background, channel_width_px=survey["channel_width_nominal_px"])
    first, last = channel.walls.columns or (0, stack.frames[0].shape[1] - 1)
    s_first, s_last = survey["straight_columns"]
    # The survey's 8 px strips against the channel's 16 px ones: half a strip's slack.
    assert first <= s_first + 8 and last >= s_last - 8, (channel.walls.columns, survey["straight_columns"])


def test_the_command_prints_the_straight_channel_and_draws_every_flagged_frame(tmp_path, capsys):
    """`capsmech extract` on the inlet stack: it prints where the straight channel is, writes
    the flag of each frame cut by its end in the per-frame report, and an overlay for every
    frame with an object, flagged or measured."""
    import csv

    from capsmech.cli.main import main
    from capsmech.imaging.rendering import write_tiff_stack

    frames = with_inlet(render_stack(capsule_outline(), 14, 20.0, 30.0, STYLE, seed=3), 11)
    tiff = write_tiff_stack(tmp_path / "inlet.tif", frames, pixel_size_um=1.0, frame_rate=1000.0)
    out = tmp_path / "m.csv"
    assert main(["extract", str(tiff), "--out", str(out), "--overlay", str(tmp_path / "ov")]) == 0
    printed = capsys.readouterr().out
    assert f"straight channel: columns 70-{STYLE.shape[1] - 1} of 0-{STYLE.shape[1] - 1}" in printed
    report = list(csv.DictReader(open(tmp_path / "m_frames.csv")))
    cut = [row for row in report if row["flag"].startswith("touches the end of the straight channel (column 70")]
    assert len(cut) == 3
    with_object = [row for row in report if row["flag"] != "no capsule"]
    assert len(list((tmp_path / "ov" / "frames").glob("*.png"))) == len(with_object) == 13
