"""The documentation site builds cleanly, and every command it tells a user to run parses.

(a) ``mkdocs build --strict`` (mkdocs.yml at the repository root, pages under docs/) exits 0:
    no warning (a broken link, a page missing from the nav, a docstring the API pages cannot
    read); the CLI reference is generated from the parser by docs/hooks/cli_reference.py.
(b) Every ``$ capsmech ...`` line of a ```console block, in README.md and docs/, parses with
    ``capsmech.cli.main.build_parser()`` the way ``capsmech.cli.main.main`` parses it (the
    arguments of ``capsmech simulate`` go to the kernel unparsed). The files the commands name
    need not exist: only the command line is checked.
"""
from __future__ import annotations

import contextlib
import io
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
CONSOLE_BLOCK = re.compile(r"^```console[ \t]*\n(.*?)^```", re.M | re.S)

#: Commands the docs show for the target interface of issue 21 that the parser does not accept
#: yet, each marked xfail (CLI reshaping in progress): remove an entry once its command lands.
#: Empty: every command the pages show parses with the CLI as it stands (the last four,
#: `capsmech databases`, `capsmech dev unlock-stale .`, `capsmech dev kernel-version` and
#: `diagnose-shear ... --pixel-size 0.5um`, landed while the pages were written).
NOT_YET: set[str] = set()


def console_commands() -> list[tuple[str, str]]:
    """(page, command) for every ``$ capsmech`` line of a console block."""
    found = []
    for page in PAGES:
        for block in CONSOLE_BLOCK.findall(page.read_text(encoding="utf-8")):
            for line in block.splitlines():
                if line.startswith("$ capsmech "):
                    found.append((str(page.relative_to(ROOT)), line[2:].strip()))
    return found


COMMANDS = console_commands()


def test_docs_show_commands():
    """The pages do show commands (the extraction above found the blocks)."""
    assert len(COMMANDS) >= 20, COMMANDS
    assert set(NOT_YET) <= {command for _, command in COMMANDS}, "NOT_YET lists a command no page shows"


def parse(command: str) -> None:
    """Parse ``command`` as ``capsmech.cli.main.main`` does; SystemExit if the parser refuses it."""
    from capsmech.cli.main import build_parser

    parser = build_parser()
    args, rest = parser.parse_known_args(shlex.split(command)[1:])
    if args.command != "simulate" and rest:
        parser.error(f"unrecognized arguments: {' '.join(rest)}")


@pytest.mark.parametrize(
    "page, command",
    [pytest.param(page, command, id=f"{page}: {command}",
                  marks=[pytest.mark.xfail(reason="CLI reshaping in progress", strict=False)]
                  if command in NOT_YET else [])
     for page, command in COMMANDS],
)
def test_command_parses(page: str, command: str):
    stderr = io.StringIO()
    try:
        with contextlib.redirect_stderr(stderr):
            parse(command)
    except SystemExit as exc:
        pytest.fail(f"{page}: `{command}` does not parse (exit {exc.code}): {stderr.getvalue().strip()}")


def test_mkdocs_build_strict(tmp_path):
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings")
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(ROOT / "mkdocs.yml"),
         "--site-dir", str(tmp_path / "site")],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert (tmp_path / "site" / "reference" / "cli" / "index.html").is_file()
    cli_page = (tmp_path / "site" / "reference" / "cli" / "index.html").read_text(encoding="utf-8")
    assert "capsmech fit-tube" in cli_page and "--database" in cli_page  # generated from the parser
