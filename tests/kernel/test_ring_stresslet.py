"""Axisymmetric double layer: the ring stresslet and the double-layer operator on a sphere.

References are computed here, independently of the Fortran: the 3D stresslet integrated over the
azimuth by adaptive quadrature (Cartesian, no algebra). Normalisation as in
kernel/src/ring_stresslet.f90:
    Q_ab(r0, z0; r, z; n) = 6 integral_0^{2 pi} (d.e_a(0)) (d.e_b(phi)) (d.n) / |d|**5 dphi,
    d = x0 - y(phi),  n = n_r e_r(phi) + n_z e_z,
so that D[q](x0) = 1/(8 pi) integral Q q r ds is -q inside a closed surface, -q/2 on it, 0 outside.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate

from conftest import axi


def phi_quadrature(r0, z0, r, z, n_r, n_z) -> np.ndarray:
    """Q by adaptive quadrature over the azimuth of the 3D stresslet."""
    x0 = np.array([r0, 0.0, z0])
    e_a = [np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])]

    def entry(phi, a, b):
        c, s = math.cos(phi), math.sin(phi)
        d = x0 - np.array([r * c, r * s, z])
        n = np.array([n_r * c, n_r * s, n_z])
        e_b = np.array([c, s, 0.0]) if b == 0 else e_a[1]
        return 6.0 * (d @ e_a[a]) * (d @ e_b) * (d @ n) / (d @ d) ** 2.5

    # Even in phi, peaked at phi = 0 with width ~ rho / sqrt(r0 r): breakpoints at multiples of it.
    rho = math.hypot(r0 - r, z0 - z)
    width = rho / math.sqrt(r0 * r) if r0 * r > 0 else math.pi
    points = [w for w in (width, 10 * width, 100 * width) if w < math.pi] or None
    return np.array([[2.0 * integrate.quad(entry, 0.0, math.pi, args=(a, b), epsabs=0.0, epsrel=1e-13,
                                           limit=1000, points=points)[0] for b in range(2)] for a in range(2)])


CASES = {
    # (r0, z0, r, z, n_r, n_z): m from 0 (axis) through the series/closed-form switch at 1/2 to ~1.
    "far": (0.3, 2.0, 0.5, -1.0, 0.6, 0.8),
    "series_side": (0.5, 0.9, 0.3, 0.1, -0.8, 0.6),     # m = 0.469
    "closed_side": (0.5, 0.8, 0.3, 0.1, 0.6, 0.8),      # m = 0.531
    "near": (0.7, 0.2, 0.69, 0.21, 0.28, 0.96),
    "very_near": (0.7, 0.2, 0.7003, 0.1996, 0.8, -0.6),
    "target_on_axis": (0.0, 0.2, 0.5, 0.1, 0.6, 0.8),
    "source_near_axis": (0.8, 0.1, 1e-3, -0.2, 1.0, 0.0),
}


@pytest.mark.parametrize("case", CASES)
def test_closed_form_matches_azimuthal_quadrature(case):
    args = CASES[case]
    v = axi("stresslet", *map(float, args))
    q = np.array([[v["q_rr"], v["q_rz"]], [v["q_zr"], v["q_zz"]]])
    ref = phi_quadrature(*args)
    assert np.max(np.abs(q - ref)) <= 1e-12 * np.max(np.abs(ref))


def test_no_radial_velocity_on_the_axis():
    v = axi("stresslet", 0.0, 0.3, 0.7, -0.2, 0.6, 0.8)
    assert v["q_rr"] == 0.0 and v["q_rz"] == 0.0


@pytest.fixture(scope="module")
def sphere():
    return {n: axi("dl-sphere", n) for n in (16, 32, 64)}


def test_constant_density_identities_on_the_sphere(sphere):
    # -c/2 on the surface (mean of the one-sided values at element mid-points), -c inside (a
    # rigid translation reproduced by its double layer), 0 outside: exact on the closed
    # polygonal surface, so only the quadrature error remains.
    for v in sphere.values():
        assert v["midpoint_identity"] < 1e-11
        assert v["inside_identity"] < 1e-11
        assert v["outside_identity"] < 1e-11


def test_principal_value_converges_at_second_order(sphere):
    # Green's identity D[v] + v/2 = SL[sigma.n]/(8 pi) at the nodes for a straining flow inside
    # the unit sphere: the node principal value (constant-density identity) and the P1 density
    # on the polygon err by O(h^2). Measured: 7.2e-4, 1.7e-4, 4.1e-5 (orders 2.08, 2.04).
    errors = [sphere[n]["green_error"] for n in (16, 32, 64)]
    orders = [math.log2(a / b) for a, b in zip(errors, errors[1:])]
    assert errors[0] < 1e-3
    assert all(1.9 < p < 2.2 for p in orders), orders
