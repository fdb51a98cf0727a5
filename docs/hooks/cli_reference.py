"""MkDocs hook: the command-line reference generated from the parser, and the API pages'
module lists generated from the package, at build time.

``docs/reference/cli.md`` holds the marker ``<!-- cli-reference -->``; this hook replaces it
with one section per ``capsmech`` subcommand (and per nested subcommand, e.g.
``capsmech database assemble``), each holding the ``--help`` text that
``capsmech.cli.main.build_parser()`` prints. Nothing is pasted by hand: a changed option shows
up in the next ``make docs``.

An API page holds ``<!-- api-modules capsmech.io -->``; the hook replaces it with one
mkdocstrings block (``::: capsmech.io.<module>``) per public module of that package, so that a
module added or removed by a reshaping is documented or dropped without editing the page.
"""
from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import re

MARKER = "<!-- cli-reference -->"
PAGE = "reference/cli.md"
API_MARKER = re.compile(r"<!-- api-modules ([\w.]+) -->")


def _subcommands(parser: argparse.ArgumentParser):
    """(name, help, sub-parser) of each subcommand of ``parser``, in declaration order."""
    for action in parser._actions:  # argparse exposes no public walk of its subparsers
        if isinstance(action, argparse._SubParsersAction):
            helps = {choice.dest: choice.help for choice in action._choices_actions}
            seen = set()
            for name, sub in action.choices.items():
                if id(sub) in seen:  # aliases
                    continue
                seen.add(id(sub))
                yield name, helps.get(name), sub


def _render(parser: argparse.ArgumentParser, path: list[str], level: int) -> list[str]:
    out = []
    for name, help_text, sub in _subcommands(parser):
        words = path + [name]
        out.append(f"{'#' * level} `{' '.join(words)}`\n")
        if help_text:
            out.append(f"{help_text[0].upper()}{help_text[1:]}.\n")
        out.append("```text\n" + sub.format_help().rstrip() + "\n```\n")
        out.extend(_render(sub, words, min(level + 1, 6)))
    return out


def cli_reference() -> str:
    """The Markdown of every subcommand's help, walked from ``build_parser()``."""
    os.environ["COLUMNS"] = "100"  # argparse wraps to the terminal: fix it for a stable page
    from capsmech.cli.main import build_parser

    parser = build_parser()
    parts = ["```text\n" + parser.format_help().rstrip() + "\n```\n"]
    parts.extend(_render(parser, [parser.prog], 2))
    return "\n".join(parts)


def api_modules(package: str) -> str:
    """One ``::: package.module`` block per public module (not subpackage) of ``package``."""
    pkg = importlib.import_module(package)
    names = sorted(info.name for info in pkgutil.iter_modules(pkg.__path__)
                   if not info.ispkg and not info.name.startswith("_"))
    return "\n".join(f"::: {package}.{name}\n" for name in names)


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ARG001 (MkDocs hook signature)
    if page.file.src_uri == PAGE and MARKER in markdown:
        markdown = markdown.replace(MARKER, cli_reference())
    return API_MARKER.sub(lambda m: api_modules(m.group(1)), markdown)
