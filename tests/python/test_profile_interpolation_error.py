"""The database's interpolation error, estimated from its own rows (``row_interpolation_errors``,
``TubeInverter.interpolation_error``) and taken into the contour chi2's floor (``profile_floor``).

The contract is checked on a table whose profiles are known in closed form: circles whose radius
is a quadratic of a/l and does not depend on Ca_s. Between two circles the interpolated profile
is the circle of the mean radius, so a linear interpolation misses by the radius's second
derivative times h^2 / 8 half-way between two rows h apart: the estimate, from the grid's rows
alone, must find that, and nothing where the profiles are linear in the parameters.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from capsmech.inversion.inverters import TubeInverter, TubeTable
from capsmech.inversion.residuals import PreparedContour
from capsmech.inversion.sharp_edge import profile_floor

A_OVER_L = np.array([0.6, 0.7, 0.8, 0.9, 1.0])
CA_S = np.array([0.02, 0.04, 0.08, 0.16, 0.32])
CURVATURE = 0.5          # d2 R / d(a/l)2 / 2 [l]: R = R0 + CURVATURE (a/l - 0.8)^2
POINTS = 33
#: The residual's own resolution on these circles [l]: the contour resampled at equal arclength
#: and its nearest points (about 1e-4 l at the poles), a tenth of the error measured here.
RESOLUTION = 1.5e-4


def radius(a_over_l: np.ndarray | float) -> np.ndarray | float:
    return 0.7 + CURVATURE * (np.asarray(a_over_l) - 0.8) ** 2


def circle_table(curvature: float = CURVATURE) -> TubeTable:
    a, ca = (g.ravel() for g in np.meshgrid(A_OVER_L, CA_S, indexing="ij"))
    big_r = 0.7 + curvature * (a - 0.8) ** 2
    theta = np.linspace(0.0, math.pi, 128)
    return TubeTable(a_over_l=a, Ca_s=ca, L_z=2 * big_r, L_p=np.zeros_like(a), vc_over_V=np.full_like(a, 1.5),
                     profile_r=big_r[:, None] * np.sin(theta), profile_z=big_r[:, None] * np.cos(theta))


def missed_at(inverter: TubeInverter, a_over_l: float, Ca_s: float) -> np.ndarray:
    """The interpolated profile's normal distance from the exact circle there [l]."""
    exact = radius(a_over_l)
    theta = np.linspace(0.0, 2 * math.pi, 400, endpoint=False)
    prepared = PreparedContour(np.column_stack([exact * np.cos(theta), exact * np.sin(theta)]), axis_y=0.0)
    return np.abs(prepared.residual(inverter.profile(a_over_l, Ca_s), points=POINTS)[1])


def test_the_estimate_is_the_interpolation_error_half_way_between_rows():
    inverter = TubeInverter(circle_table())
    h = 0.1
    worst = CURVATURE * h ** 2 / 4                      # R'' h^2 / 8 with R'' = 2 CURVATURE
    for a_mid in (0.65, 0.75, 0.85, 0.95):
        # Half-way between two rows in a/l, on a row in Ca_s: an edge's middle.
        missed = missed_at(inverter, a_mid, 0.08)
        assert missed.max() == pytest.approx(worst, rel=0.02)
        estimate = inverter.interpolation_error(a_mid, 0.08, POINTS)
        assert estimate == pytest.approx(np.full(POINTS, worst), rel=0.02)
    # On a row the interpolation is that row: no error, and none estimated.
    assert missed_at(inverter, 0.8, 0.04).max() < RESOLUTION
    assert inverter.interpolation_error(0.8, 0.04, POINTS).max() < 1e-12


def test_profiles_linear_in_the_parameters_have_no_interpolation_error():
    inverter = TubeInverter(circle_table(curvature=0.0))
    estimate = inverter.interpolation_error(0.75, 0.06, POINTS)
    assert np.all(np.isfinite(estimate)) and estimate.max() < RESOLUTION / 4


def test_the_interpolation_error_enters_the_floor_in_quadrature_and_nowhere_else():
    theta = np.linspace(0.0, math.pi, 128)
    meridian = np.column_stack([0.7 * np.sin(theta), 0.7 * np.cos(theta)])
    plain = profile_floor(meridian, 1.4, 16)
    error = np.linspace(0.0, 0.004, 16)
    raised = profile_floor(meridian, 1.4, 16, interpolation_error=error)
    assert np.allclose(raised, np.hypot(plain, error), rtol=1e-12)
    # Not known (NaN) at a point: the floor there is the databases' own.
    error[3] = math.nan
    assert profile_floor(meridian, 1.4, 16, interpolation_error=error)[3] == plain[3]
    assert np.array_equal(profile_floor(meridian, 1.4, 16, interpolation_error=None), plain)
