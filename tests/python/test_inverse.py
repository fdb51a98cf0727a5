"""Inverse analysis core (capsmech.inversion.inverters) on analytic tables: the numerical facts the
method must satisfy before it is used on simulated databases.

- A forward map that is exactly quadratic in (a/l, ln Ca_s) is inverted to round-off (the
  local fit's basis contains it); a smooth non-polynomial map is inverted with an error
  that falls with the grid spacing at the order of the quadratic fit (~h^3).
- v_c/V from the Delaunay triangulation reproduces a field linear in (a/l, ln Ca_s) exactly.
- A point outside the database is a flag, never a number.
- Shear: D12 -> Ca_s along a monotone branch, a from volume conservation, G_s = mu gdot a / Ca_s.
"""
from __future__ import annotations

import numpy as np
import pytest

from capsmech.inversion.inverters import FIVE_FITS, ShearInverter, TubeInverter, TubeTable, profile_elongation

A_GRID = np.arange(0.70, 1.101, 0.05)
CA_GRID = np.array([0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.07, 0.08, 0.09, 0.10, 0.12, 0.15, 0.18, 0.20])


def quadratic_map(a, ca):
    """(L_z, L_z - L_p) exactly quadratic in (a, ln Ca): one-to-one over the grid."""
    x, y = a - 0.9, np.log(ca) - np.log(0.05)
    l_z = 1.8 + 2.0 * x + 0.25 * y + 0.3 * x * y + 0.05 * y**2
    front = 1.5 + 1.2 * x + 0.1 * y + 0.2 * x**2
    return l_z, front


def smooth_map(a, ca):
    """A smooth, non-polynomial one-to-one map with the paper's trends (L_z, L_p grow with Ca)."""
    l_z = 2 * a * (1 + 1.5 * np.sqrt(ca) * np.exp(a - 0.9))
    l_p = 0.4 * ca**0.8 * np.exp(2 * (a - 0.9)) * 5
    return l_z, l_z - l_p


def table_from(forward, a_grid=A_GRID, ca_grid=CA_GRID, velocity=None):
    a, ca = (v.ravel() for v in np.meshgrid(a_grid, ca_grid, indexing="ij"))
    l_z, front = forward(a, ca)
    vc = velocity(a, ca) if velocity else 2 - a
    return TubeTable(a_over_l=a, Ca_s=ca, L_z=l_z, L_p=l_z - front, vc_over_V=vc)


OFF_GRID = [(0.83, 0.033), (0.92, 0.071), (1.03, 0.13), (0.76, 0.015)]


@pytest.mark.parametrize("a_true,ca_true", OFF_GRID)
def test_quadratic_forward_map_is_inverted_to_round_off(a_true, ca_true):
    inverter = TubeInverter(table_from(quadratic_map))
    l_z, front = quadratic_map(a_true, ca_true)
    fit = inverter.fit(l_z, l_z - front)
    assert fit.ok, fit.flag
    assert fit.a_over_l == pytest.approx(a_true, abs=1e-9)
    assert fit.Ca_s == pytest.approx(ca_true, rel=1e-9)


def test_smooth_map_error_falls_with_grid_spacing():
    errors = []
    for refine in (1, 2, 4):
        a_grid = np.linspace(0.7, 1.1, 8 * refine + 1)
        ca_grid = np.exp(np.linspace(np.log(0.01), np.log(0.2), 10 * refine + 1))
        inverter = TubeInverter(table_from(smooth_map, a_grid, ca_grid))
        worst = 0.0
        for a_true, ca_true in OFF_GRID:
            l_z, front = smooth_map(a_true, ca_true)
            fit = inverter.fit(l_z, l_z - front)
            assert fit.ok, fit.flag
            worst = max(worst, abs(fit.a_over_l - a_true), abs(np.log(fit.Ca_s / ca_true)))
        errors.append(worst)
    # Measured: 0.020, 0.0086, 0.00096 (largest of |error in a/l| and |error in ln Ca_s|)
    # at the paper-like spacing, half and a quarter of it: the quadratic local fit
    # converges, at about second order or better over the two refinements.
    assert errors[0] < 0.03
    assert errors[1] < errors[0] and errors[2] < errors[0] / 16, errors


def test_velocity_is_linear_in_the_delaunay_triangles_and_gives_g_s():
    # v_c/V linear in (a/l, ln Ca_s) is reproduced exactly; G_s = mu v_c / (Ca_s v_c/V).
    velocity = lambda a, ca: 1.9 - 0.8 * a + 0.02 * np.log(ca)  # noqa: E731
    inverter = TubeInverter(table_from(quadratic_map, velocity=velocity))
    a_true, ca_true = 0.92, 0.071
    l_z, front = quadratic_map(a_true, ca_true)
    mu, v_c = 0.9, 2.0e-3
    fit = inverter.fit(l_z, l_z - front, v_c=v_c, mu=mu)
    assert fit.vc_over_V == pytest.approx(velocity(a_true, ca_true), rel=1e-9)
    assert fit.G_s == pytest.approx(mu * v_c / (ca_true * velocity(a_true, ca_true)), rel=1e-8)


def test_points_outside_the_database_are_flagged_not_extrapolated():
    inverter = TubeInverter(table_from(quadratic_map))
    for a_true, ca_true in [(1.3, 0.05), (0.9, 0.5), (0.5, 0.005)]:
        l_z, front = quadratic_map(a_true, ca_true)
        fit = inverter.fit(l_z, l_z - front)
        assert not fit.ok and "outside" in fit.flag
        assert np.isnan(fit.a_over_l) and np.isnan(fit.G_s)
    assert "invalid" in inverter.fit(1.0, 1.5).flag      # L_p >= L_z


def test_five_fits_bracket_the_central_fit():
    inverter = TubeInverter(table_from(smooth_map))
    l_z, front = smooth_map(0.95, 0.08)
    fits = inverter.five_fits(l_z, l_z - front, v_c=1.0, mu=1.0)
    assert list(fits.fits) == [name for name, _, _ in FIVE_FITS]
    assert fits.n_valid == 5
    # Scaling both lengths by -+2 % mostly scales the capsule: a/l follows.
    assert fits.fits["fit2"].a_over_l < fits.fits["fit1"].a_over_l < fits.fits["fit3"].a_over_l
    low, high = min(f.G_s for f in fits.fits.values()), max(f.G_s for f in fits.fits.values())
    assert low <= fits.mean("G_s") <= high
    assert fits.spread("G_s") == pytest.approx(0.5 * (high - low))


def shear_branch():
    ca = np.array([0.01, 0.02, 0.04, 0.06, 0.08, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6])
    d12 = 25 / 12 * ca / (1 + 3 * ca)            # monotone, small-Ca slope 25/12
    l3 = 1 - 0.5 * d12**2
    return ca, d12, l3


def test_shear_inversion_recovers_ca_and_the_radius_from_volume_conservation():
    ca, d12, l3 = shear_branch()
    inverter = ShearInverter(ca, d12, l3)
    ca_true = 0.45
    d_true = 25 / 12 * ca_true / (1 + 3 * ca_true)
    l3_true = 1 - 0.5 * d_true**2
    a_true, gdot, mu = 45e-6, 350.0, 0.756
    # Semi-axes with L1 L2 L3 = a^3 and the right D12.
    ratio = (1 + d_true) / (1 - d_true)
    l2 = np.sqrt(a_true**2 / (ratio * l3_true))
    l1 = ratio * l2
    fit = inverter.fit(L1=l1, L2=l2, shear_rate=gdot, mu=mu)
    assert fit.ok, fit.flag
    assert fit.Ca_s == pytest.approx(ca_true, rel=2e-3)
    assert fit.a == pytest.approx(a_true, rel=1e-3)
    assert fit.G_s == pytest.approx(mu * gdot * a_true / ca_true, rel=3e-3)


def test_shear_small_deformation_and_out_of_range_are_flagged():
    inverter = ShearInverter(*shear_branch())
    assert "imprecise" in inverter.fit(D12=0.30).flag
    assert "outside" in inverter.fit(D12=0.9).flag
    with pytest.raises(ValueError, match="does not increase"):
        ShearInverter([0.1, 0.2, 0.3], [0.2, 0.4, 0.3], [1, 1, 1])


def test_profile_elongation_of_a_sphere_is_one_and_grows_for_a_spheroid():
    t = np.linspace(0, np.pi, 400)
    sphere = np.column_stack([0.8 * np.sin(t), 0.8 * np.cos(t)])
    assert profile_elongation(sphere, 0.8) == pytest.approx(1.0, rel=1e-4)
    prolate = np.column_stack([0.7 * np.sin(t), 1.2 * np.cos(t)])
    assert profile_elongation(prolate, 0.8) > 1.05


def test_profiles_are_blended_linearly_between_database_rows():
    # Profiles that depend linearly on (a/l, ln Ca_s) are reproduced exactly at any point.
    a, ca = (v.ravel() for v in np.meshgrid(A_GRID, CA_GRID, indexing="ij"))
    s = np.linspace(0, 1, 16)
    profile_r = np.outer(a, np.sin(np.pi * s)) + np.outer(np.log(ca), s)
    profile_z = np.outer(a, np.cos(np.pi * s))
    l_z, front = quadratic_map(a, ca)
    inverter = TubeInverter(TubeTable(a, ca, l_z, l_z - front, 2 - a, profile_r, profile_z))
    blended = inverter.profile(0.93, 0.047)
    assert blended[:, 0] == pytest.approx(0.93 * np.sin(np.pi * s) + np.log(0.047) * s, abs=1e-12)
    assert blended[:, 1] == pytest.approx(0.93 * np.cos(np.pi * s), abs=1e-12)
    assert inverter.profile(1.3, 0.05) is None
