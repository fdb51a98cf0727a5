"""Fit measured capsules against the shipped databases: the API that ``capsmech fit-tube``
and ``capsmech fit-shear`` wrap.

``fit_tube(capsules, database, laws)`` returns one result row per (capsule, law): the five
fits of paper section 4.2 reduced to a mean and a spread (half the range of the valid fits)
for a/l, Ca_s, v_c/V and G_s (where the capsule states its tube radius's uncertainty,
``tube_radius_sigma``, what the fits at l +- sigma_l move a/l, Ca_s and G_s by is added to the
spreads in quadrature, and G_s's share is ``G_s_tube_radius_error``), the number of valid fits, where the capsule has a contour its
misfit H/a at the central fit and the law's best shape on it (``a_over_l_shape``,
``Ca_s_shape``, ``H_over_a_shape``, and ``G_s_shape``, ``Delta_shape`` there: the contour fit of
``capsmech.inversion.shape_fit``; ``chi2_shape``, the contour's chi2 there against its own
tracing noise, 14 degrees of freedom when the law's shape is the capsule's; ``G_s_shape_error``,
the contour fit's own uncertainty of ``G_s_shape`` (one standard deviation, from the fitted
point's covariance, ``capsmech.inversion.shape_fit``: it grows with the capsule's tracing noise;
the velocity's error is not in it); ``tracing_noise``, the contour's noise measured about a
smooth curve (``capsmech.io.contours.contour_tracing_noise``), which also sets the asymmetry
flag's limit;
``G_s_database_error``, what the database's own accuracy moves G_s by: NaN
where the law fits no lengths, the contour is asymmetric or the fit ends on the database's
edge), and a flag with its reason when the
capsule cannot be fitted (outside the database, no valid fit): ``flag`` is a short code
(``FLAG_CODES``; empty when the capsule is fitted) and ``reason`` says why in words.
``fit_shear`` does the same from D12 (paper section 4.3), with ``G_s_spread`` from D12's
stated uncertainty (``D12_err``) where the capsule has one. Rows are plain dicts of floats and
strings, in SI units (G_s in N/m), ready for ``write_results`` (CSV and HDF5, written whole or
not at all); the public API (``capsmech.fit_tube``) turns them into a DataFrame.
"""
from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from tqdm import tqdm

from capsmech.inversion.inverters import (
    FIVE_FITS,
    FiveFits,
    ShearInverter,
    TubeFit,
    TubeFits,
    TubeInverter,
    TubeTable,
    profile_elongation,
)
from capsmech.inversion.noise import MODEL_FLOOR_REL
from capsmech.inversion.residuals import size_residual, velocity_residual
from capsmech.inversion.shape_fit import COVARIANCE_STEP, ShapeFit, fit_shape
from capsmech.inversion.sharp_edge import interpolated_accuracy, is_steady_root, smooth_accuracy
from capsmech.inversion.tube_batch import fit_batch
from capsmech.io.atomic import atomic_path
from capsmech.io.contours import (
    MAX_ASYMMETRY,
    MAX_H_OVER_A,
    contour_asymmetry,
    contour_tracing_noise,
    profile_misfit,
)
from capsmech.io.database import Database, DatabaseError, ShearDatabase, TubeDatabase
from capsmech.io.measurements import Capsule

#: Result columns and their units.
TUBE_RESULT_UNITS = {"id": "", "law": "", "L_z_over_l": "1", "L_p_over_l": "1",
                     "a_over_l": "1", "a_over_l_spread": "1", "Ca_s": "1", "Ca_s_spread": "1",
                     "vc_over_V": "1", "G_s": "N/m", "G_s_spread": "N/m", "G_s_tube_radius_error": "N/m",
                     "a": "m", "Delta": "1",
                     "valid_fits": "1", "H_over_a": "1", "a_over_l_shape": "1",
                     "Ca_s_shape": "1", "H_over_a_shape": "1", "G_s_shape": "N/m", "Delta_shape": "1",
                     "chi2_shape": "1", "G_s_shape_error": "N/m", "tracing_noise": "m",
                     "G_s_database_error": "N/m", "asymmetry": "1", "size_residual": "1",
                     "size_residual_error": "1", "vc_residual": "1", "vc_residual_error": "1",
                     "critical_Ca_s": "1", "Ca_s_over_critical": "1", "flag": "", "reason": ""}
SHEAR_RESULT_UNITS = {"id": "", "law": "", "D12": "1", "D12_err": "1", "Ca_s": "1", "L3_over_a": "1", "a": "m",
                      "G_s": "N/m", "G_s_spread": "N/m", "G_s_database_error": "N/m", "flag": "", "reason": ""}

#: The codes of a result row's ``flag`` column (empty: fitted), and what each means.
FLAG_CODES = {
    "invalid_input": "the measured values cannot describe a capsule (e.g. L_p >= L_z, D12 outside [0, 1))",
    "outside_database": "no steady simulation of the law reproduces the measured lengths or D12",
    "central_fit_outside": "the central of the five fits is outside the database (the others are not)",
    "asymmetric": "the contour's two halves differ: not an axisymmetric capsule on the axis",
    "profile_misfit": "the fitted simulation does not have the measured shape (H/a above the limit)",
    "no_velocity": "no v_c or mu: (a/l, Ca_s) fitted, G_s not computed",
    "imprecise": "D12 below the method's limit (paper section 4.3: 0.35)",
    "above_fold": "the fitted Ca_s lies above the law's critical Ca_s at the fitted a/l: no steady shape there",
}


def inverter_flag_code(reason: str) -> str:
    """The ``FLAG_CODES`` code of an inverter's flag text (``TubeFit.flag``, ``ShearFit.flag``)."""
    if reason.startswith(("invalid", "need D12")):
        return "invalid_input"
    if "too imprecise" in reason:
        return "imprecise"
    return "outside_database"


def tube_inverter(database: TubeDatabase, law: str) -> TubeInverter:
    """The tube inverter of one law, on the database's steady rows (each marked a root of the
    steady equations or not, from the kernel's message: ``sharp_edge.is_steady_root``)."""
    table = database.law(law)
    rows = table.steady_rows()
    root = np.array([is_steady_root(str(m)) for m in table.message[table.steady]], dtype=bool)
    try:
        return TubeInverter(TubeTable(a_over_l=rows["a_over_l"], Ca_s=rows["Ca_s"], L_z=rows["L_z"],
                                      L_p=rows["L_p"], vc_over_V=rows["vc_over_V"],
                                      profile_r=rows.get("profile_r"), profile_z=rows.get("profile_z"), root=root,
                                      L_z_error_rel=rows.get("L_z_mesh_error_rel"),
                                      L_p_error_rel=rows.get("L_p_mesh_error_rel")))
    except DatabaseError as err:
        raise _naming_database(err, database, law) from None


def shear_inverter(database: ShearDatabase, law: str) -> ShearInverter:
    """The shear inverter of one law, on the database's steady rows."""
    rows = database.law(law).steady_rows()
    try:
        return ShearInverter(rows["Ca_s"], rows["D12"], rows["L3_over_a"], D12_error_rel=database_d12_error(rows))
    except DatabaseError as err:
        raise _naming_database(err, database, law) from None


def _naming_database(err: DatabaseError, database: Database, law: str) -> DatabaseError:
    """The inverter's error with the database (name and file) and the law in front: the
    inverter sees rows, and every command that builds one (fit-tube, diagnose, population)
    must say which database they came from. Of several seen as one (diagnose's base and effect
    databases: ``databases``, each law taken from the first that holds it), the one holding the
    law. Unchanged when it names the file already, or when no file is known."""
    holder = next((member for member in getattr(database, "databases", ()) if law in member.laws), database)
    if getattr(holder, "path", None) is None:
        return err
    name, path = str(getattr(holder, "name", "") or ""), str(holder.path)
    if path in str(err):
        return err
    label = f"{name} ({path})" if name and name != path else path
    return DatabaseError(f"{label}, law {law}: {err}")


def database_d12_error(rows: dict[str, np.ndarray]) -> np.ndarray:
    """The relative error of each steady shear row's D12 that the database states: its time
    error and, where the grid had a mesh check, its estimated mesh error, in quadrature (NaN
    where the database states neither)."""
    time, mesh = rows["D12_time_error_rel"], rows["D12_mesh_error_rel"]
    stated = np.isfinite(time) | np.isfinite(mesh)
    return np.where(stated, np.hypot(np.nan_to_num(time), np.nan_to_num(mesh)), np.nan)


def fit_tube_rows(capsules: Sequence[Capsule], database: TubeDatabase, laws: Iterable[str] | None = None,
                  progress: bool = False) -> list[dict[str, Any]]:
    """Fit every capsule with every law (all the database's laws by default).

    Parameters
    ----------
    capsules : sequence of Capsule
        Measured capsules in SI units (``capsmech.io.measurements.read_measurements(..., 'tube')``).
    database : TubeDatabase
        A loaded tube database.
    laws : iterable of str, optional
        Law keys to fit with.

    Returns
    -------
    list of dict
        One row per (capsule, law), columns as in ``TUBE_RESULT_UNITS``.
    progress : bool
        Show a progress bar (tqdm, on stderr) when fitting takes more than a moment.
    """
    laws = list(laws) if laws is not None else list(database.laws)
    inverters = {law: tube_inverter(database, law) for law in laws}
    five = _five_fits_many(capsules, inverters)
    radius_moved = _tube_radius_fits_many(capsules, inverters)
    rows = []
    for k, capsule in enumerate(tqdm(capsules, desc="fitting", unit="capsule", disable=not progress, leave=False)):
        l = capsule["tube_radius"]
        l_z, l_p = capsule["L_z"] / l, capsule["L_p"] / l
        v_c, mu = capsule["v_c"], capsule["mu"]
        has_velocity = math.isfinite(v_c) and math.isfinite(mu)
        # The contour's symmetry does not depend on the law: measured once per capsule, over
        # the radius of the capsule's volume-equivalent size estimated from the contour itself.
        asymmetry, asymmetry_limit, axis_y = float("nan"), MAX_ASYMMETRY, None
        tracing_noise = float("nan")
        if capsule.contour is not None:
            asymmetry, asymmetry_limit, axis_y = contour_asymmetry(capsule.contour, capsule["pixel_size"])
            tracing_noise = contour_tracing_noise(capsule.contour)
        for law in laws:
            fits = FiveFits({name: five[law].row(j * len(capsules) + k)
                             for j, (name, _, _) in enumerate(FIVE_FITS)})
            row: dict[str, Any] = {"id": capsule.id, "law": law, "L_z_over_l": l_z, "L_p_over_l": l_p,
                                   "a_over_l": fits.mean("a_over_l"), "a_over_l_spread": fits.spread("a_over_l"),
                                   "Ca_s": fits.mean("Ca_s"), "Ca_s_spread": fits.spread("Ca_s"),
                                   "vc_over_V": fits.mean("vc_over_V"), "G_s": fits.mean("G_s"),
                                   "G_s_spread": fits.spread("G_s"), "G_s_tube_radius_error": float("nan"),
                                   "a": fits.mean("a_over_l") * l,
                                   "Delta": float("nan"), "valid_fits": fits.n_valid,
                                   "H_over_a": float("nan"), "a_over_l_shape": float("nan"),
                                   "Ca_s_shape": float("nan"), "H_over_a_shape": float("nan"),
                                   "G_s_shape": float("nan"), "Delta_shape": float("nan"), "chi2_shape": float("nan"),
                                   "G_s_shape_error": float("nan"), "tracing_noise": tracing_noise,
                                   "G_s_database_error": float("nan"), "asymmetry": asymmetry,
                                   "size_residual": float("nan"), "size_residual_error": float("nan"),
                                   "vc_residual": float("nan"), "vc_residual_error": float("nan"), "flag": "",
                                   "reason": ""}
            central = fits.fits["fit1"]
            if k in radius_moved[law]:
                _add_tube_radius_error(row, fits, *radius_moved[law][k])
            meridian = inverters[law].profile(central.a_over_l, central.Ca_s) if central.ok else None
            if meridian is not None:
                row["Delta"] = profile_elongation(meridian, central.a_over_l)
                if capsule.contour is not None:
                    misfit, _ = profile_misfit(capsule.contour, meridian * l, axis_y)
                    row["H_over_a"] = misfit / (central.a_over_l * l)
                    # Its uncertainty: the contour's (two halves) and the fitted a's (five fits).
                    residual, contour_error = size_residual(capsule.contour, central.a_over_l * l)
                    row["size_residual"] = residual
                    row["size_residual_error"] = math.hypot(contour_error, row["a_over_l_spread"] / central.a_over_l)
            if capsule.contour is not None and fits.n_valid > 0 and not asymmetry > asymmetry_limit:
                # The law's best shape on the contour (what population compares laws by),
                # from the central fit, or the valid fits' mean where the central one failed.
                start = ((central.a_over_l, central.Ca_s) if central.ok
                         else (fits.mean("a_over_l"), fits.mean("Ca_s")))
                shape = fit_shape(capsule.contour, inverters[law], l, start, axis_y, length=capsule["L_z"],
                                  frames_noise=capsule["contour_noise"])
                row["a_over_l_shape"], row["Ca_s_shape"] = shape.a_over_l, shape.Ca_s
                row["H_over_a_shape"], row["chi2_shape"] = shape.H_over_a, shape.chi2
                if shape.ok:
                    # G_s and Delta at the best shape: the contour pins (a/l, Ca_s) far better
                    # than the lengths' 2 % once the law is right. population reads them where
                    # chi2_shape lets it test the shapes against the noise (without that test a
                    # wrong nearby law's best shapes absorb what it lacks and its G_s stops
                    # drifting: docs/validation/inversion.md).
                    a_shape, ca_shape = shape.a_over_l, shape.Ca_s
                    row["Delta_shape"] = shape.Delta
                    if has_velocity:
                        row["G_s_shape"] = mu * v_c / (ca_shape * inverters[law].velocity_ratio(a_shape,
                                                                                                             ca_shape))
                        row["G_s_shape_error"] = row["G_s_shape"] * shape_log_g_s_error(inverters[law], shape)
            if central.ok and has_velocity:
                row["G_s_database_error"] = database_g_s_error(inverters[law], l_z, l_p, v_c, mu, central)
            if central.ok and math.isfinite(capsule["V"]) and math.isfinite(v_c):
                row["vc_residual"], row["vc_residual_error"] = velocity_residual(
                    v_c / capsule["V"], fits.mean("vc_over_V"), fits.spread("vc_over_V"))
            # An asymmetric contour comes first: it says why every fit of it is doubtful.
            if asymmetry > asymmetry_limit:
                row["flag"], row["reason"] = "asymmetric", (
                    f"asymmetric contour: its halves differ by {asymmetry:.4f} a (> {asymmetry_limit:.4f} a, "
                    "the largest of 1 % of a, one pixel and twice the contour's tracing noise), not an axisymmetric "
                    "centred capsule")
            elif fits.n_valid == 0:
                row["reason"] = fits.fits["fit1"].flag or "no valid fit"
                row["flag"] = inverter_flag_code(row["reason"])
            elif not fits.fits["fit1"].ok:
                row["flag"], row["reason"] = "central_fit_outside", "central fit: " + fits.fits["fit1"].flag
            elif row["H_over_a"] > MAX_H_OVER_A:
                row["flag"], row["reason"] = "profile_misfit", (
                    f"profile misfit: H/a = {row['H_over_a']:.3f} > {MAX_H_OVER_A} "
                    "(the fitted simulation does not have the measured shape)")
            elif not has_velocity:
                row["flag"], row["reason"] = "no_velocity", "no v_c or mu: G_s not computed"
            rows.append(row)
    return rows


#: How far above the recorded fold a fit must lie to be flagged: the fold itself moves by 3-5 %
#: between 64, 96 and 128 meridian elements (docs/validation/databases.md), so a fit closer to it
#: than that cannot be told to lie past it.
FOLD_RELATIVE_ACCURACY = 0.05


def add_fold_columns(rows: list[dict[str, Any]], database: TubeDatabase) -> None:
    """State, in each fit-tube row, the law's critical Ca_s at the fitted a/l (``critical_Ca_s``,
    from the database's ``critical`` group; NaN where it records none there) and the fitted
    Ca_s over it (``Ca_s_over_critical``: below 1, the fit lies on the steady branch). A fitted
    row above it by more than the fold's own accuracy (FOLD_RELATIVE_ACCURACY) is flagged
    ``above_fold``: past the fold the law has no steady shape (the
    capsule elongates without end), so no steady capsule has those parameters."""
    for row in rows:
        critical, kind = database.law(str(row["law"])).critical_at(float(row["a_over_l"]))
        ratio = float(row["Ca_s"]) / critical if math.isfinite(critical) else math.nan
        row["critical_Ca_s"], row["Ca_s_over_critical"] = critical, ratio
        if ratio > 1 + FOLD_RELATIVE_ACCURACY and row["flag"] in ("", "no_velocity"):
            row["flag"], row["reason"] = "above_fold", (
                f"fitted Ca_s {float(row['Ca_s']):.4g} is above {row['law']}'s critical Ca_s {critical:.4g} at a/l "
                f"{float(row['a_over_l']):.3f} ({kind}): the law has no steady shape there, the capsule could not "
                "be steady")


def shape_log_g_s_error(inverter: TubeInverter, shape: ShapeFit) -> float:
    """The contour fit's standard deviation of ln G_s: G_s = mu v_c / (Ca_s v_c/V(a/l, Ca_s)),
    so d ln G_s = -d ln Ca_s - d ln(v_c/V), propagated from the fitted point's covariance
    (NaN without one)."""
    if shape.covariance is None:
        return math.nan
    a, ca = shape.a_over_l, shape.Ca_s
    step = COVARIANCE_STEP
    ratio = [math.log(inverter.velocity_ratio(a + da, ca * math.exp(dc)))
             for da, dc in ((step, 0.0), (-step, 0.0), (0.0, step), (0.0, -step))]
    gradient = np.array([-(ratio[0] - ratio[1]) / (2 * step), -1.0 - (ratio[2] - ratio[3]) / (2 * step)])
    variance = float(gradient @ shape.covariance @ gradient)
    return math.sqrt(variance) if math.isfinite(variance) and variance >= 0 else math.nan


def database_g_s_shifts(inverter: TubeInverter, L_z: float, L_p: float, v_c: float, mu: float,
                        fit: TubeFit) -> tuple[float, float, float]:
    """The changes of a capsule's G_s [N/m] (that of ``fit``, the inverter's fit of these
    lengths) when the database's L_z, then its L_p, then its v_c/V are off by their accuracy,
    an error every capsule of a batch shares (NaN where the refit fails). Lengths in l. The
    accuracy is that of the rows the capsule's fit is
    interpolated between (``capsmech.inversion.sharp_edge.interpolated_accuracy``): 0.1 % of
    L_z on smooth shapes (64 against 128 meridian elements), up to 1.6 % of L_z, 6.5 % of L_p
    and 0.6 % of v_c/V where the parachute's edge is a corner (``capsmech.inversion.sharp_edge``)."""
    g_s = fit.G_s
    rows = inverter.triangle_turns(fit.a_over_l, fit.Ca_s) if fit.ok else None
    # Outside the triangles (or without profiles): the smooth profiles' accuracy, the
    # databases' statement.
    z_rel, p_abs, vc_rel = (interpolated_accuracy(rows[0], rows[1], rows[2], L_p, roots=rows[3])
                            if rows is not None else smooth_accuracy(L_p))
    shifts = []
    for moved in ((L_z * (1 + z_rel), L_p), (L_z, L_p + max(p_abs, MODEL_FLOOR_REL * L_z))):
        other = inverter.fit(*moved, v_c, mu)
        shifts.append(other.G_s - g_s if other.ok and math.isfinite(other.G_s) else math.nan)
    # G_s = mu v_c / (Ca_s v_c/V): an error of v_c/V moves it by the same fraction.
    shifts.append(g_s * vc_rel)
    return shifts[0], shifts[1], shifts[2]


def database_g_s_error(inverter: TubeInverter, L_z: float, L_p: float, v_c: float, mu: float, fit: TubeFit) -> float:
    """How far the database's own accuracy moves a capsule's G_s [N/m]: the three
    ``database_g_s_shifts`` in quadrature (the diagnosis's measure,
    ``capsmech.diagnosis.scoring.length_g_s_with_systematic``, per capsule), for both of
    fit-tube's G_s: the contour fits match the same profiles."""
    return math.hypot(*database_g_s_shifts(inverter, L_z, L_p, v_c, mu, fit))


def _tube_radius_fits_many(capsules: Sequence[Capsule], inverters: dict[str, TubeInverter]
                           ) -> dict[str, dict[int, tuple[FiveFits, FiveFits]]]:
    """The five fits of every capsule that states its tube radius's uncertainty sigma_l
    (``tube_radius_sigma``, finite and positive), redone with the radius at l + sigma_l and at
    l - sigma_l: ``result[law][k]`` is that pair for capsule k, the fits a refit of the capsule
    with its tube radius moved would give. The lengths are measured in l, so an error of l
    moves L_z/l and L_p/l together, as no fit of the five does. Capsules without the column
    are not refitted."""
    moved = [k for k, c in enumerate(capsules)
             if math.isfinite(c["tube_radius_sigma"]) and c["tube_radius_sigma"] > 0]
    if not moved:
        return {law: {} for law in inverters}
    chosen = [capsules[k] for k in moved]
    l = np.array([c["tube_radius"] for c in chosen], dtype=float)
    sigma = np.array([c["tube_radius_sigma"] for c in chosen], dtype=float)
    wider, narrower = _five_fits_many(chosen, inverters, l + sigma), _five_fits_many(chosen, inverters, l - sigma)
    return {law: {k: (_five_of(wider[law], j, len(chosen)), _five_of(narrower[law], j, len(chosen)))
                  for j, k in enumerate(moved)} for law in inverters}


def _five_of(fits: TubeFits, k: int, capsules: int) -> FiveFits:
    """Capsule k's five fits out of ``_five_fits_many``'s result for ``capsules`` capsules."""
    return FiveFits({name: fits.row(j * capsules + k) for j, (name, _, _) in enumerate(FIVE_FITS)})


def _add_tube_radius_error(row: dict[str, Any], fits: FiveFits, wider: FiveFits, narrower: FiveFits) -> None:
    """Add what the tube radius's uncertainty moves a/l, Ca_s and G_s by (the means of the
    five fits, ``fits`` at l, ``wider`` and ``narrower`` at l +- sigma_l) to their spreads, in
    quadrature, and write G_s's share in ``G_s_tube_radius_error``: half the change between
    l + sigma_l and l - sigma_l (one standard deviation), or the change from l of the side that
    has a valid fit where the other leaves the database (spreads unchanged where neither is
    known)."""
    for name, spread in (("a_over_l", "a_over_l_spread"), ("Ca_s", "Ca_s_spread"), ("G_s", "G_s_spread")):
        ends = [value for value in (wider.mean(name), narrower.mean(name)) if math.isfinite(value)]
        if len(ends) == 2:
            change = 0.5 * abs(ends[0] - ends[1])
        elif len(ends) == 1 and math.isfinite(fits.mean(name)):
            change = abs(ends[0] - fits.mean(name))
        else:
            continue
        if math.isfinite(row[spread]):
            row[spread] = math.hypot(row[spread], change)
        if name == "G_s":
            row["G_s_tube_radius_error"] = change


def _five_fits_many(capsules: Sequence[Capsule], inverters: dict[str, TubeInverter],
                    tube_radius: np.ndarray | None = None) -> dict[str, TubeFits]:
    """The five fits of every capsule with every law, in one ``fit_batch`` call per law
    (``TubeInverter.fit_many``'s result, faster: ``capsmech.inversion.tube_batch``):
    ``result[law].row(j * len(capsules) + k)`` is fit j of ``FIVE_FITS`` for capsule k, what
    ``inverters[law].five_fits`` gives (v_c and mu only where both are finite); lengths in
    ``tube_radius`` where given (one per capsule), else in each capsule's own."""
    l = (np.array([c["tube_radius"] for c in capsules], dtype=float) if tube_radius is None
         else np.asarray(tube_radius, dtype=float))
    l_z = np.array([c["L_z"] for c in capsules], dtype=float) / l
    l_p = np.array([c["L_p"] for c in capsules], dtype=float) / l
    v_c = np.array([c["v_c"] for c in capsules], dtype=float)
    mu = np.array([c["mu"] for c in capsules], dtype=float)
    # NaN gives G_s = NaN, as fit does without v_c and mu.
    has_velocity = np.isfinite(v_c) & np.isfinite(mu)
    v_c, mu = np.where(has_velocity, v_c, np.nan), np.where(has_velocity, mu, np.nan)
    five_z = np.concatenate([l_z * fz for _, fz, _ in FIVE_FITS])
    five_p = np.concatenate([l_p * fp for _, _, fp in FIVE_FITS])
    n_fits = len(FIVE_FITS)
    return {law: fit_batch(inverter, five_z, five_p, np.tile(v_c, n_fits), np.tile(mu, n_fits))
            for law, inverter in inverters.items()}


def fit_shear_rows(capsules: Sequence[Capsule], database: ShearDatabase, laws: Iterable[str] | None = None
                   ) -> list[dict[str, Any]]:
    """Fit every sheared capsule (semi-axes L1, L2, shear rate, viscosity) with every law.

    Where the capsule states D12's uncertainty (``D12_err``), ``G_s_spread`` is the largest
    change of G_s between the fit and the refits at D12 - D12_err and D12 + D12_err
    (``shear_g_s_spread``), so that G_s +- G_s_spread holds both; NaN without the column, or
    where neither refit is inside the database.
    """
    laws = list(laws) if laws is not None else list(database.laws)
    inverters = {law: shear_inverter(database, law) for law in laws}
    rows = []
    for capsule in capsules:
        l1, l2 = capsule["L1"], capsule["L2"]
        d12_err = capsule["D12_err"]
        for law in laws:
            fit = inverters[law].fit(L1=l1, L2=l2, shear_rate=capsule["shear_rate"], mu=capsule["mu"])
            spread = math.nan
            if fit.ok and math.isfinite(d12_err):
                spread = shear_g_s_spread(inverters[law], capsule, fit.G_s)
            rows.append({"id": capsule.id, "law": law, "D12": (l1 - l2) / (l1 + l2), "D12_err": d12_err,
                         "Ca_s": fit.Ca_s, "L3_over_a": fit.L3_over_a, "a": fit.a, "G_s": fit.G_s,
                         "G_s_spread": spread, "G_s_database_error": fit.G_s * fit.database_error_rel,
                         "flag": inverter_flag_code(fit.flag) if fit.flag else "", "reason": fit.flag})
    return rows


def shear_g_s_spread(inverter: ShearInverter, capsule: Capsule, g_s: float) -> float:
    """The largest change of a sheared capsule's G_s [N/m] (``g_s``, its fit) when D12 moves by
    its stated uncertainty ``D12_err`` either way, with the ellipse's area (sqrt(L1 L2), what the
    outline pins best) kept: the refits go through the shear inverter (Ca_s and L3/a, hence a,
    at the moved D12). NaN where neither moved D12 is inside the database."""
    size = math.sqrt(capsule["L1"] * capsule["L2"])
    d12 = (capsule["L1"] - capsule["L2"]) / (capsule["L1"] + capsule["L2"])
    changes = []
    for moved in (d12 - capsule["D12_err"], d12 + capsule["D12_err"]):
        if not 0 <= moved < 1:
            continue
        ratio = math.sqrt((1 + moved) / (1 - moved))
        other = inverter.fit(L1=size * ratio, L2=size / ratio, shear_rate=capsule["shear_rate"], mu=capsule["mu"])
        if other.ok and math.isfinite(other.G_s):
            changes.append(abs(other.G_s - g_s))
    return max(changes) if changes else math.nan


def write_results(rows: Sequence[dict[str, Any]], units: dict[str, str], out: str | Path,
                  provenance: Database | None = None) -> Path:
    """Write result rows to ``out`` (.csv: units in the header; .h5: one dataset per column
    with a ``units`` attribute), through a temporary file renamed when complete."""
    out = Path(out)
    if out.suffix not in (".csv", ".h5", ".hdf5"):
        raise ValueError(f"{out}: results go to .csv or .h5")
    with atomic_path(out) as tmp:
        if out.suffix == ".csv":
            with open(tmp, "w", newline="", encoding="utf-8") as stream:
                writer = csv.writer(stream)
                writer.writerow([f"{k} [{u}]" if u else k for k, u in units.items()])
                for row in rows:
                    writer.writerow([_cell(row[k]) for k in units])
        else:
            with h5py.File(tmp, "w", track_order=True) as f:
                # The column order, for readers that list datasets by name (capsmech.io.results).
                f.attrs["columns"] = list(units)
                for key, unit in units.items():
                    values = [row[key] for row in rows]
                    if unit == "":
                        data = np.array([str(v) for v in values], dtype=h5py.string_dtype())
                    else:
                        data = np.array(values, dtype=float)
                    ds = f.create_dataset(key, data=data)
                    ds.attrs["units"] = unit
                if provenance is not None:
                    f.attrs["database"] = str(provenance.path)
                    f.attrs["database_code_version"] = str(provenance.provenance.get("code_version", ""))
    return out


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.6g}"
    return str(value)
