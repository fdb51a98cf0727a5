"""Files that ``capsmech extract`` writes: the measurement CSV, contours, per-frame report, overlays.

Every file is written to a temporary name and renamed, so it is whole or absent.

- Measurement CSV (the tube format of ``capsmech.io.measurements``, read by ``fit-tube``):
  ``id,L_z [um],L_p [um],v_c [mm/s],tube_radius [um],pixel_size [um],[mu [Pa s],]contour [px],contour_noise [px],
  tube_radius_sigma [um][,width_check]``; in a square channel (``channel="square"``) the walls' half
  distance is the channel's ``half_width`` (and ``half_width_sigma``) instead of ``tube_radius``;
  comment lines above the header give, per capsule, its frames, the spread of the lengths
  over them and the standard error of v_c; ``contour_noise`` is one frame's tracing noise,
  from the spread of the capsule's contours over its good frames
  (``capsmech.imaging.tracking.contour_noise``); ``tube_radius_sigma`` the tube radius's
  standard uncertainty from the walls' (``Walls.radius_sigma_px``; empty where unknown: walls
  given); ``width_check``, only when a channel width was given, how it compares with the walls
  found (``channel.WidthCheck.verdict``: ``agrees``, ``disagrees (...)``, ...).
- Contour files (``<csv stem>_contours/<id>.txt``, named in the CSV relative to its
  directory): the mid-line contour of the capsule's representative frame, ``X\tY`` then two
  tab-separated columns in pixels, image coordinates of the frame as analysed (mirrored when
  the flow went in -x), the whole closed contour - ImageJ's "Save XY Coordinates" layout.
- Per-frame report (CSV): every frame with its passage, flag (empty = measured) and values.
- Overlays (PNG, one per capsule): the representative frame with the contour, the walls, the
  axis and the points L_z and L_p are measured between.
- Frame overlays (PNG, one per frame with an object, measured or not): the levelled frame, every
  traced object (contour in red, a ring's outer edge in orange) and the frame's flag written on
  it; and once per stack the channel picture: the levelled background, the walls, the tilt.
"""
from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from capsmech.errors import ExtractionError
from capsmech.imaging.extraction import CapsuleMeasurement, Channel, FrameResult, Walls
from capsmech.io.atomic import atomic_path, write_text_atomically
from capsmech.io.measurement_columns import length_scale_columns


def _write_text(path: Path, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary name (whole or not at all)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_text_atomically(path, text)


def _g(value: float, digits: int = 6) -> str:
    return "" if value is None or not math.isfinite(value) else f"{value:.{digits}g}"


def contour_text(contour: np.ndarray) -> str:
    """A contour as ImageJ's XY coordinates: header ``X\\tY``, then ``x\\ty`` lines (px)."""
    return "X\tY\n" + "".join(f"{x:.3f}\t{y:.3f}\n" for x, y in contour)


def write_measurements(path: str | Path, capsules: Sequence[CapsuleMeasurement], results: Sequence[FrameResult],
                       walls: Walls, pixel_size_um: float, ids: Sequence[str], mu_pa_s: float | None = None,
                       source: str = "", flow_direction: str = "right",
                       channel: Channel | None = None, channel_shape: str = "tube") -> tuple[Path, list[Path]]:
    """Write the measurement CSV and the contour file of each measured capsule.

    Parameters
    ----------
    path : str or Path
        The CSV to write.
    capsules : sequence of CapsuleMeasurement
        Measured capsules (all ``ok``), in the order of ``ids``.
    results : sequence of FrameResult
        Every frame's result (the contours of the representative frames are taken from it).
    walls : Walls
    pixel_size_um : float
    ids : sequence of str
        One id per capsule.
    mu_pa_s : float, optional
        Viscosity of the suspending liquid, written as the ``mu`` column when given.
    source : str
        The frames' names, for the comment line.
    flow_direction : str
        'left' when the frames were mirrored (said in a comment).
    channel : Channel, optional
        The stack's channel: its check of a given width is written (a comment line and the
        ``width_check`` column).
    channel_shape : {"tube", "square"}
        What the walls bound: a circular tube (their half distance is its radius,
        ``tube_radius``) or a square channel (its ``half_width``); the columns say it.

    Returns
    -------
    (Path, list of Path)
        The CSV and the contour files.
    """
    path = Path(path)
    by_index = {r.index: r for r in results}
    contour_dir = path.with_name(path.stem + "_contours")
    contour_files = []
    lines = io.StringIO()
    lines.write(f"# capsmech extract: {source}\n")
    sigma = f" +- {walls.radius_sigma_px:.3f}" if math.isfinite(walls.radius_sigma_px) else ""
    scale, scale_sigma = length_scale_columns(channel_shape)
    lines.write(f"# {scale.replace('_', ' ')} {walls.radius_px:.3f}{sigma} px (walls at rows {walls.top_row:.3f}, {walls.bottom_row:.3f}; "
                f"{walls.source}), "
                f"pixel size {pixel_size_um:g} um" + (", frames mirrored (flow in -x)" if flow_direction == "left" else "")
                + "\n")
    verdict = ""
    if channel is not None and channel.width_verdict:
        verdict = channel.width_verdict
        lines.write(f"# {channel.width_check}\n")
    for cap_id, cap in zip(ids, capsules):
        lines.write(f"# {cap_id}: frames {cap.frames[0]}-{cap.frames[-1]}, {len(cap.good_frames)} measured; "
                    f"L_z {cap.L_z_px:.3f} +- {cap.L_z_spread_px:.3f} px, L_p {cap.L_p_px:.3f} +- "
                    f"{cap.L_p_spread_px:.3f} px (median +- std over the frames); v_c {cap.v_c_px_s:.5g} +- "
                    f"{cap.v_c_se_px_s:.2g} px/s (slope +- standard error); contour of frame {cap.representative}\n")
    writer = csv.writer(lines, lineterminator="\n")
    header = ["id", "L_z [um]", "L_p [um]", "v_c [mm/s]", f"{scale} [um]", "pixel_size [um]"]
    if mu_pa_s is not None:
        header.append("mu [Pa s]")
    header += ["contour [px]", "contour_noise [px]", f"{scale_sigma} [um]"] + (["width_check"] if verdict else [])
    writer.writerow(header)
    for cap_id, cap in zip(ids, capsules):
        contour_path = contour_dir / f"{check_id(cap_id, 'id')}.txt"
        contour = cap.trace.contour if cap.trace is not None else by_index[cap.representative].contour
        assert contour is not None  # the representative frame is a measured one
        _write_text(contour_path, contour_text(contour))
        contour_files.append(contour_path)
        row = [cap_id, _g(cap.L_z_px * pixel_size_um), _g(cap.L_p_px * pixel_size_um),
               _g(cap.v_c_px_s * pixel_size_um * 1e-3), _g(walls.radius_px * pixel_size_um), _g(pixel_size_um)]
        if mu_pa_s is not None:
            row.append(_g(mu_pa_s))
        row += [contour_path.relative_to(path.parent).as_posix(), _g(cap.contour_noise_px),
                _g(walls.radius_sigma_px * pixel_size_um)] + ([verdict] if verdict else [])
        writer.writerow(row)
    return _write_text(path, lines.getvalue()), contour_files


REPORT_COLUMNS = ["frame", "source", "time [s]", "passage", "flag", "objects", "kind", "contour at",
                  "line_width [px]", "extent [px]", "outer_extent [px]", "L_z [px]", "L_p [px]", "x_front [px]",
                  "x_rear [px]", "x_rear_axis [px]", "centroid_x [px]", "centroid_y [px]", "asymmetry [1]",
                  "traced objects"]


def traces_text(frame: FrameResult) -> str:
    """Every object traced in a frame: track, kind and columns spanned, e.g. ``#2 ring x 120.3-160.2``."""
    return "; ".join(f"#{t.track} {t.kind} x {t.outer[:, 0].min():.1f}-{t.outer[:, 0].max():.1f}"
                     for t in frame.traces)


def write_frame_report(path: str | Path, results: Sequence[FrameResult]) -> Path:
    """Write one line per frame: its time, passage (-1: none), flag (empty: measured), what was
    traced (``kind``: ring or silhouette; ``contour at``: mid-line of the ring or outer edge of the
    silhouette), the object's extent along the flow, the lengths, and every object traced with
    its track across frames (several per frame when the flag says so)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(REPORT_COLUMNS)
    for r in results:
        writer.writerow([r.index, r.label, _g(r.time_s, 9), r.passage, r.flag, r.objects, r.kind, r.contour_at,
                         _g(r.line_width_px, 4), _g(r.extent_px), _g(r.outer_extent_px), _g(r.L_z_px),
                         _g(r.L_p_px), _g(r.x_front), _g(r.x_rear), _g(r.x_rear_axis), _g(r.centroid_x),
                         _g(r.centroid_y), _g(r.asymmetry, 3), traces_text(r)])
    return _write_text(Path(path), out.getvalue())


def write_overlay(path: str | Path, image: np.ndarray, frame: FrameResult, walls: Walls, title: str) -> Path:
    """Draw the frame with its contour, walls, axis and the L_z / L_p end points as a PNG."""
    from matplotlib.figure import Figure  # no pyplot: no GUI backend needed

    path = Path(path)
    rows, cols = image.shape
    scale = max(1.0, 800 / cols)
    fig = Figure(figsize=(cols * scale / 100, rows * scale / 100 + 0.45), dpi=100)
    ax = fig.add_axes((0, 0, 1, rows * scale / (rows * scale + 45)))
    ax.imshow(image, cmap="gray", interpolation="nearest")
    for row in (walls.top_row, walls.bottom_row):
        ax.axhline(row, color="deepskyblue", lw=1)
    ax.axhline(walls.axis_row, color="gold", lw=0.8, ls="--")
    contour = frame.contour
    assert contour is not None, "write_overlay draws a measured frame (one with a contour)"
    closed = np.vstack([contour, contour[:1]])
    ax.plot(closed[:, 0], closed[:, 1], "-", color="red", lw=1)
    ax.plot([frame.x_front, frame.x_rear_axis], [walls.axis_row, walls.axis_row], "o", color="lime", ms=4)
    rim = contour[np.argmin(contour[:, 0])]
    ax.plot([rim[0]], [rim[1]], "o", color="magenta", ms=4)
    ax.axvline(frame.x_rear, color="magenta", lw=0.6, ls=":")
    ax.set_xlim(-0.5, cols - 0.5)
    ax.set_ylim(rows - 0.5, -0.5)
    ax.set_axis_off()
    fig.text(0.01, 1 - 0.3 / fig.get_figheight(), title, fontsize=9, va="center")
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return path


def _figure(image: np.ndarray, title: str):
    """A matplotlib Figure showing ``image`` (grey) with a title line above, and its axes."""
    from matplotlib.figure import Figure  # no pyplot: no GUI backend needed

    rows, cols = image.shape
    scale = max(1.0, 800 / cols)
    lines = title.count("\n") + 1
    fig = Figure(figsize=(cols * scale / 100, rows * scale / 100 + 0.2 + 0.2 * lines), dpi=100)
    ax = fig.add_axes((0, 0, 1, rows * scale / (rows * scale + 20 + 20 * lines)))
    ax.imshow(image, cmap="gray", interpolation="nearest")
    ax.set_xlim(-0.5, cols - 0.5)
    ax.set_ylim(rows - 0.5, -0.5)
    ax.set_axis_off()
    fig.text(0.01, 1 - 0.05 / fig.get_figheight(), title, fontsize=8, va="top")
    return fig, ax


def _save(fig, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return path


def write_frame_overlay(path: str | Path, image: np.ndarray, frame: FrameResult, walls: Walls) -> Path:
    """Draw a levelled frame with every traced object and the frame's flag (or 'measured') as a PNG."""
    status = frame.flag or f"measured: L_z {frame.L_z_px:.2f} px, L_p {frame.L_p_px:.2f} px"
    what = f"; {frame.kind}, contour = {frame.contour_at}" if frame.kind else ""
    fig, ax = _figure(image, f"frame {frame.index} ({frame.label}): {status}{what}")
    for row in (walls.top_row, walls.bottom_row):
        ax.axhline(row, color="deepskyblue", lw=0.8)
    ax.axhline(walls.axis_row, color="gold", lw=0.6, ls="--")
    for column in walls.columns or ():          # the straight channel's ends
        ax.axvline(column, color="deepskyblue", lw=0.8, ls=":")
    for trace in frame.traces:
        if trace.kind == "ring":
            outer = np.vstack([trace.outer, trace.outer[:1]])
            ax.plot(outer[:, 0], outer[:, 1], "-", color="orange", lw=0.6)
        closed = np.vstack([trace.contour, trace.contour[:1]])
        ax.plot(closed[:, 0], closed[:, 1], "-", color="red", lw=0.9)
        ax.text(float(trace.outer[:, 0].mean()), float(trace.outer[:, 1].min()) - 1, f"#{trace.track}",
                color="red", fontsize=7, ha="center", va="bottom")
    return _save(fig, path)


def write_channel_overlay(path: str | Path, background: np.ndarray, channel: Channel) -> Path:
    """Draw the levelled background (or first frame) with the walls, the axis, the tilt removed."""
    title = (f"levelled by {channel.tilt_deg:+.3f} deg; walls at rows {channel.walls.top_row:.2f}, "
             f"{channel.walls.bottom_row:.2f} ({channel.walls.source}), width {channel.walls.width_px:.1f} px; "
             f"background: {channel.background_source}" + (f"\n{channel.width_check}" if channel.width_check else "")
             + (f"\n{channel.background_check}" if channel.background_check else "")
             + (f"\n{channel.geometry_check}" if channel.geometry_check else ""))
    fig, ax = _figure(background, title)
    if channel.untrusted is not None and channel.untrusted.any():
        # Where the background is a guess: objects there are flagged, not measured.
        ax.contour(channel.untrusted, levels=[0.5], colors="orangered", linewidths=0.6)
    for row in (channel.walls.top_row, channel.walls.bottom_row):
        ax.axhline(row, color="deepskyblue", lw=0.8)
    ax.axhline(channel.walls.axis_row, color="gold", lw=0.6, ls="--")
    for column in channel.walls.columns or ():
        ax.axvline(column, color="deepskyblue", lw=0.8, ls=":")
    return _save(fig, path)


# ---------------------------------------------------------------------------
# Options with units, and the whole command
# ---------------------------------------------------------------------------

_QUANTITY = r"^\s*(?P<value>[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?)\s*(?P<unit>[^\d\s].*?)?\s*$"
PIXEL_UNITS_UM = {"": 1.0, "um": 1.0, "µm": 1.0, "micron": 1.0, "nm": 1e-3, "mm": 1e3, "m": 1e6}
RATE_UNITS_HZ = {"": 1.0, "hz": 1.0, "fps": 1.0, "1/s": 1.0, "/s": 1.0, "khz": 1e3}
VISCOSITY_UNITS_PA_S = {"": 1.0, "pa s": 1.0, "pa.s": 1.0, "pas": 1.0, "mpa s": 1e-3, "mpa.s": 1e-3, "cp": 1e-3}


def parse_quantity(text: str, option: str, units: dict[str, float], default_unit: str) -> float:
    """A positive number with an optional unit (``'0.5um'``, ``'1000 Hz'``), in the unit of ``units``.

    Raises
    ------
    ExtractionError
        Naming the option, when the text is no positive number or its unit is unknown.
    """
    import re

    match = re.match(_QUANTITY, str(text))
    unit = ((match["unit"] or "") if match else "").strip()
    key = unit if unit in units else unit.lower()
    if not match or key not in units:
        known = ", ".join(u for u in units if u)
        raise ExtractionError(f"{option}: {text!r} is not a number with a unit (bare numbers are in {default_unit}; "
                              f"units: {known})")
    value = float(match["value"]) * units[key]
    if not (math.isfinite(value) and value > 0):
        raise ExtractionError(f"{option}: must be positive, got {text!r}")
    return value


#: A capsule id names its contour file (``<csv stem>_contours/<id>.txt``): a plain file name,
#: never a path, so that no id can put a file outside the output's folder.
ID_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]{0,99}")


def check_id(capsule_id: str, option: str = "--id") -> str:
    """``capsule_id`` if it is a plain name (:data:`ID_PATTERN`), else an ExtractionError."""
    if not ID_PATTERN.fullmatch(capsule_id):
        raise ExtractionError(f"{option}: {capsule_id!r} cannot be an id: it names the capsule's contour file, so "
                              "it is 1-100 letters, digits and . _ + - starting with a letter or digit")
    return capsule_id


def default_ids(stem: str, count: int) -> list[str]:
    """Capsule ids: the stem alone for one capsule, else stem-1, stem-2, ... (a file name's
    characters that are no id's become '_')."""
    stem = re.sub(r"[^A-Za-z0-9._+-]", "_", stem)[:90].lstrip("._+-") or "capsule"
    return [stem] if count == 1 else [f"{stem}-{k + 1}" for k in range(count)]
