"""Every command the docs show runs (issue 21, item 6: docs and code agree).

The ``$ capsmech`` lines of each page's console blocks are run in order, verbatim, in a
folder outside the repository that holds a copy of data/examples (the pages name it
relatively), so that a page's later commands read what its earlier ones wrote (fit.csv, then
population). ``test_docs.py`` parses every command; this module runs them, except those in
``NOT_RUN``, each with the reason it is not run here. The quick start is also run in a fresh
virtual environment with the installed package (tests/workflow/test_installed_package.py).
"""
from __future__ import annotations

import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
CONSOLE_BLOCK = re.compile(r"^```console[ \t]*\n(.*?)^```", re.M | re.S)

#: Commands not run here, and why (matched by their start).
NOT_RUN = {
    "capsmech diagnose data/examples/": "a diagnosis refits the batch hundreds of times (minutes); its verdicts on "
                                        "these batches are asserted by tests/python/test_diagnose.py and, in make "
                                        "validate, tests/python/test_undeclared.py",
    "capsmech make-batch": "runs the kernel for 24 capsules (minutes); tests/python/test_undeclared.py regenerates a "
                           "shipped batch with the same code",
    "capsmech simulate --flow tube --model 3d": "a 3D tube run takes minutes; tests/kernel/test_tube_3d.py runs it",
    "capsmech simulate --flow shear": "a level-3 shear run to steady state takes about a minute; "
                                      "tests/kernel/test_shear.py runs it",
    "capsmech show shear.h5": "needs the shear run above",
    "capsmech extract 'film/": "a placeholder for a user's own film",
    "capsmech extract recording.tif": "a placeholder for a user's recording; --background, --frame-times, "
                                      "--channel-width and --walls are run on real and rendered stacks by "
                                      "tests/python/test_real_frames.py and test_extraction.py",
    "capsmech extract measurement.rtdc": "a placeholder for a user's .rtdc recording (the shipped .rtdc excerpts are "
                                         "cells, which extract measures as no capsule); tests/python/test_rtdc.py "
                                         "runs extract on them and checks frames, times and traces",
    "capsmech extract film.mp4": "a placeholder for a user's video; tests/python/test_video.py runs extract on a "
                                 "real AVI and a generated MKV",
    "capsmech diagnose batch.csv --simulate": "a placeholder for a user's batch, and ~190 kernel cases; "
                                              "tests/workflow/test_simulate_on_demand.py runs the on-demand path "
                                              "(make validate: this command on a Skalak C = 3 batch)",
    "capsmech database simulate --law SK_C5 --like tube-paper": "198 kernel cases (the paper grid); "
                                                                "tests/workflow/test_simulate_on_demand.py runs it "
                                                                "over the smoke grid",
    "capsmech diagnose-shear shear.csv": "a placeholder for a user's own batch (the same command on a shipped "
                                         "batch runs above)",
    "capsmech extract-shear": "placeholders for a user's Couette images; tests/python/test_shear_images.py runs "
                              "extract-shear on drawn frames and fit-shear on what it writes",
}
#: Placeholders the pages use for a user's file, and the shipped file that stands in for it.
STAND_INS = {"shear.csv": "data/examples/undeclared/shear_batch_A.csv"}


def page_commands() -> list[tuple[Path, list[str]]]:
    pages = []
    for page in PAGES:
        commands = [line[2:].strip() for block in CONSOLE_BLOCK.findall(page.read_text(encoding="utf-8"))
                    for line in block.splitlines() if line.startswith("$ capsmech ")]
        if commands:
            pages.append((page, commands))
    return pages


PAGE_COMMANDS = page_commands()


def reason_not_run(command: str) -> str | None:
    return next((why for start, why in NOT_RUN.items() if command.startswith(start)), None)


def test_every_exception_is_still_shown():
    """NOT_RUN names only commands the pages show (no stale exception hides a new command)."""
    shown = [c for _, commands in PAGE_COMMANDS for c in commands]
    for start in NOT_RUN:
        assert any(c.startswith(start) for c in shown), f"NOT_RUN entry {start!r} matches no command"


@pytest.mark.parametrize("page, commands", PAGE_COMMANDS, ids=[str(p.relative_to(ROOT)) for p, _ in PAGE_COMMANDS])
def test_page_commands_run(page: Path, commands: list[str], tmp_path: Path) -> None:
    shutil.copytree(ROOT / "data" / "examples", tmp_path / "data" / "examples")
    for name, source in STAND_INS.items():
        shutil.copy(ROOT / source, tmp_path / name)
    capsmech = Path(sys.executable).with_name("capsmech")
    ran = 0
    for command in commands:
        if reason_not_run(command):
            continue
        run = subprocess.run([str(capsmech), *shlex.split(command)[1:]], cwd=tmp_path, text=True,
                             capture_output=True, timeout=300)
        assert run.returncode == 0, f"{page.name}: {command}\n{run.stdout[-2000:]}\n{run.stderr[-3000:]}"
        assert "Traceback" not in run.stderr, run.stderr
        ran += 1
    if ran == 0:
        pytest.skip("every command of this page is in NOT_RUN: " + "; ".join(
            sorted({reason_not_run(c) or "" for c in commands})))
