"""The API as the only front door, and options that mean the same in every command.

- diagnose-shear, compare-methods, make-batch and simulate reach their domain code through
  ``capsmech.api`` (the call stack at the domain function holds an ``api`` frame between the
  CLI's and the domain's), and fit-tube loads its database and checks its laws once;
- law keys are parsed in one module, ``capsmech.io.laws``: the inversion and the diagnosis do
  not import the workflow's grid for them, and the grid's ``parse_law`` is the same parser (its
  error a ``GridError``);
- in every command, ``--law`` is repeatable or says it takes one key, ``--out`` never names a
  Markdown report (``--report`` does; the old ``--out REPORT.md`` still works, with a warning),
  and every command that reports a result has ``--json`` and ``--force``.
"""
from __future__ import annotations

import argparse
import ast
import inspect
import warnings
from pathlib import Path
from typing import Any

import pytest

import capsmech
from capsmech.cli.main import build_parser, main

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "analysis" / "src" / "capsmech"
EXAMPLES = ROOT / "data" / "examples"
#: Commands that report a result (a table, a verdict, a case, the files of a batch).
REPORTING = ("fit-tube", "fit-shear", "population", "diagnose", "diagnose-shear", "compare-methods", "extract",
             "extract-shear", "show", "make-batch", "databases")


def stack_modules() -> list[str]:
    """The modules of the calling frames, innermost first."""
    return [frame.frame.f_globals.get("__name__", "") for frame in inspect.stack()[1:]]


def through_the_api(modules: list[str]) -> bool:
    """The calls go CLI -> api -> here: an api frame, and a cli frame outside it."""
    api = next((k for k, m in enumerate(modules) if m == "capsmech.api"), None)
    cli = next((k for k, m in enumerate(modules) if m.startswith("capsmech.cli")), None)
    return api is not None and cli is not None and api < cli


class Spy:
    """Wraps a function; records the call stack's modules at each call."""

    def __init__(self, function: Any, result: Any = None) -> None:
        self.function, self.result, self.stacks = function, result, []

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        self.stacks.append(stack_modules())
        return self.result if self.result is not None else self.function(*args, **kwargs)


def run(argv: list[str]) -> int:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", capsmech.CapsmechWarning)
        return main(argv)


def test_diagnose_shear_goes_through_the_api(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from capsmech.diagnosis import shear

    spy = Spy(shear.diagnose_shear)
    monkeypatch.setattr(shear, "diagnose_shear", spy)
    assert run(["diagnose-shear", str(EXAMPLES / "undeclared" / "shear_batch_L.csv")]) == 0
    assert len(spy.stacks) == 1 and through_the_api(spy.stacks[0])


def test_compare_methods_goes_through_the_api(monkeypatch: pytest.MonkeyPatch) -> None:
    from capsmech.inversion import microrheometry

    spy = Spy(microrheometry.compare_methods)
    monkeypatch.setattr(microrheometry, "compare_methods", spy)
    assert run(["compare-methods", "--law", "NH"]) == 0
    assert len(spy.stacks) == 1 and through_the_api(spy.stacks[0])


def test_make_batch_goes_through_the_api(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    from capsmech.diagnosis import undeclared_tube

    # No kernel run: the batch is a stand-in, written by a stand-in writer.
    batch = undeclared_tube.Batch(rows=[{"id": "s000"}], truth=[{"id": "s000"}], effects={"prestress": 0.05})
    made = Spy(undeclared_tube.make_batch, batch)
    out = tmp_path / "b.csv"
    written = Spy(undeclared_tube.write_batch, (out, tmp_path / "b_truth.csv"))
    monkeypatch.setattr(undeclared_tube, "make_batch", made)
    monkeypatch.setattr(undeclared_tube, "write_batch", written)
    assert run(["make-batch", "--effect", "prestress", "--strength", "0.05", "--out", str(out),
                "--json", str(tmp_path / "b.json")]) == 0
    assert len(made.stacks) == len(written.stacks) == 1
    assert through_the_api(made.stacks[0]) and through_the_api(written.stacks[0])
    assert f"wrote {out} (1 capsules)" in capsys.readouterr().out


def test_simulate_goes_through_the_api(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    import subprocess
    import sys

    kernel = tmp_path / "fake_capsim"
    kernel.write_text(f"#!{sys.executable}\nprint('fake capsim')\n", encoding="utf-8")
    kernel.chmod(0o755)
    monkeypatch.setenv("CAPSIM", str(kernel))
    spy = Spy(subprocess.Popen)
    monkeypatch.setattr(subprocess, "Popen", spy)
    assert main(["simulate", "--version"]) == 0
    assert len(spy.stacks) == 1 and through_the_api(spy.stacks[0])


def test_fit_tube_loads_its_database_and_checks_its_laws_once(monkeypatch: pytest.MonkeyPatch,
                                                              tmp_path: Path) -> None:
    import capsmech.api as api

    loads, checks = Spy(api.load_database), Spy(api.check_laws)
    monkeypatch.setattr(api, "load_database", loads)
    monkeypatch.setattr(api, "check_laws", checks)
    assert run(["fit-tube", str(EXAMPLES / "tube_batch_NH.csv"), "--law", "NH", "--out", str(tmp_path / "f.h5")]) == 0
    assert len(loads.stacks) == 1 and len(checks.stacks) == 1
    # The results' provenance is the database loaded (its path, in the HDF5 file).
    import h5py

    from capsmech.io.catalog import database_path

    with h5py.File(tmp_path / "f.h5", "r") as f:
        assert Path(f.attrs["database"]) == database_path("tube-paper")


def test_an_unknown_law_names_the_option(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["fit-tube", str(EXAMPLES / "tube_batch_NH.csv"), "--law", "NH", "--law", "XY"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("capsmech: error: --law: ") and "'XY'" in err and "valid laws: NH" in err


def imported_modules(path: Path) -> set[str]:
    """Every module ``path`` imports, at any depth of its code."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module:
            found |= {node.module, *(f"{node.module}.{alias.name}" for alias in node.names)}
        elif isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
    return found


def test_law_keys_are_parsed_in_one_ground_floor_module() -> None:
    for layer in ("inversion", "diagnosis", "io"):
        for path in (PACKAGE / layer).rglob("*.py"):
            # The workflow's grids themselves (effect_grid writes them) are another matter.
            laws = imported_modules(path) & {f"capsmech.workflow.grid.{name}" for name in ("parse_law", "Law", "EFFECTS")}
            assert not laws, f"{path.relative_to(ROOT)} imports {laws} (law keys: capsmech.io.laws)"
    from capsmech.io.laws import LawKeyError, parse_law
    from capsmech.workflow import grid

    # The kernel's flags for each form of key (capsim --help lists --law, --C, --nu-s, --kb).
    assert parse_law("GH_nu0.5+kb0.01").kernel_args() == ["--law", "GH", "--nu-s", "0.5", "--kb", "0.01"]
    assert parse_law("SK_C1").kernel_args() == ["--law", "SK", "--C", "1"]
    assert grid.parse_law("NH+prestress0.05") == parse_law("NH+prestress0.05")
    with pytest.raises(LawKeyError, match="nu_s must lie in"):
        parse_law("GH_nu1.5")
    with pytest.raises(grid.GridError, match="unknown law key 'MR'"):
        grid.parse_law("MR")


def subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def test_options_mean_the_same_in_every_command() -> None:
    commands = subcommands()
    for name, sub in commands.items():
        options = {o: a for a in sub._actions for o in a.option_strings}
        law = options.get("--law")
        if law is not None:
            # Repeatable where several laws are fitted; elsewhere one key, a repeat refused.
            assert isinstance(law, argparse._AppendAction) or type(law).__name__ == "_OneLawAction", name
        out = options.get("--out")
        if out is not None and out.help != argparse.SUPPRESS:
            assert not str(out.metavar).endswith(".md"), f"{name}: --out names a Markdown report"
        if name in REPORTING:
            assert "--json" in options and "--force" in options, name


def test_the_old_report_option_still_works_with_a_warning(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    batch = str(EXAMPLES / "undeclared" / "shear_batch_A.csv")
    old, new = tmp_path / "old.md", tmp_path / "new.md"
    assert main(["diagnose-shear", batch, "--out", str(old)]) == 0
    err = capsys.readouterr().err
    assert "warning: --out" in err and "--report" in err and old.is_file()
    assert main(["diagnose-shear", batch, "--report", str(new)]) == 0
    assert "warning" not in capsys.readouterr().err and new.is_file()
    # The report's text is the same whichever option named it (but the file's own name).
    assert old.read_text(encoding="utf-8").replace("old", "new") == new.read_text(encoding="utf-8")


@pytest.mark.parametrize("command", ["diagnose", "diagnose-shear"])
def test_a_single_law_command_refuses_a_second_law(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main([command, str(EXAMPLES / "tube_batch_NH.csv"), "--law", "NH", "--law", "GH_nu0.5"])
    assert stop.value.code == 2
    assert "--law: one base law key here, given NH, GH_nu0.5" in capsys.readouterr().err
