"""Read and validate the HDF5 case files written by the ``capsim`` kernel.

Case file layout (schema version 1)
-----------------------------------
Root attributes
    ``schema_version`` (int), ``code_version`` (str), ``flow`` ('shear' | 'tube'),
    ``law`` ('NH' | 'SK' | 'GH'), ``nu_s``, ``C``, ``a_over_l`` (may be absent for
    shear flow), ``Ca_s``, ``mesh_level`` (int), ``dt``, ``status`` ('steady' |
    'continuous_elongation' | 'max_time' | 'failed'), ``message`` (str),
    ``wall_time_s``, ``threads`` (int).
``/history``
    1-D datasets of equal length: ``t``, ``area``, ``volume``, ``D12``, ``L1``, ...
``/steady``
    Scalar datasets (``D12``, ``L1``, ``theta``, ``t``, ...); may be absent or
    empty when ``status != 'steady'``.
``/mesh``
    ``reference_nodes`` and ``nodes`` of shape (n, 3) float, ``triangles`` of
    shape (m, 3) int, 0-based (attribute ``index_base = 0`` on ``triangles``).
``/profile``
    1-D ``y`` and ``z``: the capsule contour in the shear plane x = 0, ordered
    by angle.

Every dataset carries a ``units`` string attribute.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from capsmech.errors import CapsmechError
from capsmech.io.laws import KERNEL_LAWS

#: The only case-file schema version this reader understands.
SCHEMA_VERSION = 1

FLOWS = ("shear", "tube")
LAWS = KERNEL_LAWS
STATUSES = ("steady", "continuous_elongation", "max_time", "failed")

#: Root attributes every case file must carry (``a_over_l`` is optional for shear flow).
REQUIRED_ATTRS = (
    "schema_version",
    "code_version",
    "flow",
    "law",
    "nu_s",
    "C",
    "Ca_s",
    "mesh_level",
    "dt",
    "status",
    "message",
    "wall_time_s",
    "threads",
)

_STR_ATTRS = ("code_version", "flow", "law", "status", "message")
_INT_ATTRS = ("schema_version", "mesh_level", "threads")
_FLOAT_ATTRS = ("nu_s", "C", "Ca_s", "dt", "wall_time_s")
#: How the kernel's message of a steady tube case ends when its Newton polish after time
#: stepping stalled or found an unstable shape: the row is then no root of the steady equations.
POLISH_DISCARDED = "and was discarded"


def polish_discarded(message: str) -> bool:
    """Whether a case's message says that its Newton polish was discarded (at its end: a case
    the workflow reran says first why, then gives the rerun's own outcome)."""
    return message.rstrip().endswith(POLISH_DISCARDED)


#: Effects beyond the base model (issue 6): root attribute -> its neutral value, which a case
#: file written before the effect existed implicitly has.
EFFECT_DEFAULTS = {"prestress": 0.0, "lambda": 1.0, "kb": 0.0, "offset": 0.0}
#: Root attribute of an effect whose name differs from the effect's (law key) name.
EFFECT_ATTRS = {"kb": "k_b"}


class CaseFileError(CapsmechError, ValueError):
    """A case file is missing pieces, malformed, truncated or not HDF5.

    The message always names the file and what is wrong with it.
    """


class NotSteadyError(CapsmechError, RuntimeError):
    """A steady-state value was requested from a case that did not reach steady state."""


@dataclass(frozen=True, eq=False, repr=False)
class CaseResult:
    """One capsim run, as read from its case file.

    Attributes
    ----------
    flow : str
        Background flow, 'shear' or 'tube'.
    law : str
        Membrane law: 'NH' (neo-Hookean), 'SK' (Skalak) or 'GH' (generalised Hooke).
    nu_s : float
        Surface Poisson ratio [-].
    C : float
        Area-dilatation parameter of the Skalak law [-].
    Ca_s : float
        Capillary number, viscous over elastic forces [-].
    a_over_l : float
        Capsule radius over tube radius [-]; NaN when absent (shear flow).
    mesh_level : int
        Icosahedral subdivision level of the membrane mesh [-].
    dt : float
        Time step [units of the ``t`` history dataset].
    status : str
        'steady', 'continuous_elongation', 'max_time' or 'failed'.
    message : str
        Human-readable explanation of ``status``.
    code_version : str
        Version of the kernel that wrote the file.
    schema_version : int
        Case-file schema version (always :data:`SCHEMA_VERSION`).
    wall_time_s : float
        Wall-clock time of the run [s].
    threads : int
        Number of OpenMP threads used.
    history : dict[str, numpy.ndarray]
        Time series, 1-D arrays of equal length (read-only), keyed by name.
    steady : dict[str, float]
        Steady-state scalars; always empty unless ``status == 'steady'``.
    profile : dict[str, numpy.ndarray]
        Shear-plane contour: 1-D ``y`` and ``z`` (read-only); empty if absent.
    mesh : dict[str, numpy.ndarray]
        ``reference_nodes``, ``nodes`` (n, 3) and 0-based ``triangles`` (m, 3)
        (read-only); empty if absent.
    units : dict[str, str]
        Units of every dataset, keyed by its path without the leading slash,
        e.g. ``'steady/D12'``.
    path : str
        File the case was read from.
    effects : dict[str, float]
        Effects beyond the base model (``EFFECT_DEFAULTS``: pre-stress alpha, viscosity ratio
        lambda, bending stiffness kb from the attribute ``k_b``), their neutral values when the
        file does not record them.
    time_error_rel : float
        Shear, steady: the estimated relative change of D12 still to come after the run stopped
        (attribute ``time_error_rel``, kernel 0.3.2 on); NaN when the file does not record it.
    """

    flow: str
    law: str
    nu_s: float
    C: float
    Ca_s: float
    a_over_l: float
    mesh_level: int
    dt: float
    status: str
    message: str
    code_version: str
    schema_version: int
    wall_time_s: float
    threads: int
    history: dict[str, np.ndarray]
    steady: dict[str, float]
    profile: dict[str, np.ndarray]
    mesh: dict[str, np.ndarray]
    units: dict[str, str] = field(default_factory=dict)
    path: str = ""
    effects: dict[str, float] = field(default_factory=dict)
    time_error_rel: float = math.nan

    @property
    def is_steady(self) -> bool:
        """bool: True when the run reached a steady state."""
        return self.status == "steady"

    def steady_value(self, name: str) -> float:
        """Return one steady-state scalar.

        Parameters
        ----------
        name : str
            Name of a dataset in ``/steady``, e.g. ``'D12'``.

        Returns
        -------
        float
            The value, in the units given by :meth:`unit` (``'steady/<name>'``).

        Raises
        ------
        NotSteadyError
            If the run did not reach steady state (names status and message).
        KeyError
            If the case is steady but has no such value.
        """
        if not self.is_steady:
            raise NotSteadyError(
                f"{self.path or 'case'}: no steady value {name!r}: the run did not reach "
                f"steady state (status={self.status!r}: {self.message})"
            )
        if name not in self.steady:
            raise KeyError(
                f"{self.path or 'case'}: no steady value {name!r}; "
                f"available: {', '.join(sorted(self.steady)) or 'none'}"
            )
        return self.steady[name]

    def unit(self, key: str) -> str:
        """Return the units of a dataset.

        Parameters
        ----------
        key : str
            Dataset path without leading slash, e.g. ``'history/t'``.

        Returns
        -------
        str
            Its ``units`` attribute, or ``''`` if the dataset does not exist.
        """
        return self.units.get(key.lstrip("/"), "")

    def __repr__(self) -> str:
        return (
            f"CaseResult(path={self.path!r}, flow={self.flow!r}, law={self.law!r}, "
            f"Ca_s={self.Ca_s!r}, status={self.status!r})"
        )


# ---------------------------------------------------------------------------
# Small pure helpers: decoding HDF5 values
# ---------------------------------------------------------------------------


def decode_str(value: Any) -> str:
    """Decode an HDF5 string value, whatever form h5py returns it in.

    Parameters
    ----------
    value : str, bytes, numpy.bytes_, numpy.str_ or 1-element numpy.ndarray
        Raw attribute value (fixed- or variable-length, ASCII or UTF-8).

    Returns
    -------
    str
        The text, with trailing NULs and blanks (Fortran padding) removed.

    Raises
    ------
    TypeError
        If ``value`` is not a single string.
    """
    if isinstance(value, np.ndarray):
        if value.size != 1:
            raise TypeError(f"expected a single string, got an array of shape {value.shape}")
        value = value.reshape(-1)[0]
    if isinstance(value, (bytes, np.bytes_)):
        value = bytes(value).decode("utf-8", errors="replace")
    if not isinstance(value, str):
        raise TypeError(f"expected a string, got {type(value).__name__}")
    return str(value).rstrip("\x00 ")


def to_scalar(value: Any) -> float | int:
    """Convert a numeric HDF5 scalar (or 1-element array) to a Python number.

    Parameters
    ----------
    value : Any
        Raw attribute or dataset value.

    Returns
    -------
    float or int
        ``int`` for integer data, ``float`` otherwise.

    Raises
    ------
    TypeError
        If ``value`` is not a single real number.
    """
    arr = np.asarray(value)
    if arr.size != 1:
        raise TypeError(f"expected a single number, got shape {arr.shape}")
    if arr.dtype.kind in "iu":
        return int(arr.reshape(-1)[0])
    if arr.dtype.kind == "f":
        return float(arr.reshape(-1)[0])
    raise TypeError(f"expected a number, got dtype {arr.dtype}")


def to_int(value: Any) -> int:
    """Convert an HDF5 integer value (an integral float is accepted) to ``int``.

    Raises
    ------
    TypeError
        If ``value`` is not a single integral number.
    """
    number = to_scalar(value)
    if isinstance(number, float):
        if not number.is_integer():
            raise TypeError(f"expected an integer, got {number!r}")
        return int(number)
    return number


def _readonly(array: np.ndarray) -> np.ndarray:
    """Return ``array`` flagged read-only (CaseResult is immutable)."""
    array.setflags(write=False)
    return array


# ---------------------------------------------------------------------------
# Validation of an open file
# ---------------------------------------------------------------------------


def _collect_units(f: h5py.File, where: str) -> dict[str, str]:
    """Return the units of every dataset in the file; fail on a dataset without them."""
    datasets: list[tuple[str, h5py.Dataset]] = []

    def visit(name: str, obj: Any) -> None:
        if isinstance(obj, h5py.Dataset):
            datasets.append((name, obj))

    f.visititems(visit)
    units: dict[str, str] = {}
    for name, ds in datasets:
        if "units" not in ds.attrs:
            raise CaseFileError(f"{where}: dataset '/{name}' has no 'units' attribute")
        try:
            units[name] = decode_str(ds.attrs["units"])
        except TypeError as exc:
            raise CaseFileError(f"{where}: dataset '/{name}': 'units' attribute: {exc}") from exc
    return units


def _read_root_attrs(attrs: Mapping[str, Any], where: str) -> dict[str, Any]:
    """Check and decode the root attributes; name the first bad or missing one."""
    for name in REQUIRED_ATTRS:
        if name not in attrs:
            raise CaseFileError(f"{where}: missing required root attribute '{name}'")
    out: dict[str, Any] = {}
    converters = (
        [(n, decode_str) for n in _STR_ATTRS]
        + [(n, to_int) for n in _INT_ATTRS]
        + [(n, lambda v: float(to_scalar(v))) for n in _FLOAT_ATTRS]
    )
    for name, convert in converters:
        try:
            out[name] = convert(attrs[name])
        except TypeError as exc:
            raise CaseFileError(f"{where}: root attribute '{name}': {exc}") from exc
    if out["schema_version"] != SCHEMA_VERSION:
        raise CaseFileError(
            f"{where}: root attribute 'schema_version' is {out['schema_version']}, "
            f"this reader understands only {SCHEMA_VERSION}"
        )
    for name, allowed in (("flow", FLOWS), ("law", LAWS), ("status", STATUSES)):
        if out[name] not in allowed:
            raise CaseFileError(
                f"{where}: root attribute '{name}' is {out[name]!r}, expected one of {allowed}"
            )
    if "a_over_l" in attrs:
        try:
            out["a_over_l"] = float(to_scalar(attrs["a_over_l"]))
        except TypeError as exc:
            raise CaseFileError(f"{where}: root attribute 'a_over_l': {exc}") from exc
    elif out["flow"] == "tube":
        raise CaseFileError(f"{where}: missing root attribute 'a_over_l' (required for tube flow)")
    else:
        out["a_over_l"] = math.nan
    return out


def _group_datasets(f: h5py.File, group: str) -> dict[str, h5py.Dataset]:
    """Return the datasets directly in ``group`` (empty when the group is absent)."""
    if group not in f:
        return {}
    return {k: v for k, v in f[group].items() if isinstance(v, h5py.Dataset)}


def _read_history(f: h5py.File, where: str) -> dict[str, np.ndarray]:
    """Read ``/history``: numeric 1-D arrays of one common length, including ``t``."""
    datasets = _group_datasets(f, "history")
    if not datasets:
        return {}
    if "t" not in datasets:
        raise CaseFileError(f"{where}: '/history' has no time dataset 't'")
    history: dict[str, np.ndarray] = {}
    n_t = datasets["t"].shape
    for name, ds in datasets.items():
        if ds.ndim != 1 or ds.dtype.kind not in "iuf":
            raise CaseFileError(f"{where}: dataset '/history/{name}' must be a 1-D numeric array")
        if ds.shape != n_t:
            raise CaseFileError(
                f"{where}: dataset '/history/{name}' has length {ds.shape[0]}, "
                f"but '/history/t' has length {n_t[0]}"
            )
        history[name] = _readonly(np.asarray(ds[()]))
    return history


def _read_steady(f: h5py.File, where: str, status: str) -> dict[str, float]:
    """Read ``/steady`` scalars; empty unless the run is steady (then it must not be)."""
    datasets = _group_datasets(f, "steady")
    if status != "steady":
        return {}
    if not datasets:
        raise CaseFileError(f"{where}: status is 'steady' but '/steady' is missing or empty")
    steady: dict[str, float] = {}
    for name, ds in datasets.items():
        if ds.shape not in ((), (1,)) or ds.dtype.kind not in "iuf":
            raise CaseFileError(
                f"{where}: dataset '/steady/{name}' must be a numeric scalar, got shape {ds.shape}"
            )
        steady[name] = float(to_scalar(ds[()]))
    return steady


def _check_xyz(ds: h5py.Dataset, name: str, where: str) -> np.ndarray:
    """Return a (n, 3) float array, with a hint when it looks transposed (Fortran order)."""
    if ds.ndim != 2 or ds.shape[1] != 3 or ds.dtype.kind not in "f":
        hint = " (looks transposed: (3, n) instead of (n, 3))" if ds.shape[:1] == (3,) else ""
        raise CaseFileError(
            f"{where}: dataset '/mesh/{name}' must be float of shape (n, 3), "
            f"got {ds.dtype} {ds.shape}{hint}"
        )
    return _readonly(np.asarray(ds[()]))


def _read_meridian_mesh(datasets: dict[str, h5py.Dataset], where: str) -> dict[str, np.ndarray]:
    """Read the axisymmetric ``/mesh``: reference and current meridians, (n, 2) of (r, z)."""
    out: dict[str, np.ndarray] = {}
    for name in ("reference_meridian", "meridian"):
        if name not in datasets:
            raise CaseFileError(f"{where}: '/mesh' has no dataset '{name}'")
        ds = datasets[name]
        if ds.ndim != 2 or ds.shape[1] != 2 or ds.dtype.kind not in "f":
            raise CaseFileError(
                f"{where}: dataset '/mesh/{name}' must be float of shape (n, 2), got {ds.dtype} {ds.shape}"
            )
        out[name] = _readonly(np.asarray(ds[()]))
    if out["meridian"].shape != out["reference_meridian"].shape:
        raise CaseFileError(f"{where}: '/mesh/meridian' and '/mesh/reference_meridian' differ in shape")
    return out


def _read_mesh(f: h5py.File, where: str, flow: str = "shear") -> dict[str, np.ndarray]:
    """Read ``/mesh``: nodes, reference nodes and 0-based triangles (3D), or meridians (tube,
    axisymmetric), checked for consistency."""
    datasets = _group_datasets(f, "mesh")
    if not datasets:
        return {}
    if flow == "tube" and "meridian" in datasets:
        return _read_meridian_mesh(datasets, where)
    for name in ("reference_nodes", "nodes", "triangles"):
        if name not in datasets:
            raise CaseFileError(f"{where}: '/mesh' has no dataset '{name}'")
    nodes = _check_xyz(datasets["nodes"], "nodes", where)
    reference = _check_xyz(datasets["reference_nodes"], "reference_nodes", where)
    if nodes.shape != reference.shape:
        raise CaseFileError(
            f"{where}: '/mesh/nodes' {nodes.shape} and '/mesh/reference_nodes' "
            f"{reference.shape} differ in shape"
        )
    tri_ds = datasets["triangles"]
    if tri_ds.ndim != 2 or tri_ds.shape[1] != 3 or tri_ds.dtype.kind not in "iu":
        raise CaseFileError(
            f"{where}: dataset '/mesh/triangles' must be integer of shape (m, 3), "
            f"got {tri_ds.dtype} {tri_ds.shape}"
        )
    if "index_base" not in tri_ds.attrs:
        raise CaseFileError(f"{where}: dataset '/mesh/triangles' has no 'index_base' attribute")
    base = to_scalar(tri_ds.attrs["index_base"])
    if base != 0:
        raise CaseFileError(f"{where}: '/mesh/triangles' attribute 'index_base' is {base}, expected 0")
    triangles = _readonly(np.asarray(tri_ds[()]))
    if triangles.size and (triangles.min() < 0 or triangles.max() >= nodes.shape[0]):
        raise CaseFileError(
            f"{where}: '/mesh/triangles' indices span [{triangles.min()}, {triangles.max()}], "
            f"outside [0, {nodes.shape[0] - 1}] for {nodes.shape[0]} nodes"
        )
    return {"reference_nodes": reference, "nodes": nodes, "triangles": triangles}


def _read_profile(f: h5py.File, where: str, flow: str = "shear") -> dict[str, np.ndarray]:
    """Read ``/profile``: 1-D ``y`` and ``z`` (shear plane) or ``r`` and ``z`` (tube meridian)
    of equal length."""
    datasets = _group_datasets(f, "profile")
    if not datasets:
        return {}
    first = "r" if flow == "tube" and "r" in datasets else "y"
    for name in (first, "z"):
        if name not in datasets:
            raise CaseFileError(f"{where}: '/profile' has no dataset '{name}'")
        ds = datasets[name]
        if ds.ndim != 1 or ds.dtype.kind not in "f":
            raise CaseFileError(f"{where}: dataset '/profile/{name}' must be a 1-D float array")
    if datasets[first].shape != datasets["z"].shape:
        raise CaseFileError(
            f"{where}: '/profile/{first}' {datasets[first].shape} and '/profile/z' "
            f"{datasets['z'].shape} differ in length"
        )
    return {name: _readonly(np.asarray(datasets[name][()])) for name in (first, "z")}


def _read_open_case(f: h5py.File, where: str) -> CaseResult:
    """Validate and read an open case file."""
    attrs = _read_root_attrs(f.attrs, where)
    units = _collect_units(f, where)
    return CaseResult(
        flow=attrs["flow"],
        law=attrs["law"],
        nu_s=attrs["nu_s"],
        C=attrs["C"],
        Ca_s=attrs["Ca_s"],
        a_over_l=attrs["a_over_l"],
        mesh_level=attrs["mesh_level"],
        dt=attrs["dt"],
        status=attrs["status"],
        message=attrs["message"],
        code_version=attrs["code_version"],
        schema_version=attrs["schema_version"],
        wall_time_s=attrs["wall_time_s"],
        threads=attrs["threads"],
        history=_read_history(f, where),
        steady=_read_steady(f, where, attrs["status"]),
        profile=_read_profile(f, where, attrs["flow"]),
        mesh=_read_mesh(f, where, attrs["flow"]),
        units=units,
        path=where,
        effects={name: float(to_scalar(f.attrs[attr])) if attr in f.attrs else default
                 for name, default in EFFECT_DEFAULTS.items() for attr in (EFFECT_ATTRS.get(name, name),)},
        time_error_rel=float(to_scalar(f.attrs["time_error_rel"])) if "time_error_rel" in f.attrs else math.nan,
    )


def require_hdf5_file(path: Path, kind: str, error: type[Exception]) -> str:
    """Return ``str(path)`` after checking that it is an existing HDF5 file.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist (the message says ``kind not found``).
    Exception
        ``error`` if the file is not HDF5 (empty, truncated or another format).
    """
    where = str(path)
    if not path.is_file():
        raise FileNotFoundError(f"{kind} not found: {where}")
    if not h5py.is_hdf5(path):
        raise error(f"{where}: not an HDF5 file (empty, truncated or another format)")
    return where


def read_case(path: str | Path) -> CaseResult:
    """Read and validate one capsim case file.

    Parameters
    ----------
    path : str or Path
        The HDF5 case file.

    Returns
    -------
    CaseResult
        The validated, immutable contents.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    CaseFileError
        If the file is not HDF5, is truncated or corrupt, has a schema version
        other than :data:`SCHEMA_VERSION`, lacks a required attribute or
        group member, or has a dataset without ``units``. The message names
        the file and the offending attribute or dataset.
    """
    p = Path(path)
    where = require_hdf5_file(p, "case file", CaseFileError)
    try:
        with h5py.File(p, "r") as f:
            return _read_open_case(f, where)
    except CaseFileError:
        raise
    except (OSError, KeyError, RuntimeError, ValueError) as exc:
        raise CaseFileError(f"{where}: cannot read HDF5 case file (truncated or corrupt?): {exc}") from exc
