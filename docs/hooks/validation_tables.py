"""MkDocs hook: the validation tables computed from the shipped data, at build time.

A page holds ``<!-- generated-table NAME -->``; this hook replaces the marker with the table
that ``scripts/validation_tables.py NAME`` prints (computed from the shipped databases, example
batches and film: seconds), followed by a line saying so. A table that cannot be made fails the
build: a validation page never shows a stale or missing table silently.
"""
from __future__ import annotations

import importlib.util
import re
from functools import cache
from pathlib import Path
from types import ModuleType

MARKER = re.compile(r"<!-- generated-table ([\w-]+) -->")
SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "validation_tables.py"


@cache
def _tables() -> ModuleType:
    spec = importlib.util.spec_from_file_location("validation_tables", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@cache
def _table(name: str) -> str:
    tables = _tables().TABLES
    if name not in tables:
        raise KeyError(f"<!-- generated-table {name} -->: no such table in {SCRIPT.name} (it has {', '.join(tables)})")
    return tables[name]()


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ARG001 (MkDocs hook signature)
    def render(match: re.Match[str]) -> str:
        name = match.group(1)
        return (f"{_table(name)}\n\n*Computed from the shipped files at this build: "
                f"`scripts/validation_tables.py {name}`.*")

    return MARKER.sub(render, markdown)
