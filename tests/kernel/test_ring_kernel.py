"""Axisymmetric single layer: elliptic integrals, ring Stokeslet, segment integrals, sphere.

References are computed here, independently of the Fortran: scipy's elliptic integrals, the
3D Stokeslet integrated over the azimuth by adaptive quadrature, and adaptive quadrature along
the meridian segment. Normalisation as in kernel/src/ring_stokeslet.f90:
    M_ab(r0, z0; r, z) = integral_0^{2 pi} e_a(0) . J(x0 - y(phi)) . e_b(phi) dphi,
    J(d) = I/|d| + d d^T/|d|^3,  a, b in {r, z}.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, special

from conftest import axi


def kernel_matrix(r0, z0, r, z) -> np.ndarray:
    v = axi("kernel", float(r0), float(z0), float(r), float(z))
    return np.array([[v["m_rr"], v["m_rz"]], [v["m_zr"], v["m_zz"]]])


# --- references --------------------------------------------------------------------------------

def phi_quadrature(r0, z0, r, z) -> np.ndarray:
    """M by adaptive quadrature over the azimuth of the 3D Stokeslet (Cartesian, no algebra)."""
    x0 = np.array([r0, 0.0, z0])
    e_a = [np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])]

    def entry(phi, a, b):
        c, s = math.cos(phi), math.sin(phi)
        d = x0 - np.array([r * c, r * s, z])
        n = math.sqrt(d @ d)
        e_b = np.array([c, s, 0.0]) if b == 0 else np.array([0.0, 0.0, 1.0])
        return (e_a[a] @ e_b) / n + (e_a[a] @ d) * (d @ e_b) / n**3

    # The integrand is even in phi and peaks at phi = 0 with width ~ rho / sqrt(r0 r):
    # integrate over [0, pi] with breakpoints at multiples of that width.
    rho = math.hypot(r0 - r, z0 - z)
    width = rho / math.sqrt(r0 * r) if r0 * r > 0 else math.pi
    points = [w for w in (width, 10 * width, 100 * width) if w < math.pi] or None
    m = np.empty((2, 2))
    for a in range(2):
        for b in range(2):
            val, _ = integrate.quad(entry, 0.0, math.pi, args=(a, b), epsabs=1e-13, epsrel=1e-13,
                                    limit=1000, points=points)
            m[a, b] = 2.0 * val
    return m


def kebd_scipy(m, m1):
    """K, E, B = (E - m1 K)/m, D = (K - E)/m from scipy (series where the quotients cancel)."""
    if m < 1e-4:
        k = math.pi / 2 * (1 + m / 4 + 9 * m * m / 64)
        d = math.pi / 4 * (1 + 3 * m / 8 + 15 * m * m / 64)
        e = math.pi / 2 * (1 - m / 4 - 3 * m * m / 64)
        return k, e, k - d, d
    k = special.ellipkm1(m1)
    e = special.ellipe(m)
    return k, e, (e - m1 * k) / m, (k - e) / m


def reference_kernel(r0, z0, r, z, offset=None) -> np.ndarray:
    """The closed form (same derivation as ring_stokeslet.f90) on scipy's K and E; it is checked
    against phi_quadrature below, then used under quad for the segment integrals. `offset`,
    when given, is x0 - y exactly (quad samples points within 1e-17 of an endpoint target)."""
    dr, dz = offset if offset is not None else (r0 - r, z0 - z)
    rho2 = dr * dr + dz * dz
    big2 = (2 * r0 - dr) ** 2 + dz * dz
    big = math.sqrt(big2)
    # m = 1 - m1 can round above 1 (where scipy's E is NaN) when the source is within 1e-8 of x0.
    k, e, b, d = kebd_scipy(min(4 * r0 * r / big2, 1.0), rho2 / big2)
    c = 4 / big
    return np.array([
        [c * (2 * d - k + dz * dz * (d / big2 - b / rho2)), c * dz * (dr * e / rho2 + 2 * r * d / big2)],
        [c * dz * (dr * e / rho2 - 2 * r0 * d / big2), c * (k + dz * dz * e / rho2)],
    ])


def reference_segment(x0, a, b, fa, fb, target_end):
    """integral_0^1 M(x0; p(t)) . f(t) r(t) L dt by adaptive quadrature, on pieces that shrink
    geometrically towards the point of the segment nearest to the target (quad alone stalls on
    the 1e-6-wide peak of a very near target)."""
    a, b, fa, fb = map(np.asarray, (a, b, fa, fb))
    if target_end == 2:
        # The integral does not depend on the direction of travel: start from the target.
        a, b, fa, fb, target_end = b, a, fb, fa, 1
    if target_end == 1:
        x0 = a
    length = float(np.hypot(*(b - a)))
    t_near = min(max(float(np.dot(np.asarray(x0) - a, b - a)) / length**2, 0.0), 1.0)
    breaks = sorted({0.0, 1.0, t_near} | {t for k in range(1, 10) for t in (t_near - 10.0**-k, t_near + 10.0**-k)
                                           if 0.0 < t < 1.0})

    def integrand(t, comp):
        p = a + t * (b - a)
        f = fa + t * (fb - fa)
        offset = np.asarray(x0) - p if target_end == 0 else (a - b) * t
        return (reference_kernel(x0[0], x0[1], p[0], p[1], offset) @ f)[comp] * p[0] * length

    return np.array([sum(integrate.quad(integrand, t0, t1, args=(c,), epsabs=0.0, epsrel=1e-12, limit=200)[0]
                         for t0, t1 in zip(breaks, breaks[1:])) for c in range(2)])


# --- elliptic integrals ------------------------------------------------------------------------

@pytest.mark.parametrize("m", [0.0, 1e-9, 0.01, 0.1, 0.3, 0.5, 0.7, 0.9, 0.99, 0.999999])
def test_elliptic_k_e_match_scipy(m):
    v = axi("ellip-m", m)
    assert v["k"] == pytest.approx(special.ellipk(m), rel=2e-15, abs=0)
    assert v["e"] == pytest.approx(special.ellipe(m), rel=2e-15, abs=0)


@pytest.mark.parametrize("m1", [1.0, 0.5, 0.1, 1e-3, 1e-6, 1e-10, 1e-16, 1e-30, 1e-100, 1e-300])
def test_elliptic_from_complementary_parameter(m1):
    # Near m = 1 only m1 is known accurately: K ~ ln(4/sqrt(m1)) must keep full precision.
    v = axi("ellip", m1)
    m = 1.0 - m1
    assert v["k"] == pytest.approx(special.ellipkm1(m1), rel=2e-15, abs=0)
    if m1 < 1e-12:
        # E = 1 + (m1/2)(ln(4/sqrt(m1)) - 1/2) + O(m1^2 ln m1)  (DLMF 19.12.2)
        e_ref = 1 + 0.5 * m1 * (math.log(4 / math.sqrt(m1)) - 0.5)
    else:
        e_ref = special.ellipe(m)
    assert v["e"] == pytest.approx(e_ref, rel=2e-15, abs=0)
    # B = (E - m1 K)/m and D = (K - E)/m: where the quotients cancel, against their series.
    if m > 0.05:
        b_ref, d_ref = (e_ref - m1 * v["k"]) / m, (v["k"] - e_ref) / m
    else:
        b_ref, d_ref = math.pi / 4 * (1 + m / 8), math.pi / 4 * (1 + 3 * m / 8)
    assert v["b"] == pytest.approx(b_ref, rel=3e-15 if m > 0.05 else 1e-15 + m * m, abs=0)
    assert v["d"] == pytest.approx(d_ref, rel=3e-15 if m > 0.05 else 1e-15 + m * m, abs=0)


def test_fast_elliptic_integrals_match_the_agm():
    # The polynomial-logarithm form the ring kernels use against Bulirsch's AGM (two
    # independent algorithms, each good to a few ulps): m on [0, 1) and up to 1 - 1e-15 for
    # K(m), E(m); all four of K, E, B, D from m1 down to 1e-300 (measured 1.1e-15: the two
    # roundings together).
    v = axi("ellip-sweep")
    assert set(v) == {"m_k", "m_e", "m1_k", "m1_e", "m1_b", "m1_d"}
    assert max(v.values()) < 1e-14


@pytest.mark.parametrize("m", [0.01, 0.2, 0.5, 0.8, 0.9999])
def test_elliptic_legendre_relation(m):
    # E K' + E' K - K K' = pi/2, an identity that involves no outside reference.
    v, w = axi("ellip", 1.0 - m), axi("ellip", m)
    assert v["e"] * w["k"] + w["e"] * v["k"] - v["k"] * w["k"] == pytest.approx(math.pi / 2, rel=1e-14)


# --- ring kernel -------------------------------------------------------------------------------

KERNEL_POINTS = [
    # far
    (1.0, 0.0, 2.0, 1.0),
    (0.5, 0.3, 3.0, -2.0),
    (1.0, 0.0, 0.2, -3.0),
    # near: rho/r0 = 1e-2 and 1e-4, several directions
    (1.0, 0.0, 1.006, 0.008),
    (1.0, 0.0, 1.0, 0.01),
    (1.0, 0.3, 1.0 - 6e-5, 0.3 + 8e-5),
    (2.0, 0.0, 2.0 + 2e-4, 0.0),
    (0.7, -1.0, 0.7 + 5e-5, -1.0 - 5e-5),
    # target on the axis
    (0.0, 0.0, 1.0, 0.5),
    (0.0, 1.0, 0.3, -0.2),
    # source on the axis
    (1.0, 0.5, 0.0, 0.0),
    (0.2, 0.0, 0.0, 1.0),
    # r0 >> r and r0 << r
    (100.0, 0.0, 1.0, 0.3),
    (50.0, 1.0, 0.01, 0.0),
    (0.01, 0.0, 1.0, 0.2),
    (1e-3, 0.1, 2.0, 0.1),
]


@pytest.mark.parametrize("point", KERNEL_POINTS)
def test_ring_kernel_matches_azimuthal_quadrature(point):
    ref = phi_quadrature(*point)
    m = kernel_matrix(*point)
    scale = np.abs(ref).max()
    assert np.abs(m - ref).max() / scale < 1e-10, (m, ref)
    # The Python closed form used as the reference for the segment integrals is checked too.
    assert np.abs(reference_kernel(*point) - ref).max() / scale < 1e-10


def test_ring_kernel_axis_limits():
    # Target on the axis: no radial velocity, so M_rr = M_rz = 0; M_zr, M_zz in closed form.
    r, dz = 0.3, 1.2
    big = math.hypot(r, dz)
    m = kernel_matrix(0.0, dz, r, 0.0)
    assert abs(m[0, 0]) < 1e-15 and abs(m[0, 1]) < 1e-15
    assert m[1, 0] == pytest.approx(-2 * math.pi * dz * r / big**3, rel=1e-14)
    assert m[1, 1] == pytest.approx(2 * math.pi * (1 / big + dz * dz / big**3), rel=1e-14)
    # Source ring of zero radius: 2 pi times the point Stokeslet's z column; f_r does nothing.
    r0 = 0.4
    big = math.hypot(r0, dz)
    m = kernel_matrix(r0, dz, 0.0, 0.0)
    assert abs(m[0, 0]) < 1e-15 and abs(m[1, 0]) < 1e-15
    assert m[0, 1] == pytest.approx(2 * math.pi * r0 * dz / big**3, rel=1e-14)
    assert m[1, 1] == pytest.approx(2 * math.pi * (1 / big + dz * dz / big**3), rel=1e-14)
    # Both on the axis, and a coincident point: finite, never NaN.
    assert np.isfinite(kernel_matrix(0.0, 1.0, 0.0, 0.0)).all()
    assert np.isfinite(kernel_matrix(1.0, 0.0, 1.0, 0.0)).all()


def test_ring_kernel_reciprocity():
    # J symmetric and even, and the geometry rotation-invariant: M_ab(x0; y) = M_ba(y; x0).
    for x0, y in [((1.0, 0.2), (0.4, -0.5)), ((2.0, 0.0), (2.001, 0.001)), ((0.05, 1.0), (3.0, 0.0))]:
        assert np.allclose(kernel_matrix(*x0, *y), kernel_matrix(*y, *x0).T, rtol=1e-14, atol=0)


@pytest.mark.parametrize("alpha", [0.0, 0.3, 1.2, math.pi / 2, 2.5, -2.0])
def test_log_coefficient_and_near_field_limit(alpha):
    # M = -A ln(rho) + bounded, A = (2/r0) I; along a fixed direction X/rho = (cos a, sin a),
    # X = (r0 - r, z0 - z), the bounded part tends to
    #   (2/r0) [ln(8 r0) I + diag(-2, 0) + [[-sin^2 a, cos a sin a], [cos a sin a, sin^2 a]]]
    # with an error O(rho ln rho).
    r0, z0 = 0.7, 0.2
    a = axi("log-coefficient", r0)["a"]
    assert a == pytest.approx(2 / r0, rel=1e-15)
    c, s = math.cos(alpha), math.sin(alpha)

    def limit(c, s):
        return 2 / r0 * (math.log(8 * r0) * np.eye(2) + np.diag([-2.0, 0.0])
                         + np.array([[-s * s, c * s], [c * s, s * s]]))

    rhos, regular, limits = [], [], []
    for k in range(2, 10):
        r, z = r0 - 10.0**-k * c, z0 - 10.0**-k * s
        # The distance and direction the probe actually sees: r0 - r is exact in floating
        # point, 10^-k * cos(a) is not, and at rho = 1e-9 that matters at 1e-7.
        rho = math.hypot(r0 - r, z0 - z)
        rhos.append(rho)
        regular.append(kernel_matrix(r0, z0, r, z) + a * math.log(rho) * np.eye(2))
        limits.append(limit((r0 - r) / rho, (z0 - z) / rho))
    for rho, g, lim in zip(rhos, regular, limits):
        assert np.abs(g - lim).max() < 4 / r0 * rho * abs(math.log(rho)), (rho, g, lim)
    # Successive differences shrink like rho ln rho (a factor ~10 per decade of rho).
    diffs = [np.abs(g1 - g0).max() for g0, g1 in zip(regular, regular[1:])]
    for rho, d in zip(rhos, diffs):
        assert d < 4 / r0 * rho * abs(math.log(rho))
    for coarse, fine in zip(diffs, diffs[1:]):
        assert fine < coarse / 5


# --- segment integrals -------------------------------------------------------------------------

SEG_A, SEG_B = np.array([1.0, 0.0]), np.array([0.9, 0.3])
FA, FB = np.array([0.3, -1.0]), np.array([1.2, 0.5])


def off_segment_targets():
    ab = SEG_B - SEG_A
    length = np.hypot(*ab)
    tangent = ab / length
    normal = np.array([-tangent[1], tangent[0]])
    mid = 0.5 * (SEG_A + SEG_B)
    cases = {}
    for d in (1e-1, 1e-2, 1e-3, 1e-6):
        cases[f"mid+{d:g}"] = mid + d * length * normal
        cases[f"mid-{d:g}"] = mid - d * length * normal
    cases["quarter+1e-3"] = SEG_A + 0.23 * ab + 1e-3 * length * normal
    cases["beyond_a_1e-3"] = SEG_A - 1e-3 * ab                       # on the line, past a
    cases["beside_b_1e-3"] = SEG_B + 1e-3 * length * normal          # next to an endpoint
    cases["neighbour_node"] = SEG_B + 1.0 * ab                       # the next meridian node
    cases["far_3L"] = mid + 3 * length * normal
    cases["far_10L"] = mid - 10 * length * normal
    return cases


@pytest.mark.parametrize("name,target", list(off_segment_targets().items()))
def test_segment_integral_off_segment(name, target):
    ref = reference_segment(target, SEG_A, SEG_B, FA, FB, 0)
    v = axi("segment", *map(float, (*target, *SEG_A, *SEG_B, *FA, *FB)), 0)
    u = np.array([v["u_r"], v["u_z"]])
    assert np.abs(u - ref).max() / np.abs(ref).max() < 1e-10, (name, u, ref)


SEGMENTS = {
    # (a, b, fa, fb): an ordinary element, one close to the axis (r0 < L at a), one ending on it
    "ordinary": (SEG_A, SEG_B, FA, FB),
    "near_axis": (np.array([0.05, 0.2]), np.array([0.25, 0.1]), np.array([0.5, 1.0]), np.array([-0.4, 0.8])),
    "from_axis": (np.array([0.0, 1.0]), np.array([0.2, 0.98]), np.array([0.0, 1.0]), np.array([0.7, 0.2])),
}


@pytest.mark.parametrize("name", list(SEGMENTS))
@pytest.mark.parametrize("target_end", [1, 2])
def test_segment_integral_target_at_endpoint(name, target_end):
    a, b, fa, fb = SEGMENTS[name]
    ref = reference_segment(None, a, b, fa, fb, target_end)
    x0 = a if target_end == 1 else b
    v = axi("segment", *map(float, (*x0, *a, *b, *fa, *fb)), target_end)
    u = np.array([v["u_r"], v["u_z"]])
    assert np.abs(u - ref).max() / np.abs(ref).max() < 1e-10, (name, u, ref)


# --- sphere --------------------------------------------------------------------------------------

@pytest.mark.parametrize("mode", ["translate", "pressure"])
def test_sphere_velocity_converges_at_second_order(mode):
    # Uniform f = e_z: U = 2 a f/(3 mu) = (0, 2/3) at every node. f = n (uniform pressure):
    # u = 0 (no flow from a pressure on a closed surface); this one exercises M_rr, M_rz, M_zr.
    # The error is the flat-segment geometry error, O(h^2).
    errors = [axi("sphere", n, mode)["max_error"] for n in (16, 32, 64, 128)]
    assert errors[-1] < (5e-5 if mode == "translate" else 1e-6), errors
    for coarse, fine in zip(errors, errors[1:]):
        order = math.log(coarse / fine, 2)
        assert order > 1.9, f"convergence order {order:.2f} < 2 (errors {errors})"
