"""The sharp parachute edge and the databases' accuracy there (capsmech.inversion.sharp_edge).

At large Ca_s the rear rim of a membrane without bending stiffness is a corner of the kernel's
meridian, and the tube databases (64 elements) are less accurate there than they state for
smooth shapes. The reference here is data the Python code under test did not make: the same
cases run by the kernel on a meridian twice as fine (128 elements, from the sphere, kernel
0.3.3, 2026-11-26; scripts/tube_mesh_accuracy.py measures more of them). A capsule whose true
shape is the finer one is fitted against the shipped database; its G_s error must lie within
the database error that fit-tube reports.
"""
from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import capsmech
from capsmech.inversion import sharp_edge
from capsmech.inversion.fitting import database_g_s_error, tube_inverter
from capsmech.inversion.noise import DOF
from capsmech.inversion.shape_fit import fit_shape
from capsmech.inversion.sharp_edge import (
    ACCURACY_BY_TURN,
    BUCKLING_ROW,
    NEAR_FOLD_ROW,
    NOT_A_ROOT_ROW,
    interpolated_accuracy,
    is_steady_root,
    largest_turn,
    row_accuracy,
)

#: law, a/l, Ca_s, then L_z [l], L_p [l], v_c/V of the case on 128 meridian elements, and whether
#: the row was among those that set ACCURACY_BY_TURN ("in") or not ("out"; "near": not, and
#: where the 64-element database is good, the region of the NH example batch). The rows at a/l 1.1
#: are on the database's edge: their finer lengths fall outside it and are not fitted.
FINER = """\
SK_C1    0.9  1.0  2.589719 0.689451 1.292342 in
GH_nu0.5 0.9  1.5  2.758145 1.252523 1.216384 in
GH_nu0.5 0.9  0.3  2.190283 0.421042 1.262244 out
SK_C1    1.0  0.8  3.045712 0.739376 1.242461 out
GH_nu0.2 0.9  0.8  2.721792 1.237355 1.208143 out
NH       1.0  0.08 2.745343 0.379663 1.234759 out
GH_nu0   0.85 0.2  2.055399 0.564112 1.262854 out
GH_nu0.5 1.05 0.5  3.110410 0.805512 1.182407 out
SK_C1    0.8  2.0  2.331761 0.784516 1.352628 out
NH       1.0  0.06 2.452263 0.237578 1.200972 near
NH       0.95 0.07 2.256129 0.258339 1.224039 near
NH       1.05 0.05 2.642976 0.196878 1.178179 near
NH       0.9  0.09 2.125529 0.302982 1.257554 near"""
MU, V = 1.0, 1e-3   # [Pa s], [m/s]: G_s = mu V / Ca_s


@pytest.fixture(scope="module")
def database():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return capsmech.load_database("tube-paper")


def test_largest_turn_of_known_polylines():
    # A right-angled corner between two straight lines, whatever the points on either side.
    r = np.concatenate([np.linspace(0, 1, 7), np.ones(5)])
    z = np.concatenate([np.zeros(7), np.linspace(0.2, 1, 5)])
    assert largest_turn(r, z) == pytest.approx(90.0)
    assert largest_turn(r[::-1], z[::-1]) == pytest.approx(90.0)
    # A circle of n points turns by 360/n degrees at each: two segments, twice that.
    n = 128
    t = np.linspace(0, 2 * np.pi, n + 1)
    assert largest_turn(np.cos(t), np.sin(t)) == pytest.approx(2 * 360 / n)
    assert math.isnan(largest_turn(np.array([0.0, 1.0]), np.array([0.0, 0.0])))


def test_the_databases_profiles_have_the_kernels_corner(database):
    # On the kernel's own meridian (64 elements) SK C = 1 at a/l 0.9 turns by 132 degrees at one
    # node at Ca_s 1 (a corner, meridional tension about zero there) and by at most 15 degrees
    # at Ca_s 0.02: the resampled profiles of the database tell the two apart.
    table = tube_inverter(database, "SK_C1").table
    for ca, low, high in ((1.0, 90.0, 180.0), (0.02, 0.0, 30.0)):
        i = int(np.flatnonzero(np.isclose(table.a_over_l, 0.9) & np.isclose(table.Ca_s, ca))[0])
        assert low <= largest_turn(table.profile_r[i], table.profile_z[i]) < high


def test_accuracy_interpolates_the_rows_and_is_the_databases_statement_on_smooth_rows():
    smooth, corner = ACCURACY_BY_TURN[0][1], ACCURACY_BY_TURN[-1][1]
    assert smooth.L_z_rel == pytest.approx(1e-3)        # the databases' own 0.1 %
    assert row_accuracy(math.nan) == smooth
    assert row_accuracy(120.0, 0.5) == corner
    assert row_accuracy(10.0, 0.01) == BUCKLING_ROW     # the rear's buckling, whatever the turn
    # Near the fold (Ca_s 0.02-0.03) a smooth row is as good as the near-fold spread, a corner as
    # its class: the larger of the two, component by component.
    near = row_accuracy(10.0, 0.03)
    assert (near.L_z_rel, near.L_p_abs, near.v_c_rel) == (NEAR_FOLD_ROW.L_z_rel, NEAR_FOLD_ROW.L_p_abs, NEAR_FOLD_ROW.v_c_rel)
    assert row_accuracy(120.0, 0.03) == corner
    assert row_accuracy(10.0, 0.04) == smooth
    # A row that is no root of the steady equations (its polish discarded) is at least as far as
    # the refills moved such rows, whatever its class; a corner keeps its larger L_p part.
    loose = row_accuracy(10.0, 0.1, root=False)
    assert (loose.L_z_rel, loose.L_p_abs, loose.v_c_rel) == (NOT_A_ROOT_ROW.L_z_rel, NOT_A_ROOT_ROW.L_p_abs,
                                                             NOT_A_ROOT_ROW.v_c_rel)
    assert row_accuracy(120.0, 0.5, root=False).L_p_rel == corner.L_p_rel
    mixed = interpolated_accuracy(np.array([10.0, 10.0]), np.array([0.1, 0.1]), np.array([0.5, 0.5]), 0.3,
                                  roots=np.array([True, False]))
    assert mixed[0] == pytest.approx(0.5 * (smooth.L_z_rel + NOT_A_ROOT_ROW.L_z_rel))
    one = interpolated_accuracy(np.array([10.0, 120.0, 20.0]), np.array([0.1, 0.5, 0.1]), np.array([0.0, 1.0, 0.0]), 1.0)
    assert one == pytest.approx((corner.L_z_rel, corner.L_p(1.0), corner.v_c_rel))
    halfway = interpolated_accuracy(np.array([10.0, 120.0]), np.array([0.1, 0.5]), np.array([0.5, 0.5]), 0.3)
    assert halfway[1] == pytest.approx(0.5 * (smooth.L_p(0.3) + corner.L_p(0.3)))


def test_the_rows_that_are_no_root_are_read_from_the_kernels_messages(database):
    """tube-paper (kernel 0.3.5) has 6 steady rows whose Newton polish the kernel discarded,
    also when rerun with a steady rule 100 and 1000 times stricter (26 before those reruns;
    validation: databases); the inverters see them, each row's flag next to its values."""
    assert is_steady_root("... Newton polish: residual 3.439E-07, largest growth rate 7.031E-03 V/l")
    assert not is_steady_root("...; the Newton polish stopped at residual 9.892E-03 V and was discarded")
    # A rerun says why it was rerun first, then its own outcome: a root here, none there.
    rerun = "rerun with a steady rule 100 times stricter (...) after the Newton polish was discarded: ..."
    assert is_steady_root(rerun + "; Newton polish: residual 1.737E-07, largest growth rate -1.044E-02 V/l")
    assert not is_steady_root(rerun + "; the Newton polish stopped at residual 2.342E-03 V and was discarded")
    not_roots = 0
    for law in database.laws:
        table = tube_inverter(database, law).table
        assert table.root is not None and table.root.shape == table.Ca_s.shape
        not_roots += int((~table.root).sum())
    assert not_roots == 6


def _fitted(database, line):
    law, a, ca, lz, lp, vcv, tag = line.split()
    ca, lz, lp, vcv = float(ca), float(lz), float(lp), float(vcv)
    inverter = tube_inverter(database, law)
    fit = inverter.fit(lz, lp, vcv * V, MU)
    error = database_g_s_error(inverter, lz, lp, vcv * V, MU, fit)
    return inverter, (lz, lp, vcv), fit, error, MU * V / ca, tag


def test_the_database_error_covers_a_finer_meridian(database, monkeypatch):
    # Measured (kernel-0.3.5 database): at a sharp edge G_s off by +0.1 to +7.6 % (the
    # 64-element database reads G_s high on deep parachutes); the reported database error
    # 6.4-21.3 %, covering all 9, the 7 rows
    # that did not set the accuracy classes among them. The databases' former statement (0.1 %
    # of L_z for every row) gave 0.5-1.2 % there and covered 1 of 9. Near the NH example batch
    # G_s is off by 0.1-0.7 %: the error reported is 2.3-3.0 % (the former 0.8-0.9 %).
    covered_by_former = 0
    for line in FINER.splitlines():
        inverter, lengths, fit, error, truth, tag = _fitted(database, line)
        assert fit.ok, line
        off = abs(fit.G_s - truth)
        assert off <= error, (line, off / truth, error / truth)
        if tag == "near":
            assert error < 0.03 * truth, line
            continue
        # With every row of the smooth class (the former statement), the same capsule:
        monkeypatch.setattr(sharp_edge, "ACCURACY_BY_TURN", ((math.inf, ACCURACY_BY_TURN[0][1]),))
        monkeypatch.setattr(sharp_edge, "BUCKLING_CA_S", 0.0)
        monkeypatch.setattr(sharp_edge, "NEAR_FOLD_CA_S", 0.0)
        former = database_g_s_error(inverter, lengths[0], lengths[1], lengths[2] * V, MU, fit)
        monkeypatch.undo()
        assert former < 0.015 * truth and error > 4 * former
        covered_by_former += off <= former
    assert covered_by_former <= 2


#: Meridians (129 nodes, front pole to rear pole, [l]) of four cases on 128 elements with a
#: corner at the rim (kernel 0.3.3, from the sphere: ``capsim --flow tube --law GH --nu-s 0.5
#: --a-over-l 0.9 --ca 1.5 --n-meridian 128``, and so on; ``profile/r``, ``profile/z``).
CORNER_PROFILES = Path(__file__).resolve().parents[1] / "data" / "corner_profiles_128.npz"


def _contour_fits(database, name, law, seeds=range(3)):
    """chi2/DOF of the contour fit with ``law`` of the traced shape ``name`` (the independent
    generator's tracing: 2.5 px steps, 0.45 px correlated noise, a 100 px tube radius)."""
    import independent_batches as ib

    l_px = ib.TUBE_RADIUS_UM / ib.PIXEL_SIZE_UM
    truth_law, a, ca = name.rsplit("_", 2)
    with np.load(CORNER_PROFILES) as f:
        section = ib._closed_section(f[name + "/r"], f[name + "/z"]) * l_px + [300.0, 150.0]
    values = []
    for seed in seeds:
        contour = ib.traced(section, np.random.default_rng(seed))
        fit = fit_shape(contour, tube_inverter(database, law), l_px, (float(a), float(ca)), 150.0)
        values.append(fit.chi2 / DOF if fit.ok else math.inf)
    return np.array(values)


@pytest.mark.parametrize("name", ["GH_nu0.5_0.9_1.5", "GH_nu0.2_0.9_0.8", "SK_C1_0.9_1.0", "GH_nu0_0.85_0.2"])
def test_a_capsule_of_the_right_law_with_a_sharp_edge_reaches_the_noise(database, name, monkeypatch):
    # Measured (tube-paper of kernel 0.3.5): the right law's best shape leaves chi2/DOF 0.3-1.2
    # with the rim's floor (0.2-3.0 against the 0.3.2 database); with the smooth floor alone
    # 4.7-6.4 on the two deep parachutes (GH nu_s 0.5 at Ca_s 1.5, 0.2 at 0.8: the misfit just
    # behind the rim; 10-15 against the 0.3.2 database, whose rows there differed from the finer
    # meridian's by more), which would call the right law "misfits noise" (its limit at p = 0.01
    # is 1.5-1.7 for 10-12 capsules). SK C = 1 on the GH shapes stays far off (12-290).
    law = name.rsplit("_", 2)[0]
    with_rim = _contour_fits(database, name, law)
    assert np.median(with_rim) < 2.0 and with_rim.max() < 3.5, with_rim
    if name in ("GH_nu0.5_0.9_1.5", "GH_nu0.2_0.9_0.8"):
        monkeypatch.setattr(sharp_edge, "row_accuracy", lambda turn, Ca_s=math.inf: ACCURACY_BY_TURN[0][1])
        assert np.median(_contour_fits(database, name, law, seeds=[0])) > 4.0
        monkeypatch.undo()
        assert np.min(_contour_fits(database, name, "SK_C1")) > 10.0


def test_a_strengths_systematic_weighs_the_rims_floor_by_where_the_effect_shows():
    """The databases' accuracy moves a diagnosed strength by (floor along the signature) over
    the signature: with one floor everywhere, floor / rms(signature) as before; with the rim's
    floor behind the rim, more where the effect's signature sits there, and as before where the
    signature sits in front of it."""
    from capsmech.diagnosis.scoring import BatchScore, _systematic_half_width
    from capsmech.io.measurements import Capsule

    points, n = 16, 4
    values = np.array([0.0, 1.0])
    capsules = [Capsule(f"c{i}", {"L_z": 200e-6, "pixel_size": 1e-6}, i + 2) for i in range(n)]
    usable, on_grid = np.ones(n, bool), np.ones(2, bool)
    smooth = np.full((n, points), 0.2)                 # 0.1 % of a 200 px capsule
    rim = smooth.copy()
    rim[:, 10:] = 7.0

    def systematic(signature, floor):
        scores = [BatchScore(np.ones(n), np.ones(n), np.ones(n), residual=np.zeros((n, points)), floor=floor),
                  BatchScore(np.ones(n), np.ones(n), np.ones(n), residual=np.tile(signature, (n, 1)), floor=floor)]
        return _systematic_half_width(capsules, values, scores, usable, on_grid, 0.5)

    front, behind = np.zeros(points), np.zeros(points)
    front[2:6], behind[11:15] = 1.0, 1.0
    rms = math.sqrt(4 / points)
    assert systematic(front, smooth) == pytest.approx(0.2 / rms)
    assert systematic(front, rim) == pytest.approx(0.2 / rms)
    assert systematic(behind, rim) == pytest.approx(7.0 / rms)
