"""Give every dataset of the shipped databases HDF5's Fletcher-32 checksum (issue 25, item 2).

The workflow's assembly writes new databases with the filter (``capsmech.workflow.assembly``);
this script rewrites the files shipped before it, in place (``FILE.tmp`` then rename), and
checks that nothing but the filter changed: every group, every attribute (name, HDF5 type and
bytes) and every dataset (HDF5 type, shape and the bytes of every value) is the same before
and after (a SHA-256 digest of all of it). Datasets keep their compression; contiguous ones
become one chunk each (the filter needs chunks). A scalar dataset cannot be chunked and is
copied as it is (the shipped files have none).

    PYTHONPATH=analysis/src .venv/bin/python scripts/checksum_databases.py [--check]

``--check`` rewrites nothing: it fails unless every dataset of every shipped file has the filter.
"""
from __future__ import annotations

import argparse
import hashlib
import os
import sys
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np

from capsmech.io.catalog import CATALOG, database_path


def _raw(obj: h5py.Dataset | h5py.AttributeManager, name: str | None = None) -> np.ndarray:
    """The stored values of a dataset (name None) or of attribute ``name``, as h5py reads them."""
    if name is None:
        assert isinstance(obj, h5py.Dataset)
        buf = np.empty(obj.shape, dtype=obj.dtype)
        if obj.size:
            obj.id.read(h5py.h5s.ALL, h5py.h5s.ALL, buf)
        return buf
    attr = h5py.h5a.open(obj._id, name.encode())  # type: ignore[union-attr]
    buf = np.empty(attr.shape, dtype=attr.dtype)
    attr.read(buf)
    return buf


def _value_bytes(values: np.ndarray) -> bytes:
    """The bytes of every value (text as UTF-8: variable-length strings hold pointers)."""
    if values.dtype.kind == "O":
        return b"\x1f".join(v if isinstance(v, bytes) else str(v).encode() for v in values.reshape(-1))
    return np.ascontiguousarray(values).tobytes()


def _is_text(dataset: h5py.Dataset) -> bool:
    return h5py.check_string_dtype(dataset.dtype) is not None


def digest(path: Path, skip: Callable[[str], bool] = lambda name: False) -> str:
    """SHA-256 of every group, attribute (name, HDF5 type, values) and dataset (type, shape, values;
    text datasets: shape and text), but the objects whose path ``skip`` names."""
    sha = hashlib.sha256()

    def attributes(obj: h5py.Group | h5py.Dataset) -> None:
        for name in sorted(obj.attrs):
            attr = h5py.h5a.open(obj.id, name.encode())
            sha.update(f"@{obj.name}/{name}:{attr.get_type().encode()!r}".encode())
            sha.update(_value_bytes(_raw(obj.attrs, name)))

    def visit(name: str, obj: h5py.Group | h5py.Dataset) -> None:
        if skip(name):
            return
        sha.update(f"#{name}:{type(obj).__name__}".encode())
        attributes(obj)
        if isinstance(obj, h5py.Dataset) and _is_text(obj):
            # Text is compared as text: the script turns variable-length strings into fixed-length.
            sha.update(f"text{obj.shape}".encode())
            sha.update("\x1f".join(obj.asstr()[()].reshape(-1)).encode())
        elif isinstance(obj, h5py.Dataset):
            sha.update(f"{obj.id.get_type().encode()!r}{obj.shape}".encode())
            sha.update(_value_bytes(_raw(obj)))

    with h5py.File(path, "r") as f:
        attributes(f)
        f.visititems(visit)
    return sha.hexdigest()


def _copy_attributes(source: h5py.Group | h5py.Dataset, target: h5py.Group | h5py.Dataset) -> None:
    """Every attribute with its own HDF5 type and bytes (low level: nothing converted)."""
    for name in source.attrs:
        attr = h5py.h5a.open(source.id, name.encode())
        copy = h5py.h5a.create(target.id, name.encode(), attr.get_type(), attr.get_space())
        copy.write(_raw(source.attrs, name))


def _copy_dataset(source: h5py.Dataset, group: h5py.Group, name: str) -> None:
    """The dataset with its type, shape, compression and values, chunked, with Fletcher-32."""
    original = source.id.get_create_plist()
    plist = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    if source.shape:
        plist.set_chunk(source.chunks or tuple(max(1, n) for n in source.shape))
        filters = [original.get_filter(i)[:3] for i in range(original.get_nfilters())]
        for code, flags, values in filters:
            if code != h5py.h5z.FILTER_FLETCHER32:
                plist.set_filter(code, flags, values)
        plist.set_fletcher32()
    values = _raw(source)
    kind = source.id.get_type()
    if _is_text(source) and values.dtype.kind == "O":
        # HDF5 filters cannot check variable-length data: text becomes fixed-length UTF-8.
        encoded = [v if isinstance(v, bytes) else str(v).encode() for v in values.reshape(-1)]
        values = np.array(encoded, dtype=f"S{max([1, *map(len, encoded)])}").reshape(values.shape)
        kind = h5py.h5t.py_create(h5py.string_dtype("utf-8", values.dtype.itemsize))
    dataset = h5py.h5d.create(group.id, name.encode(), kind, source.id.get_space(), dcpl=plist)
    if values.size:
        dataset.write(h5py.h5s.ALL, h5py.h5s.ALL, values, mtype=kind)
    _copy_attributes(source, group[name])


def _copy_group(source: h5py.Group, target: h5py.Group) -> None:
    _copy_attributes(source, target)
    for name, obj in source.items():
        if isinstance(obj, h5py.Dataset):
            _copy_dataset(obj, target, name)
        else:
            _copy_group(obj, target.create_group(name))


def unchecked_datasets(path: Path) -> list[str]:
    """The datasets of ``path`` that have no Fletcher-32 filter (scalars cannot have one)."""
    missing: list[str] = []
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: missing.append(name)
                     if isinstance(obj, h5py.Dataset) and obj.shape and not obj.fletcher32 else None)
    return missing


def add_checksums(path: Path) -> None:
    """Rewrite ``path`` with Fletcher-32 on every dataset; fail (leaving it as it was) unless
    the digest of its contents is unchanged."""
    before = digest(path)
    tmp = path.with_name(path.name + ".tmp")
    try:
        with h5py.File(path, "r") as source, h5py.File(tmp, "w") as target:
            _copy_group(source, target)
        after = digest(tmp)
        if after != before or unchecked_datasets(tmp):
            raise SystemExit(f"{path}: the rewritten file differs (digest {after} != {before}); left as it was")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="only check that every dataset has the filter")
    args = parser.parse_args()
    failed = False
    for name in CATALOG:
        path = database_path(name)
        if not args.check and unchecked_datasets(path):
            add_checksums(path)
            print(f"{name}: {path}: Fletcher-32 added, contents unchanged (sha256 {digest(path)[:16]})")
        missing = unchecked_datasets(path)
        if missing:
            failed = True
            print(f"{name}: {path}: {len(missing)} datasets without Fletcher-32, e.g. {missing[0]}")
        elif args.check:
            print(f"{name}: every dataset has Fletcher-32")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
