"""Mesh convergence of the 3D steady solver in the square duct (and the circular tube), and the
duct against the tube for a capsule much smaller than the channel.

Why: the duct model (capsim --channel square) has no published capsule result to compare with;
its accuracy is what its own mesh refinement says, and where the channel walls matter little
(a small capsule) it should behave as the circular tube does once the two flows' different
centreline velocity and curvature are taken out.

1. Convergence: NH, a/w 0.8, Ca_s 0.05, capsule levels 2, 3, 4, on the wall of the tube's
   level-3 validation (docs/validation/kernel-tube.md, "3D mesh convergence": element size
   0.2 far, 0.1 over |z| < 1, channel length 6, in the half-width w or radius l), solved by
   Newton-Krylov (--integrator newton). L_z, L_p, v_c/V at each level, the observed order
   p = log2(|f2 - f3| / |f3 - f4|) in the element size, Richardson's estimate
   f4 + (f4 - f3) / (2^p - 1), and the solver's residual, evaluations and time. The tube is
   also compared with the axisymmetric model on a converged meridian (192 elements).
2. Small capsule: duct and tube at the same a and Ca_s. Each v_c/V is compared with its own
   rigid-sphere law (duct: Faxen, u_max + a^2 Lap(u) / 6 = 2.0963 - 1.1856 a^2; tube:
   Haberman & Sayre), and the deformation D = L_z / (2a) - 1 of the duct with the tube's
   scaled by the ratio of the flows' Laplacians (7.1135 / 8): at small a the capsule feels
   only the quadratic part of the flow, whose strength is that Laplacian.

Runs are serial, one thread each; each case file is kept in --work and reused if present.

    python scripts/duct_convergence.py [--levels 2 3 4] [--tube] [--small 0.4:0.2 0.5:0.3:2 ...]
        [--work DIR] [--capsim PATH] [--csv docs/validation/runs/duct_convergence.csv]
"""
from __future__ import annotations

import argparse
import csv
import math
import subprocess
import sys
import time
from pathlib import Path

import h5py

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "analysis" / "src"))
from capsmech.io.case import read_case  # noqa: E402

#: The wall of the tube's level-2..4 convergence study (docs/validation/kernel-tube.md).
WALL = ["--wall-h-far", "0.2", "--wall-h-centre", "0.1", "--tube-length", "6"]
#: Square duct, U = 1, w = 1 (docs/theory/duct.md): centreline velocity and -Lap(u) = G,
#: G = 2 f Re / D_h^2 with f Re = 14.227077, D_h = 2.
DUCT_U_MAX = 2.0962560
DUCT_G = 2 * 14.227077 / 4.0
#: Circular tube, U = 1, l = 1: u = 2 (1 - r^2), -Lap(u) = 8.
TUBE_G = 8.0
CONVERGENCE_SIZE, CONVERGENCE_CA = 0.8, 0.05
QUANTITIES = ("L_z", "L_p", "v_c")


def duct_faxen_velocity(a: float) -> float:
    """v_c/V of a small rigid sphere on the square duct's axis: u_max + a^2 Lap(u) / 6."""
    return DUCT_U_MAX - DUCT_G * a**2 / 6


def haberman_sayre_velocity(a: float) -> float:
    """v_c/V of a rigid sphere on a tube's axis (Haberman & Sayre 1958, wall correction)."""
    return 2.0 * (1 - 2.0 / 3.0 * a**2 - 0.20217 * a**5) / (1 - 0.75857 * a**5)


def run_case(capsim: Path, work: Path, cache: Path, channel: str, size: float, ca: float, level: int,
             integrator: str = "newton") -> dict:
    """One steady case, Newton-Krylov or time-stepped (reused from work/ if its file is there); its row."""
    out = work / (f"{channel}_a{size}_ca{ca}_L{level}" + ("" if integrator == "newton" else f"_{integrator}") + ".h5")
    elapsed = math.nan
    if not out.exists():
        args = [str(capsim), "--flow", "tube", "--model", "3d", "--integrator", integrator, "--law", "NH",
                "--a-over-l", repr(size), "--ca", repr(ca), "--level", str(level), *WALL,
                "--wall-cache", str(cache), "--threads", "1", "--quiet", "--out", str(out)]
        if channel != "tube":
            args += ["--channel", channel]
        start = time.perf_counter()
        subprocess.run(args, check=False, capture_output=True, text=True)
        elapsed = time.perf_counter() - start
    row: dict = {"channel": channel, "a": size, "ca": ca, "level": level, "integrator": integrator}
    if not out.exists():
        return row | {"status": "no file"}
    case = read_case(out)
    with h5py.File(out) as f:
        attrs = dict(f.attrs)
    row |= {"status": case.status, "residual": float(attrs.get("newton_residual", math.nan)),
            "newton_steps": int(attrs.get("newton_iterations", -1)),
            "evaluations": int(attrs.get("velocity_evaluations", -1)),
            # stable -1: no estimate (the kernel then writes the largest double as the rate).
            "growth_rate": float(attrs["growth_rate"]) if int(attrs.get("stable", -1)) != -1 else math.nan,
            "stable": int(attrs.get("stable", -1)),
            # The run's wall-clock time without the wall's assembly and LU (cached after the first run).
            "time_s": float(attrs.get("wall_time_s", elapsed)) - float(attrs.get("wall_setup_s", 0.0)),
            "wall_setup_s": float(attrs.get("wall_setup_s", math.nan))}
    if case.status == "steady":
        row |= {name: case.steady_value(name) for name in QUANTITIES}
    return row


def axisymmetric_reference(capsim: Path, work: Path, size: float, ca: float, n_meridian: int = 192) -> dict:
    """The axisymmetric tube model at (size, ca) on a converged meridian."""
    out = work / f"axi_a{size}_ca{ca}_n{n_meridian}.h5"
    if not out.exists():
        subprocess.run([str(capsim), "--flow", "tube", "--law", "NH", "--a-over-l", repr(size), "--ca", repr(ca),
                        "--n-meridian", str(n_meridian), "--threads", "1", "--quiet", "--out", str(out)], check=True)
    case = read_case(out)
    return {name: case.steady_value(name) for name in QUANTITIES}


def observed_order(f2: float, f3: float, f4: float) -> tuple[float, float]:
    """Observed order in the element size (halved per level) and Richardson's estimate."""
    d23, d34 = f3 - f2, f4 - f3
    if d23 == 0 or d34 == 0 or d23 * d34 < 0:
        return math.nan, math.nan
    p = math.log2(abs(d23 / d34))
    return p, f4 + d34 / (2**p - 1)


def convergence_table(rows: list[dict], reference: dict | None) -> list[str]:
    lines = ["| level | L_z | L_p | v_c/V | residual [V] | evaluations | time [s] |"
             + (" L_z − axi | L_p − axi | v_c − axi |" if reference else ""),
             "|---|---|---|---|---|---|---|" + ("---|---|---|" if reference else "")]
    for r in rows:
        if "L_z" not in r:
            lines.append(f"| {r['level']} | {r['status']} | | | | | |")
            continue
        line = (f"| {r['level']} | {r['L_z']:.5f} | {r['L_p']:.5f} | {r['v_c']:.5f} | {r['residual']:.1e} | "
                f"{r['evaluations']} | {r['time_s']:.0f} |")
        if reference:
            line += (f" {100 * (r['L_z'] / reference['L_z'] - 1):+.2f} % | {r['L_p'] - reference['L_p']:+.4f} | "
                     f"{100 * (r['v_c'] / reference['v_c'] - 1):+.2f} % |")
        lines.append(line)
    converged = [r for r in rows if "L_z" in r]
    if len(converged) == 3:
        cells = []
        for name in QUANTITIES:
            p, extrapolated = observed_order(*(r[name] for r in converged))
            cells.append(f"{name}: order {p:.2f}, Richardson {extrapolated:.5f}")
        lines.append("")
        lines.append("; ".join(cells))
    if reference:
        lines.append("")
        lines.append(f"axisymmetric (192 elements): L_z {reference['L_z']:.5f}, L_p {reference['L_p']:.5f}, "
                     f"v_c/V {reference['v_c']:.5f}")
    return lines


def equivalent_tube_ca(ca: float) -> float:
    """The tube's Ca_s whose quadratic flow about the axis loads a small capsule as the duct's at ca:
    both flows are u_max - (G/4) r^2 + ..., and the membrane load scales with Ca_s G."""
    return round(ca * DUCT_G / TUBE_G, 6)


def small_table(triples: list[tuple[dict, dict, dict]]) -> list[str]:
    """Duct at Ca_s, tube at the same Ca_s, and tube at the equivalent Ca_s (same G Ca_s)."""
    lines = ["| a | Ca_s duct (tube eq.) | level | v_c duct − Faxén | v_c tube − Haberman–Sayre | "
             "(u_max − v_c)/G: duct / tube eq. | L_z: duct / tube / tube eq. | L_p: duct / tube / tube eq. |",
             "|---|---|---|---|---|---|---|---|"]
    for duct, tube, equivalent in triples:
        a = duct["a"]
        if any("L_z" not in r for r in (duct, tube, equivalent)):
            lines.append(f"| {a} | {duct['ca']} ({equivalent['ca']}) | {duct['level']} | "
                         f"{duct['status']} | {tube['status']} | {equivalent['status']} | | |")
            continue
        lag_duct = (DUCT_U_MAX - duct["v_c"]) / DUCT_G
        lag_tube = (2.0 - equivalent["v_c"]) / TUBE_G
        lines.append(
            f"| {a} | {duct['ca']} ({equivalent['ca']}) | {duct['level']} | "
            f"{duct['v_c']:.4f} ({100 * (duct['v_c'] / duct_faxen_velocity(a) - 1):+.2f} %) | "
            f"{tube['v_c']:.4f} ({100 * (tube['v_c'] / haberman_sayre_velocity(a) - 1):+.2f} %) | "
            f"{lag_duct:.5f} / {lag_tube:.5f} ({100 * (lag_duct / lag_tube - 1):+.1f} %) | "
            f"{duct['L_z']:.4f} / {tube['L_z']:.4f} / {equivalent['L_z']:.4f} | "
            f"{duct['L_p']:.4f} / {tube['L_p']:.4f} / {equivalent['L_p']:.4f} |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--levels", type=int, nargs="*", default=[2, 3, 4],
                        help="capsule levels of the convergence study (none: skip it)")
    parser.add_argument("--tube", action="store_true", help="also the circular tube at the same levels")
    parser.add_argument("--small", nargs="*", default=[], metavar="A:CA",
                        help="small-capsule duct-vs-tube cases A:CA[:LEVELS], e.g. 0.4:0.2 or 0.5:0.3:2,3 "
                        "(default levels: --small-levels)")
    parser.add_argument("--small-levels", type=int, nargs="+", default=[2])
    parser.add_argument("--small-integrator", choices=("newton", "rk2"), default="newton",
                        help="rk2: time-step the small cases to steady (where Newton does not converge)")
    parser.add_argument("--work", type=Path, default=Path("duct_convergence_runs"))
    parser.add_argument("--cache", type=Path, default=None, help="wall LU cache (default: --work)")
    parser.add_argument("--capsim", type=Path, default=REPO / "bin" / "capsim")
    parser.add_argument("--csv", type=Path, default=None, help="write every run's row here")
    options = parser.parse_args()
    options.work.mkdir(parents=True, exist_ok=True)
    cache = options.cache or options.work

    def case(channel: str, size: float, ca: float, level: int, integrator: str = "newton") -> dict:
        row = run_case(options.capsim, options.work, cache, channel, size, ca, level, integrator)
        print(f"# {row}", flush=True)
        return row

    all_rows: list[dict] = []
    report: list[str] = []
    small = []
    for item in options.small:
        fields = item.split(":")
        levels = [int(level) for level in fields[2].split(",")] if len(fields) > 2 else options.small_levels
        small += [(float(fields[0]), float(fields[1]), level) for level in levels]
    integrator = options.small_integrator
    triples = [(case("square", a, ca, level, integrator), case("tube", a, ca, level, integrator),
                case("tube", a, equivalent_tube_ca(ca), level, integrator))
               for a, ca, level in small]
    for triple in triples:
        all_rows += list(triple)
    channels = ((["square"] + (["tube"] if options.tube else [])) if options.levels else [])
    for channel in channels:
        rows = [case(channel, CONVERGENCE_SIZE, CONVERGENCE_CA, level) for level in options.levels]
        all_rows += rows
        reference = (axisymmetric_reference(options.capsim, options.work, CONVERGENCE_SIZE, CONVERGENCE_CA)
                     if channel == "tube" else None)
        report += [f"## {channel}, NH a {CONVERGENCE_SIZE}, Ca_s {CONVERGENCE_CA}", ""]
        report += convergence_table(rows, reference) + [""]
    if triples:
        report += ["## small capsule, duct against tube", ""] + small_table(triples) + [""]
    print("\n".join(report))
    if options.csv:
        fields = ["channel", "a", "ca", "level", "integrator", "status", *QUANTITIES, "residual", "newton_steps", "evaluations",
                  "growth_rate", "stable", "time_s", "wall_setup_s"]
        with open(options.csv, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=fields, extrasaction="ignore")
            writer.writeheader()
            for row in all_rows:
                writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})


if __name__ == "__main__":
    main()
