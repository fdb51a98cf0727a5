"""Off-centre capsules in the tube (issue 7): the radial offset b of each capsule, fitted from
the up-down asymmetry of its contour.

What the 3D tube kernel shows (``--offset-mode held``, README "Off-centre capsule")
--------------------------------------------------------------------------------
The section through the tube axis and the centroid of a capsule held b off the axis is the
centred capsule's profile plus a displacement along each half's normal:

- an antisymmetric part, +b m(s) on the half towards the wall and -b m(s) on the other, first
  order in b and concentrated at the rear (the parachute's rim): measured at a/l 0.75,
  Ca_s 0.075, m agrees between b = 0.025 and 0.05 l within about 10 % (linear in b) and
  between mesh levels 2 and 3 within about 15 %;
- a symmetric part, second order in b (the flow is symmetric under b -> -b), with large
  coefficients: L_z +1.6 % and +6.3 % at b = 0.025 and 0.05 l (level 2, t = 6).

``OffcentreTable`` holds m(s) over an (a/l, Ca_s) grid, each from a held run at b0 and a
centred run on the same mesh (the mesh's own errors cancel in their difference), with the
second-order changes of L_z, L_p and v_c/V per b0**2. ``fit_offset`` fits b of one capsule
by linear least squares of its contour's antisymmetric residual against m; its standard error
comes from what the fit leaves.

Conventions: b in tube radii l, positive towards larger image y (the contour's upper half);
m(s) in l per l of offset, along the fitted meridian's normalised arclength s (front pole 0).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import h5py
import numpy as np
from scipy.interpolate import RegularGridInterpolator

from capsmech.errors import CapsmechError
from capsmech.inversion.residuals import PreparedContour

if TYPE_CHECKING:
    from capsmech.io.case import CaseResult

FORMAT = "capsmech-offcentre-table"
#: Points of the antisymmetric mode along the meridian.
MODE_POINTS = 32
#: Second-order coefficients stored per case: quantity -> history column of the case files.
SECOND_ORDER = {"L_z": "L_z", "L_p": "L_p", "vc_over_V": "v_c"}


class OffcentreError(CapsmechError, ValueError):
    """An off-centre table cannot be built or read; the message names the item."""


@dataclass(frozen=True)
class OffcentreTable:
    """Antisymmetric mode m(s) and second-order length changes on an (a/l, Ca_s) grid.

    Attributes
    ----------
    a_over_l, Ca_s : np.ndarray
        The grid's axes (sorted, each value once).
    s : np.ndarray
        Normalised arclength of the mode's points (MODE_POINTS).
    mode : np.ndarray
        (len(a_over_l), len(Ca_s), len(s)): m(s) [l per l of offset].
    second_order : dict[str, np.ndarray]
        (len(a_over_l), len(Ca_s)) change of L_z, L_p [l] and v_c/V per b**2 [1/l**2].
    b0 : float
        The offset of the held runs [l].
    source : str
        Provenance (kernel version, mesh, wall, times).
    """

    a_over_l: np.ndarray
    Ca_s: np.ndarray
    s: np.ndarray
    mode: np.ndarray
    second_order: dict[str, np.ndarray]
    b0: float
    source: str

    @cached_property
    def _interpolators(self) -> dict[str, RegularGridInterpolator]:
        """Bilinear interpolators in (a/l, log Ca_s) of the mode and of each coefficient, built
        once per table (a capsule's fit asks for them several times)."""
        axes = (self.a_over_l, np.log(self.Ca_s))
        values = {"mode": self.mode, **self.second_order}
        return {name: RegularGridInterpolator(axes, v, bounds_error=False, fill_value=np.nan)
                for name, v in values.items()}

    def outside(self, a_over_l: float, Ca_s: float) -> str:
        """Why (a/l, Ca_s) cannot be taken from the table ('' when it can)."""
        if self.contains(a_over_l, Ca_s):
            return ""
        return (f"outside the off-centre table: a/l = {a_over_l:.3f}, Ca_s = {Ca_s:.3g} (table: a/l "
                f"{self.a_over_l[0]:g}-{self.a_over_l[-1]:g}, Ca_s {self.Ca_s[0]:g}-{self.Ca_s[-1]:g})")

    def contains(self, a_over_l: float, Ca_s: float) -> bool:
        """Whether (a/l, Ca_s) lies within the grid (the table never extrapolates)."""
        return bool(self.a_over_l[0] <= a_over_l <= self.a_over_l[-1] and self.Ca_s[0] <= Ca_s <= self.Ca_s[-1])

    def clamp(self, a_over_l: float, Ca_s: float) -> tuple[float, float]:
        """The grid's point nearest (a/l, Ca_s) along each axis."""
        return (float(np.clip(a_over_l, self.a_over_l[0], self.a_over_l[-1])),
                float(np.clip(Ca_s, self.Ca_s[0], self.Ca_s[-1])))

    def mode_at(self, a_over_l: float, Ca_s: float) -> np.ndarray | None:
        """m(s) at (a/l, Ca_s), bilinear in (a/l, log Ca_s); None outside the grid."""
        if not self.contains(a_over_l, Ca_s):
            return None
        return self._interpolators["mode"]([[a_over_l, math.log(Ca_s)]])[0]

    def second_order_at(self, a_over_l: float, Ca_s: float) -> dict[str, float] | None:
        """Changes of L_z, L_p and v_c/V per b**2 at (a/l, Ca_s); None outside the grid."""
        if not self.contains(a_over_l, Ca_s):
            return None
        point = [[a_over_l, math.log(Ca_s)]]
        return {name: float(self._interpolators[name](point)[0]) for name in self.second_order}

    def write(self, path: str | Path) -> Path:
        """Write the table to HDF5, whole or not at all (temporary name, then rename)."""
        path = Path(path)
        tmp = path.with_name(path.name + ".tmp")
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = FORMAT
            f.attrs["b0"] = self.b0
            f.attrs["source"] = self.source
            for name in ("a_over_l", "Ca_s", "s", "mode"):
                f[name] = getattr(self, name)
            for name, values in self.second_order.items():
                f[f"second_order/{name}"] = values
        tmp.replace(path)
        return path

    @classmethod
    def read(cls, path: str | Path) -> OffcentreTable:
        """Read a table written by ``write``."""
        path = Path(path)
        if not path.is_file():
            raise OffcentreError(f"{path}: no such off-centre table")
        try:
            with h5py.File(path, "r") as f:
                if f.attrs.get("format") != FORMAT:
                    raise OffcentreError(f"{path}: not an off-centre table (format attribute "
                                         f"{f.attrs.get('format')!r})")
                return cls(a_over_l=f["a_over_l"][()], Ca_s=f["Ca_s"][()], s=f["s"][()], mode=f["mode"][()],
                           second_order={name: f[f"second_order/{name}"][()] for name in SECOND_ORDER},
                           b0=float(f.attrs["b0"]), source=str(f.attrs["source"]))
        except (OSError, KeyError, RuntimeError) as err:
            # A damaged file: its checksums (Fletcher-32 on the datasets, the object headers')
            # fail on read; a truncated one does not open.
            raise OffcentreError(f"{path}: damaged or not an off-centre table ({err})") from None


def antisymmetric_part(section: np.ndarray | PreparedContour, meridian: np.ndarray, points: int = MODE_POINTS
                       ) -> tuple[np.ndarray, np.ndarray]:
    """(s, A): the antisymmetric displacement of a closed section against a meridian.

    The section is folded about its axis of best mirror symmetry, as a measured contour is
    (``capsmech.inversion.residuals.PreparedContour``; pass one to fold it once for many meridians);
    A = (upper - lower) / 2 of the halves' signed normal distances from the meridian, in the
    units of the inputs.
    """
    prepared = section if isinstance(section, PreparedContour) else PreparedContour(section)
    s, upper, lower = prepared.halves(meridian, points)
    return s, 0.5 * (upper - lower)


def mode_from_cases(held: CaseResult, centred: CaseResult, points: int = MODE_POINTS) -> tuple[np.ndarray, np.ndarray, dict[str, float]]:
    """m(s) and the second-order coefficients from a held off-centre case and a centred one.

    Both are ``capsmech.io.case.CaseResult`` of the 3D tube at the same (a/l, Ca_s) and mesh; the
    held one's section through its centroid (the plane y = 0; the offset is along x) is taken
    against the centred one's meridian, so that the mesh's own errors cancel.
    """
    from capsmech.imaging.mesh_section import plane_section

    b0 = float(held.effects["offset"])
    if not b0 > 0 or centred.effects.get("offset", 0.0) != 0.0:
        raise OffcentreError(f"need a held case with offset > 0 and a centred case, got offsets {b0} and "
                             f"{centred.effects.get('offset')}")
    section = plane_section(held.mesh["nodes"], held.mesh["triangles"], normal_axis=1)
    meridian = np.column_stack([centred.profile["r"], centred.profile["z"]])
    s, antisymmetric = antisymmetric_part(section, meridian, points)
    second = {name: (float(held.history[column][-1]) - float(centred.history[column][-1])) / b0**2
              for name, column in SECOND_ORDER.items()}
    return s, antisymmetric / b0, second


def build_table(pairs: Sequence[tuple[CaseResult, CaseResult]], source: str, points: int = MODE_POINTS) -> OffcentreTable:
    """An ``OffcentreTable`` from (held, centred) case pairs filling a rectangular grid."""
    keys = [(round(float(h.a_over_l), 6), round(float(h.Ca_s), 6)) for h, _ in pairs]
    a_axis, ca_axis = sorted({k[0] for k in keys}), sorted({k[1] for k in keys})
    if len(keys) != len(set(keys)) or len(keys) != len(a_axis) * len(ca_axis):
        raise OffcentreError(f"the cases do not fill an (a/l, Ca_s) grid once: {sorted(keys)}")
    if len(a_axis) < 2 or len(ca_axis) < 2:
        raise OffcentreError("a table needs at least two values of a/l and of Ca_s")
    b0s = {float(h.effects["offset"]) for h, _ in pairs}
    if len(b0s) != 1:
        raise OffcentreError(f"the held cases have different offsets: {sorted(b0s)}")
    mode = np.empty((len(a_axis), len(ca_axis), points))
    second = {name: np.empty((len(a_axis), len(ca_axis))) for name in SECOND_ORDER}
    s = np.empty(0)
    for (held, centred), (a, ca) in zip(pairs, keys):
        i, j = a_axis.index(a), ca_axis.index(ca)
        s, mode[i, j], coefficients = mode_from_cases(held, centred, points)
        for name, value in coefficients.items():
            second[name][i, j] = value
    return OffcentreTable(a_over_l=np.array(a_axis), Ca_s=np.array(ca_axis), s=s, mode=mode,
                          second_order=second, b0=b0s.pop(), source=source)


@dataclass(frozen=True)
class OffsetFit:
    """The fitted offset of one capsule.

    Attributes
    ----------
    offset, error : float
        b [l] (positive towards the contour's upper half) and its standard error; NaN with a
        flag when it cannot be fitted.
    flag : str
        Why there is no fit ('' when there is one).
    """

    offset: float
    error: float
    flag: str = ""


def fit_offset(contour: np.ndarray | PreparedContour, meridian: np.ndarray, tube_radius: float,
               table: OffcentreTable, a_over_l: float, Ca_s: float) -> OffsetFit:
    """Fit one capsule's offset b from the antisymmetric part of its contour.

    Parameters
    ----------
    contour : np.ndarray or PreparedContour
        Measured contour (n, 2), x along the flow, in the units of ``tube_radius`` (or it
        prepared once, when it is fitted against several meridians).
    meridian : np.ndarray
        The fitted centred meridian (r, z) in the same units.
    tube_radius : float
        l in those units.
    table : OffcentreTable
        The antisymmetric modes.
    a_over_l, Ca_s : float
        The capsule's fitted parameters, where the mode is taken.

    Notes
    -----
    With A(s) the antisymmetric residual, b = sum A m / (l sum m**2) (least squares); the
    noise variance is what the fit leaves, sum (A - b l m)**2 / (n - 1), over nearly
    independent points (32 along a capsule of ~100 px: ~10 px apart), and the standard
    error of b follows from it.
    """
    mode = table.mode_at(a_over_l, Ca_s)
    if mode is None:
        return OffsetFit(math.nan, math.nan, flag=table.outside(a_over_l, Ca_s))
    _, antisymmetric = antisymmetric_part(contour, meridian, len(table.s))
    basis = tube_radius * mode
    norm = float(np.sum(basis**2))
    offset = float(np.sum(antisymmetric * basis) / norm)
    left = antisymmetric - offset * basis
    variance = float(np.sum(left**2) / (len(left) - 1))
    return OffsetFit(offset=offset, error=math.sqrt(variance / norm))


#: Relative uncertainty of the antisymmetric mode, added to the statistical error of b:
#: measured at a/l 0.75, Ca_s 0.075, the mode differs by 10-15 % between mesh levels 2 and 3,
#: and carried from the 3D kernel's capsule onto the axisymmetric model's (a different rear)
#: it gives b 13-16 % low on noise-free capsules (``offcentre_hybrid``).
MODE_RELATIVE_ERROR = 0.2


@dataclass(frozen=True)
class OffcentreCapsuleFit:
    """One capsule fitted as centred and with its fitted offset.

    ``offset`` is the offset fitted in the last round (at the (a/l, Ca_s) the round before
    gave); ``interval`` is b +- two standard
    errors, the statistical one and ``MODE_RELATIVE_ERROR`` b combined; the centred
    and corrected fits give (a/l, Ca_s, G_s) before and after.
    """

    id: str
    offset: OffsetFit
    interval: tuple[float, float]
    centred: tuple[float, float, float]
    corrected: tuple[float, float, float]
    flag: str = ""

    @property
    def summary(self) -> str:
        """One line: the offset with its interval and G_s as centred and with the offset."""
        if self.flag:
            return f"{self.id}: offset not fitted: {self.flag}"
        b, (low, high) = self.offset.offset, self.interval
        before = (f"G_s {self.centred[2]:.4g} N/m as centred (a/l {self.centred[0]:.3f}, Ca_s {self.centred[1]:.3g})"
                  if math.isfinite(self.centred[0]) else "no fit as centred (lengths outside the database)")
        return (f"{self.id}: offset b = {b:+.4f} l [{low:+.4f}, {high:+.4f}] ({abs(b) / self.offset.error:.0f} "
                f"standard errors from 0 by the contour's noise alone); {before} -> G_s "
                f"{self.corrected[2]:.4g} N/m with the offset (a/l {self.corrected[0]:.3f}, Ca_s {self.corrected[1]:.3g})")


def fit_offcentre_capsule(capsule, inverter, table: OffcentreTable, iterations: int = 3) -> OffcentreCapsuleFit:
    """Fit one tube capsule with a contour as centred, then with its offset b.

    The offset comes from the contour's antisymmetric part (``fit_offset``) at the current
    (a/l, Ca_s); the measured lengths are then corrected by the second-order changes
    (L - c b**2) and refitted, and the model's v_c/V by + c_v b**2 in G_s = mu v_c / (Ca_s
    v_c/V); a few rounds, as (a/l, Ca_s) move the mode and the coefficients.

    Parameters
    ----------
    capsule : capsmech.io.measurements.Capsule
        SI units, with a contour.
    inverter : capsmech.inversion.inverters.TubeInverter
        The base law's inverter.
    table : OffcentreTable
    iterations : int
        Rounds of offset fit and length refit (at least 1: the offset is fitted in a round).
    """
    if iterations < 1:
        raise ValueError(f"iterations: at least one round fits the offset, got {iterations}")
    nan3 = (math.nan, math.nan, math.nan)
    l = capsule["tube_radius"]
    L_z, L_p, v_c, mu = capsule["L_z"] / l, capsule["L_p"] / l, capsule["v_c"], capsule["mu"]
    if capsule.contour is None:
        return OffcentreCapsuleFit(capsule.id, OffsetFit(math.nan, math.nan), (math.nan, math.nan), nan3, nan3,
                                   "no contour: the offset is fitted from the contour")
    first = inverter.fit(L_z, L_p, v_c, mu)
    if first.ok:
        centred = (first.a_over_l, first.Ca_s, first.G_s)
        a_over_l, ca = first.a_over_l, first.Ca_s
    else:
        # The offset's elongation can take a capsule's lengths past the database as a centred
        # one (then there is no G_s before): start from the table's centre instead.
        centred = nan3
        a_over_l, ca = float(np.median(table.a_over_l)), float(np.exp(np.median(np.log(table.Ca_s))))
    offset = OffsetFit(math.nan, math.nan)
    # Folded once (its symmetry axis is a search): every round fits it against a new meridian.
    prepared = PreparedContour(capsule.contour)
    for _ in range(iterations):
        meridian = inverter.profile(a_over_l, ca)
        if meridian is None:
            return OffcentreCapsuleFit(capsule.id, offset, (math.nan, math.nan), centred, nan3,
                                       f"no database profile at a/l = {a_over_l:.3f}, Ca_s = {ca:.3g}")
        # A capsule fitted as centred looks more deformed than it is (the offset lengthens it):
        # its first (a/l, Ca_s) may lie past the table's edge, so the mode is taken at the
        # nearest grid point until the corrected fit, which must lie inside, is known.
        inside = table.clamp(a_over_l, ca)
        coefficients = table.second_order_at(*inside)
        assert coefficients is not None  # clamped into the grid
        offset = fit_offset(prepared, meridian * l, l, table, *inside)
        b2 = offset.offset**2
        refit = inverter.fit(L_z - coefficients["L_z"] * b2, L_p - coefficients["L_p"] * b2)
        if not refit.ok:
            return OffcentreCapsuleFit(capsule.id, offset, (math.nan, math.nan), centred, nan3,
                                       f"refit with the offset's length changes: {refit.flag}")
        a_over_l, ca = refit.a_over_l, refit.Ca_s
    if table.outside(a_over_l, ca):
        return OffcentreCapsuleFit(capsule.id, offset, (math.nan, math.nan), centred, nan3,
                                   table.outside(a_over_l, ca) + " with the offset")
    second_order = table.second_order_at(a_over_l, ca)
    assert second_order is not None  # inside the table: checked above
    velocity = inverter.velocity_ratio(a_over_l, ca) + second_order["vc_over_V"] * b2
    g_s = mu * v_c / (ca * velocity) if math.isfinite(v_c) and math.isfinite(mu) else math.nan
    half_width = 2.0 * math.hypot(offset.error, MODE_RELATIVE_ERROR * offset.offset)
    return OffcentreCapsuleFit(capsule.id, offset, (offset.offset - half_width, offset.offset + half_width), centred,
                               (a_over_l, ca, g_s))
