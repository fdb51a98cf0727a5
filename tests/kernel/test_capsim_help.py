"""`capsim --help` lists every option the kernel accepts, with its unit and default (issue 21).

The accepted names are read from the kernel's source, not typed here: the case labels of
bind_option in run_options.f90 (which ties each option to its field) and the names of
option_table.f90 (the parser accepts exactly those). The defaults the help prints are checked
against what a run without the option records, where a tiny run shows it.
"""
from __future__ import annotations

import re
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest

from conftest import REPO

SRC = REPO / "kernel" / "src"
DEFAULT = re.compile(r"\(default: (.+)\)$")


def bound_options() -> set[str]:
    """Option names in the case labels of run_options.f90 (the parser's bindings)."""
    text = (SRC / "run_options.f90").read_text()
    names: set[str] = set()
    for labels in re.findall(r"^\s*case\s*\(([^)]*)\)", text, flags=re.M):
        names.update(n for n in re.findall(r"'([^']*)'", labels) if n.startswith("-"))
    return names


def table_options() -> set[str]:
    """Long and short names of option_table.f90, the list the parser accepts."""
    text = (SRC / "option_table.f90").read_text()
    return set(re.findall(r"\bname='(-[^']*)'", text)) | set(re.findall(r"\bshort='(-[^']*)'", text))


@pytest.fixture(scope="module")
def help_text(capsim: Path) -> str:
    result = subprocess.run([str(capsim), "--help"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""
    return result.stdout


@pytest.fixture(scope="module")
def help_options(help_text: str) -> dict[str, dict[str, str | None]]:
    """Long name -> {short, arg, text, unit, default} of every option line of the help."""
    found: dict[str, dict[str, str | None]] = {}
    for line in help_text.splitlines():
        if not line.startswith("  -"):
            continue
        # "  -h, --name ARG   help [unit] (default: X)"
        m = re.match(r"^  (?:(-\w), )?(--[\w-]+)(?: (\S+))? +(\S.*)$", line)
        assert m, line
        short, name, arg, rest = m.groups()
        default = DEFAULT.search(rest)
        unit = re.search(r"\[([^\]]+)\] \(default: ", rest)
        found[name] = {"short": short, "arg": arg, "text": rest, "unit": unit and unit.group(1),
                       "default": default and default.group(1)}
    return found


def test_help_exits_0_and_h_is_the_same(capsim, help_text):
    short = subprocess.run([str(capsim), "-h"], capture_output=True, text=True, timeout=60)
    assert short.returncode == 0 and short.stdout == help_text
    assert help_text.startswith("usage: capsim ")


def test_every_accepted_option_is_in_the_help(help_options):
    bound = bound_options()
    assert len(bound) > 30                       # the regex found the parser's cases
    assert bound == {n for n in table_options() if n.startswith("--")}, \
        "option_table.f90 and bind_option in run_options.f90 name different options"
    listed = set(help_options) | {o["short"] for o in help_options.values() if o["short"]}
    assert table_options() <= listed, sorted(table_options() - listed)
    assert bound <= listed, sorted(bound - listed)


def test_every_option_line_has_a_default_and_numbers_a_unit(help_options):
    for name, o in help_options.items():
        # A value, or "required" / "none" where there is none.
        assert o["default"] and o["default"].strip(), f"{name}: no (default: ...)"
        first = o["default"].split()[0]
        try:
            float(first)
        except ValueError:
            continue
        # A numeric option says its unit (or that it is dimensionless / a count).
        assert o["unit"], f"{name}: numeric default {first} but no [unit]"
    assert help_options["--ca"]["default"] == "required"
    assert "dimensionless" in help_options["--ca"]["unit"] and "mu V / G_s" in help_options["--ca"]["unit"]
    for name in ("--tube-length", "--wall-h-far", "--wall-h-centre", "--offset"):
        assert help_options[name]["unit"].startswith("l "), name
    assert help_options["--max-length"]["unit"].startswith("a ")


def _default(help_options, name: str) -> str:
    return help_options[name]["default"].split()[0]


def test_printed_defaults_are_the_ones_a_run_uses(capsim, help_options, tmp_path):
    """A run given only the required options records the defaults it used."""
    shear = tmp_path / "shear.h5"
    subprocess.run([str(capsim), "--flow", "shear", "--law", "NH", "--ca", "0.2", "--t-max", "0.16",
                    "--threads", "1", "--quiet", "--out", str(shear)], check=True, timeout=60)
    with h5py.File(shear) as f:
        attrs = dict(f.attrs)
        t = f["history/t"][()]
        x = f["mesh/reference_nodes"][()]
        tri = f["mesh/triangles"][()]
    for option, attr in [("--nu-s", "nu_s"), ("--C", "C"), ("--lambda", "lambda"), ("--prestress", "prestress"),
                         ("--kb", "k_b"), ("--offset", "offset"), ("--level", "mesh_level")]:
        assert float(_default(help_options, option)) == attrs[attr], option
    assert _default(help_options, "--offset-mode") == attrs["offset_mode"].decode()
    assert attrs["volume_correction"] == {"on": 1, "off": 0}[_default(help_options, "--volume-correction")]
    # --dt 0 (automatic): dt = dt_factor Ca_s h_min, h_min the shortest edge of the mesh.
    assert _default(help_options, "--dt") == "0"
    edges = np.concatenate([x[tri[:, i]] - x[tri[:, (i + 1) % 3]] for i in range(3)])
    h_min = np.linalg.norm(edges, axis=1).min()
    assert attrs["dt"] == pytest.approx(float(_default(help_options, "--dt-factor")) * 0.2 * h_min, rel=1e-12)
    # The k-th record is the first step at or after k * record_every (the last row is t_max).
    every = float(_default(help_options, "--record-every"))
    for k, tk in enumerate(t[1:-1], start=1):
        assert k * every - 1e-12 <= tk < k * every + attrs["dt"], (k, tk)

    tube = tmp_path / "tube.h5"
    subprocess.run([str(capsim), "--flow", "tube", "--law", "NH", "--ca", "0.1", "--a-over-l", "0.5",
                    "--t-max", "0.05", "--threads", "1", "--quiet", "--out", str(tube)], check=True, timeout=60)
    with h5py.File(tube) as f:
        assert f.attrs["model"].decode() == _default(help_options, "--model")
        assert f.attrs["tube_length"] == float(_default(help_options, "--tube-length"))
        assert f["mesh/meridian"].shape[0] == int(_default(help_options, "--n-meridian")) + 1


@pytest.mark.parametrize("argv, named", [(["--no-such-option"], "--no-such-option"),
                                         (["--flow", "shear", "--bogus=1"], "--bogus"),
                                         (["--quiet=yes"], "--quiet")])
def test_a_bad_option_exits_2_with_one_line_naming_it(capsim, argv, named):
    result = subprocess.run([str(capsim), *argv], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("capsim: error: " + named), result.stderr
    assert result.stdout == ""
