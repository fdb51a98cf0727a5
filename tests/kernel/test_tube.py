"""Capsule in a circular tube (axisymmetric model): input validation and physics."""
from __future__ import annotations

import subprocess

import pytest

BAD_TUBE_INPUTS = [
    (["--a-over-l", "0"], "--a-over-l"),
    (["--a-over-l", "-0.5"], "--a-over-l"),
    (["--a-over-l", "1.31"], "--a-over-l"),
    (["--ca", "0"], "--ca"),
    (["--ca", "-0.1"], "--ca"),
    (["--model", "fem"], "--model"),
    (["--n-meridian", "4"], "--n-meridian"),
    (["--integrator", "euler"], "--integrator"),
]


@pytest.mark.parametrize("override,field", BAD_TUBE_INPUTS, ids=[f"{f}={o[1]}" for o, f in BAD_TUBE_INPUTS])
def test_bad_tube_input_exits_2_naming_the_field(capsim, tmp_path, override, field):
    args = {"--flow": "tube", "--law": "NH", "--ca": "0.05", "--a-over-l": "0.8", "--out": str(tmp_path / "x.h5")}
    args.update(dict(zip(override[::2], override[1::2])))
    argv = [str(capsim)] + [a for kv in args.items() for a in kv]
    result = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("capsim: error: " + field), result.stderr
    assert not (tmp_path / "x.h5").exists()


def test_missing_a_over_l_is_named(capsim, tmp_path):
    result = subprocess.run([str(capsim), "--flow", "tube", "--law", "NH", "--ca", "0.05",
                             "--out", str(tmp_path / "x.h5")], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and "--a-over-l" in result.stderr
