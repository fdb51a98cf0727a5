"""The shape a law's database reaches on a measured contour: the contour fit behind the law
comparison of ``capsmech.inversion.population`` (issue 19, item 1).

Why not the misfit at the length fit
------------------------------------
``fit-tube``'s ``H_over_a`` is the contour misfit of the law's profile at the parameters
(a/l, Ca_s) fitted to the *lengths* L_z, L_p. Those carry a measurement error of about 2 %
(the paper's), far coarser than the contour's tracing noise (about 0.005 a): the length
fit's parameters miss the capsule's, and the profile there misses the contour by much more
than the law's shapes need to. Measured on the shipped GH nu_s = 0.5 batch with the right law
(``results/issue19_law``, median over the 12 capsules, H/a):

====================================================  ======
profile at the fitted (lengths) parameters             0.0107
database profile at the true parameters                0.0046
kernel profile (exact) at the true parameters          0.0046
database profile against the exact one, no noise       0.0007
contour fit (this module)                              0.0047
====================================================  ======

So the misfit at the length fit is dominated by the lengths' error carried into the
parameters, neither by the tracing noise nor by the database's interpolation (leaving a Ca_s
node out of the database and interpolating it from its neighbours, at twice the grid's
spacing, misses it by a median 0.0002 a over Ca_s 0.03-0.1 for GH nu_s 0.5, 0.0017 a for NH).
The law's own best shape, fitted to the contour, reaches the tracing noise for the right law,
and a wrong law's best shape stays above it: that difference is what tells laws apart.

Method
------
(a/l, ln Ca_s) minimise the sum of squared signed normal residuals between the law's
database profile (``TubeInverter.profile``) and the contour's two halves folded about its
axis (``capsmech.inversion.residuals.PreparedContour.residual``, ``SHAPE_POINTS`` points along
the meridian; the axial position is the least-squares one), by Nelder-Mead from the length
fit. The fit is reported by the paper's measure, H/a (``capsmech.io.contours.profile_misfit``)
at the fitted parameters, over the fitted a. A fit that ends on the edge of the database (a
step of ``EDGE_STEP`` in a/l or ln Ca_s leaves it) has its minimum outside what the database
knows: no fit (NaN, with the reason).

Uncertainty
-----------
The fitted point's covariance in (a/l, ln Ca_s) is the linearised least-squares one of the
chi2's residual profile (``CHI2_POINTS`` points, each of variance sigma^2 plus the databases'
accuracy there, sigma the contour's own tracing noise): (J^T W J)^-1, J the residuals'
derivatives by central differences (``COVARIANCE_STEP``), scaled up by chi2 / DOF where the
shape misses the contour by more than the noise. Noisy tracing thus widens a capsule's
interval rather than discarding the capsule; the velocity's own error is not in it.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from capsmech.inversion.inverters import Fit, TubeInverter, profile_elongation
from capsmech.inversion.noise import CHI2_POINTS, DOF, tracing_noise, weighted_chi2
from capsmech.inversion.residuals import PreparedContour
from capsmech.inversion.sharp_edge import profile_floor
from capsmech.io.contours import profile_misfit

#: Points of the residual profile along the meridian in the fit's objective.
SHAPE_POINTS = 32
#: Step in a/l and ln Ca_s that must stay inside the database around a fitted point.
EDGE_STEP = 2e-3
#: Nelder-Mead tolerances: 1e-3 in a/l and ln Ca_s (far below the five fits' spread), and in
#: the objective (mean squared residual in units of (1e-3 l)^2; tracing noise gives ~10).
XATOL = 1e-3
FATOL = 1e-3
#: The objective outside the database.
OUTSIDE = 1e12
#: Step in a/l and ln Ca_s of the central differences behind the fitted point's covariance
#: (about 0.5 px on a 100 px tube radius: far above the residual's resolution, within the
#: profiles' linear range).
COVARIANCE_STEP = 5e-3


@dataclass
class ShapeFit(Fit):
    """The law's database shape that best fits a contour (``G_s`` is not set here: it needs
    the capsule's velocity; ``flag`` says why there is no fit, '' when there is).

    Attributes
    ----------
    a_over_l, Ca_s : float
        Fitted parameters [1] (NaN when flagged).
    H_over_a : float
        Modified Hausdorff distance between the contour and the fitted profile over the fitted
        a (NaN when flagged).
    Delta : float
        Profile elongation p / (2 pi a) of the fitted profile [1] (NaN when flagged).
    chi2 : float
        The contour's chi2 at the fitted profile against its own tracing noise and the
        databases' accuracy (``capsmech.inversion.noise.contour_chi2``; ``DOF`` = 14 degrees of
        freedom when the law's shape is the capsule's; NaN when flagged).
    covariance : np.ndarray or None
        Covariance (2, 2) of (a/l, ln Ca_s) at the fitted point (module: Uncertainty); None
        when flagged or when a step of ``COVARIANCE_STEP`` leaves the database.
    """

    a_over_l: float = math.nan
    Ca_s: float = math.nan
    H_over_a: float = math.nan
    Delta: float = math.nan
    chi2: float = math.nan
    covariance: np.ndarray | None = None


def on_database_edge(inverter: TubeInverter, a_over_l: float, Ca_s: float, step: float = EDGE_STEP) -> bool:
    """Whether a step of ``step`` in a/l or ln Ca_s from the point leaves the database."""
    return any(inverter.profile(a_over_l + da, Ca_s * math.exp(dc)) is None
               for da, dc in ((step, 0.0), (-step, 0.0), (0.0, step), (0.0, -step)))


def best_profile(prepared: PreparedContour, inverter: TubeInverter, tube_radius: float, start: tuple[float, float],
                 points: int, objective: Callable[[np.ndarray], float], fatol: float) -> tuple[float, float, float]:
    """(a/l, Ca_s, objective there): the database point whose profile best fits the prepared
    contour, by Nelder-Mead in (a/l, ln Ca_s) from ``start`` (tolerance ``XATOL`` in both,
    ``fatol`` in the objective; first simplex steps 0.02 in a/l and 0.1 in ln Ca_s). The
    objective maps the ``points`` signed normal distances of the residual profile to a number;
    outside the database it is ``OUTSIDE``. Shared by this module and the contour fits of
    ``capsmech.diagnosis.scoring``."""

    def value(x: np.ndarray) -> float:
        meridian = inverter.profile(float(x[0]), float(math.exp(x[1])))
        if meridian is None:
            return OUTSIDE
        _, distance, _ = prepared.residual(meridian * tube_radius, points=points)
        return objective(distance)

    x0 = np.array([start[0], math.log(start[1])])
    best = minimize(value, x0, method="Nelder-Mead",
                    options={"xatol": XATOL, "fatol": fatol, "initial_simplex": [x0, x0 + [0.02, 0.0], x0 + [0.0, 0.1]]})
    return float(best.x[0]), float(math.exp(best.x[1])), float(best.fun)


def fit_shape(contour: np.ndarray, inverter: TubeInverter, tube_radius: float,
              start: tuple[float, float], axis_y: float | None = None, length: float | None = None,
              frames_noise: float = math.nan) -> ShapeFit:
    """Fit the law's database profile to a contour (see the module).

    Parameters
    ----------
    contour : np.ndarray
        Measured contour (n, 2) in the tube radius's units.
    inverter : TubeInverter
        The law's inverter (its table must hold the profiles).
    tube_radius : float
        l, in the contour's units.
    start : (a/l, Ca_s)
        Where the search starts (the length fit).
    axis_y : float, optional
        The contour's axis (by default its axis of best mirror symmetry).
    length : float, optional
        The capsule's length L_z in the contour's units, for the databases' accuracy in the
        chi2 (by default the contour's extent along the axis).
    frames_noise : float, optional
        The contour's tracing noise measured across video frames, in its units (the chi2's
        noise is the larger of it and the halves' noise).
    """
    a0, ca0 = (float(v) for v in start)
    if not (math.isfinite(a0) and math.isfinite(ca0) and ca0 > 0 and tube_radius > 0):
        return ShapeFit(flag=f"no start for the contour fit (a/l = {a0}, Ca_s = {ca0})")
    prepared = PreparedContour(contour, axis_y)
    if inverter.profile(a0, ca0) is None:
        return ShapeFit(flag=f"the contour fit's start a/l = {a0:.3f}, Ca_s = {ca0:.3g} is outside the database")
    unit = 1e-3 * tube_radius
    a_fit, ca_fit, value = best_profile(prepared, inverter, tube_radius, (a0, ca0), SHAPE_POINTS,
                                        lambda distance: float(np.mean((distance / unit) ** 2)), FATOL)
    if value >= OUTSIDE or on_database_edge(inverter, a_fit, ca_fit):
        return ShapeFit(flag=f"the contour fit ends on the edge of the database (a/l = {a_fit:.3f}, "
                               f"Ca_s = {ca_fit:.3g}): its best shape lies outside what the database holds")
    meridian = inverter.profile(a_fit, ca_fit)
    if meridian is None:   # not reached: on_database_edge checked the point's neighbours and the objective the point
        return ShapeFit(flag=f"no database profile at a/l = {a_fit:.3f}, Ca_s = {ca_fit:.3g}")
    misfit, _ = profile_misfit(contour, meridian * tube_radius, prepared.axis_y)
    length = float(np.ptp(contour[:, 0])) if length is None else length
    scaled = meridian * tube_radius
    stated = inverter.stated_error(a_fit, ca_fit)
    interpolation = inverter.interpolation_error(a_fit, ca_fit, CHI2_POINTS) * tube_radius
    sigma = tracing_noise(prepared, scaled, frames_noise)
    variance = sigma ** 2 + profile_floor(scaled, length, CHI2_POINTS, tube_radius, stated, interpolation) ** 2
    chi2 = weighted_chi2(prepared, scaled, variance)
    return ShapeFit(a_over_l=a_fit, Ca_s=ca_fit, H_over_a=misfit / (a_fit * tube_radius),
                    Delta=profile_elongation(meridian, a_fit), chi2=chi2,
                    covariance=fit_covariance(prepared, inverter, tube_radius, (a_fit, ca_fit), variance, chi2))


def fit_covariance(prepared: PreparedContour, inverter: TubeInverter, tube_radius: float,
                   point: tuple[float, float], variance: np.ndarray, chi2: float) -> np.ndarray | None:
    """Covariance (2, 2) of (a/l, ln Ca_s) at a fitted ``point`` (a/l, Ca_s): (J^T W J)^-1 of the
    ``CHI2_POINTS`` residuals of the prepared contour, W their inverse ``variance`` [contour
    units^2], scaled by chi2 / DOF where above 1; None where a step leaves the database or the
    residuals do not constrain both parameters."""
    if not (np.all(np.isfinite(variance)) and np.all(variance > 0)):
        return None
    columns = []
    for da, dc in ((COVARIANCE_STEP, 0.0), (0.0, COVARIANCE_STEP)):
        sides = []
        for sign in (1.0, -1.0):
            meridian = inverter.profile(point[0] + sign * da, point[1] * math.exp(sign * dc))
            if meridian is None:
                return None
            sides.append(prepared.residual(meridian * tube_radius, points=CHI2_POINTS)[1])
        columns.append((sides[0] - sides[1]) / (2 * COVARIANCE_STEP))
    jacobian = np.column_stack(columns)
    information = jacobian.T @ (jacobian / variance[:, None])
    if not np.all(np.isfinite(information)) or np.linalg.det(information) <= 0:
        return None
    inflation = max(1.0, chi2 / DOF) if math.isfinite(chi2) else 1.0
    return np.linalg.inv(information) * inflation

