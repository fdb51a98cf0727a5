"""``capsmech extract``: frames of capsules in the tube -> the measurement CSV that fit-tube reads,
contours, a per-frame report and overlays."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


def cmd_extract(args: argparse.Namespace) -> int:
    """``extract``: frames of a capsule in the tube -> measurement CSV, contours, report, overlays.

    Exit status 0 when at least one capsule was measured, 1 when none could be (the reasons
    are printed and the per-frame report is still written), 2 for unreadable files or bad
    options (``ExtractionError``).
    """
    from capsmech.imaging.extraction import (
        ExtractionError,
        ExtractionSettings,
        extract,
        measure_capsules,
        progress_printer,
        read_frames,
    )
    from capsmech.imaging.extraction_output import (
        PIXEL_UNITS_UM,
        RATE_UNITS_HZ,
        VISCOSITY_UNITS_PA_S,
        default_ids,
        parse_quantity,
        write_frame_report,
        write_measurements,
        write_overlay,
    )

    pixel_um = parse_quantity(args.pixel_size, "--pixel-size", PIXEL_UNITS_UM, "um") if args.pixel_size else None
    rate = parse_quantity(args.frame_rate, "--frame-rate", RATE_UNITS_HZ, "Hz") if args.frame_rate else None
    mu = parse_quantity(args.mu, "--mu", VISCOSITY_UNITS_PA_S, "Pa s") if args.mu else None
    settings = ExtractionSettings(max_asymmetry=args.max_asymmetry, max_line_width_px=args.max_line_width,
                                  min_good_frames=args.min_frames)
    stack = read_frames(args.frames, args.flow_direction)
    pixel_um = pixel_um or stack.pixel_size_um
    rate = rate or stack.frame_rate
    if pixel_um is None:
        raise ExtractionError("--pixel-size: required (the files carry no pixel size)")
    if rate is None:
        raise ExtractionError("--frame-rate: required (the files carry no frame interval)")
    walls, results = extract(stack, settings, progress_printer())
    out = Path(args.out)
    report = Path(args.report) if args.report else out.with_name(out.stem + "_frames.csv")
    write_frame_report(report, results)
    print(f"{len(stack)} frames of {stack.frames[0].shape[1]}x{stack.frames[0].shape[0]} px; tube radius "
          f"{walls.radius_px:.2f} px = {walls.radius_px * pixel_um:.4g} um, axis at row {walls.axis_row:.2f}; "
          f"pixel {pixel_um:g} um, {rate:g} frames/s")
    flags: dict[str, int] = {}
    for r in results:
        if r.flag:
            reason = r.flag.split(" (")[0]
            flags[reason] = flags.get(reason, 0) + 1
    good = sum(r.good for r in results)
    print(f"{good} frames measured" + (", flagged: " + ", ".join(f"{n} {k}" for k, n in sorted(flags.items()))
                                       if flags else "") + f" (per frame: {report})")
    capsules = measure_capsules(results, rate, settings)
    measured = [c for c in capsules if c.ok]
    ids = default_ids(args.id or Path(stack.labels[0].split("[")[0]).stem, len(capsules))
    for cap_id, cap in zip(ids, capsules):
        if not cap.ok:
            print(f"capsule {cap_id} (frames {cap.frames[0]}-{cap.frames[-1]}) not measured: {cap.problem}")
    if not measured:
        why = "no capsule in any frame" if not capsules else "no capsule had enough good frames"
        print(f"capsmech: nothing measured ({why}); {out} not written", file=sys.stderr)
        return 1
    kept_ids = [i for i, c in zip(ids, capsules) if c.ok]
    csv_path, _ = write_measurements(out, measured, results, walls, pixel_um, kept_ids, mu,
                                     source=" ".join(str(f) for f in args.frames), flow_direction=args.flow_direction)
    print(f"{'id':>12} {'frames':>7} {'L_z [um]':>16} {'L_p [um]':>16} {'v_c [mm/s]':>18}")
    for cap_id, cap in zip(kept_ids, measured):
        print(f"{cap_id:>12} {len(cap.good_frames):>7} {cap.L_z_px * pixel_um:>8.4g} +- {cap.L_z_spread_px * pixel_um:<4.2g}"
              f" {cap.L_p_px * pixel_um:>8.4g} +- {cap.L_p_spread_px * pixel_um:<4.2g}"
              f" {cap.v_c_px_s * pixel_um * 1e-3:>9.5g} +- {cap.v_c_se_px_s * pixel_um * 1e-3:<5.2g}")
        if args.overlay:
            frame = next(r for r in results if r.index == cap.representative)
            title = (f"{cap_id}, frame {frame.index}: L_z = {cap.L_z_px * pixel_um:.4g} um, L_p = "
                     f"{cap.L_p_px * pixel_um:.4g} um, tube radius {walls.radius_px * pixel_um:.4g} um, "
                     f"v_c = {cap.v_c_px_s * pixel_um * 1e-3:.4g} mm/s")
            print(f"wrote {write_overlay(Path(args.overlay) / f'{cap_id}.png', stack.frames[frame.index], frame, walls, title)}")
    print(f"wrote {csv_path}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``extract``."""
    ext = sub.add_parser("extract", help="frames of capsules in the tube -> measurement CSV (fit-tube), contours, overlays")
    ext.add_argument("frames", nargs="+", metavar="FRAMES", help="multi-page TIFF, image files, directories or glob patterns, in frame order")
    ext.add_argument("--pixel-size", help="size of one pixel, e.g. 0.5um (bare numbers: um; default: the TIFF's metadata)")
    ext.add_argument("--frame-rate", help="frames per second, e.g. 1000 (default: the TIFF's frame interval)")
    ext.add_argument("--mu", help="viscosity of the liquid, e.g. 1.0 (Pa s) or 50mPa s: written as the mu column (needed for G_s)")
    ext.add_argument("--out", required=True, metavar="CSV", help="measurement file to write (the format fit-tube reads)")
    ext.add_argument("--overlay", metavar="DIR", help="write one PNG per capsule: its contour and the walls on a frame")
    ext.add_argument("--report", metavar="CSV", help="per-frame report (default: <out stem>_frames.csv)")
    ext.add_argument("--flow-direction", choices=("right", "left"), default="right",
                     help="direction of the flow in the images (left: the frames are mirrored first)")
    ext.add_argument("--id", help="capsule id (several capsules: ID-1, ID-2, ...; default: the first file's name)")
    ext.add_argument("--max-asymmetry", type=float, default=0.05,
                     help="flag frames whose two halves differ by more than this fraction of L_z/2 (default 0.05)")
    ext.add_argument("--max-line-width", type=float, default=10.0,
                     help="flag frames whose membrane line is wider than this, px (out of focus; default 10)")
    ext.add_argument("--min-frames", type=int, default=3, help="good frames a capsule needs to be measured (default 3)")
    ext.set_defaults(func=cmd_extract)
