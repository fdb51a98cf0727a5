"""Numbers, units and tables as text: how capsmech prints quantities (CLI tables, figure labels)."""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any


def fmt(value: Any, digits: int = 6) -> str:
    """A number compactly (``digits`` significant digits); NaN prints as 'n/a'; other values as text."""
    if isinstance(value, float):
        return "n/a" if math.isnan(value) else f"{value:.{digits}g}"
    return str(value)


def bracketed_unit(text: str) -> str:
    """``'[text]'``, with ``'[-]'`` for an empty (dimensionless) unit."""
    return f"[{text or '-'}]"


def format_table(rows: Sequence[Mapping[str, Any]], columns: Sequence[str], units: Mapping[str, str],
                 digits: int = 4) -> str:
    """A fixed-width text table of ``rows``: one header line with every column's unit
    (``G_s [N/m]``; ``[1]`` for dimensionless quantities; no unit for text columns)."""
    headers = [f"{c} [{units[c]}]" if units.get(c) else c for c in columns]
    cells = [[fmt(row[c], digits) for c in columns] for row in rows]
    widths = [max([len(h)] + [len(r[i]) for r in cells]) for i, h in enumerate(headers)]
    out = ["  ".join(h.rjust(w) for h, w in zip(headers, widths))]
    out += ["  ".join(c.rjust(w) for c, w in zip(r, widths)) for r in cells]
    return "\n".join(out)
