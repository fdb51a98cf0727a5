#!/usr/bin/env python3
"""Make (or check) the real-frame fixtures of tests/data/real_frames/ from dclab's test data.

The real-time deformability cytometry (RT-DC) test recordings that the dclab project publishes
(GitHub ZELLMECHANIK-DRESDEN/dclab, ``tests/data/*.zip``; the same zips ship in dclab's sdist on
PyPI) are bright-field frames of cells and beads flowing through a microchannel.  This script takes
a few frames of each recording that shows images, and writes per recording::

    tests/data/real_frames/<zip stem>/
        frames.tif        ImageJ multi-page TIFF, 8 bit, zlib with horizontal predictor; pixel size [um] and frame interval
                          in its metadata (capsmech extract reads both)
        background.png    the acquisition software's background image (events/image_bg), if any
        masks.npz         the acquisition software's reference masks: masks (event, row, col; bool)
                          and page (the frames.tif page of each event), if any
        contours.csv      the reference contours: event, page, x, y (px), if any
        frame_times.csv   page, event, frame (camera frame index), time_s
        meta.json         source (repository, path, commit, sha256), licence, pixel size, frame rate,
                          per-event reference features, and a survey of the channel (walls, tilt,
                          illumination) made by this script

Usage::

    scripts/fetch_real_frames.py                       # download dclab's sdist from PyPI (pip)
    scripts/fetch_real_frames.py --source DIR          # a dclab checkout, or a folder of the zips
    scripts/fetch_real_frames.py --source dclab-0.73.4.tar.gz
    scripts/fetch_real_frames.py --check [--source ...]   # regenerate in a temporary folder and
                                                          # compare with the committed fixtures

Needs numpy, scipy, h5py, tifffile, Pillow, and hdf5plugin for the zstd-compressed recordings
(filter id 32015).  Nothing of dclab itself is imported.
"""
from __future__ import annotations

import argparse
import hashlib
import io
import json
import re
import shutil
import struct
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from pathlib import Path

import numpy as np

REPO = "ZELLMECHANIK-DRESDEN/dclab"
# The GitHub snapshot these fixtures were checked against (all zips but fmt-hdf5_reference_2025,
# which is newer, are byte-identical in it and in the sdist below).
GIT_COMMIT = "b43a414e96c6da55fe99a12a60aca96ddba46f2c"
SDIST_VERSION = "0.73.4"
# Zips of the sdist that the GitHub snapshot GIT_COMMIT (2025-01-07) does not have yet.
NOT_IN_GIT_COMMIT = {"fmt-hdf5_reference_2025"}
LICENCE = ("GPL-2.0-or-later: dclab's LICENSE ('Unless otherwise specified by LICENSE files in individual "
           "directories, all code is GNU GPL version 2'; pyproject.toml: 'GPL version 2.0 or later'). "
           "tests/data/ has no LICENSE file of its own nor any separate note on the data, so the test "
           "data fall under the repository's GPL-2.0-or-later. Copyright: Paul Mueller and the dclab "
           "contributors / ZELLMECHANIK DRESDEN.")
DEFAULT_OUT = Path(__file__).resolve().parent.parent / "tests" / "data" / "real_frames"
MAX_FRAMES = 10

# Recordings with images.  Left out: fmt-hdf5_fl_2017 (artificial: random noise images),
# fmt-hdf5_polygon_gate_2021 (a black placeholder image with the text "Img0 Img1"),
# fmt-hdf5_segfault-compound_2023 and the tdms "no-image" / minimal / 2015 sets (no images).
RECORDINGS: dict[str, dict] = {
    "fmt-hdf5_fl_2018": dict(
        shows="calibration beads (dark rings, transparent interior) in a 20 um channel; channel tilted "
              "about -2.4 deg; doubled wall lines"),
    "fmt-hdf5_mask-contour_2018": dict(
        shows="cells (filled, darker interior) in a 20 um channel; dark wall lines with bright bands "
              "inside them and a second, fainter outer line at the top"),
    "fmt-hdf5_image-mask-blood_2021": dict(
        shows="whole blood: one leukocyte (masked) per event plus red blood cells (filled silhouettes, "
              "bullet/slipper shapes), several objects per frame; doubled wall lines"),
    "fmt-hdf5_fl_wide-channel_2023": dict(
        max_frames=8,
        shows="cells (semi-transparent, dark rim) in a 30 um channel, long field of view (1010 px); "
              "outer wall line at the very top; a notch at the right end"),
    "fmt-hdf5_raw-cytoshot-exported": dict(
        shows="cells / red blood cells in a 20 um channel; the top wall is cut by the image edge "
              "(only the bottom wall line is in view); no masks"),
    "fmt-hdf5_reference_2025": dict(
        shows="cells and debris in a 20 um channel; several events share one camera frame (the frames "
              "are stored once, the masks per event); background image given"),
    "fmt-hdf5_fl-no-contour_2019": dict(
        shows="beads (large faint disks) in a 20 um channel at 0.68 um/px; rows 42-44 black (padding); "
              "a vertical bright seam near x=37; masks with artefacts; channel tilted about 1.3 deg"),
    "fmt-hdf5_image-bg_2020": dict(
        shows="'background image example': dark filled ellipses on a flat noisy background, no channel "
              "walls in view (likely synthetic); background image given"),
    "fmt-hdf5_wide-channel_2023": dict(
        max_frames=3,
        shows="sample 'inlet': faint rings (bright rim) on a flat noisy background, no channel walls in "
              "view (the wide inlet region)"),
    "fmt-tdms_fl-image-bright_2017": dict(
        shows="cells (filled, textured) and debris in a 20 um channel; doubled wall lines (old tdms+avi "
              "format, frames from the uncompressed AVI); the reference contour of page 2 covers only a "
              "small dark fragment at x=190-200, not the large cell at x=110-195"),
    "fmt-tdms_fl-image_2016": dict(
        # The AVI holds 2 frames, burned-in labelled "2" and "3": events 2 and 3 (the beads match the
        # 2nd and 3rd contour of the contours file), so its first frame is the 2nd event.
        event_offset=1,
        shows="beads (dark filled disks with a bright centre) in a 20 um channel; frame number burned into "
              "the top-left corner; only 2 complete frames in the truncated AVI"),
    "fmt-tdms_fl-image-large-fov_2017": dict(
        shows="the whole constriction: channel walls widen to the reservoirs at both ends (walls not "
              "straight across the frame); one faint cell; only 1 complete frame in the truncated AVI"),
}


# ---------------------------------------------------------------------------
# Source
# ---------------------------------------------------------------------------


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def load_zips(source: str | None, workdir: Path) -> tuple[dict[str, bytes], str]:
    """The dclab test zips by stem, and a description of where they came from."""
    if source is None:
        dest = workdir / "sdist"
        # --no-binary dclab (not :all:): the build dependencies may come as wheels.
        cmd = [sys.executable, "-m", "pip", "download", f"dclab=={SDIST_VERSION}", "--no-deps",
               "--no-binary", "dclab", "-d", str(dest)]
        print("+", " ".join(cmd), file=sys.stderr)
        subprocess.run(cmd, check=True, stdout=sys.stderr)
        source = str(next(dest.glob("dclab-*.tar.gz")))
    path = Path(source)
    zips: dict[str, bytes] = {}
    if path.is_file() and path.name.endswith((".tar.gz", ".tgz")):
        with tarfile.open(path) as tar:
            for member in tar.getmembers():
                if re.search(r"/tests/data/[^/]+\.zip$", member.name):
                    zips[Path(member.name).stem] = tar.extractfile(member).read()
        where = f"PyPI sdist {path.name}"
    elif path.is_dir():
        folder = path / "tests" / "data" if (path / "tests" / "data").is_dir() else path
        for z in sorted(folder.glob("*.zip")):
            zips[z.stem] = z.read_bytes()
        where = f"local folder {folder}"
    else:
        raise SystemExit(f"{source}: neither a dclab sdist (.tar.gz) nor a folder")
    if not zips:
        raise SystemExit(f"{source}: no tests/data/*.zip found")
    return zips, where


# ---------------------------------------------------------------------------
# Readers
# ---------------------------------------------------------------------------


def read_rtdc(blob: bytes, workdir: Path, stem: str) -> dict:
    import h5py
    try:
        import hdf5plugin  # noqa: F401 - registers the zstd / bitshuffle filters
    except ImportError:
        hdf5plugin = None
    with zipfile.ZipFile(io.BytesIO(blob)) as zf:
        name = next(n for n in zf.namelist() if n.endswith(".rtdc"))
        target = workdir / stem
        target.mkdir(parents=True, exist_ok=True)
        zf.extract(name, target)
    rec: dict = {"file": name}
    with h5py.File(target / name, "r") as f:
        attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
        ev = f["events"]
        filters = sorted({flt for k in ev if isinstance(ev[k], h5py.Dataset) for flt in ev[k]._filters})
        rec["filters"] = filters
        rec["needs_hdf5plugin"] = any(flt.isdigit() for flt in filters)
        if rec["needs_hdf5plugin"] and hdf5plugin is None:
            raise SystemExit(f"{stem}: compressed with HDF5 filter(s) {filters}: pip install hdf5plugin")
        rec["attrs"] = attrs
        rec["image"] = ev["image"][:]
        rec["image_bg"] = ev["image_bg"][:] if "image_bg" in ev else None
        rec["mask"] = (ev["mask"][:] > 0) if "mask" in ev else None
        if "contour" in ev:
            grp = ev["contour"]
            rec["contour"] = [np.asarray(grp[k][:]) for k in sorted(grp, key=int)]
        else:
            rec["contour"] = None
        rec["frame"] = np.asarray(ev["frame"][:], dtype=float) if "frame" in ev else None
        rec["time"] = np.asarray(ev["time"][:], dtype=float) if "time" in ev else None
        feats = {}
        for k in ("pos_x", "pos_y", "size_x", "size_y", "deform", "area_um", "bright_avg"):
            if k in ev:
                feats[k] = np.asarray(ev[k][:], dtype=float)
        rec["features"] = feats
    rec["pixel_um"] = float(attrs["imaging:pixel size"])
    rec["frame_rate"] = float(attrs["imaging:frame rate"])
    rec["channel_width_um"] = float(attrs["setup:channel width"])
    return rec


def _ini(text: str) -> dict[str, str]:
    out = {}
    for line in text.splitlines():
        m = re.match(r"\s*([^#=\[]+?)\s*=\s*(.*?)\s*$", line)
        if m:
            out[m.group(1).lower()] = m.group(2).strip('"')
    return out


def _avi_frames(data: bytes, partial: list | None = None) -> list[tuple[int, np.ndarray]]:
    """(chunk index, frame) of the complete frames of an uncompressed (8-bit DIB) or I420 AVI.

    The chunks of the 'movi' list are walked in order; the n-th video chunk is the n-th event.
    Empty or truncated chunks (the test AVIs are truncated) are skipped but counted. The rows
    that a truncated last chunk of a bottom-up DIB still holds (the frame's bottom rows) are
    appended to ``partial``, when given, as (chunk index, first image row, rows)."""
    i = data.find(b"strf")
    _, width, height, _, bpp, compression = struct.unpack("<IiiHHI", data[i + 8:i + 28])
    h = abs(height)
    if compression == 0 and bpp == 8:
        stride = ((width * bpp + 31) // 32) * 4
        size = stride * h
    elif compression == struct.unpack("<I", b"I420")[0]:
        stride = width
        size = width * h * 3 // 2
    else:
        raise SystemExit(f"AVI: unsupported compression {compression:#x} / {bpp} bit")
    pos = data.find(b"movi") + 4
    frames, index = [], 0
    while pos + 8 <= len(data):
        cid, n = data[pos:pos + 4], struct.unpack("<I", data[pos + 4:pos + 8])[0]
        if cid == b"LIST":
            pos += 12
            continue
        chunk = data[pos + 8:pos + 8 + n]
        if cid[2:] in (b"db", b"dc"):
            if n == size and len(chunk) == n:
                img = np.frombuffer(chunk[:stride * h], np.uint8).reshape(h, stride)[:, :width]
                if compression == 0 and height > 0:
                    img = img[::-1]   # bottom-up DIB
                frames.append((index, np.ascontiguousarray(img)))
            elif partial is not None and compression == 0 and height > 0 and len(chunk) >= stride:
                k = len(chunk) // stride
                rows_kept = np.frombuffer(chunk[:stride * k], np.uint8).reshape(k, stride)[:, :width][::-1]
                partial.append((index, h - k, np.ascontiguousarray(rows_kept)))
            index += 1
        elif cid == b"idx1":
            break
        pos += 8 + n + (n & 1)
    return frames


def read_tdms_avi(blob: bytes, event_offset: int = 0) -> dict:
    """Old RT-DC format (ShapeIn 1): frames from the AVI, metadata from the ini files, the contours."""
    with zipfile.ZipFile(io.BytesIO(blob)) as zf:
        names = zf.namelist()
        avi = next(n for n in names if n.endswith(".avi"))
        para = _ini(zf.read(next(n for n in names if n.endswith("_para.ini"))).decode("latin-1"))
        cam = _ini(zf.read(next(n for n in names if n.endswith("_camera.ini"))).decode("latin-1"))
        partial: list = []
        frames = _avi_frames(zf.read(avi), partial)
        contours = []
        cname = next((n for n in names if n.endswith("contours.txt")), None)
        if cname:
            text = zf.read(cname).decode("latin-1")
            for block in re.split(r"Contour in frame", text)[1:]:
                num, _, rest = block.partition("\n")
                pts = np.array([[int(a), int(b)] for a, b in re.findall(r"\(\s*(-?\d+)\s*,\s*(-?\d+)\s*\)", rest)])
                contours.append((int(num.strip()), pts))
    image = np.stack([f for _, f in frames])
    chunk_index = [k + event_offset for k, _ in frames]
    rec = {"file": avi, "filters": ["none (uncompressed AVI)"], "needs_hdf5plugin": False,
           "attrs": {"para.ini": para, "camera.ini": cam}, "image": image, "image_bg": None, "mask": None,
           "frame": None, "time": None, "features": {},
           "pixel_um": float(para["pix size"]), "frame_rate": float(cam["frame rate"]),
           "channel_width_um": float(para["channel width"])}
    # The n-th contour belongs to the n-th event = the n-th video chunk of the AVI (the test AVIs are
    # truncated: empty chunks are skipped, so the kept frames keep their chunk's contour).
    rec["contour"] = [contours[k][1] for k in chunk_index]
    rec["contour_frame_numbers"] = [contours[k][0] for k in chunk_index]
    rec["avi_chunk_index"] = chunk_index
    # The truncated chunk after the last complete frame, numbered like the events.
    rec["partial_frame"] = (partial[0][0] + event_offset, *partial[0][1:]) if partial else None
    if partial and partial[0][0] + event_offset < len(contours):
        rec["partial_frame_contour_number"] = contours[partial[0][0] + event_offset][0]
    return rec


def next_frame_survey(frame: np.ndarray, partial: tuple[int, int, np.ndarray], contour: np.ndarray | None,
                      contour_number: int | None, next_number: int | None) -> dict:
    """The last complete frame's object against the rows of the next, truncated frame (the camera's
    next frame: the object has moved on, so those rows are the empty channel there).

    The contrast ``1 - frame / (gain next)`` (the gain: the median ratio of the two) smoothed
    1 px, its noise the robust deviation over the rows; per threshold (3-6 deviations, on the
    absolute contrast, the dark part, the bright part) the columns of the component, joined over
    2 px, that has the most pixels within the reference contour's columns (+-25 px), and the
    largest deviation there. It shows how faint the object is even against its true background,
    and how far the reference contour covers it."""
    from scipy import ndimage as ndi

    chunk, first_row, rows = partial
    part = frame[first_row:first_row + len(rows)].astype(float)
    nxt = rows.astype(float)
    gain = float(np.median(part / np.maximum(nxt, 1)))
    c = ndi.gaussian_filter(1 - part / np.maximum(gain * nxt, 1), 1.0)
    sigma = float(1.4826 * np.median(np.abs(c - np.median(c))))
    out: dict = {"chunk": int(chunk), "contour_frame_number": next_number, "image_rows": [int(first_row),
                 int(first_row + len(rows) - 1)], "gain": round(gain, 4), "noise_1px": round(sigma, 5)}
    if contour is None or not len(contour):
        return out
    lo, hi = int(contour[:, 0].min()) - 25, int(contour[:, 0].max()) + 25
    in_rows = contour[contour[:, 1] >= first_row]
    out["reference_contour"] = {"frame_number": contour_number, "columns": [int(contour[:, 0].min()),
                                int(contour[:, 0].max())],
                                "columns_in_these_rows": ([int(in_rows[:, 0].min()), int(in_rows[:, 0].max())]
                                                          if len(in_rows) else None)}
    for name, values in (("abs", np.abs(c)), ("dark", c), ("bright", -c)):
        out[f"peak_{name}_sigmas"] = round(float(values[:, max(lo, 0):hi].max() / sigma), 2)
        spans = {}
        for k in (3, 4, 5, 6):
            mask = values > k * sigma
            labels, _ = ndi.label(ndi.binary_dilation(mask, iterations=2))
            labels = np.where(mask, labels, 0)
            counts = np.bincount(labels[:, max(lo, 0):hi].ravel())
            counts[0] = 0
            if counts.max() == 0:
                spans[str(k)] = None
                continue
            cols = np.nonzero((labels == int(np.argmax(counts))).any(axis=0))[0]
            spans[str(k)] = [int(cols.min()), int(cols.max())]
        out[f"object_columns_{name}"] = spans
    return out


# ---------------------------------------------------------------------------
# Survey of the channel: wall lines, tilt, illumination
# ---------------------------------------------------------------------------


def _subpix(col: np.ndarray, r: int) -> float:
    a, b, c = col[r - 1], col[r], col[r + 1]
    d = a - 2 * b + c
    return float(r + 0.5 * (a - c) / d) if d > 0 else float(r)


def survey(image: np.ndarray, bg: np.ndarray | None, pixel_um: float, channel_um: float) -> dict:
    """Dark horizontal lines of the background (median of the frames if none given), each fitted with
    a straight line (tilt = atan(d row / d x), image coordinates, rows down), the channel's inner
    walls (the innermost lines either side of the centre), and the illumination along the channel."""
    from scipy import ndimage as ndi
    from scipy.signal import find_peaks

    back = bg.astype(float) if bg is not None else np.median(image.astype(float), axis=0)
    H, W = back.shape
    valid_rows = back.mean(1) > 5          # black padding rows are no wall
    pad = ~valid_rows
    near_pad = ndi.binary_dilation(pad, iterations=2) & ~pad

    def levelled(angle: float) -> np.ndarray:
        """Row profile along lines of the given tilt: top-hat (dark lines), padding masked."""
        t = np.tan(np.radians(angle))
        rows = np.arange(H, dtype=float)
        acc, cnt = np.zeros(H), np.zeros(H)
        for x in range(0, W, 2):
            rr = rows + t * (x - W / 2)
            ok = (rr >= 0) & (rr <= H - 1)
            acc[ok] += np.interp(rr[ok], rows, back[:, x])
            cnt[ok] += 1
        prof = acc / np.maximum(cnt, 1)
        th = ndi.grey_closing(prof, size=9) - prof
        th[(cnt < W / 3) | pad | near_pad] = 0
        return th

    def score(angle: float) -> float:
        return float(np.sort(levelled(angle))[-2:].sum())

    angles = np.arange(-4.0, 4.001, 0.1)
    best = float(angles[int(np.argmax([score(a) for a in angles]))])
    fine = np.arange(best - 0.1, best + 0.1001, 0.01)
    best = float(fine[int(np.argmax([score(a) for a in fine]))])
    tophat = levelled(best)
    t_best = np.tan(np.radians(best))
    peaks, _ = find_peaks(tophat, height=max(4.0, 0.2 * float(tophat.max(initial=0))))
    lines = []
    for r0 in peaks:
        xs, ys, full = [], [], []
        for x0 in range(0, W - 8, 8):
            col = back[:, x0:x0 + 8].mean(1)
            pred = int(round(r0 + t_best * (x0 + 4 - W / 2)))
            lo, hi = pred - 2, pred + 3
            if lo < 1 or hi > H - 1:
                continue
            r = lo + int(np.argmin(col[lo:hi]))
            if r in (lo, hi - 1):        # the minimum lies outside the window: another line
                continue
            xs.append(x0 + 4)
            ys.append(_subpix(col, r))
            # The whole line: darker than the rows 3 px beside it by half its depth over the frame.
            beside = [col[q] for q in (r - 3, r + 3) if 0 <= q < H]
            full.append(bool(np.mean(beside) - col[r] >= 0.5 * tophat[r0]))
        if len(xs) < max(5, 0.4 * (W // 8)):   # a line must span most of the frame
            continue
        xa, ya = np.array(xs, float), np.array(ys)
        b, a = np.polyfit(xa, ya, 1)
        keep = np.abs(ya - (a + b * xa)) < 1.0
        if keep.sum() >= 5:
            b, a = np.polyfit(xa[keep], ya[keep], 1)
        whole = keep & np.array(full)
        row = float(a + b * W / 2)
        if any(abs(row - ln["row_at_centre"]) < 1.5 for ln in lines):
            continue
        lines.append({"row_at_centre": round(row, 2),
                      "tilt_deg": round(float(np.degrees(np.arctan(b))), 3),
                      "depth_grey": round(float(tophat[r0]), 1),
                      "rms_px": round(float(np.std(ya[keep] - (a + b * xa[keep]))), 2),
                      "columns_fitted": f"{int(keep.sum())}/{len(xs)}",
                      # First and last column of the 8 px strips where the whole line (half its
                      # depth at least) lies on the fit (within 1 px): beyond, the wall leaves its
                      # row (an inlet, a widening) or is hidden.
                      "columns_on_line": ([int(xa[whole].min()) - 4, int(xa[whole].max()) + 3]
                                          if whole.any() else None)})
    out: dict = {"background": "events/image_bg" if bg is not None else "median of the frames",
                 "levelling_tilt_deg_coarse": round(best, 2), "dark_lines": lines}
    centre = H / 2
    above = [ln for ln in lines if ln["row_at_centre"] < centre]
    below = [ln for ln in lines if ln["row_at_centre"] > centre]
    nominal = channel_um / pixel_um
    out["channel_width_nominal_px"] = round(nominal, 1)
    if above and below:
        top, bottom = above[-1], below[0]
        if top["columns_on_line"] and bottom["columns_on_line"]:
            out["straight_columns"] = [max(top["columns_on_line"][0], bottom["columns_on_line"][0]),
                                       min(top["columns_on_line"][1], bottom["columns_on_line"][1])]
        width = bottom["row_at_centre"] - top["row_at_centre"]
        out["inner_walls_rows"] = [top["row_at_centre"], bottom["row_at_centre"]]
        out["wall_tilt_deg"] = [top["tilt_deg"], bottom["tilt_deg"]]
        out["channel_width_px"] = round(width, 1)
        out["channel_width_um"] = round(width * pixel_um, 2)
        out["width_vs_nominal_pct"] = round(100 * (width / nominal - 1), 1)
        r0, r1 = int(top["row_at_centre"]) + 4, int(bottom["row_at_centre"]) - 3
    else:
        out["inner_walls_rows"] = None
        out["note"] = "fewer than one dark line either side of the centre: wall(s) not in view"
        r0, r1 = int(H * 0.2), int(H * 0.8)
    if r1 - r0 >= 3:
        cp = back[r0:r1].mean(0)
        x = np.arange(W)
        b, _ = np.polyfit(x, cp, 1)
        out["illumination_gradient_pct"] = round(float(b * W / cp.mean() * 100), 2)
        smooth = ndi.uniform_filter1d(cp, max(5, W // 20))[W // 20:-W // 20]
        out["illumination_range_pct"] = round(float((smooth.max() - smooth.min()) / cp.mean() * 100), 2)
    return out


def object_kind(image: np.ndarray, bg: np.ndarray, mask: np.ndarray) -> float | None:
    """Contrast of the object's core over that of its rim (image - background): about 0 for a ring
    (transparent interior), about 1 or more for a filled silhouette."""
    from scipy import ndimage as ndi
    if mask.sum() < 30:
        return None
    lab, n = ndi.label(mask)
    if n > 1:
        mask = lab == 1 + int(np.argmax(ndi.sum(mask, lab, range(1, n + 1))))
    dt = ndi.distance_transform_edt(mask)
    core, rim = dt >= max(2.0, 0.5 * dt.max()), (dt > 0) & (dt <= 2)
    d = image.astype(float) - bg
    if not core.any() or abs(d[rim].mean()) < 1e-6:
        return None
    return round(float(d[core].mean() / d[rim].mean()), 2)


# ---------------------------------------------------------------------------
# Writing
# ---------------------------------------------------------------------------


def select_events(rec: dict, limit: int) -> tuple[list[int], list[int], np.ndarray]:
    """Events kept (the first ``limit`` distinct camera frames, in time order), the page of each kept
    event, and the page images."""
    n = len(rec["image"])
    frame = rec["frame"] if rec["frame"] is not None else np.arange(n, dtype=float)
    order = sorted(range(n), key=lambda i: (frame[i], i))
    pages_frames: list[float] = []
    events, pages = [], []
    for i in order:
        if frame[i] not in pages_frames:
            if len(pages_frames) == limit:
                continue
            pages_frames.append(frame[i])
        events.append(i)
        pages.append(pages_frames.index(frame[i]))
    first_of_page = [events[pages.index(p)] for p in range(len(pages_frames))]
    return events, pages, rec["image"][first_of_page]


def write_recording(stem: str, blob: bytes, where: str, out: Path, workdir: Path) -> dict:
    import tifffile
    from PIL import Image

    cfg = RECORDINGS[stem]
    rec = read_tdms_avi(blob, cfg.get("event_offset", 0)) if stem.startswith("fmt-tdms") else read_rtdc(blob, workdir, stem)
    events, pages, frames = select_events(rec, cfg.get("max_frames", MAX_FRAMES))
    d = out / stem
    if d.exists():
        shutil.rmtree(d)
    d.mkdir(parents=True)
    pix, rate = rec["pixel_um"], rec["frame_rate"]
    tifffile.imwrite(d / "frames.tif", frames.astype(np.uint8), imagej=True,
                     resolution=(1.0 / pix, 1.0 / pix), compression="zlib", predictor=True,
                     metadata={"axes": "TYX", "unit": "um", "finterval": 1.0 / rate})
    files = ["frames.tif"]
    bg = None
    if rec["image_bg"] is not None:
        bgs = rec["image_bg"][events]
        bg_img = np.median(bgs, axis=0).round().astype(np.uint8)
        Image.fromarray(bg_img).save(d / "background.png", optimize=True)
        files.append("background.png")
        bg = bg_img
        bg_note = ("events/image_bg, identical for all kept events" if all((b == bgs[0]).all() for b in bgs)
                   else "median over the kept events of events/image_bg (they differ by at most "
                        f"{int(np.abs(bgs.astype(int) - bg_img).max())} grey levels)")
    else:
        bg_note = None
    if rec["mask"] is not None:
        np.savez_compressed(d / "masks.npz", masks=rec["mask"][events], page=np.array(pages, np.int16),
                            event=np.array(events, np.int32))
        files.append("masks.npz")
    if rec["contour"] is not None:
        with open(d / "contours.csv", "w") as fh:
            fh.write("event,page,x,y\n")
            for ev, pg in zip(events, pages):
                if ev < len(rec["contour"]):
                    for x, y in rec["contour"][ev]:
                        fh.write(f"{ev},{pg},{int(x)},{int(y)}\n")
        files.append("contours.csv")
    frame = rec["frame"]
    time = rec["time"]
    with open(d / "frame_times.csv", "w") as fh:
        fh.write("page,event,frame,time_s\n")
        for ev, pg in zip(events, pages):
            fr = "" if frame is None else f"{frame[ev]:.4f}".rstrip("0").rstrip(".")
            t = time[ev] if time is not None else (frame[ev] / rate if frame is not None else "")
            fh.write(f"{pg},{ev},{fr},{t if t == '' else format(t, '.7g')}\n")
    files.append("frame_times.csv")

    srv = survey(frames, bg, pix, rec["channel_width_um"])
    last = rec.get("avi_chunk_index", [None])[-1] if rec.get("avi_chunk_index") else None
    if rec.get("partial_frame") is not None and last is not None and rec["partial_frame"][0] == last + 1:
        ev_last = len(rec["image"]) - 1
        srv["next_frame_rows"] = next_frame_survey(
            rec["image"][ev_last], rec["partial_frame"],
            np.asarray(rec["contour"][ev_last]) if rec["contour"] is not None else None,
            rec["contour_frame_numbers"][ev_last], rec.get("partial_frame_contour_number"))
    back = bg.astype(float) if bg is not None else np.median(frames.astype(float), axis=0)
    ev_rows = []
    H, W = frames.shape[1:]
    for ev, pg in zip(events, pages):
        row: dict = {"event": int(ev), "page": int(pg)}
        if frame is not None:
            row["frame"] = float(frame[ev])
        if time is not None:
            row["time_s"] = round(float(time[ev]), 7)
        for k, v in rec["features"].items():
            row[k] = round(float(v[ev]), 4)
        if rec["mask"] is not None:
            m = rec["mask"][ev]
            if m.any():
                from scipy import ndimage as ndi
                lab, ncomp = ndi.label(m)
                row["mask_components"] = int(ncomp)
                row["mask_touches_border_any"] = bool(m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any())
                if ncomp > 1:
                    m = lab == 1 + int(np.argmax(ndi.sum(m, lab, range(1, ncomp + 1))))
                ys, xs = np.nonzero(m)
                row["mask_largest_bbox_px"] = [int(xs.min()), int(xs.max()), int(ys.min()), int(ys.max())]
                row["mask_largest_extent_x_px"] = int(xs.max() - xs.min() + 1)
                row["mask_largest_touches_border"] = bool(xs.min() == 0 or ys.min() == 0 or xs.max() == W - 1
                                                  or ys.max() == H - 1)
                row["core_to_rim_contrast"] = object_kind(frames[pg], back, m)
        if rec["mask"] is None and rec["contour"] is not None and ev < len(rec["contour"]):
            c = np.asarray(rec["contour"][ev])
            row["contour_bbox_px"] = [int(c[:, 0].min()), int(c[:, 0].max()), int(c[:, 1].min()), int(c[:, 1].max())]
            row["contour_extent_x_px"] = int(c[:, 0].max() - c[:, 0].min() + 1)
            row["contour_touches_border"] = bool(c[:, 0].min() <= 0 or c[:, 1].min() <= 0
                                                 or c[:, 0].max() >= W - 1 or c[:, 1].max() >= H - 1)
        if rec.get("avi_chunk_index"):
            row["event_in_tdms"] = rec["avi_chunk_index"][ev]
        if rec.get("contour_frame_numbers"):
            row["contour_frame_number"] = rec["contour_frame_numbers"][ev] if ev < len(rec["contour"]) else None
        ev_rows.append(row)
    attrs = rec["attrs"]
    keep_attrs = {k: (v if isinstance(v, (str, int, float, dict)) else (v.item() if hasattr(v, "item") else str(v)))
                  for k, v in attrs.items()
                  if k.startswith(("imaging:", "setup:", "experiment:", "online_contour:", "para.ini", "camera.ini",
                                   "pipeline:dcnum background"))}
    frames_gaps = None
    if frame is not None and len(events) > 1:
        fsorted = [float(frame[e]) for e in events]
        diffs = np.diff(sorted(set(fsorted)))
        frames_gaps = {"min": float(diffs.min()), "max": float(diffs.max()),
                       "consecutive_pages": int((diffs == 1).sum()),
                       "events_sharing_a_frame": len(fsorted) - len(set(fsorted)),
                       "all_events_in_file_time_ordered": bool(np.all(np.diff(frame) >= 0)),
                       "non_integer_frame_values": [float(x) for x in frame if float(x) != round(float(x))]}
    meta = {
        "recording": stem,
        "shows": cfg["shows"],
        "source": {"repository": f"https://github.com/{REPO}", "path": f"tests/data/{stem}.zip",
                   "file_in_zip": rec["file"], "git_commit_checked": GIT_COMMIT,
                   "in_git_commit_checked": stem not in NOT_IN_GIT_COMMIT,
                   "pypi_sdist": f"dclab-{SDIST_VERSION}.tar.gz", "zip_sha256": sha256(blob),
                   "read_from": where},
        "licence": LICENCE,
        "made_by": "scripts/fetch_real_frames.py",
        "pixel_size_um": pix, "frame_rate_hz": rate, "channel_width_um_nominal": rec["channel_width_um"],
        "image_shape_rows_cols": [int(H), int(W)], "pages": int(len(frames)),
        "events_in_recording": int(len(rec["image"])), "events_kept": len(events),
        "hdf5_filters": rec["filters"], "needs_hdf5plugin": rec["needs_hdf5plugin"],
        "background": bg_note, "files": files,
        "frame_gaps": frames_gaps,
        "time_note": ("frame_times.csv time_s is events/time" if time is not None else
                      "frame_times.csv time_s is frame / frame rate" if frame is not None else
                      "no frame index: consecutive AVI frames of separate events (times unknown)"),
        "survey": srv,
        "events": ev_rows,
        "attributes": keep_attrs,
    }
    with open(d / "meta.json", "w") as fh:
        json.dump(meta, fh, indent=1, default=lambda o: o.item() if hasattr(o, "item") else str(o))
        fh.write("\n")
    return meta


# ---------------------------------------------------------------------------
# Check
# ---------------------------------------------------------------------------


def compare(fresh: Path, committed: Path) -> list[str]:
    import tifffile
    problems = []
    for d in sorted(fresh.iterdir()):
        if not d.is_dir():
            continue
        c = committed / d.name
        if not c.is_dir():
            problems.append(f"{d.name}: missing in {committed}")
            continue
        for f in sorted(d.iterdir()):
            g = c / f.name
            if not g.exists():
                problems.append(f"{d.name}/{f.name}: missing")
            elif f.suffix == ".tif":
                if not np.array_equal(tifffile.imread(f), tifffile.imread(g)):
                    problems.append(f"{d.name}/{f.name}: frames differ")
            elif f.suffix == ".npz":
                a, b = np.load(f), np.load(g)
                if set(a) != set(b) or any(not np.array_equal(a[k], b[k]) for k in a):
                    problems.append(f"{d.name}/{f.name}: arrays differ")
            elif f.suffix == ".png":
                from PIL import Image
                if not np.array_equal(np.asarray(Image.open(f)), np.asarray(Image.open(g))):
                    problems.append(f"{d.name}/{f.name}: image differs")
            elif f.name == "meta.json":
                a, b = json.loads(f.read_text()), json.loads(g.read_text())
                a["source"].pop("read_from", None)
                b["source"].pop("read_from", None)
                if a != b:
                    problems.append(f"{d.name}/meta.json differs")
            elif f.read_bytes() != g.read_bytes():
                problems.append(f"{d.name}/{f.name}: differs")
    return problems


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--source", help="dclab checkout / folder of the zips / dclab sdist .tar.gz "
                                     f"(default: pip download dclab=={SDIST_VERSION} from PyPI)")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"fixture folder (default {DEFAULT_OUT})")
    ap.add_argument("--check", action="store_true", help="regenerate in a temporary folder and compare")
    ap.add_argument("--only", nargs="*", help="recordings (zip stems) to make")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        zips, where = load_zips(args.source, work)
        target = work / "out" if args.check else args.out
        target.mkdir(parents=True, exist_ok=True)
        missing = []
        for stem in args.only or RECORDINGS:
            if stem not in zips:
                missing.append(stem)
                print(f"{stem}: not in {where}", file=sys.stderr)
                continue
            meta = write_recording(stem, zips[stem], where, target, work)
            size = sum(f.stat().st_size for f in (target / stem).iterdir())
            print(f"{stem}: {meta['pages']} frames {meta['image_shape_rows_cols']}, {size / 1024:.0f} KiB",
                  file=sys.stderr)
        if args.check:
            problems = compare(target, args.out)
            for p in problems:
                print("DIFF", p, file=sys.stderr)
            print("check:", "OK" if not problems and not missing else "FAILED", file=sys.stderr)
            return 1 if problems or missing else 0
    return 1 if missing else 0


if __name__ == "__main__":
    sys.exit(main())
