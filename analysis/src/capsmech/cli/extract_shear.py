"""``capsmech extract-shear``: images of capsules in a Couette rheometer's shear plane -> the
measurement CSV that fit-shear reads, a per-object report with the uncertainties, overlays."""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from capsmech.api import extract_shear
from capsmech.cli.common import add_force_option, add_json_option, format_table, plan_output, write_json
from capsmech.errors import ExtractionError

#: Units a shear rate may be given in (bare numbers: 1/s).
SHEAR_RATE_UNITS = {"": 1.0, "1/s": 1.0, "/s": 1.0, "s^-1": 1.0, "s-1": 1.0}
#: Below this D12 fit-shear gives no G_s (paper §4.3: too imprecise).
FIT_SHEAR_MIN_D12 = 0.35


def cmd_extract_shear(args: argparse.Namespace) -> int:
    """``extract-shear``: frames -> ellipses -> measurement CSV, report, overlays.

    Exit status 0 when at least one capsule was measured, 1 when none could be (the reasons
    are printed and the report is still written), 2 for unreadable files or bad options.
    """
    from capsmech.imaging.extraction_output import VISCOSITY_UNITS_PA_S, parse_quantity
    from capsmech.imaging.shear_plane import (
        CAPSULE_UNITS,
        COVERAGE,
        report_rows,
        write_report,
        write_shear_measurements,
        write_shear_overlay,
    )

    out_file = plan_output(args.out, "--out", (".csv",), args.force)
    out = out_file.path
    report = plan_output(args.report or out.with_name(out.stem + "_ellipses.csv"), "--report", (".csv",),
                         args.force).path
    json_out = plan_output(args.json, "--json", (".json",), args.force) if args.json else None
    if args.overlay and Path(args.overlay).exists() and not Path(args.overlay).is_dir():
        raise ExtractionError(f"--overlay {args.overlay}: exists and is not a folder")
    if not math.isfinite(args.flow_angle):
        raise ExtractionError(f"--flow-angle: need a finite angle in degrees, got {args.flow_angle}")
    if not (math.isfinite(args.min_radius) and args.min_radius > 0):
        raise ExtractionError(f"--min-radius: need a positive number of pixels, got {args.min_radius}")
    shear_rate = parse_quantity(args.shear_rate, "--shear-rate", SHEAR_RATE_UNITS, "1/s")
    mu = parse_quantity(args.mu, "--mu", VISCOSITY_UNITS_PA_S, "Pa s")
    try:
        found = extract_shear(args.frames, args.pixel_size, one_capsule=args.one_capsule, capsule_id=args.id,
                              line=args.line, flow_angle=args.flow_angle, min_radius=args.min_radius,
                              background=args.background, progress=sys.stderr.isatty())
    except ExtractionError as err:
        raise ExtractionError(str(err).replace("pixel_size:", "--pixel-size:")) from None
    write_report(report, report_rows(found))
    frames = len({o.frame for o in found.objects})
    flags: dict[str, int] = {}
    for obj in found.objects:
        if obj.flag:
            flags[obj.flag.split(":")[0]] = flags.get(obj.flag.split(":")[0], 0) + 1
    print(f"{len(found.objects)} objects in {frames} frames with objects; {len(found.ids)} measured"
          + (", left out: " + ", ".join(f"{n} {k}" for k, n in sorted(flags.items())) if flags else "")
          + f" (per object: {report})")
    if args.overlay:
        for index in sorted({o.frame for o in found.objects}):
            write_shear_overlay(Path(args.overlay) / f"frame_{index:05d}.png", found, index)
        print(f"wrote {frames} overlays in {args.overlay}" if frames else "no object: no overlay written")
    if not found.capsules:
        print(f"capsmech: nothing measured (no capsule outline in any frame); {out} not written", file=sys.stderr)
        return 1
    rows = found.capsule_rows()
    print(format_table(rows, list(CAPSULE_UNITS), CAPSULE_UNITS))
    print(f"uncertainties (*_err) at {COVERAGE:g} standard deviations: the outline's scatter about its ellipse, "
          "its correlation along the outline, and the ring's blur and offset")
    small = [str(r["id"]) for r in rows if float(str(r["D12"])) < FIT_SHEAR_MIN_D12]
    if small:
        print(f"capsmech: warning: D12 < {FIT_SHEAR_MIN_D12} for {', '.join(small)}: fit-shear flags such capsules "
              "as too imprecise to fit (paper §4.3)", file=sys.stderr)
    path = write_shear_measurements(out, found, shear_rate, mu, report=report.name,
                                    source=" ".join(str(f) for f in args.frames))
    print(out_file.wrote(path))
    if json_out is not None:
        payload = {"frames": [str(f) for f in args.frames], "measurements": str(path), "object_report": str(report),
                   "shear_rate": shear_rate, "mu": mu, "units": {**CAPSULE_UNITS, "shear_rate": "1/s", "mu": "Pa s"},
                   "rows": rows}
        print(json_out.wrote(write_json(json_out.path, "extract-shear", payload)))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``extract-shear``."""
    ext = sub.add_parser("extract-shear", help="images of capsules in a Couette shear plane -> ellipses -> "
                         "measurement CSV (fit-shear)")
    ext.add_argument("frames", nargs="+", metavar="FRAMES",
                     help="image files (TIFF, PNG, ...), multi-page TIFFs, directories or glob patterns")
    ext.add_argument("--out", required=True, metavar="CSV", help="measurement file to write (the format fit-shear reads)")
    ext.add_argument("--shear-rate", required=True, help="the rheometer's shear rate, e.g. 350 (1/s): written per capsule")
    ext.add_argument("--mu", required=True, help="viscosity of the liquid, e.g. 0.756 (Pa s) or 756mPa s")
    ext.add_argument("--pixel-size", help="size of one pixel, e.g. 1.4um (bare numbers: um; default: the TIFF's "
                     "resolution)")
    ext.add_argument("--one-capsule", action="store_true",
                     help="the frames show one capsule: the largest object of each frame is it, and its frames are "
                          "combined into one row (mean, and an uncertainty with their scatter)")
    ext.add_argument("--id", help="capsule id (several capsules: ID-1, ID-2, ...; default: the first file's name)")
    ext.add_argument("--line", choices=("dark", "bright"), default="dark",
                     help="the membrane is a dark ring (bright field, default) or a bright one")
    ext.add_argument("--flow-angle", type=float, default=0.0, metavar="DEG",
                     help="direction of the flow on the screen, counter-clockwise from the image's x axis (default 0: "
                          "horizontal); theta is measured from it")
    ext.add_argument("--min-radius", type=float, default=6.0, metavar="PX",
                     help="smaller objects (equivalent radius) are specks (default 6 px)")
    ext.add_argument("--background", metavar="IMAGE",
                     help="image of the empty field (default: a smooth surface fitted to each frame)")
    ext.add_argument("--report", metavar="CSV", help="per-object report (default: <out stem>_ellipses.csv)")
    ext.add_argument("--overlay", metavar="DIR", help="write one PNG per frame: the traced outlines and their ellipses")
    add_json_option(ext, "every measured capsule's L1, L2 [um], D12 and theta [deg] with their uncertainties")
    add_force_option(ext)
    ext.set_defaults(func=cmd_extract_shear)
