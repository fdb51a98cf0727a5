"""Grid validation: malformed grids are refused with a message naming the key, by capsmech and
by the workflow itself."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from capsmech.workflow.grid import GridError, Law, expand_cases, load_grid, parse_law, validate_grid

from conftest import SMOKE, run_snakemake

SMOKE_GRID = yaml.safe_load(SMOKE.read_text())


def malformed(path: tuple, value) -> dict:
    grid = copy.deepcopy(SMOKE_GRID)
    node = grid
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return grid


BAD_GRIDS = [
    # (what is wrong, grid, text the message must contain)
    ("negative Ca", malformed(("tube", "Ca_s"), [0.002, -0.1]), "tube.Ca_s[1]: -0.1 is less than or equal to the minimum of 0"),
    ("unknown law", malformed(("shear", "laws"), ["NH", "MR"]), "shear.laws[1]: 'MR' does not match"),
    ("empty list", malformed(("shear", "Ca_s"), []), "shear.Ca_s: [] should be non-empty"),
    ("unknown setting", malformed(("tube", "settings"), {"n_meridan": 24}), "tube.settings: Additional properties are not allowed ('n_meridan'"),
    ("nu_s out of range", malformed(("tube", "laws"), ["GH_nu1.5"]), "tube.laws[0]: law key 'GH_nu1.5': nu_s must lie in (-1, 1)"),
    ("duplicate Ca", malformed(("shear", "Ca_s"), [0.05, 0.05]), "shear.Ca_s: duplicate values"),
    ("unknown effect", malformed(("tube", "laws"), ["NH+swelling0.1"]), "tube.laws[0]: law key 'NH+swelling0.1': unknown effect 'swelling'"),
    ("effect out of range", malformed(("tube", "laws"), ["NH+prestress0.9"]), "tube.laws[0]: law key 'NH+prestress0.9': prestress must lie in [0, 0.5]"),
    ("offset without the 3D model", malformed(("tube", "laws"), ["NH+offset0.2"]), "tube.laws[0]: law key 'NH+offset0.2': offset needs tube.settings.model: 3d"),
    ("offset in shear", malformed(("shear", "laws"), ["NH+offset0.2"]), "shear.laws[0]: law key 'NH+offset0.2': the kernel has offset only in tube flow"),
    ("3D mesh level with the axisymmetric model", malformed(("tube", "settings"), {"level": 3}),
     "tube.settings.level: applies to tube.settings.model: 3d only (this grid's model is axi)"),
    ("meridian elements with the 3D model", malformed(("tube", "settings"), {"model": "3d", "n_meridian": 64}),
     "tube.settings.n_meridian: applies to tube.settings.model: axi only (this grid's model is 3d)"),
    ("unknown shear integrator", malformed(("shear", "settings"), {"integrator": "newton"}), "shear.settings.integrator: 'newton' is not one of"),
    ("implicit threshold not positive", malformed(("shear", "settings"), {"implicit_below_Ca_s": 0}), "shear.settings.implicit_below_Ca_s: 0 is less than or equal to the minimum of 0"),
]


@pytest.mark.parametrize("what, grid, message", BAD_GRIDS, ids=[b[0] for b in BAD_GRIDS])
def test_validate_grid_names_the_key(what: str, grid: dict, message: str) -> None:
    with pytest.raises(GridError) as error:
        validate_grid(grid, "bad.yaml")
    assert message in str(error.value)
    assert str(error.value).startswith("bad.yaml: invalid grid")


@pytest.mark.parametrize("what, grid, key", [(b[0], b[1], b[2].split(":")[0]) for b in BAD_GRIDS[:3]],
                         ids=[b[0] for b in BAD_GRIDS[:3]])
def test_workflow_refuses_malformed_grid(what: str, grid: dict, key: str, tmp_path: Path) -> None:
    """Snakemake stops before running anything, and its message names the key."""
    config = tmp_path / "bad.yaml"
    config.write_text(yaml.safe_dump(grid))
    result = run_snakemake(tmp_path / "work", config, "--dry-run")
    assert result.returncode != 0
    assert "Error validating config file" in result.stdout
    # tube.Ca_s[1] -> On instance['tube']['Ca_s'][1]
    instance = "".join(f"['{part}']" for part in key.split("[")[0].split(".")) + \
        "".join(f"[{index}" for index in key.split("[")[1:])
    assert f"On instance{instance}" in result.stdout
    assert not (tmp_path / "work" / "results").exists()


def test_lambda_in_the_3d_tube_is_accepted() -> None:
    # capsim has lambda /= 1 in both tube models (tests/kernel/test_tube3d_lambda.py).
    grid = malformed(("tube", "laws"), ["NH", "NH+lambda0.1"])
    grid["tube"]["settings"] = {"model": "3d"}
    validate_grid(grid, "grid.yaml")
    args = [case.kernel_args() for case in expand_cases(grid, "tube")]
    assert any(a[a.index("--lambda") + 1] == "0.1" and a[a.index("--model") + 1] == "3d"
               for a in args if "--lambda" in a)


def test_tube_laws_take_lambda() -> None:
    grid = malformed(("tube", "laws"), ["NH", "NH+lambda0.2"])
    validate_grid(grid, "grid.yaml")
    args = [case.kernel_args() for case in expand_cases(grid, "tube")]
    assert any(a[a.index("--lambda") + 1] == "0.2" for a in args if "--lambda" in a)
    assert sum("--lambda" in a for a in args) == len(args) // 2


def test_smoke_grid_is_valid_and_expands() -> None:
    grid = load_grid(SMOKE)
    tube, shear = expand_cases(grid, "tube"), expand_cases(grid, "shear")
    assert len(tube) == 2 * 3 * 2 and len(shear) == 2 * 3
    assert tube[0].relative_path == "tube/NH/a0.4_Ca0.002.h5"
    assert tube[0].kernel_args() == ["--flow", "tube", "--law", "NH", "--ca", "0.002",
                                     "--a-over-l", "0.4", "--n-meridian", "24"]


def test_paper_grid_is_valid() -> None:
    grid = load_grid(SMOKE.parent / "paper.yaml")
    assert grid["tube"]["laws"] == ["NH", "SK_C1", "GH_nu0.5", "GH_nu0.2", "GH_nu0"]
    assert grid["tube"]["a_over_l"] == [0.7, 0.75, 0.8, 0.85, 0.9, 0.95, 1.0, 1.05, 1.1]
    assert min(grid["shear"]["Ca_s"]) == 0.01 and max(grid["shear"]["Ca_s"]) == 1.0


@pytest.mark.parametrize("key, law, flags", [
    ("NH", Law("NH", "NH"), ["--law", "NH"]),
    ("SK_C1", Law("SK_C1", "SK", C=1.0), ["--law", "SK", "--C", "1"]),
    ("GH_nu0.5", Law("GH_nu0.5", "GH", nu_s=0.5), ["--law", "GH", "--nu-s", "0.5"]),
    ("GH_nu0", Law("GH_nu0", "GH", nu_s=0.0), ["--law", "GH", "--nu-s", "0"]),
    ("GH_nu0.5+prestress0.05", Law("GH_nu0.5+prestress0.05", "GH", nu_s=0.5, effects=(("prestress", 0.05),)),
     ["--law", "GH", "--nu-s", "0.5", "--prestress", "0.05"]),
])
def test_law_keys_map_to_kernel_flags(key: str, law: Law, flags: list[str]) -> None:
    assert parse_law(key) == law
    assert parse_law(key).kernel_args() == flags


def test_offset_grid_with_the_3d_model_expands_to_3d_cases() -> None:
    grid = malformed(("tube", "laws"), ["NH+offset0.2"])
    grid["tube"]["settings"] = {"model": "3d", "level": 2, "wall_h_far": 0.28, "wall_h_centre": 0.14}
    validate_grid(grid)
    args = expand_cases(grid, "tube")[0].kernel_args()
    for flag, value in (("--offset", "0.2"), ("--model", "3d"), ("--level", "2"), ("--wall-h-centre", "0.14")):
        assert args[args.index(flag) + 1] == value


def test_implicit_below_Ca_s_changes_exactly_the_cases_below_it() -> None:
    grid = copy.deepcopy(SMOKE_GRID)
    grid["shear"]["Ca_s"] = [0.01, 0.05, 0.07, 0.2]
    before = expand_cases(grid, "shear")
    grid["shear"]["settings"] = {**grid["shear"].get("settings", {}), "implicit_below_Ca_s": 0.07}
    validate_grid(grid)
    after = expand_cases(grid, "shear")
    changed = [b.Ca_s for b, a in zip(before, after, strict=True) if a.kernel_args() != b.kernel_args()]
    assert sorted(set(changed)) == [0.01, 0.05]          # 0.07 itself is not below
    for case in after:
        args = case.kernel_args()
        assert "implicit_below_Ca_s" not in " ".join(args)
        assert (args[args.index("--integrator") + 1] == "implicit") if case.Ca_s < 0.07 else "--integrator" not in args
