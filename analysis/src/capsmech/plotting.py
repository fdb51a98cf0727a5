"""Figures a user asks for, as matplotlib Figures (no pyplot state, no file needed): a case's
history and profile (``plot_case``); the population's G_s against Delta is
``capsmech.inversion.population_report.plot_population``. ``save_figure`` writes any of them."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from capsmech.formatting import bracketed_unit, fmt
from capsmech.io.case import CaseResult

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def save_figure(figure: Figure, out: str | Path, dpi: int = 150) -> Path:
    """Write ``figure`` to ``out`` (format from the suffix: .png, .pdf, .svg), creating its folder."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=dpi)
    return out


def _axis_label(case: CaseResult, group: str, name: str) -> str:
    """Return an axis label ``'name [units]'`` for dataset ``group/name``."""
    return f"{name} {bracketed_unit(case.unit(f'{group}/{name}'))}"


def plot_case(case: CaseResult) -> Figure:
    """Draw a 2-panel PNG: deformation history and shear-plane profile.

    Left: D12 against t (or L1 and L2 against t when D12 is absent), with the
    steady value as a dashed line when there is one. Right: the contour in
    the shear plane x = 0, z against y, equal aspect.

    Parameters
    ----------
    case : CaseResult
        The case to plot.

    Returns
    -------
    Figure
        The figure (write it with ``save_figure``).
    """
    from matplotlib.figure import Figure  # no pyplot: no GUI backend needed

    fig = Figure(figsize=(10, 4.2), layout="constrained")
    ax_h, ax_p = fig.subplots(1, 2)

    names: list[str]
    if case.flow == "tube":
        names = [n for n in ("L_z", "L_p", "v_c") if n in case.history]
    else:
        names = ["D12"] if "D12" in case.history else [n for n in ("L1", "L2") if n in case.history]
    if "t" in case.history and names:
        t = case.history["t"]
        for name in names:
            ax_h.plot(t, case.history[name], label=name)
            if name in case.steady:
                ax_h.axhline(case.steady[name], ls="--", lw=0.8, color="0.4", label=f"steady {name}")
        ax_h.set_xlabel(_axis_label(case, "history", "t"))
        ax_h.set_ylabel(", ".join(_axis_label(case, "history", n) for n in names))
        ax_h.legend(loc="best", fontsize="small")
    else:
        ax_h.text(0.5, 0.5, "no history", ha="center", va="center", transform=ax_h.transAxes)
    ax_h.set_title("deformation history")
    ax_h.grid(True, alpha=0.3)

    if "r" in case.profile:
        # Meridian mirrored about the axis: the capsule as the microscope sees it, flow to the right.
        r, z = case.profile["r"], case.profile["z"]
        ax_p.plot(list(z) + list(z[::-1]), list(r) + list(-r[::-1]), "-", lw=1.5)
        ax_p.axhline(1.0, color="0.3", lw=2)
        ax_p.axhline(-1.0, color="0.3", lw=2)
        ax_p.set_aspect("equal", adjustable="datalim")
        ax_p.set_xlabel(_axis_label(case, "profile", "z"))
        ax_p.set_ylabel(_axis_label(case, "profile", "r"))
    elif case.profile:
        y = list(case.profile["y"]) + [case.profile["y"][0]]  # close the contour
        z_closed = list(case.profile["z"]) + [case.profile["z"][0]]
        ax_p.plot(y, z_closed, "-", lw=1.5)
        ax_p.set_aspect("equal", adjustable="datalim")
        ax_p.set_xlabel(_axis_label(case, "profile", "y"))
        ax_p.set_ylabel(_axis_label(case, "profile", "z"))
    else:
        ax_p.text(0.5, 0.5, "no profile", ha="center", va="center", transform=ax_p.transAxes)
    ax_p.set_title("meridian in the tube (wall at r = l)" if case.flow == "tube" else "profile in the shear plane x = 0")
    ax_p.grid(True, alpha=0.3)

    fig.suptitle(f"{case.flow}, {case.law}, Ca_s = {fmt(case.Ca_s)}: {case.status}")
    return fig
