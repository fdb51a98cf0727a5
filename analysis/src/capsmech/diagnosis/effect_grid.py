"""The extra simulations a diagnose candidate needs, as a grid the workflow runs.

When a candidate effect (e.g. pre-stress) needs law groups no database has, diagnose does not
guess: it asks for exactly the cases that would let the batch be refitted with the effect on,
i.e. the effect's law keys on only the tube nodes around the batch's fitted points (each
capsule's bracketing a/l and Ca_s nodes of the base database, and one node more on each
side), with the base database's
mesh and time settings. The grid is a config file of the workflow's schema
(``make database GRID=<name>``); its cost is estimated from the wall times the base
database recorded for its own cases at those nodes.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from capsmech.io.database import TubeDatabase
from capsmech.workflow.grid import by_continuation, uses_branches, validate_grid
from capsmech.workflow.simulate import case_count

#: Nodes added beyond the batch's fitted points on each side: the effect moves the points the
#: refit lands on (pre-stress stiffens the membrane: the same lengths mean a larger Ca_s), and
#: the local fit of the inversion needs neighbours around each point.
MARGIN = 1


def bracketing_nodes(nodes: Sequence[float], values: np.ndarray, margin: int = MARGIN) -> list[float]:
    """The nodes on either side of every finite value (the end node for values beyond), and
    ``margin`` more nodes beyond the outermost on each side."""
    axis = np.sort(np.asarray(nodes, dtype=float))
    chosen: set[int] = set()
    for value in np.asarray(values, dtype=float):
        if not math.isfinite(value):
            continue
        k = int(np.clip(np.searchsorted(axis, value) - 1, 0, len(axis) - 2)) if len(axis) > 1 else 0
        chosen.update((k, min(k + 1, len(axis) - 1)))
    if not chosen:
        return []
    low, high = max(min(chosen) - margin, 0), min(max(chosen) + margin, len(axis) - 1)
    return [float(v) for v in axis[low:high + 1]]


#: How far a law family's members move a shape's fitted Ca_s from the base law's: the pool's
#: Skalak C = 3 capsules (true Ca_s 0.022-0.067) fit NH at 0.01-0.04, and C = 8 needs more
#: still; a family's grid spans the base fits' Ca_s from /SPREAD_LOW to xSPREAD_HIGH.
FAMILY_CA_SPREAD = (1.5, 3.0)


def needed_grid(effect: str, laws: Sequence[str], database: TubeDatabase, a_over_l: np.ndarray,
                Ca_s: np.ndarray, ca_spread: tuple[float, float] = (1.0, 1.0)) -> dict[str, Any]:
    """The grid of the effect's law keys on the nodes around the fitted (a/l, Ca_s);
    ``ca_spread`` (low, high) widens the Ca_s range to [min / low, max * high] first (a law
    family, ``FAMILY_CA_SPREAD``)."""
    base = database.grid
    tube = base["tube"]
    finite = np.asarray(Ca_s, dtype=float)
    finite = finite[np.isfinite(finite)]
    if len(finite) and ca_spread != (1.0, 1.0):
        Ca_s = np.concatenate([finite, [finite.min() / ca_spread[0], finite.max() * ca_spread[1]]])
    # The shipped effect libraries (tube-<effect>) extend the axisymmetric circular tube: a grid
    # for another model or channel (a square duct's 3D database) is named after its base, so that
    # writing or refilling it never replaces a library of another geometry.
    own = "" if tube.get("settings", {}).get("model", "axi") == "axi" else f"-{base['name']}"
    name = f"effects_{effect}{own.replace('-', '_')}"
    grid: dict[str, Any] = {
        "name": name,
        "description": f"{effect} candidate of capsmech diagnose: {', '.join(laws)} around a batch's fitted points",
        # Where the shipped effect databases live, so that a refill is found by name (tube-<effect>).
        "databases_dir": f"analysis/src/capsmech/databases/effects/{effect}{own}",
        "results_dir": f"results/{name}",
        "profile_points": int(base.get("profile_points", 64)),
        "tube": {"laws": list(laws), "a_over_l": bracketing_nodes(tube["a_over_l"], a_over_l),
                 "Ca_s": bracketing_nodes(tube["Ca_s"], Ca_s),
                 "database": {"name": f"tube-{effect}{own}", "version": 1,
                              "accuracy": "the mesh of the base database: " + str(tube.get("database", {}).get(
                                  "accuracy", "see its grid"))}},
    }
    # By continuation in Ca_s where the model allows it (the same cases, in fewer CPU seconds).
    grid["tube"]["settings"] = by_continuation(tube.get("settings"))
    validate_grid(grid, name)
    return grid


def estimated_core_minutes(grid: dict[str, Any], database: TubeDatabase, base_law: str) -> float:
    """Core-minutes of the grid case by case: its case count times the mean wall time the base
    database recorded for the base law at the same nodes (every node's if none match). A grid
    computed by continuation (``by_continuation``) usually takes less: the Skalak C = 3 grid
    of docs/validation/diagnosis.md, 189 cases, estimated at 11 core-minutes from tube-paper's
    kernel-0.3.2 times, took 2.9 by continuation and 3.8 case by case (kernel 0.3.4, 2 cores)."""
    table = database.law(base_law)
    wall = table.column("wall_time_s", steady_only=False)
    a, ca = table.column("a_over_l", steady_only=False), table.column("Ca_s", steady_only=False)
    here = np.isin(np.round(a, 9), np.round(grid["tube"]["a_over_l"], 9)) & np.isin(
        np.round(ca, 9), np.round(grid["tube"]["Ca_s"], 9)) & np.isfinite(wall)
    seconds = float(np.mean(wall[here])) if here.any() else float(np.nanmean(wall))
    return case_count(grid) * seconds / 60


def cost_text(grid: dict[str, Any], database: TubeDatabase, base_law: str) -> str:
    """``189 cases (~11 core-min case by case; by continuation, usually less)``: what the grid
    costs, as both of diagnose's messages say it."""
    how = "; by continuation, usually less" if uses_branches(grid) else ""
    return f"{case_count(grid)} cases (~{estimated_core_minutes(grid, database, base_law):.0f} core-min case by case{how})"


def write_grid(grid: dict[str, Any], path: str | Path, header: str = "") -> Path:
    """Write the grid as a workflow config (YAML) with a comment header."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = "".join(f"# {line}\n" for line in header.splitlines())
    text += yaml.safe_dump(grid, sort_keys=False, default_flow_style=None)
    path.write_text(text, encoding="utf-8")
    return path
