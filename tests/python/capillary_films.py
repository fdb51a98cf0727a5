"""Films of one capsule passing through a glass capillary, drawn for the end-to-end tests.

Apart from the package's renderer (``capsmech.imaging.rendering``) and from its databases:

- the **shapes** are the kernel's steady capsules of the independent pool
  (tests/data/independent_pool/pool.npz: 96 meridian elements, the databases have 64; made by
  tests/python/independent_batches.py), each with its truth (a/l, Ca_s, L_z, L_p, v_c/V);
- the **glass** is tests/python/glass_walls.py's: each wall a dark band outside the liquid
  (liquid-side edge = the interface), blurred, with an optional refraction line, tilted about
  the image's centre column, under an illumination gradient;
- the **capsule** is drawn as tests/python/event_frames.py draws its rings: the membrane a dark
  line (Gaussian across the outline, centred on it) around an interior slightly brighter than
  the liquid; here around the exact meridian section (distance to a finely sampled outline),
  turned with the channel's tilt and moved along its axis;
- static dirt (dark specks) and Gaussian camera noise, 8 bit.

Truth is in physical units: the capsule's L_z, L_p [um] are the pool's lengths times the tube
radius; its v_c = (v_c/V) Ca_s G_s / mu.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from event_frames import Optics
from glass_walls import Glass, film_background
from matplotlib.path import Path as PolygonPath
from scipy import ndimage
from scipy.spatial import cKDTree

POOL = Path(__file__).resolve().parents[1] / "data" / "independent_pool" / "pool.npz"

G_S = 0.04               # N/m
MU = 1.0                 # Pa s
TUBE_RADIUS_UM = 30.0
PIXEL_SIZE_UM = 0.5
SHAPE = (160, 480)
#: The membrane's line (event_frames' optics; only its ring and interior are used here).
MEMBRANE = Optics(ring_width_px=1.2, ring_absorption=0.4, interior_gain=0.04)
TOP_ROW = 20.0           # the top interface's row at the centre column (the bottom one 2 l below)


@dataclass(frozen=True)
class Capsule:
    """One steady capsule of the pool, its truth in the pool's units (lengths in tube radii)."""

    index: int
    a_over_l: float
    ca_s: float
    L_z: float
    L_p: float
    vc_over_V: float
    r: np.ndarray
    z: np.ndarray

    @property
    def v_c_mm_s(self) -> float:
        return self.vc_over_V * self.ca_s * G_S / MU * 1e3


@dataclass(frozen=True)
class Film:
    """A drawn film: its frames, the frame rate it was drawn at and its truth."""

    frames: np.ndarray
    frame_rate: float
    capsule: Capsule
    glass: Glass
    flip: bool


def pool_capsules(key: str = "NH") -> list[Capsule]:
    """The pool's steady capsules of membrane ``key``."""
    with np.load(POOL) as pool:
        k = [str(name) for name in pool["keys"]].index(key)
        return [Capsule(i, float(pool["a_over_l"][i]), float(pool["Ca_s"][i]), float(pool["L_z"][k, i]),
                        float(pool["L_p"][k, i]), float(pool["vc_over_V"][k, i]), pool["r"][k, i], pool["z"][k, i])
                for i in np.flatnonzero(pool["status"][k] == "steady")]


def section_px(capsule: Capsule, l_px: float) -> np.ndarray:
    """The closed section through the axis, (x along the flow, y across) [px], about the capsule's
    own centre of length (front pole to rear-most point), finely resampled (0.05 px steps)."""
    upper = np.column_stack([capsule.z, capsule.r])
    lower = np.column_stack([capsule.z[::-1], -capsule.r[::-1]])[1:-1]
    curve = np.vstack([upper, lower, upper[:1]]) * l_px
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(curve, axis=0).T))])
    fine = np.linspace(0.0, s[-1], int(s[-1] / 0.05), endpoint=False)
    points = np.column_stack([np.interp(fine, s, curve[:, 0]), np.interp(fine, s, curve[:, 1])])
    points[:, 0] -= 0.5 * (points[:, 0].max() + points[:, 0].min())
    return points


def capsule_transmission(outline: np.ndarray, tree: cKDTree, centre: np.ndarray, optics: Optics) -> np.ndarray:
    """Transmission of a capsule whose outline [px, (x, y) about its centre] is placed at ``centre``
    (image x, row): a dark line centred on it (event_frames' ring) around a slightly brighter
    interior. ``tree``: the outline's k-d tree (built once a film)."""
    rows, cols = SHAPE
    transmission = np.ones(SHAPE)
    x0, y0 = np.floor(outline.min(axis=0) + centre - 8).astype(int)
    x1, y1 = np.ceil(outline.max(axis=0) + centre + 8).astype(int)
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, cols), min(y1, rows)
    if x0 >= x1 or y0 >= y1:
        return transmission
    yy, xx = np.mgrid[y0:y1, x0:x1].astype(float)
    points = np.column_stack([xx.ravel(), yy.ravel()]) - centre
    # Beyond 6 sigma the line absorbs nothing: the tree need not look further.
    distance, _ = tree.query(points, distance_upper_bound=6 * optics.ring_width_px)
    # The interior is blurred anyway: a polygon of 0.5 px sides is exact enough (and 10 times faster).
    inside = PolygonPath(outline[::10]).contains_points(points).reshape(xx.shape).astype(float)
    ring = optics.ring_absorption * np.exp(-0.5 * (np.minimum(distance, 1e3).reshape(xx.shape)
                                                    / optics.ring_width_px) ** 2)
    interior = optics.interior_gain * ndimage.gaussian_filter(inside, 1.0)
    transmission[y0:y1, x0:x1] = 1 - ring + interior
    return transmission


def dirt(rng: np.random.Generator, specks: int = 14) -> np.ndarray:
    """Static dirt on the chip: dark Gaussian specks of 0.7-2 px, 3-12 % deep."""
    rows, cols = SHAPE
    y, x = np.mgrid[0:rows, 0:cols].astype(float)
    transmission = np.ones(SHAPE)
    for _ in range(specks):
        cy, cx = rng.uniform(0, rows), rng.uniform(0, cols)
        size, depth = rng.uniform(0.7, 2.0), rng.uniform(0.03, 0.12)
        transmission -= depth * np.exp(-0.5 * ((y - cy) ** 2 + (x - cx) ** 2) / size ** 2)
    return transmission


def film_batch(indices: list[int], seed: int = 40) -> list[tuple[int, Glass, bool]]:
    """The film-chain batch's films: the pool capsules ``indices`` in turn, the glass of each
    film (every third a thick 15 px band, the others thin 6-10 px bands with or without a
    refraction line; tilt up to 2 deg, gradients 5-25 %, noise 2-4 grey levels, drawn from
    ``seed``) and whether its image is upside down (about half of them)."""
    rng = np.random.default_rng(seed)
    films = []
    for n, index in enumerate(indices):
        thick = n % 3 == 2
        glass = Glass(15.0 if thick else float(rng.choice([6, 7, 8, 9, 10])),
                      "none" if thick else str(rng.choice(["liquid", "glass", "none"])),
                      darkness=float(rng.uniform(0.35, 0.6)), blur_px=float(rng.uniform(0.8, 1.2)),
                      tilt_deg=float(rng.uniform(-2, 2)), gradient=float(rng.uniform(0.05, 0.25)),
                      noise=float(rng.uniform(2, 4)))
        films.append((index, glass, bool(rng.integers(2))))
    return films


def passage(capsule: Capsule, glass: Glass, seed: int, frames: int = 22, step_px: float = 16.0,
            flip: bool = False, optics: Optics = MEMBRANE) -> Film:
    """One passage of ``capsule`` through the channel: ``frames`` frames, about ``step_px`` a frame
    (the frame rate is chosen for it from the true v_c and rounded to whole frames/s), the front
    entering the view in the first frame. ``glass.noise`` is the camera's noise; ``flip`` turns the
    image upside down."""
    rng = np.random.default_rng(seed)
    l_px = TUBE_RADIUS_UM / PIXEL_SIZE_UM
    v_px_s = capsule.v_c_mm_s * 1e3 / PIXEL_SIZE_UM
    frame_rate = float(round(v_px_s / step_px))
    step = v_px_s / frame_rate
    # The glass without noise (the camera's noise is added after the capsule).
    light, _, _ = film_background(replace(glass, noise=0.0, flip=False), shape=SHAPE, top=TOP_ROW,
                                  width=2 * l_px, seed=seed)
    light = light.astype(float) * dirt(rng)
    section = section_px(capsule, l_px)
    slope = math.tan(math.radians(glass.tilt_deg))
    turn = np.array([[math.cos(math.radians(glass.tilt_deg)), -math.sin(math.radians(glass.tilt_deg))],
                     [math.sin(math.radians(glass.tilt_deg)), math.cos(math.radians(glass.tilt_deg))]])
    turned = section @ turn.T
    tree = cKDTree(turned)
    centre_col = (SHAPE[1] - 1) / 2
    half_length = 0.5 * capsule.L_z * l_px
    first = -half_length + 30.0 + rng.uniform(0, step)
    out = []
    for k in range(frames):
        # Along the tilted axis: x the centre of length, the row the axis's row at that column.
        x = first + step * k
        row = TOP_ROW + l_px + (x - centre_col) * slope
        seen = light * capsule_transmission(turned, tree, np.array([x, row]), optics)
        noisy = np.clip(np.rint(seen + rng.normal(0.0, glass.noise, SHAPE)), 0, 255).astype(np.uint8)
        out.append(noisy[::-1] if flip else noisy)
    return Film(np.stack(out), frame_rate, capsule, glass, flip)
