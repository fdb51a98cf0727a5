#!/usr/bin/env python3
"""Make (or check) the .rtdc excerpts of tests/data/rtdc/ from dclab's test data.

Each excerpt is an original ``.rtdc`` file of dclab's ``tests/data/*.zip`` (GitHub
ZELLMECHANIK-DRESDEN/dclab) cut to its first few events, written in the original's layout:
every kept dataset is created with the original's HDF5 creation property list (type, chunks,
filters: gzip, fletcher32, zstd), so the reader meets the file as the instrument wrote it;
the root attributes are copied; the fluorescence traces and logs are left out (capsmech does not
read them). The dclab zips are read from a checkout (``--source``).

    .venv/bin/python scripts/fetch_rtdc_excerpts.py --source /path/to/dclab [--check]

Needs numpy, h5py and hdf5plugin (the zstd-compressed file, HDF5 filter 32015).
"""
from __future__ import annotations

import argparse
import hashlib
import io
import json
import tempfile
import zipfile
from pathlib import Path

import numpy as np

GIT_COMMIT = "b43a414e96c6da55fe99a12a60aca96ddba46f2c"
OUT = Path(__file__).resolve().parent.parent / "tests" / "data" / "rtdc"
#: zip stem -> (file in the zip, events kept, what it shows)
EXCERPTS = {
    "fmt-hdf5_fl_2018": ("calibration_beads.rtdc", 7,
                         "calibration beads (dark rings), channel tilted about -2.4 deg; gzip; events/frame, no "
                         "events/time; events/mask"),
    "fmt-hdf5_mask-contour_2018": ("mask_contour_reference.rtdc", 6,
                                   "cells (filled) in a 20 um channel; events/time, events/mask and events/contour"),
    "fmt-hdf5_raw-cytoshot-exported": ("cytoshot_shapeout_export.rtdc", 4,
                                       "cells in a 20 um channel, top wall cut by the image edge; zstd (HDF5 filter "
                                       "32015: needs hdf5plugin); no mask"),
    "fmt-hdf5_image-bg_2020": ("2020-10_image_bg.rtdc", 3,
                               "dark ellipses on a flat background, no walls; events/image_bg"),
}
LEFT_OUT = ("trace", "logs", "tables")


def excerpt(source: bytes, keep: int, out: Path) -> None:
    """Write the first ``keep`` events of the .rtdc file ``source`` to ``out``, in its own layout."""
    import h5py
    import hdf5plugin  # noqa: F401 - the zstd filter

    with h5py.File(io.BytesIO(source), "r") as src, h5py.File(out, "w", track_order=True) as dst:
        for key, value in src.attrs.items():
            dst.attrs[key] = value
        events = dst.create_group("events")

        def copy(name: str, obj) -> None:
            if any(name.split("/")[0] == part for part in LEFT_OUT) or not isinstance(obj, h5py.Dataset):
                return
            if name.startswith("contour/"):
                if int(name.split("/")[1]) >= keep:
                    return
                shape = obj.shape
            else:
                shape = (min(keep, obj.shape[0]), *obj.shape[1:])
            parent = events.require_group(name.rsplit("/", 1)[0]) if "/" in name else events
            space = h5py.h5s.create_simple(shape, obj.id.get_space().get_simple_extent_dims(True))
            h5py.h5d.create(parent.id, name.rsplit("/", 1)[-1].encode(), obj.id.get_type(), space,
                            dcpl=obj.id.get_create_plist())
            events[name][...] = obj[: shape[0]]
            for key, value in obj.attrs.items():
                events[name].attrs[key] = value

        src["events"].visititems(copy)
        dst.attrs["experiment:event count"] = np.int64(keep)


def build(dclab: Path, folder: Path) -> dict:
    folder.mkdir(parents=True, exist_ok=True)
    sources = {}
    for stem, (member, keep, shows) in EXCERPTS.items():
        data = (dclab / "tests" / "data" / f"{stem}.zip").read_bytes()
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            original = archive.read(member)
        excerpt(original, keep, folder / f"{stem}.rtdc")
        sources[stem] = {"zip": f"tests/data/{stem}.zip", "zip_sha256": hashlib.sha256(data).hexdigest(),
                         "file": member, "events_kept": keep, "shows": shows}
    return sources


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", required=True, type=Path, help="a dclab checkout")
    parser.add_argument("--check", action="store_true", help="rebuild in a temporary folder and compare the data")
    options = parser.parse_args()
    if not options.check:
        sources = build(options.source, OUT)
        (OUT / "sources.json").write_text(json.dumps({"repository": "ZELLMECHANIK-DRESDEN/dclab",
                                                      "commit": GIT_COMMIT, "licence": "GPL-2.0-or-later",
                                                      "excerpts": sources}, indent=1) + "\n")
        return
    import h5py
    import hdf5plugin  # noqa: F401

    with tempfile.TemporaryDirectory() as tmp:
        build(options.source, Path(tmp))
        for stem in EXCERPTS:
            with h5py.File(Path(tmp) / f"{stem}.rtdc") as a, h5py.File(OUT / f"{stem}.rtdc") as b:
                names: list[str] = []
                a.visit(names.append)
                for name in names:
                    if isinstance(a[name], h5py.Dataset) and not np.array_equal(a[name][...], b[name][...]):
                        raise SystemExit(f"{stem}: {name} differs")
        print("the excerpts match their sources")


if __name__ == "__main__":
    main()
