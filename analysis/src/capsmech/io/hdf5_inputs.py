"""HDF5 input files are read from their own bytes only.

An external link, a virtual dataset (its sources are other files) or a dataset in external raw
storage makes h5py open whatever file the input's author named: a database or results file
handed over by someone else could make capsmech read any file the user can. Such members are
found without following them, and the input is refused before any of its data are read.
"""
from __future__ import annotations

from typing import Any


def data_elsewhere(handle: Any) -> str | None:
    """The first member of the open HDF5 file ``handle`` whose data live in another file, said
    in words (``"'NH' is an external link to 'other.h5'"``); None when every member is local.

    Links are walked without being followed: soft links stay inside the file and are skipped,
    every object is visited once (hard links may form cycles)."""
    import h5py

    seen: set[Any] = set()
    pending = [("", handle)]
    while pending:
        prefix, group = pending.pop()
        for name in group:
            member = f"{prefix}{name}"
            link = group.get(name, getlink=True)
            if isinstance(link, h5py.ExternalLink):
                return f"{member!r} is an external link to {link.filename!r}"
            if not isinstance(link, h5py.HardLink):
                continue
            item = group[name]
            if item.id in seen:
                continue
            seen.add(item.id)
            if isinstance(item, h5py.Group):
                pending.append((member + "/", item))
            elif isinstance(item, h5py.Dataset) and item.is_virtual:
                # A source named '.' is this file itself.
                sources = sorted({source.file_name for source in item.virtual_sources()} - {"."})
                if sources:
                    return f"{member!r} is a virtual dataset of {', '.join(map(repr, sources))}"
            elif isinstance(item, h5py.Dataset) and item.external:
                return f"{member!r} is stored in external files"
    return None
