"""The reference paper's figures 2-6, drawn from our database files (PNG and PDF).

Tube database
    figure 2: steady profiles for the GH laws (effect of nu_s), one panel per Ca_s;
    figure 3: L_z, L_p and v_c/V against Ca_s for the GH laws, one symbol per a/l;
    figure 4: as figure 2 for the laws with K_s = 3 G_s (NH, SK_C1, GH_nu0.5);
    figure 5: as figure 3 for NH against GH_nu0.5;
    steady range (ours): the last steady Ca_s against a/l for every law, with where and how
    each steady branch ends (continuous elongation, mesh breakdown, time limit).
Shear database
    figure 6: D12 against Ca_s, and L3/a against D12, for every law.

Only steady rows are drawn; each figure states how many cases it omits and why
(continuous elongation, time limit, failure), so a gap in a curve is never silent.
Laws missing from the database are left out of a figure (a figure with none is skipped).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from capsmech.io.database import (
    Database,
    LawTable,
    ShearDatabase,
    TubeDatabase,
    load_database,
)

GH_LAWS = ("GH_nu0.5", "GH_nu0.2", "GH_nu0")
K3_LAWS = ("NH", "SK_C1", "GH_nu0.5")
SOFT_HARD_LAWS = ("NH", "GH_nu0.5")
#: Ca_s of the paper's profile panels (figures 2 and 4).
PAPER_PROFILE_CA = (0.01, 0.07, 0.15)
MARKERS = "osD^v<>ph*"
LINESTYLES = ("-", "--", ":", "-.")


def _laws(database: Database, wanted: Sequence[str]) -> list[str]:
    """Return the wanted laws present in the database (all of them when none is)."""
    present = [key for key in wanted if key in database.laws]
    return present or list(database.laws)


def _omitted_note(tables: Sequence[LawTable]) -> str:
    """Return 'omitted (not steady): 2 continuous_elongation, 1 max_time', or ''."""
    counts = Counter(s for table in tables for s in table.status if s != "steady")
    if not counts:
        return ""
    return "not steady, omitted: " + ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))


def _finish(fig: Figure, title: str, note: str, out_dir: Path, stem: str) -> list[Path]:
    """Add title and note, save PNG and PDF, return their paths."""
    fig.suptitle(title)
    if note:
        fig.supxlabel(note, fontsize="small", color="0.35")
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / f"{stem}.{ext}" for ext in ("png", "pdf")]
    for path in paths:
        fig.savefig(path, dpi=130)
    return paths


def nearest_values(available: np.ndarray, requested: Sequence[float]) -> list[float]:
    """Return, for each requested value, the nearest available one (without repeats, in order)."""
    values = np.unique(available)
    chosen: list[float] = []
    for value in requested:
        nearest = float(values[np.argmin(np.abs(values - value))])
        if nearest not in chosen:
            chosen.append(nearest)
    return chosen


def profile_figure(database: TubeDatabase, laws: Sequence[str], ca_values: Sequence[float]) -> Figure:
    """Steady meridian profiles in the tube: one panel per Ca_s, one row per a/l, one line per law.

    Each capsule is drawn mirrored about its axis (the yz-plane), flow to the right, centred
    on z = 0, with the tube walls r = +-l; rows for different a/l are stacked 2.5 l apart.
    """
    tables = [database.law(key) for key in laws]
    all_ca = np.concatenate([t.columns["Ca_s"] for t in tables])
    panels = nearest_values(all_ca, ca_values)
    sizes = np.unique(np.concatenate([t.columns["a_over_l"] for t in tables]))
    fig = Figure(figsize=(4.2 * len(panels), 1.2 + 1.4 * len(sizes)), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(panels), sharey=True))
    for ax, ca in zip(axes, panels):
        for row, size in enumerate(sizes):
            offset = -2.5 * row
            ax.axhline(offset + 1, color="0.5", lw=1)
            ax.axhline(offset - 1, color="0.5", lw=1)
            ax.text(-2.4, offset, f"a/l = {size:g}", fontsize="small", va="center")
            for i, table in enumerate(tables):
                match = np.flatnonzero((table.columns["a_over_l"] == size) & (table.columns["Ca_s"] == ca)
                                       & table.steady)
                if match.size == 0:
                    continue
                r, z = table.profiles["profile_r"][match[0]], table.profiles["profile_z"][match[0]]
                z = z - 0.5 * (z.max() + z.min())
                ax.plot(np.concatenate([z, z[::-1]]), offset + np.concatenate([r, -r[::-1]]),
                        LINESTYLES[i % len(LINESTYLES)], color=f"C{i}", lw=1.3,
                        label=table.key if row == 0 else None)
        ax.set_title(f"Ca_s = {ca:g}")
        ax.set_xlabel("z [l]")
        ax.set_xlim(-2.5, 2.5)
        ax.set_aspect("equal")
    axes[0].set_ylabel("r [l] (rows offset by a/l)")
    if axes[0].get_legend_handles_labels()[0]:
        axes[0].legend(loc="upper right", fontsize="small")
    else:
        axes[0].text(0.5, 0.5, "no steady case", transform=axes[0].transAxes, ha="center")
    return fig


def lengths_figure(database: TubeDatabase, laws: Sequence[str], ca_max: float = np.inf) -> Figure:
    """L_z/l, L_p/l and v_c/V against Ca_s up to ``ca_max``: colour and line style per law,
    symbol per a/l."""
    fig = Figure(figsize=(13, 4.3), layout="constrained")
    axes = fig.subplots(1, 3)
    quantities = (("L_z", "L_z/l"), ("L_p", "L_p/l"), ("vc_over_V", "v_c/V"))
    for i, key in enumerate(laws):
        table = database.law(key)
        for j, size in enumerate(np.unique(table.columns["a_over_l"])):
            rows = (table.columns["a_over_l"] == size) & table.steady & (table.columns["Ca_s"] <= ca_max)
            order = np.argsort(table.columns["Ca_s"][rows])
            for ax, (name, _) in zip(axes, quantities):
                ax.plot(table.columns["Ca_s"][rows][order], table.columns[name][rows][order],
                        LINESTYLES[i % len(LINESTYLES)], marker=MARKERS[j % len(MARKERS)], color=f"C{i}",
                        ms=4, lw=1, label=f"{key}, a/l = {size:g}")
    for ax, (_, label) in zip(axes, quantities):
        ax.set_xlabel("Ca_s [-]")
        ax.set_ylabel(f"{label} [-]")
        ax.grid(True, alpha=0.3)
    if axes[1].get_legend_handles_labels()[0]:
        axes[1].legend(fontsize="x-small", ncol=2)
    return fig


#: How a steady branch ends, by the status of the first case past it: marker and label.
BRANCH_ENDS = {"continuous_elongation": ("^", "continuous elongation"), "failed": ("x", "failed (mesh breakdown)"),
               "max_time": ("s", "no steady state by t_max")}


def steady_range_figure(database: TubeDatabase, laws: Sequence[str]) -> Figure:
    """The last steady Ca_s against a/l, one line per law, and the status of the next case.

    A branch that is steady up to the grid's largest Ca_s is drawn with an open circle there:
    its end lies beyond the grid.
    """
    fig = Figure(figsize=(6.5, 4.6), layout="constrained")
    ax = fig.subplots()
    labelled: set[str] = set()
    for i, key in enumerate(laws):
        table = database.law(key)
        sizes = np.unique(table.columns["a_over_l"])
        last = np.full(len(sizes), np.nan)
        for j, size in enumerate(sizes):
            rows = np.flatnonzero(table.columns["a_over_l"] == size)
            rows = rows[np.argsort(table.columns["Ca_s"][rows])]
            steady = table.steady[rows]
            # The branch ends at the first case that is not steady (from the small-Ca_s end).
            first_bad = int(np.argmin(steady)) if not steady.all() else len(rows)
            if first_bad == 0:
                continue
            last[j] = table.columns["Ca_s"][rows[first_bad - 1]]
            if first_bad < len(rows):
                status = str(table.status[rows[first_bad]])
                marker, label = BRANCH_ENDS.get(status, ("d", status))
                ax.plot(size, table.columns["Ca_s"][rows[first_bad]], marker, color=f"C{i}", ms=6,
                        mfc="none", label=None if label in labelled else f"next case: {label}")
                labelled.add(label)
            else:
                ax.plot(size, last[j], "o", color=f"C{i}", ms=7, mfc="none",
                        label=None if "beyond" in labelled else "steady up to the grid's end")
                labelled.add("beyond")
        ax.plot(sizes, last, LINESTYLES[i % len(LINESTYLES)], marker=".", color=f"C{i}", lw=1.4, label=key)
    ax.set(xlabel="a/l [-]", ylabel="last steady Ca_s [-]", yscale="log")
    ax.grid(True, alpha=0.3, which="both")
    ax.legend(fontsize="small")
    return fig


def shear_figure(database: ShearDatabase, laws: Sequence[str]) -> Figure:
    """(a) D12 against Ca_s; (b) L3/a against D12; one colour and line style per law."""
    fig = Figure(figsize=(10, 4.3), layout="constrained")
    ax_d, ax_l = fig.subplots(1, 2)
    for i, key in enumerate(laws):
        table = database.law(key)
        ca, d12, l3 = (table.column(n) for n in ("Ca_s", "D12", "L3_over_a"))
        order = np.argsort(ca)
        style = dict(ls=LINESTYLES[i % len(LINESTYLES)], marker=MARKERS[i % len(MARKERS)], color=f"C{i}",
                     ms=4, lw=1.2, label=key)
        ax_d.plot(ca[order], d12[order], **style)
        ax_l.plot(d12[order], l3[order], **style)
    ax_d.set(xlabel="Ca_s [-]", ylabel="D12 [-]", title="(a) deformation in the shear plane")
    ax_l.set(xlabel="D12 [-]", ylabel="L3/a [-]", title="(b) semi-axis along the vorticity")
    for ax in (ax_d, ax_l):
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize="small")
    return fig


def draw_figures(database_path: str | Path, out_dir: str | Path,
                 grid: Mapping[str, Any] | None = None) -> list[Path]:
    """Draw every figure a database supports into ``out_dir`` (PNG and PDF).

    Parameters
    ----------
    database_path : str or Path
        ``tube.h5`` (figures 2-5) or ``shear.h5`` (figure 6).
    out_dir : str or Path
        Output directory, created if needed.
    grid : mapping, optional
        Grid whose ``figures.profile_Ca_s`` chooses the profile panels (default: the
        paper's Ca_s = 0.01, 0.07, 0.15, or the nearest values in the database).

    Returns
    -------
    list of Path
        The files written.
    """
    database = load_database(database_path)
    out_dir = Path(out_dir)
    written: list[Path] = []
    if isinstance(database, ShearDatabase):
        laws = list(database.laws)
        fig = shear_figure(database, laws)
        return _finish(fig, "Figure 6: simple shear flow", _omitted_note([database.law(k) for k in laws]),
                       out_dir, "figure6_shear_D12_L3")
    figure_settings = (grid or {}).get("figures", {})
    ca_values = figure_settings.get("profile_Ca_s", PAPER_PROFILE_CA)
    ca_max = float(figure_settings.get("lengths_Ca_s_max", np.inf))
    specs = (
        ("figure2_tube_profiles_nu_s", GH_LAWS, "Figure 2: tube flow, effect of Ca_s and nu_s on the profile", True),
        ("figure3_tube_lengths_nu_s", GH_LAWS, "Figure 3: tube flow, lengths and velocity (GH laws)", False),
        ("figure4_tube_profiles_laws", K3_LAWS, "Figure 4: tube flow, effect of the law (K_s = 3 G_s)", True),
        ("figure5_tube_lengths_laws", SOFT_HARD_LAWS, "Figure 5: tube flow, NH against GH (nu_s = 0.5)", False),
    )
    for stem, wanted, title, is_profile in specs:
        laws = _laws(database, wanted)
        fig = (profile_figure(database, laws, ca_values) if is_profile
               else lengths_figure(database, laws, ca_max))
        written += _finish(fig, title, _omitted_note([database.law(k) for k in laws]), out_dir, stem)
    laws = list(database.laws)
    written += _finish(steady_range_figure(database, laws), "Tube flow: where each law's steady branch ends",
                       "", out_dir, "tube_steady_range")
    return written
