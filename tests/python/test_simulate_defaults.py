"""A case run by hand takes the paper database's model choices that its flags leave open, so
that a first shear run at small Ca_s reaches the steady state the database holds (without them
it stepped explicitly with dt 7e-4 and ended at max_time with a node-scale ripple)."""
from __future__ import annotations

from pathlib import Path

import pytest

from capsmech.cli.case import REFERENCE_GRID, database_choices
from capsmech.workflow.grid import case_settings, load_grid

ROOT = Path(__file__).resolve().parents[2]
GRID = load_grid(ROOT / "config" / f"{REFERENCE_GRID}.yaml")


def _flags(flow: str, ca: float) -> dict[str, str]:
    settings = dict(case_settings(GRID, flow, ca))
    names = {"integrator": "--integrator", "k_b": "--kb"}
    return {names[k]: str(v) for k, v in settings.items() if k in names}


@pytest.mark.parametrize("ca", [0.01, 0.05, 0.3])
def test_a_shear_case_takes_the_database_integrator_and_bending(ca: float, capsys: pytest.CaptureFixture[str]) -> None:
    added = database_choices(["--flow", "shear", "--law", "NH", "--ca", str(ca), "--out", "x.h5"])
    expected = _flags("shear", ca)
    assert dict(zip(added[::2], added[1::2])) == expected
    assert expected["--kb"] == "0.0003"                            # the database's stated model choice
    assert ("--integrator" in expected) == (ca < 0.07)             # implicit steps below Ca_s 0.07
    assert "database's settings" in capsys.readouterr().out


def test_the_user_s_own_flags_win(capsys: pytest.CaptureFixture[str]) -> None:
    added = database_choices(["--flow", "shear", "--law", "NH", "--ca", "0.01", "--kb", "0", "--integrator=rk2",
                              "--out", "x.h5"])
    assert added == []
    assert capsys.readouterr().out == ""


@pytest.mark.parametrize("args", [["--namelist", "run.nml"], ["--flow", "shear", "--ca", "abc"], ["--help"],
                                  ["--flow", "shear", "--law", "NH", "--ca", "0.01", "--help"]])
def test_nothing_is_added_where_the_case_is_not_known(args: list[str]) -> None:
    assert database_choices(args) == []


def test_a_tube_case_gets_only_what_the_tube_grid_chooses() -> None:
    added = database_choices(["--flow", "tube", "--law", "NH", "--ca", "0.1", "--a-over-l", "0.8", "--out", "x.h5"])
    assert dict(zip(added[::2], added[1::2])) == _flags("tube", 0.1)
