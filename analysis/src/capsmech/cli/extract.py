"""``capsmech extract``: frames of capsules in the tube -> the measurement CSV that fit-tube reads,
contours, a per-frame report and overlays."""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path

from capsmech.api import extract
from capsmech.cli.common import (
    add_force_option,
    add_json_option,
    format_table,
    plan_output,
    records,
    table_json,
    write_json,
)
from capsmech.imaging.extraction import ExtractionError
from capsmech.io.measurement_columns import CHANNEL_SHAPES, length_scale_columns


def check_options(args: argparse.Namespace) -> None:
    """Refuse thresholds that mean nothing and outputs that cannot be written, before any work.

    Raises
    ------
    ExtractionError
        Naming the option (and the path) at fault.
    """
    if args.min_frames < 1:
        raise ExtractionError(f"--min-frames: need at least 1 good frame per capsule, got {args.min_frames}")
    for option, value in (("--max-asymmetry", args.max_asymmetry), ("--max-line-width", args.max_line_width)):
        if not (math.isfinite(value) and value > 0):
            raise ExtractionError(f"{option}: need a positive finite number, got {value:g}")
    tolerance = args.channel_width_tolerance
    if not (math.isfinite(tolerance) and 0 <= tolerance < 50):
        raise ExtractionError(f"--channel-width-tolerance: need a percentage from 0 to 50, got {tolerance:g}")
    out = Path(args.out)
    report = Path(args.report) if args.report else out.with_name(out.stem + "_frames.csv")
    contours = out.with_name(out.stem + "_contours")
    for option, path in (("--out", out), ("--report", report)):
        if path.is_dir():
            raise ExtractionError(f"{option} {path}: is a directory (give a file name, e.g. {path / 'measurements.csv'})")
        if path.exists() and not path.is_file():
            raise ExtractionError(f"{option} {path}: not a regular file")
    if contours.exists() and not contours.is_dir():
        raise ExtractionError(f"--out {out}: the contours' folder {contours} exists and is not a folder")
    if args.overlay and Path(args.overlay).exists() and not Path(args.overlay).is_dir():
        raise ExtractionError(f"--overlay {args.overlay}: exists and is not a folder")


def cmd_extract(args: argparse.Namespace) -> int:
    """``extract``: frames of a capsule in the tube -> measurement CSV, contours, report, overlays.

    Exit status 0 when at least one capsule was measured, 1 when none could be (the reasons
    are printed and the per-frame report is still written), 2 for unreadable files or bad
    options (``ExtractionError``).
    """
    from capsmech.imaging.extraction_output import (
        PIXEL_UNITS_UM,
        RATE_UNITS_HZ,
        VISCOSITY_UNITS_PA_S,
        parse_quantity,
        write_channel_overlay,
        write_frame_overlay,
        write_frame_report,
        write_measurements,
        write_overlay,
    )

    check_options(args)
    out_file = plan_output(args.out, "--out", (".csv",), args.force)
    plan_output(args.report or out_file.path.with_name(out_file.path.stem + "_frames.csv"), "--report",
                (".csv",), args.force)
    json_out = plan_output(args.json, "--json", (".json",), args.force) if args.json else None
    mu = parse_quantity(args.mu, "--mu", VISCOSITY_UNITS_PA_S, "Pa s") if args.mu else None
    pixel_um = parse_quantity(args.pixel_size, "--pixel-size", PIXEL_UNITS_UM, "um") if args.pixel_size else None
    rate = parse_quantity(args.frame_rate, "--frame-rate", RATE_UNITS_HZ, "Hz") if args.frame_rate else None
    try:
        found = extract(args.frames, pixel_um, rate, flow_direction=args.flow_direction,
                        capsule_id=args.id, max_asymmetry=args.max_asymmetry, max_line_width=args.max_line_width,
                        min_frames=args.min_frames, progress=sys.stderr.isatty(), background=args.background,
                        walls=args.walls, channel_width=args.channel_width, frame_times=args.frame_times,
                        tilt=args.tilt, channel_width_tolerance=args.channel_width_tolerance / 100,
                        channel_shape=args.channel)
    except ExtractionError as err:
        # A calibration neither the files nor the options give: the API names its parameter,
        # the command line its option.
        raise ExtractionError(str(err).replace("pixel_size:", "--pixel-size:")
                              .replace("frame_rate:", "--frame-rate:")
                              .replace("channel_width:", "--channel-width:")
                              .replace("frame_times:", "--frame-times:")) from None
    walls, results, stack = found.walls, found.results, found.stack
    for note in stack.notes:
        print(f"capsmech: warning: {note}", file=sys.stderr)
    pixel_um, rate = found.pixel_size_um, found.frame_rate
    out = Path(args.out)
    report = Path(args.report) if args.report else out.with_name(out.stem + "_frames.csv")
    write_frame_report(report, results)
    sigma = f" +- {walls.radius_sigma_px:.2f}" if math.isfinite(walls.radius_sigma_px) else ""
    scale, _ = length_scale_columns(args.channel)
    print(f"{len(stack)} frames of {stack.frames[0].shape[1]}x{stack.frames[0].shape[0]} px; {scale.replace('_', ' ')} "
          f"{walls.radius_px:.2f}{sigma} px = {walls.radius_px * pixel_um:.4g} um, axis at row {walls.axis_row:.2f}; "
          f"pixel {pixel_um:g} um, {rate:g} frames/s")
    channel = found.channel
    print(f"channel levelled by {channel.tilt_deg:+.3f} deg; walls at rows {walls.top_row:.2f}, {walls.bottom_row:.2f} "
          f"({walls.source}), width {walls.width_px:.2f} px = {walls.width_px * pixel_um:.4g} um; "
          f"background: {channel.background_source}")
    if channel.width_check:
        print(channel.width_check)
    if channel.width_disagrees:
        # On the screen even when the printout goes to a file: the tube radius may be wrong.
        print(f"capsmech: warning: {channel.width_check}", file=sys.stderr)
    if channel.background_check:
        print(channel.background_check)
    if channel.geometry_check:
        print(channel.geometry_check)
    print(channel.flow_check)
    if channel.independent_events:
        print(channel.independent_events)
    if args.overlay:
        # The level/tilt/walls picture once, and every frame that shows an object, measured or not.
        shown = channel.background if channel.background is not None else channel.levelled(stack.frames[0])
        write_channel_overlay(Path(args.overlay) / "channel.png", shown, channel)
        for r in results:
            if r.objects:
                write_frame_overlay(Path(args.overlay) / "frames" / f"frame_{r.index:05d}.png",
                                    channel.levelled(stack.frames[r.index]), r, walls)
        print(f"wrote {Path(args.overlay) / 'channel.png'} and {sum(1 for r in results if r.objects)} frame overlays "
              f"in {Path(args.overlay) / 'frames'}")
    flags: dict[str, int] = {}
    for r in results:
        if r.flag:
            reason = r.flag.split(" (")[0]
            flags[reason] = flags.get(reason, 0) + 1
    good = sum(r.good for r in results)
    # Objects of frames with several are measured on their own, for their tracks.
    shared = sum(1 for r in results if len(r.traces) > 1 for t in r.traces if not t.flag)
    print(f"{good} frames measured" + (", flagged: " + ", ".join(f"{n} {k}" for k, n in sorted(flags.items()))
                                       if flags else "")
          + (f"; {shared} objects measured in frames with several" if shared else "") + f" (per frame: {report})")
    pieces = sorted({r.index for r in results for t in r.traces if t.dropped})
    if pieces:
        print(f"pieces cut by the frame's edge or in a wall's band not measured (frame{'s' if len(pieces) > 1 else ''} "
              f"{', '.join(map(str, pieces))}): beside no whole capsule, not capsules of their own")
    capsules = found.capsules
    for row, cap in zip(records(capsules), found.measurements):
        if row["flag"]:
            print(f"capsule {row['id']} (frames {cap.frames[0]}-{cap.frames[-1]}) not measured: {row['reason']}")
    measured = capsules[capsules["flag"] == ""]
    if measured.empty:
        why = "no capsule in any frame" if capsules.empty else "no capsule had enough good frames"
        print(f"capsmech: nothing measured ({why}); {out} not written", file=sys.stderr)
        return 1
    kept = [cap for cap in found.measurements if cap.ok]
    csv_path, _ = write_measurements(out, kept, results, walls, pixel_um, list(measured["id"]), mu,
                                     source=" ".join(str(f) for f in args.frames), flow_direction=channel.flow_direction,
                                     channel=channel, channel_shape=args.channel)
    print(format_table(records(measured), ["id", "good_frames", "L_z", "L_z_spread", "L_p", "L_p_spread", "v_c",
                                           "v_c_se"], capsules.attrs["units"]))
    if args.overlay:
        for row, cap in zip(records(measured), kept):
            frame = next(r for r in results if r.index == cap.representative)
            if cap.trace is not None:      # the capsule's own object, also in a frame with several
                t = cap.trace
                frame = replace(frame, contour=t.contour, x_front=t.x_front, x_rear=t.x_rear, x_rear_axis=t.x_rear_axis)
            title = (f"{row['id']}, frame {frame.index}: L_z = {row['L_z']:.4g} um, L_p = {row['L_p']:.4g} um, "
                     f"{scale.replace('_', ' ')} {row[scale]:.4g} um, v_c = {row['v_c']:.4g} mm/s")
            path = write_overlay(Path(args.overlay) / f"{row['id']}.png", channel.levelled(stack.frames[frame.index]),
                                 frame, walls, title)
            print(f"wrote {path}")
    print(out_file.wrote(csv_path))
    if json_out is not None:
        payload = {"frames": [str(f) for f in args.frames], "measurements": str(csv_path),
                   "frame_report": str(report), "pixel_size_um": pixel_um, "frame_rate_hz": rate,
                   "channel": args.channel, f"{scale}_um": walls.radius_px * pixel_um, "flow_direction": channel.flow_direction,
                   **table_json(capsules)}
        print(json_out.wrote(write_json(json_out.path, "extract", payload)))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``extract``."""
    ext = sub.add_parser("extract", help="frames of capsules in the tube -> measurement CSV (fit-tube), contours, overlays")
    ext.add_argument("frames", nargs="+", metavar="FRAMES",
                     help="multi-page TIFF, image files, directories or glob patterns in frame order, an .rtdc "
                          "recording or a video (AVI, MP4, MKV, MOV, ...)")
    ext.add_argument("--pixel-size", help="size of one pixel, e.g. 0.5um (bare numbers: um; default: the file's "
                     "metadata: TIFF resolution, .rtdc imaging:pixel size)")
    ext.add_argument("--frame-rate", help="frames per second, e.g. 1000 (default: the file's: TIFF frame interval, "
                     ".rtdc imaging:frame rate, the video's rate; frame numbers and gaps from the file are kept)")
    ext.add_argument("--mu", help="viscosity of the liquid, e.g. 1.0 (Pa s) or 50mPa s: written as the mu column (needed for G_s)")
    ext.add_argument("--out", required=True, metavar="CSV", help="measurement file to write (the format fit-tube reads)")
    ext.add_argument("--overlay", metavar="DIR", help="write PNGs: one per capsule (its contour and the walls), one per "
                     "frame with an object (frames/, the flag written on it) and the levelled channel (channel.png)")
    ext.add_argument("--background", metavar="IMAGE",
                     help="image of the empty channel (default: the temporal median of the frames)")
    ext.add_argument("--walls", metavar="ROW1,ROW2",
                     help="rows of the two walls (px, at the image's centre column) instead of detecting them")
    ext.add_argument("--channel", choices=CHANNEL_SHAPES, default="tube",
                     help="what the walls bound: a circular tube (default; writes tube_radius) or a square channel "
                          "seen through a face (writes its half_width, the length scale of a square-channel database)")
    ext.add_argument("--channel-width",
                     help="channel width, e.g. 20um (bare numbers: um): checked against the walls found, and used "
                          "to place a wall outside the view")
    ext.add_argument("--channel-width-tolerance", type=float, default=2.0, metavar="PERCENT",
                     help="tolerance of --channel-width, in %% (default 2): a width found that differs by more than "
                          "it plus twice the found width's uncertainty is a warning and says so in the CSV's "
                          "width_check column")
    ext.add_argument("--frame-times", metavar="CSV",
                     help="time of each frame (a time_s column, optionally page): gaps between frames are honoured")
    ext.add_argument("--tilt", type=float, metavar="DEG",
                     help="tilt of the channel in degrees (atan of rows per column; default: estimated from the walls)")
    ext.add_argument("--report", metavar="CSV", help="per-frame report (default: <out stem>_frames.csv)")
    ext.add_argument("--flow-direction", choices=("auto", "right", "left"), default="auto",
                     help="direction of the flow in the images (default auto: from the objects' motion between "
                          "consecutive frames; left: the frames are mirrored first; a given one is checked)")
    ext.add_argument("--id", help="capsule id (several capsules: ID-1, ID-2, ...; default: the first file's name)")
    ext.add_argument("--max-asymmetry", type=float, default=0.05,
                     help="flag frames whose two halves differ by more than this fraction of L_z/2 (default 0.05)")
    ext.add_argument("--max-line-width", type=float, default=10.0,
                     help="flag frames whose membrane line is wider than this, px (out of focus; default 10)")
    ext.add_argument("--min-frames", type=int, default=3, help="good frames a capsule needs to be measured (default 3)")
    add_json_option(ext, "every capsule passage (measured or with its flag and reason), lengths in um, v_c in mm/s, "
                    "and the calibration used")
    add_force_option(ext)
    ext.set_defaults(func=cmd_extract)
