"""The paper's two methods with the viscosity ratio of its shear experiment (issue 7, item 5):
the microrheometry database (config/microrheometry.yaml, lambda = 0.001, made by the
workflow) against the paper grid's shear database (lambda = 1)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from capsmech.cli.main import main
from capsmech.inversion.fitting import shear_inverter
from capsmech.inversion.microrheometry import PAPER_EXAMPLE, compare_methods, modulus_ratio
from capsmech.io.catalog import database_path
from capsmech.io.database import load_database

REPO = Path(__file__).resolve().parents[2]
SHEAR_DB = database_path("shear-paper")
LAMBDA_DB = database_path("shear-microrheometry")
LAWS = ("NH", "GH_nu0.5", "GH_nu0.2")
SUFFIX = "+lambda0.001"


@pytest.fixture(scope="module")
def databases():
    return load_database(SHEAR_DB), load_database(LAMBDA_DB)


def test_microrheometry_database_has_the_experiments_viscosity_ratio(databases):
    _, with_lambda = databases
    assert sorted(with_lambda.laws) == sorted(law + SUFFIX for law in LAWS)
    for law in LAWS:
        table = with_lambda.law(law + SUFFIX)
        assert table.steady.sum() >= 6, (law, list(table.status))


@pytest.mark.parametrize("law", LAWS)
def test_a_nearly_inviscid_core_deforms_more(databases, law):
    # Foessel et al. (2011): the internal viscosity lowers the deformation as it grows; at the
    # same Ca_s, lambda = 0.001 gives a larger D12 than lambda = 1 on every steady case.
    base, with_lambda = databases
    b, e = base.law(law), with_lambda.law(law + SUFFIX)
    for ca, d12 in zip(e.columns["Ca_s"][e.steady], e.columns["D12"][e.steady]):
        match = np.flatnonzero(np.isclose(b.columns["Ca_s"], ca) & b.steady)
        if match.size:
            assert d12 > b.columns["D12"][match[0]], (law, ca)


@pytest.mark.parametrize("law", LAWS)
def test_the_viscosity_ratio_raises_the_fitted_modulus(databases, law):
    # Same D12 read at a smaller Ca_s -> a larger G_s; the correction is the ratio of the two
    # analyses and must equal the direct refit of the section 4.3 capsule.
    base, with_lambda = databases
    inv_b, inv_e = shear_inverter(base, law), shear_inverter(with_lambda, law + SUFFIX)
    kwargs = {k: PAPER_EXAMPLE[k] for k in ("a", "shear_rate", "mu")}
    before = inv_b.modulus(D12=PAPER_EXAMPLE["D12"], **kwargs).G_s
    after = inv_e.modulus(D12=PAPER_EXAMPLE["D12"], **kwargs).G_s
    assert after > before
    # modulus() takes a as given, so its ratio is Ca_s,1 / Ca_s,lambda; modulus_ratio adds the
    # radius measured through L3/a.
    l3 = inv_e.fit(D12=PAPER_EXAMPLE["D12"]).L3_over_a / inv_b.fit(D12=PAPER_EXAMPLE["D12"]).L3_over_a
    ratio = modulus_ratio(inv_b, inv_e, np.array([PAPER_EXAMPLE["D12"]]))[0]
    assert ratio == pytest.approx(after / before * np.sqrt(l3), rel=1e-12)


def test_identical_databases_need_no_correction(databases):
    base, _ = databases
    for row in compare_methods(base, base, ""):
        assert row.ratio_mean == pytest.approx(1.0, abs=1e-12)
        assert row.example_after == row.example_before


def test_compare_methods_cli_prints_the_table_and_refuses_a_missing_group(capsys):
    paths = ["--database", str(SHEAR_DB), "--lambda-database", str(LAMBDA_DB)]
    assert main(["compare-methods", *paths]) == 0
    out = capsys.readouterr().out
    assert all(f"| {law} |" in out for law in LAWS)
    assert main(["compare-methods", *paths, "--lambda-value", "0.2"]) == 2
    assert "no law group NH+lambda0.2" in capsys.readouterr().err
