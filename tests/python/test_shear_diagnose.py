"""The viscosity ratio as a diagnose candidate for shear batches (capsmech.diagnosis.shear, issue 7).

Facts checked:
- the score is exact on exact data: capsules built from one group's database nodes (no noise)
  give chi2 = 0 for that group and its G_s to 1e-9; the same capsules read with the lambda = 1
  group give a G_s that falls with D12 (an inviscid core deforms more at the same Ca_s);
- the propagated standard error of ln G_s is that of the +-1 px noise model (Monte Carlo);
- the batch G_s states the database's share of its error: what moving every row's D12 by its
  stated error does to the batch G_s (it does not average out over capsules);
- capsules outside a group's D12 range are flagged with the reason, and a candidate is
  scored only on the capsules both groups fit;
- on the shipped kernel batches: lambda = 0.001 undeclared (shear_batch_L) is named, G_s moves
  to the truth and its drift with D12 disappears; with lambda = 1 (shear_batch_A) no
  candidate is supported; the same batches with the inclination angle measured to 1 deg
  (_theta) decide far more sharply, and the same way;
- the batches are kernel runs: re-running a capsule reproduces its steady D12.
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from capsmech.cli.main import main
from capsmech.diagnosis.shear import (
    ShearGroups,
    database_error,
    diagnose_shear,
    length_error,
    modulus,
    score_group,
    weighted_mean,
)
from capsmech.diagnosis.undeclared_shear import law_key, read_shear_truth
from capsmech.inversion.fitting import database_d12_error, shear_inverter
from capsmech.inversion.inverters import ShearInverter
from capsmech.io.catalog import database_path
from capsmech.io.database import load_database
from capsmech.io.measurements import Capsule, read_measurements

ROOT = Path(__file__).resolve().parents[2]
BATCHES = ROOT / "data" / "examples" / "undeclared"
LAMBDA_KEY = "NH+lambda0.001"
G_S = 0.04
MU = 0.756


@pytest.fixture(scope="module")
def groups():
    return ShearGroups([load_database(database_path("shear-paper")),
                        load_database(database_path("shear-microrheometry"))])


def truth(name: str) -> dict[str, dict[str, str]]:
    with open(BATCHES / f"{name}_truth.csv", newline="", encoding="utf-8") as stream:
        return {row["id"]: row for row in csv.DictReader(stream)}


def node_capsules(groups: ShearGroups, key: str, a: float = 45e-6) -> list[Capsule]:
    """Noise-free capsules at a group's steady database nodes with D12 >= 0.35 (the last node
    left out: D12 recomputed from its semi-axes may round past the range's end), radius a, of
    modulus G_S. Their shear rate is set with the radius the inversion reads from the
    semi-axes, a sqrt(l1 l2 l3) (the kernel's semi-axes give l1 l2 l3 = 0.992, not 1), so
    that the inversion of exact data must return G_S exactly."""
    database = next(d for d in groups.databases if key in d.laws)
    rows = database.law(key).steady_rows()
    out = []
    for k in np.flatnonzero((rows["D12"] >= 0.35) & (rows["D12"] < np.nanmax(rows["D12"]))):
        l1, l2, l3, ca, theta = (float(rows[c][k]) for c in ("L1_over_a", "L2_over_a", "L3_over_a", "Ca_s", "theta"))
        rate = ca * G_S / (MU * a * math.sqrt(l1 * l2 * l3))
        out.append(Capsule(f"n{k}", {"L1": l1 * a, "L2": l2 * a, "shear_rate": rate, "mu": MU, "theta": theta}, k))
    return out


@pytest.mark.parametrize("key", ["NH", LAMBDA_KEY])
def test_exact_nodes_give_zero_chi2_and_the_modulus(groups, key):
    capsules = node_capsules(groups, key)
    assert len(capsules) >= 4
    score = score_group(capsules, groups.inverter(key), key, theta=groups.theta(key))
    assert score.fitted.all(), score.flags
    mean, _, chi2 = weighted_mean(score.y, score.s)
    assert chi2 < 1e-12
    assert np.all(np.abs(score.t) < 1e-9)
    assert modulus(score.y, score.s)[0] == pytest.approx(G_S, rel=1e-9)


def test_batch_g_s_carries_the_database_error_that_shifting_its_rows_shows(groups):
    """Every capsule reads the same rows: moving each steady row's D12 by its stated error
    (time and mesh, shear-paper) moves the batch G_s by the stated database share, to first
    order (errors ~1e-3: within 5 % of itself), however many capsules there are."""
    capsules = node_capsules(groups, "NH")
    rows = groups._database("NH").law("NH").steady_rows()
    error = database_d12_error(rows)
    assert np.all(np.isfinite(error[rows["D12"] >= 0.35])) and np.nanmax(error) > 1e-4
    score = score_group(capsules, groups.inverter("NH"), "NH")
    g_s, _ = modulus(score.y, score.s)
    stated = database_error(g_s, score.s, score.e)
    shifted = ShearInverter(rows["Ca_s"], rows["D12"] * (1 + np.nan_to_num(error)), rows["L3_over_a"])
    moved = score_group(capsules, shifted, "NH")
    # The same weights: the database share is a shift of every capsule's ln G_s.
    w = 1.0 / score.s ** 2
    g_shifted = math.exp(float(np.sum(w * moved.y) / np.sum(w)))
    assert stated > 0
    assert stated == pytest.approx(abs(g_shifted - g_s), rel=0.05)
    # Doubling the batch (the same capsules twice) shrinks the noise's share by sqrt(2), not
    # the database's.
    twice = score_group(capsules + capsules, groups.inverter("NH"), "NH")
    assert modulus(twice.y, twice.s)[1] == pytest.approx(modulus(score.y, score.s)[1] / math.sqrt(2), rel=1e-9)
    assert database_error(g_s, twice.s, twice.e) == pytest.approx(stated, rel=1e-12)
    # Rows that state no error contribute none (never a made-up zero error elsewhere).
    bare = score_group(capsules, ShearInverter(rows["Ca_s"], rows["D12"], rows["L3_over_a"]), "NH")
    assert np.all(np.isnan(bare.e)) and database_error(g_s, bare.s, bare.e) == 0.0


def test_lambda_one_reads_an_inviscid_core_as_a_softening_material(groups):
    """Read with lambda = 1, exact lambda = 0.001 capsules give G_s below the truth, the more
    the larger D12 (capsmech.inversion.microrheometry: ratio 1.13 to 1.37 over D12 0.35-0.5)."""
    capsules = node_capsules(groups, LAMBDA_KEY)
    base = score_group(capsules, groups.inverter("NH"), "NH")
    ok = base.fitted
    assert ok.sum() >= 3
    g = np.exp(base.y[ok])
    assert np.all(g < G_S / 1.1)
    assert np.all(np.diff(g[np.argsort(base.d12[ok])]) < 0)
    result = diagnose_shear(capsules, groups, "NH", {"lambda": LAMBDA_KEY})
    assert result.results[0].chi2 < 1e-12 < result.results[0].chi2_base


def test_standard_error_is_that_of_the_pixel_noise(groups):
    """s_i of one capsule against the spread of ln G_s over 4000 noisy copies (uniform +-1 px)."""
    capsule = read_measurements(BATCHES / "shear_batch_A.csv", "shear")[0]
    inverter = groups.inverter("NH")
    s = score_group([capsule], inverter, "NH").s[0]
    bound = length_error(capsule) * math.sqrt(3)
    rng = np.random.default_rng(3)
    samples = []
    for dL1, dL2 in rng.uniform(-bound, bound, (4000, 2)):
        fit = inverter.fit(L1=capsule["L1"] + dL1, L2=capsule["L2"] + dL2, shear_rate=capsule["shear_rate"],
                           mu=capsule["mu"])
        samples.append(math.log(fit.G_s))
    # 4000 samples: the standard deviation is known to ~1.1 %.
    assert np.std(samples, ddof=1) == pytest.approx(s, rel=0.05)


def test_capsules_outside_a_group_are_flagged_and_left_out(groups):
    capsules = read_measurements(BATCHES / "shear_batch_L.csv", "shear")
    result = diagnose_shear(capsules, groups, "NH", {"law GH_nu0.5": "GH_nu0.5"})
    r = result.results[0]
    lo, hi = shear_inverter(groups.databases[0], "GH_nu0.5").D12_range
    outside = np.array([not lo <= (c["L1"] - c["L2"]) / (c["L1"] + c["L2"]) <= hi for c in capsules])
    assert outside.any() and not outside.all()
    assert all("outside the database" in f for f, o in zip(r.score.flags, outside) if o)
    assert np.all(np.isnan(r.score.y[outside]))
    assert r.capsules == int((~outside & result.base.fitted).sum())


def test_undeclared_viscosity_ratio_is_named_and_corrected(groups):
    capsules = read_measurements(BATCHES / "shear_batch_L.csv", "shear")
    result = diagnose_shear(capsules, groups, "NH")
    true = read_shear_truth(BATCHES / "shear_batch_L_truth.csv")
    assert result.chosen is not None, result.verdict
    assert result.chosen.law == law_key("NH", true["viscosity_ratio"]) == LAMBDA_KEY, result.verdict
    c = result.chosen
    g_true = true["G_s"]
    assert abs(c.g_s_after[0] - g_true) < abs(c.g_s_before[0] - g_true)
    assert abs(c.g_s_after[0] - g_true) < 3 * c.g_s_after[1]
    assert c.drift_p_before < 0.05 < c.drift_p_after


def test_batch_without_effect_supports_no_candidate(groups):
    capsules = read_measurements(BATCHES / "shear_batch_A.csv", "shear")
    result = diagnose_shear(capsules, groups, "NH")
    assert result.chosen is None, result.verdict
    base = result.base
    # The noise model holds: chi2 about n - 1 (within 3 of its standard deviations).
    n = int(base.fitted.sum())
    assert abs(weighted_mean(base.y[base.fitted], base.s[base.fitted])[2] - (n - 1)) < 3 * math.sqrt(2 * (n - 1))


@pytest.mark.parametrize("name", ["shear_batch_A", "shear_batch_L"])
def test_measured_inclination_sharpens_the_same_verdict(groups, name):
    plain = diagnose_shear(read_measurements(BATCHES / f"{name}.csv", "shear"), groups, "NH")
    sharp = diagnose_shear(read_measurements(BATCHES / f"{name}_theta.csv", "shear"), groups, "NH")
    assert (sharp.chosen is None) == (plain.chosen is None)
    if plain.chosen is not None:
        assert sharp.chosen.law == plain.chosen.law == LAMBDA_KEY
        assert sharp.chosen.cv_p_value < plain.chosen.cv_p_value / 10
    lam, lam_plain = sharp.results[0], plain.results[0]
    assert lam.law == LAMBDA_KEY
    # The angle's evidence adds to that of the G_s drift, in the same direction.
    assert abs(lam.bic_drop) > abs(lam_plain.bic_drop) and lam.bic_drop * lam_plain.bic_drop > 0


def test_theta_column_is_read_and_checked(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("id,L1 [um],L2 [um],shear_rate [1/s],mu [Pa s],theta [deg]\nc1,60,25,350,0.756,30\n")
    assert read_measurements(path, "shear")[0]["theta"] == pytest.approx(math.pi / 6)
    path.write_text("id,L1 [um],L2 [um],shear_rate [1/s],mu [Pa s],theta [deg]\nc1,60,25,350,0.756,95\n")
    with pytest.raises(ValueError, match="field 'theta' must be below 90 deg"):
        read_measurements(path, "shear")


def test_cli_writes_the_report_and_names_bad_fields(tmp_path, capsys):
    report = tmp_path / "report.md"
    assert main(["diagnose-shear", str(BATCHES / "shear_batch_L.csv"), "--out", str(report)]) == 0
    assert "verdict: viscosity ratio" in capsys.readouterr().out
    assert (tmp_path / "report_gs_d12.png").exists()
    assert "NH+lambda0.001" in report.read_text()
    for args, field in ((["--law", "XX"], "--law"), (["--pixel-size", "-1"], "--pixel-size"),
                        (["--lambda-value", "0.2"], "--lambda-value"), (["--theta-error", "0"], "--theta-error")):
        assert main(["diagnose-shear", str(BATCHES / "shear_batch_A.csv"), *args]) == 2
        assert f"capsmech: error: {field}" in capsys.readouterr().err
    assert main(["diagnose-shear", str(BATCHES / "batch_A.csv")]) == 2
    assert "the header has the columns of a tube file" in capsys.readouterr().err


def _rerun(name: str, capsule_id: str) -> tuple[float, float]:
    from capsmech.diagnosis.undeclared_shear import simulate_shear

    row = truth(name)[capsule_id]
    return simulate_shear(float(row["Ca_s"]), row["law"]).D12, float(row["D12"])


def test_lambda_one_batch_capsule_is_a_kernel_run():
    """A few seconds: the lambda = 1 capsule's steady D12 against the truth file's. The file was
    made by kernel 0.3.0, whose stopping rule stopped in the decay after the overshoot, +0.4 %
    above the long-time limit at Ca_s 0.3 (validation: shear flow, stopping rule); kernel 0.3.2
    runs to the limit. Measured: 0.390059 against 0.391481 (-0.36 %). Until the batch is
    remade, the rerun must lie below the recorded value by that bias, not more."""
    d12, recorded = _rerun("shear_batch_A", "c002")
    assert -0.006 < d12 / recorded - 1 < -0.001


@pytest.mark.validate
def test_lambda_batch_capsule_is_a_kernel_run():
    """About a minute: the same for a lambda = 0.001 capsule."""
    d12, recorded = _rerun("shear_batch_L", "c002")
    assert d12 == pytest.approx(recorded, rel=1e-5)
