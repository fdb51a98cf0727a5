"""The validation tables computed from the shipped data (scripts/validation_tables.py, put into
the docs at build time by docs/hooks/validation_tables.py) hold what the pages say of them."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def tables():
    spec = importlib.util.spec_from_file_location("validation_tables", ROOT / "scripts" / "validation_tables.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def rows(table: str) -> list[list[str]]:
    return [[cell.strip() for cell in line.strip("|").split("|")] for line in table.splitlines()[2:]]


def test_every_marker_names_a_table(tables):
    names = {line.split()[2] for page in (ROOT / "docs").rglob("*.md") for line in page.read_text().splitlines()
             if line.startswith("<!-- generated-table ")}
    assert names and names <= set(tables.TABLES)


def test_the_databases_table_lists_every_shipped_database(tables):
    from capsmech.io.catalog import shipped_databases

    listed = {row[0].strip("`") for row in rows(tables.databases())}
    assert listed == {d.name for d in shipped_databases() if d.kind == "database"}


def test_nh_reaches_continuous_elongation_sooner_in_a_narrower_tube(tables):
    """The paper (figure 3): the larger the capsule for its tube, the smaller the last steady Ca_s of NH."""
    nh = next(row for row in rows(tables.tube_steady_range()) if row[0] == "NH")
    last = [float(v) for v in nh[1:]]
    assert all(b <= a for a, b in zip(last, last[1:])), last


def test_each_example_batch_is_fitted_best_by_its_own_law(tables):
    """The contour misfit is smallest with the law the batch was made with (the paper's basis for
    telling laws apart)."""
    by_batch: dict[str, dict[str, float]] = {}
    for batch, law, _, misfit, *_ in rows(tables.example_fits()):
        by_batch.setdefault(batch.strip("`"), {})[law] = float(misfit)
    assert min(by_batch["tube_batch_NH"], key=by_batch["tube_batch_NH"].get) == "NH"
    assert min(by_batch["tube_batch_GH_nu0.5"], key=by_batch["tube_batch_GH_nu0.5"].get) == "GH_nu0.5"
