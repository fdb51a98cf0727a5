"""Assembling a grid's case files into a database file (``capsmech database assemble``, the
workflow's last step per flow); the file's layout is described in :mod:`capsmech.io.database`,
which reads it."""
from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from capsmech.imaging.mesh_section import SectionError, plane_section
from capsmech.io.case import EFFECT_DEFAULTS, CaseResult, decode_str
from capsmech.io.database import (
    ACCURACY_COLUMNS,
    CRITICAL_GROUP,
    DUCT_LENGTH_SCALE,
    FORMAT,
    FORMAT_VERSION,
    LENGTH_SCALE,
    PARAMETERS,
    PROFILES,
    RESULTS,
    TEXT_COLUMNS,
    DatabaseError,
    expected_units,
    mesh_error_rel,
)
from capsmech.version import __version__
from capsmech.workflow.grid import (
    Branch,
    Case,
    case_level,
    expand_branches,
    expand_cases,
    flow_settings,
    grid_json,
    mesh_check_cases,
    mesh_check_rows,
    parse_law,
)
from capsmech.workflow.runner import read_outcome


def database_identity(grid: Mapping[str, Any], flow: str) -> dict[str, Any]:
    """Return the identity a grid gives its ``flow`` database: name, version, accuracy.

    Parameters
    ----------
    grid : mapping
        The validated grid; its optional ``<flow>.database`` holds ``name``, ``version`` and
        ``accuracy``.
    flow : str
        'tube' or 'shear'.

    Returns
    -------
    dict
        ``name`` (default ``'<flow>-<grid name>'``), ``version`` (default 1) and
        ``accuracy`` (default ``'not stated by grid <grid name>'``).
    """
    given = grid.get(flow, {}).get("database", {})
    return {"name": str(given.get("name", f"{flow}-{grid['name']}")),
            "version": int(given.get("version", 1)),
            "accuracy": str(given.get("accuracy", f"not stated by grid {grid['name']}"))}


def resample_by_arclength(x: np.ndarray, y: np.ndarray, n: int, closed: bool) -> np.ndarray:
    """Resample a polyline to ``n`` points equally spaced in arclength.

    Parameters
    ----------
    x, y : numpy.ndarray
        Coordinates of the polyline's points, in order.
    n : int
        Number of output points.
    closed : bool
        True for a closed contour (the segment back to the first point counts, and the
        first point is not repeated); False for an open curve (both ends kept).

    Returns
    -------
    numpy.ndarray
        Shape (2, n): resampled x and y.
    """
    points = np.column_stack([x, y]).astype(float)
    if closed:
        points = np.vstack([points, points[:1]])
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    targets = np.linspace(0.0, s[-1], n, endpoint=not closed)
    return np.vstack([np.interp(targets, s, points[:, 0]), np.interp(targets, s, points[:, 1])])


def mid_plane_meridian(nodes: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A 3D capsule's outline in the plane y = 0, its half x >= 0 from the front pole to the rear
    pole: the database profile of a 3D tube or duct case.

    The kernel's own ``/profile`` of a 3D case keeps the membrane nodes near the plane, and
    loses a pole whose node lies just off it (measured on duct-dev: the front pole of 9 of its
    54 steady rows missing, their outline 0.008-0.031 w short at the front and ending 0.08-0.15 w
    off the axis; the rear pole of 10, their outline ending 0.08-0.12 w off the axis on the
    parachute's flank, short of its depth by 0.007-0.011 w). The section of the membrane mesh by
    the plane, ``capsmech.imaging.mesh_section.plane_section``, is the outline a microscope
    focused there sees, poles included, and what a measured contour is compared with.

    Parameters
    ----------
    nodes : (n, 3) array
        Membrane node positions [l]; the flow is along +z.
    triangles : (m, 3) int array
        The membrane's triangles (0-based).

    Returns
    -------
    r, z : numpy.ndarray
        The half-outline's points (x, z) [l], from the front pole (the larger z on the axis x = 0)
        to the rear pole; both poles are where the section crosses x = 0.

    Raises
    ------
    SectionError
        If the plane does not cut the membrane in one closed curve, or that curve does not
        cross the axis x = 0 exactly twice.
    """
    z, x = plane_section(nodes, triangles, normal_axis=1).T
    ahead = x >= 0.0
    following = np.roll(np.arange(len(x)), -1)
    crossing = np.flatnonzero(ahead != ahead[following])
    if len(crossing) != 2:
        raise SectionError(f"the outline in the plane y = 0 crosses the axis x = 0 {len(crossing)} times, not twice")

    def on_axis(k: int) -> tuple[float, float]:
        j = following[k]
        weight = x[k] / (x[k] - x[j])
        return 0.0, float(z[k] + weight * (z[j] - z[k]))

    first, second = (int(k) for k in crossing)
    inside = np.arange(first + 1, second + 1) if ahead[following[first]] else \
        np.arange(second + 1, first + 1 + len(x)) % len(x)
    start, end = (first, second) if ahead[following[first]] else (second, first)
    half = np.vstack([on_axis(start), np.column_stack([x[inside], z[inside]]), on_axis(end)])
    # A node on the axis gives its crossing twice: keep each point once.
    keep = np.concatenate([[True], np.any(np.diff(half, axis=0) != 0.0, axis=1)])
    half = half[keep]
    if half[0, 1] < half[-1, 1]:
        half = half[::-1]
    return half[:, 0].copy(), half[:, 1].copy()


def _check_case_matches(case: Case, result: CaseResult, path: Path) -> None:
    """Fail when a case file is not the run the grid asks for (wrong file in the place)."""
    expected = parse_law(case.law.key)
    pairs = [("flow", case.flow, result.flow), ("law", expected.name, result.law)]
    mismatch = [f"{name} {found!r}, grid wants {want!r}" for name, want, found in pairs if want != found]
    numbers = [("Ca_s", case.Ca_s, result.Ca_s)]
    if case.a_over_l is not None:
        numbers.append(("a_over_l", case.a_over_l, result.a_over_l))
    if expected.nu_s is not None:
        numbers.append(("nu_s", expected.nu_s, result.nu_s))
    if expected.C is not None:
        numbers.append(("C", expected.C, result.C))
    wanted_effects = case.effects
    for name, neutral in EFFECT_DEFAULTS.items():
        numbers.append((name, wanted_effects.get(name, neutral), result.effects.get(name, neutral)))
    mismatch += [f"{name} {found!r}, grid wants {want!r}" for name, want, found in numbers
                 if not math.isclose(want, found, rel_tol=1e-12, abs_tol=1e-15)]
    if case.flow == "tube":
        mismatch += _channel_mismatch(case, path)
    if mismatch:
        raise DatabaseError(f"{path}: not the case of the grid: " + "; ".join(mismatch))


def _channel_mismatch(case: Case, path: Path) -> list[str]:
    """A tube case file's channel against the grid's (a file without one is the circular tube's)."""
    settings = dict(case.settings)
    want = (str(settings.get("channel", "tube")), float(settings.get("aspect", 1.0)))
    with h5py.File(path, "r") as f:
        found = (decode_str(f.attrs.get("channel", "tube")), float(f.attrs.get("aspect", 1.0)))
    if found[0] != want[0] or not math.isclose(found[1], want[1], rel_tol=1e-12):
        return [f"channel {found[0]} aspect {found[1]:g}, grid wants {want[0]} aspect {want[1]:g}"]
    return []


def _read_case_file(case: Case, cases_dir: Path, what: str) -> tuple[str, str, str, CaseResult | None]:
    """``read_outcome`` of the case's file, checked to be the grid's case; ``what`` names the
    file in the message when it is missing."""
    path = cases_dir / case.relative_path
    if not path.is_file():
        raise DatabaseError(f"{path}: {what} missing (run the workflow to compute it)")
    status, message, code_version, result = read_outcome(path)
    if result is not None:
        _check_case_matches(case, result, path)
    return status, message, code_version, result


def _steady(result: CaseResult | None, source: str) -> float:
    """A case's steady value of ``source``, NaN unless it is steady."""
    return result.steady_value(source) if result is not None and result.is_steady else math.nan


def _mesh_accuracy(case: Case, coarse: CaseResult | None, companion: Case, finer: CaseResult | None,
                   rows_from: str) -> dict[str, float]:
    """A shear row's mesh columns from its two levels: the other level's D12, the estimated
    relative mesh error of the row's D12 (of the coarse or of the finer value) and the row's
    level; the error is NaN unless both levels are steady."""
    d12_coarse, d12_finer = _steady(coarse, "D12"), _steady(finer, "D12")
    use_finer = rows_from == "finer" and not math.isnan(d12_finer)
    levels = case_level(companion) - case_level(case)
    return {"mesh_level": float(case_level(companion) if use_finer else case_level(case)),
            "D12_mesh_check": d12_coarse if use_finer else d12_finer,
            "D12_mesh_error_rel": float(mesh_error_rel(d12_coarse, d12_finer, levels,
                                                       of="finer" if use_finer else "coarse"))}


def _tube_mesh_accuracy(case: Case, own: CaseResult | None, companion: Case, other: CaseResult | None,
                        orders: Mapping[str, float]) -> dict[str, float]:
    """A 3D tube row's mesh columns (its values are its own level's): per result column the
    companion level's value and the estimated relative mesh error of the row's value, Richardson
    with that column's observed order (of the finer value where the companion is coarser, of the
    coarser value where it is finer); NaN unless both levels are steady."""
    apart = case_level(companion) - case_level(case)
    columns: dict[str, float] = {"mesh_level": float(case_level(case))}
    for name, (source, _, _) in RESULTS["tube"].items():
        mine, check = _steady(own, source), _steady(other, source)
        coarse, finer = (check, mine) if apart < 0 else (mine, check)
        columns[f"{name}_mesh_check"] = check
        columns[f"{name}_mesh_error_rel"] = float(mesh_error_rel(coarse, finer, abs(apart), of="finer" if apart < 0
                                                                 else "coarse", order=float(orders[name])))
    return columns


def _case_row(case: Case, cases_dir: Path, points: int, companion: Case | None = None,
              rows_from: str = "coarse", orders: Mapping[str, float] | None = None) -> dict[str, Any]:
    """Read one case file (or failure record) into a database row; a shear case with a mesh
    check (``companion``, the same case on a finer level) takes its values from the finer
    level when ``rows_from`` is ``'finer'`` and that run is steady, else from its own level; a
    tube case with a mesh check keeps its own level's values, its error estimated with ``orders``
    (``tube.mesh_check.orders``)."""
    path = cases_dir / case.relative_path
    status, message, code_version, result = _read_case_file(case, cases_dir, "case file")
    flow = case.flow
    row: dict[str, Any] = {name: getattr(case, attr) for name, (attr, _) in PARAMETERS[flow].items()}
    names, _ = PROFILES[flow]
    row.update({name: math.nan for name in RESULTS[flow]})
    row.update({f"profile_{c}": np.full(points, np.nan) for c in names})
    row.update({name: math.nan for name in ACCURACY_COLUMNS[flow]})
    if companion is not None:
        finer_status, finer_message, finer_version, finer = _read_case_file(companion, cases_dir, "mesh-check case file")
        if finer_version != code_version:
            raise DatabaseError(f"{cases_dir / companion.relative_path}: written by kernel {finer_version}, "
                                f"its case {path} by {code_version}: rerun the workflow")
        if flow == "tube":
            row.update(_tube_mesh_accuracy(case, result, companion, finer, orders or {}))
        else:
            row.update(_mesh_accuracy(case, result, companion, finer, rows_from))
        if flow == "shear" and rows_from == "finer" and finer is not None and finer.is_steady:
            path, status, message, result = cases_dir / companion.relative_path, finer_status, finer_message, finer
        elif flow == "shear" and rows_from == "finer":
            message = (f"level {case_level(companion)} {finer_status} ({finer_message}); "
                       f"values of level {case_level(case)}: {message}")
    elif flow == "shear" or dict(case.settings).get("model") == "3d":
        row["mesh_level"] = float(case_level(case))
    row.update(status=status, message=message, code_version=code_version,
               wall_time_s=math.nan if result is None else result.wall_time_s)
    if result is None or status != "steady":
        return row
    if flow == "shear":
        row["D12_time_error_rel"] = result.time_error_rel
    for name, (source, unit, _) in RESULTS[flow].items():
        found = result.unit(f"steady/{source}")
        if found != unit:
            raise DatabaseError(f"{path}: '/steady/{source}' has units {found!r}, expected {unit!r}")
        row[name] = result.steady_value(source)
    for c in names:
        if result.unit(f"profile/{c}") != PROFILES[flow][1]:
            raise DatabaseError(f"{path}: '/profile/{c}' has units {result.unit(f'profile/{c}')!r}, "
                                f"expected {PROFILES[flow][1]!r}")
    if flow == "tube" and "triangles" in result.mesh:
        try:
            r, z = mid_plane_meridian(result.mesh["nodes"], result.mesh["triangles"])
        except SectionError as exc:
            raise DatabaseError(f"{path}: the membrane mesh gives no outline in the plane y = 0 ({exc})") from None
    else:
        r, z = result.profile[names[0]], result.profile[names[1]]
    resampled = resample_by_arclength(r, z, points, closed=flow == "shear")
    row.update({f"profile_{c}": resampled[i] for i, c in enumerate(names)})
    return row


def _write_dataset(group: h5py.Group, name: str, data: Any, units: str, text: bool | None = None) -> None:
    """Write one dataset with its ``units`` attribute and HDF5's Fletcher-32 checksum.

    Text (``text``, by default the columns of TEXT_COLUMNS) is fixed-length UTF-8 (as long as
    its longest entry): HDF5 cannot checksum variable-length data, and a reader decodes both alike.
    """
    if name in TEXT_COLUMNS if text is None else text:
        encoded = [str(text).encode() for text in data]
        values = np.array(encoded, dtype=f"S{max([1, *map(len, encoded)])}")
        dtype = h5py.string_dtype("utf-8", values.dtype.itemsize)
        ds = group.create_dataset(name, shape=values.shape, dtype=dtype, fletcher32=True)
        # The bytes are UTF-8 already: written as the file's type (numpy's are ASCII to h5py).
        ds.id.write(h5py.h5s.ALL, h5py.h5s.ALL, values, mtype=ds.id.get_type())
    else:
        ds = group.create_dataset(name, data=np.asarray(data, dtype=float), fletcher32=True)
    ds.attrs["units"] = units


def critical_rows(branches: Sequence[Branch], branches_dir: Path, code_version: str) -> dict[str, dict[str, list]]:
    """Per law key, the critical Ca_s of each branch's a/l from its branch file (NaN where the
    branch did not end inside the grid or failed; the kind says which, the message how).

    Raises
    ------
    DatabaseError
        If a branch file is missing, is not a branch file, or was written by another kernel
        than ``code_version`` (the rows' kernel)."""
    rows: dict[str, dict[str, list]] = {}
    for branch in branches:
        path = branches_dir / branch.relative_path
        if not path.is_file():
            raise DatabaseError(f"{path}: branch file missing (run the workflow to compute it)")
        try:
            with h5py.File(path, "r") as f:
                critical = float(f.attrs["critical_Ca_s"])
                kind = f.attrs["critical_kind"]
                version = f.attrs["code_version"]
                message = f.attrs.get("critical_message", kind)
        except (OSError, KeyError) as exc:
            raise DatabaseError(f"{path}: not a branch file of capsim --branch-ca ({exc})") from None
        kind, version, message = decode_str(kind), decode_str(version), decode_str(message)
        if version != code_version:
            raise DatabaseError(f"{path}: written by kernel {version}, the cases by {code_version}: "
                                "rerun the workflow so that every case is recomputed by one kernel")
        law = rows.setdefault(branch.law.key, {"a_over_l": [], "Ca_s": [], "kind": [], "message": []})
        law["a_over_l"].append(branch.a_over_l)
        law["Ca_s"].append(critical)
        law["kind"].append(kind)
        law["message"].append(message)
    return rows


#: How the critical Ca_s of a database are found (the ``method`` of its ``critical`` groups).
CRITICAL_METHOD = ("pseudo-arclength continuation of the steady equations in Ca_s "
                   "(capsim --branch-ca over the grid's Ca_s); NaN: no end inside the grid's Ca_s")


def write_critical_group(group: h5py.Group, rows: Mapping[str, Sequence[Any]],
                         attrs: Mapping[str, Any] | None = None) -> None:
    """Write a law group's ``critical`` group (``a_over_l``, ``Ca_s``, ``kind`` and, where
    given, the kernel's ``message`` per a/l), with the method and ``attrs`` as attributes."""
    ends = group.create_group(CRITICAL_GROUP)
    ends.attrs["method"] = CRITICAL_METHOD
    ends.attrs.update(dict(attrs or {}))
    _write_dataset(ends, "a_over_l", rows["a_over_l"], "1")
    _write_dataset(ends, "Ca_s", rows["Ca_s"], "1")
    _write_dataset(ends, "kind", rows["kind"], "", text=True)
    if "message" in rows:
        _write_dataset(ends, "message", rows["message"], "", text=True)


def _channel_attrs(settings: Mapping[str, Any]) -> dict[str, Any]:
    """A tube database's channel, aspect and length scale (a duct's lengths are in its half-width)."""
    channel = str(settings.get("channel", "tube"))
    attrs: dict[str, Any] = {"channel": channel, "aspect": float(settings.get("aspect", 1.0))}
    if channel != "tube":
        attrs["length_scale"] = DUCT_LENGTH_SCALE
    return attrs


def assemble_database(grid: Mapping[str, Any], flow: str, cases_dir: str | Path, out: str | Path,
                      *, created: str | None = None, branches_dir: str | Path | None = None) -> Path:
    """Assemble the case files of one flow of a grid into a database file.

    Parameters
    ----------
    grid : mapping
        The validated grid (see :mod:`capsmech.workflow.grid`).
    flow : str
        'tube' or 'shear'.
    cases_dir : str or Path
        Directory holding ``<flow>/<law>/<case>.h5``.
    out : str or Path
        Database file to write (``OUT.tmp`` first, renamed when complete).
    created : str, optional
        Creation time recorded in the provenance; default now (UTC, ISO 8601).
    branches_dir : str or Path, optional
        Directory holding ``tube/<law>/a<a/l>.h5``, the branch files of a grid computed by
        continuation (``tube.settings.branch``): each law group gets a ``critical`` group with
        the critical Ca_s where its steady branch ends, per a/l.

    Returns
    -------
    Path
        The database file.

    Raises
    ------
    DatabaseError
        If a case file is missing, is not the grid's case, has unexpected units, or the
        cases were written by different kernel versions.
    """
    cases = expand_cases(grid, flow)
    if not cases:
        raise DatabaseError(f"grid {grid['name']!r} has no {flow} cases")
    points = int(grid.get("profile_points", 64))
    cases_dir, out = Path(cases_dir), Path(out)
    rows: dict[str, list[dict[str, Any]]] = {}
    companions = mesh_check_cases(grid)
    rows_from = mesh_check_rows(grid)
    orders = grid[flow].get("mesh_check", {}).get("orders")
    for case in cases:
        rows.setdefault(case.law.key, []).append(
            _case_row(case, cases_dir, points, companions.get(case.relative_path), rows_from, orders))
    versions = sorted({row["code_version"] for law_rows in rows.values() for row in law_rows})
    if len(versions) != 1:
        raise DatabaseError(f"{cases_dir}: {flow} cases were written by several kernel versions {versions}: "
                            "rerun the workflow so that every case is recomputed by one kernel")
    critical = (critical_rows(expand_branches(grid), Path(branches_dir), versions[0])
                if branches_dir is not None and flow == "tube" else {})
    units = expected_units(flow)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    with h5py.File(tmp, "w") as f:
        f.attrs.update({
            **database_identity(grid, flow),
            "format": FORMAT, "format_version": FORMAT_VERSION, "flow": flow,
            "grid_name": grid["name"], "grid": grid_json(grid),
            "settings": json.dumps(flow_settings(grid, flow), sort_keys=True),
            "code_version": versions[0],
            "created": created or datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "case_count": len(cases), "profile_points": points,
            "capsmech_version": __version__, "length_scale": LENGTH_SCALE[flow],
        })
        if flow == "tube":
            f.attrs.update(_channel_attrs(flow_settings(grid, flow)))
        effects = {case.law.key: case.effects for case in cases}
        for key, law_rows in rows.items():
            law = parse_law(key)
            group = f.create_group(key)
            group.attrs.update({
                "law": law.name,
                "nu_s": math.nan if law.nu_s is None else law.nu_s,
                "C": math.nan if law.C is None else law.C,
                **{name: effects[key].get(name, neutral) for name, neutral in EFFECT_DEFAULTS.items()},
                "case_count": len(law_rows),
                "steady_count": sum(row["status"] == "steady" for row in law_rows),
            })
            for name, unit in units.items():
                _write_dataset(group, name, [row[name] for row in law_rows], unit)
            if key in critical:
                write_critical_group(group, critical[key])
    os.replace(tmp, out)
    return out
