"""Synthetic measurements made by the kernel at known parameters, for tests and examples.

``simulate_tube(a_over_l, Ca_s, law)`` runs ``capsim`` (axisymmetric tube) and returns its
steady L_z, L_p, v_c/V and meridian; ``tube_batch(...)`` turns a list of such capsules into
rows of the tube measurement format (``capsmech.io.measurements``) in micrometres for one
material (one G_s; each capsule's Ca_s set by its flow rate), with realistic noise: each
length off by a relative Gaussian error (2 % by default, the paper's estimate), the
velocity likewise, and the contour traced with +-1 pixel errors (``noisy_contour``: points
every 2 pixels, each coordinate off by a uniform error in [-1, 1] px). The truth is kept
beside the rows, never written into them.
"""
from __future__ import annotations

import csv
import math
import subprocess
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capsmech.io.case import read_case
from capsmech.io.laws import parse_law
from capsmech.workflow.paths import capsim_executable


@dataclass(frozen=True)
class SimulatedCapsule:
    """Steady state of one simulated tube case (lengths in l)."""

    a_over_l: float
    Ca_s: float
    law: str
    L_z: float
    L_p: float
    vc_over_V: float
    meridian: np.ndarray
    status: str
    #: The whole closed section (z, x) [l] of a capsule that is not axisymmetric (off the
    #: axis, ``simulate_offcentre_tube``), used for its contour instead of the mirrored meridian.
    section: np.ndarray | None = None
    #: Radial position of the centroid [l] (0 on the axis).
    r_c: float = 0.0


def simulate_tube(a_over_l: float, Ca_s: float, law: str, n_meridian: int = 64, threads: int = 1,
                  capsim: str | Path | None = None) -> SimulatedCapsule:
    """Run the kernel for one centred capsule in the tube; NaN results when not steady."""
    kernel = Path(capsim) if capsim else capsim_executable()
    flags = parse_law(law).kernel_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "case.h5"
        subprocess.run([str(kernel), "--flow", "tube", *flags, "--a-over-l", repr(float(a_over_l)), "--ca", repr(float(Ca_s)),
                        "--n-meridian", str(n_meridian), "--threads", str(threads), "--quiet", "--out", str(out)],
                       check=True, capture_output=True, text=True)
        case = read_case(out)
    if case.status != "steady":
        nan = math.nan
        return SimulatedCapsule(float(a_over_l), float(Ca_s), law, nan, nan, nan, np.empty((0, 2)), case.status)
    meridian = np.column_stack([case.profile["r"], case.profile["z"]])
    return SimulatedCapsule(float(a_over_l), float(Ca_s), law, case.steady_value("L_z"), case.steady_value("L_p"),
                            case.steady_value("v_c"), meridian, case.status)


def noisy_contour(meridian: np.ndarray, pixels_per_l: float, rng: np.random.Generator,
                  error_px: float = 1.0, spacing_px: float = 2.0) -> np.ndarray:
    """A hand-traced contour [px] of a simulated meridian (r, z) [l], as ImageJ would export it.

    The profile (both halves) is placed at a random position in the image, flow in +x, and
    sampled every ``spacing_px`` pixels; each coordinate is off by a uniform error in
    [-error_px, error_px] (the paper's +-1 pixel).
    """
    from capsmech.io.contours import full_profile

    return traced_contour(full_profile(meridian), pixels_per_l, rng, error_px, spacing_px)


def traced_contour(section: np.ndarray, pixels_per_l: float, rng: np.random.Generator,
                   error_px: float = 1.0, spacing_px: float = 2.0) -> np.ndarray:
    """A hand-traced contour [px] of a closed section (x along the flow, y across) [l]: placed,
    sampled and traced with errors as ``noisy_contour`` says."""
    from capsmech.io.contours import resample_curve

    profile = np.asarray(section, dtype=float) * pixels_per_l
    length = np.sum(np.hypot(*np.diff(np.vstack([profile, profile[:1]]), axis=0).T))
    points = resample_curve(profile, n=max(int(length / spacing_px), 16), closed=True)
    origin = np.array([rng.uniform(200, 400), rng.uniform(150, 250)])
    return points + origin + rng.uniform(-error_px, error_px, points.shape)


def run_tube_3d(a_over_l: float, Ca_s: float, out: str | Path, t_max: float, law: str = "NH",
                offset: float = 0.0, offset_mode: str = "drift", level: int = 2,
                wall: tuple[float, float] = (0.28, 0.14), tube_length: float = 6.0, self_quadrature: str = "full",
                wall_cache: str | Path | None = None, capsim: str | Path | None = None) -> Path:
    """Run the 3D tube kernel for one capsule (centred, or ``offset`` [l] off the axis,
    drifting or held) to ``t_max`` or its steady state, unless ``out`` exists already (then it is
    reused: the kernel's runs take minutes). Returns ``out``."""
    path = Path(out)
    if path.exists():
        return path
    kernel = Path(capsim) if capsim else capsim_executable()
    args = [str(kernel), "--flow", "tube", "--model", "3d", *parse_law(law).kernel_args(),
            "--a-over-l", repr(float(a_over_l)), "--ca", repr(float(Ca_s)), "--level", str(level),
            "--wall-h-far", repr(wall[0]), "--wall-h-centre", repr(wall[1]), "--tube-length", repr(tube_length),
            "--t-max", repr(float(t_max)), "--self-quadrature", self_quadrature, "--threads", "1", "--quiet",
            "--out", str(path)]
    if offset:
        args += ["--offset", repr(float(offset)), "--offset-mode", offset_mode]
    if wall_cache is not None:
        args += ["--wall-cache", str(wall_cache)]
    subprocess.run(args, check=True, capture_output=True, text=True)
    return path


def simulate_offcentre_tube(a_over_l: float, Ca_s: float, offset: float, t_max: float, law: str = "NH",
                            level: int = 2, wall: tuple[float, float] = (0.28, 0.14), tube_length: float = 6.0,
                            self_quadrature: str = "full", out: str | Path | None = None,
                            capsim: str | Path | None = None) -> SimulatedCapsule:
    """Run the 3D tube kernel for a capsule released ``offset`` [l] off the axis, to ``t_max``.

    It migrates towards the axis while it deforms; what is returned is its state at the end
    (lengths and v_c/V of the last history row, its radial position ``r_c``, and its section
    through the tube axis and its centroid, ``capsmech.imaging.mesh_section``), whatever the run's
    status: an off-centre capsule is a snapshot of a slow migration, not a steady state.
    ``self_quadrature``: the 3D kernel's membrane self term (``full`` or ``vertex``).
    ``out``: keep the case file there (and reuse it when it exists). Minutes a case at level 2.
    """
    from capsmech.imaging.mesh_section import plane_section

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(out) if out else Path(tmp) / "case.h5"
        run_tube_3d(a_over_l, Ca_s, path, t_max, law=law, offset=offset, level=level, wall=wall,
                    tube_length=tube_length, self_quadrature=self_quadrature, capsim=capsim)
        case = read_case(path)
    # The capsule is offset along x and symmetric about y = 0: the section there, (z, x).
    section = plane_section(case.mesh["nodes"], case.mesh["triangles"], normal_axis=1)
    last = {name: float(case.history[name][-1]) for name in ("L_z", "L_p", "v_c", "r_c")}
    meridian = np.column_stack([case.profile["r"], case.profile["z"]])
    return SimulatedCapsule(float(a_over_l), float(Ca_s), law, last["L_z"], last["L_p"], last["v_c"], meridian,
                            case.status, section=section, r_c=last["r_c"])


def offcentre_hybrid(axisymmetric: SimulatedCapsule, off_axis: str | Path, centred: str | Path,
                     points: int = 400) -> SimulatedCapsule:
    """A capsule off the axis made of the 3D kernel's off-centre capsule, corrected to the
    axisymmetric model.

    ``off_axis`` and ``centred`` are 3D tube case files at the same (a/l, Ca_s) and mesh, one
    off the axis (drifting or held) and one centred; ``axisymmetric`` is the axisymmetric
    model's capsule at that (a/l, Ca_s) (``simulate_tube``). The result is the off-axis
    capsule plus the difference between the two models' centred capsules, i.e. the
    axisymmetric model plus the 3D off-centre increment, so that the 3D mesh's own errors
    (common to both runs) cancel:
    - lengths and v_c/V: axisymmetric + (off-axis - centred), last history rows;
    - section: each point of the off-axis section (through the tube axis and the centroid),
      folded about the capsule's own axis x = r_c, is moved by the difference between the
      axisymmetric and the centred 3D meridians at the nearest point of the centred meridian
      (both at equal normalised arclength), on its own side of the axis. Where the two
      capsules coincide this gives the axisymmetric profile exactly, and the up-down
      asymmetry is the 3D kernel's, untouched.
    ``r_c`` is the off-axis capsule's radial position at the end, its side towards the wall
    being the section's upper one (larger y).
    """
    from scipy.spatial import cKDTree

    from capsmech.imaging.mesh_section import plane_section
    from capsmech.io.contours import resample_curve

    moved, still = read_case(off_axis), read_case(centred)
    r_c = float(moved.history["r_c"][-1])
    section = plane_section(moved.mesh["nodes"], moved.mesh["triangles"], normal_axis=1)   # (z, x)
    meridian_3d = resample_curve(np.column_stack([still.profile["z"], still.profile["r"]]), n=points)
    meridian_axi = resample_curve(axisymmetric.meridian[:, ::-1], n=points)                 # (z, r)
    side = np.where(section[:, 1] >= r_c, 1.0, -1.0)
    folded = np.column_stack([section[:, 0], np.abs(section[:, 1] - r_c)])
    nearest = cKDTree(meridian_3d).query(folded)[1]
    moved_folded = folded + (meridian_axi - meridian_3d)[nearest]
    hybrid = np.column_stack([moved_folded[:, 0], side * moved_folded[:, 1]])
    increment = {name: float(moved.history[name][-1]) - float(still.history[name][-1]) for name in ("L_z", "L_p", "v_c")}
    return SimulatedCapsule(axisymmetric.a_over_l, axisymmetric.Ca_s, axisymmetric.law,
                            axisymmetric.L_z + increment["L_z"], axisymmetric.L_p + increment["L_p"],
                            axisymmetric.vc_over_V + increment["v_c"], axisymmetric.meridian, "steady",
                            section=hybrid, r_c=r_c)


def tube_batch(capsules: Sequence[SimulatedCapsule], g_s: float = 0.04, tube_radius_um: float = 50.0,
               mu_pa_s: float = 1.0, noise: float = 0.02, seed: int = 0, pixel_size_um: float | None = None,
               id_prefix: str = "s") -> list[dict[str, float | str | np.ndarray]]:
    """Measurement rows (L_z, L_p [um], v_c [mm/s], tube_radius [um], mu [Pa s]) with noise,
    and with ``pixel_size_um`` given, a traced contour [px] (``noisy_contour``) per capsule.

    The batch is one material: every capsule has the modulus g_s [N/m], and its Ca_s was
    reached by its flow rate, V = Ca_s g_s / mu (so v_c = (v_c/V) V). The contours' errors
    come from a generator of their own, so that adding contours leaves the lengths unchanged.
    Ids are ``id_prefix`` and the capsule's number (``s001`` ...).
    """
    rng = np.random.default_rng(seed)
    contour_rng = np.random.default_rng(seed + 1000)
    rows = []
    for k, capsule in enumerate(capsules):
        if capsule.status != "steady" and capsule.section is None:
            continue
        scale = 1 + noise * rng.standard_normal(3)
        mean_velocity_mm_s = capsule.Ca_s * g_s / mu_pa_s * 1e3
        row: dict[str, float | str | np.ndarray] = {
            "id": f"{id_prefix}{k + 1:03d}", "L_z": capsule.L_z * tube_radius_um * scale[0],
            "L_p": capsule.L_p * tube_radius_um * scale[1], "v_c": capsule.vc_over_V * mean_velocity_mm_s * scale[2],
            "tube_radius": tube_radius_um, "mu": mu_pa_s}
        if pixel_size_um is not None:
            row["pixel_size"] = pixel_size_um
            row["contour"] = (noisy_contour(capsule.meridian, tube_radius_um / pixel_size_um, contour_rng)
                              if capsule.section is None else
                              traced_contour(capsule.section, tube_radius_um / pixel_size_um, contour_rng))
        rows.append(row)
    return rows


def write_tube_csv(rows: Sequence[dict[str, float | str | np.ndarray]], path: str | Path, comment: str = "") -> Path:
    """Write rows in the tube measurement format; rows with a contour also get their contour
    file (ImageJ XY format, pixels) in the folder ``<csv stem>_contours`` beside the CSV."""
    path = Path(path)
    columns = ["L_z", "L_p", "v_c", "tube_radius", "mu"]
    header = ["id", "L_z [um]", "L_p [um]", "v_c [mm/s]", "tube_radius [um]", "mu [Pa s]"]
    with_contours = bool(rows) and "contour" in rows[0]
    if with_contours:
        columns.append("pixel_size")
        header += ["pixel_size [um]", "contour [px]"]
        folder = path.with_name(f"{path.stem}_contours")
        folder.mkdir(exist_ok=True)
    with open(path, "w", newline="", encoding="utf-8") as stream:
        for line in comment.splitlines():
            stream.write(f"# {line}\n")
        writer = csv.writer(stream)
        writer.writerow(header)
        for row in rows:
            cells = [row["id"], *(f"{row[k]:.6g}" for k in columns)]
            if with_contours:
                contour_file = folder / f"{row['id']}.txt"
                np.savetxt(contour_file, row["contour"], fmt="%.3f", delimiter="\t", header="X\tY", comments="")
                cells.append(f"{folder.name}/{contour_file.name}")
            writer.writerow(cells)
    return path
