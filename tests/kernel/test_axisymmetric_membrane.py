"""Axisymmetric membrane (frustum elements): energy gradient, rigid motion, Laplace law."""
from __future__ import annotations

import math

import pytest


@pytest.mark.parametrize("law,nu_s,c", [("NH", 0.5, 1.0), ("SK", 0.5, 1.0), ("GH", 0.2, 1.0)])
@pytest.mark.parametrize("n", [16, 64])
def test_ring_forces_are_the_energy_gradient(probe, law, nu_s, c, n):
    r = probe("axi-fd", law, nu_s, c, n)
    assert r["fd_max_error_rel"] < 1e-7            # central differences, eps = 1e-6
    assert r["volume_gradient_error"] < 1e-8       # dV/dx used by the volume-flux correction
    assert r["net_axial_force_rel"] < 1e-12        # axial translation invariance of E
    assert r["rigid_max_force"] < 1e-12


def test_frustum_sphere_converges_at_second_order(probe):
    errors = []
    for n in (16, 32, 64):
        r = probe("axi-fd", "NH", 0.5, 1.0, n)
        errors.append((abs(r["sphere_area"] / (4 * math.pi) - 1), abs(r["sphere_volume"] / (4 * math.pi / 3) - 1)))
    for (a0, v0), (a1, v1) in zip(errors, errors[1:]):
        assert a0 / a1 == pytest.approx(4.0, rel=0.05)
        assert v0 / v1 == pytest.approx(4.0, rel=0.05)


@pytest.mark.parametrize("law,nu_s", [("NH", 0.5), ("GH", 0.5), ("GH", 0.0)])
def test_inflated_sphere_laplace_law_at_every_node(probe, law, nu_s):
    # With dual-cell node areas the uniform inflation gives 2T/R exactly, poles included.
    r = probe("axi-laplace", law, nu_s, 1.0, 1.1, 32)
    assert r["pressure_max_rel_error_interior"] < 1e-10
    assert r["pressure_rel_error_pole"] < 1e-10
