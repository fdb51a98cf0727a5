"""An independent picture of a glass channel's walls, for the wall-finding tests.

Not the package's renderer (``capsmech.imaging.rendering`` draws each wall as one thin uniform
line just outside the interface): here the glass lies outside the liquid and shows as the optics of a
bright-field microscope make it look. Each wall is a dark band of ``band_px`` whose inner
(liquid-side) edge is the interface, box-shaped and blurred by a Gaussian point spread
(erf edges, averaged over each pixel's height by 5 sub-rows), optionally with

- a bright refraction line (a narrow Gaussian ridge) against the band on the liquid side or
  on the glass side;
- a "bright band between dark lines" picture: the glass itself bright, bounded by two dark
  lines, the inner one's liquid-side edge being the interface;
- a doubled line: a second, fainter line outside the first (the interface's edge is that of
  the inner one).

The whole picture is tilted (the distance to each wall taken across the tilted line),
multiplied by an illumination gradient along a random direction, and given Gaussian noise on an
8-bit scale. Truth: the two interfaces' rows at the image's centre column.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import erf


@dataclass(frozen=True)
class Glass:
    """How one film's walls look.

    Attributes
    ----------
    band_px : float
        Width of the dark band (or of each dark line of the ``bright_between`` and ``doubled``
        pictures).
    refraction : {"none", "liquid", "glass"}
        Where a bright refraction line lies against the band.
    picture : {"band", "bright_between", "doubled"}
    darkness : float
        Fraction of the light the band absorbs.
    blur_px : float
        Standard deviation of the point spread.
    tilt_deg, gradient, noise : float
        Tilt of the walls, illumination gradient (fractional change across the image) and noise
        (grey levels, the bright level being ~200).
    flip : bool
        The image turned upside down (the top and bottom walls' pictures exchanged).
    """

    band_px: float
    refraction: str = "none"
    picture: str = "band"
    darkness: float = 0.5
    blur_px: float = 1.0
    tilt_deg: float = 0.0
    gradient: float = 0.0
    noise: float = 3.0
    flip: bool = False


def _box(distance: np.ndarray, first: float, last: float, blur: float) -> np.ndarray:
    """A box from ``first`` to ``last`` (distances into the glass) blurred by a Gaussian."""
    s = blur * math.sqrt(2.0)
    return 0.5 * (erf((distance - first) / s) - erf((distance - last) / s))


def _glass_absorption(depth: np.ndarray, glass: Glass) -> np.ndarray:
    """Absorbed fraction at ``depth`` px into the glass (negative: in the liquid), transmission
    gain > 1 where a refraction line brightens it (returned negative)."""
    w, b = glass.band_px, glass.blur_px
    if glass.picture == "band":
        absorbed = glass.darkness * _box(depth, 0.0, w, b)
    elif glass.picture == "bright_between":
        # Two dark lines of width w, the glass between them (3 w wide) brighter than the liquid.
        absorbed = (glass.darkness * (_box(depth, 0.0, w, b) + _box(depth, 4 * w, 5 * w, b))
                    - 0.12 * _box(depth, w, 4 * w, b))
    else:                                                               # doubled
        absorbed = glass.darkness * _box(depth, 0.0, w, b) + 0.6 * glass.darkness * _box(depth, w + 2.5, 2 * w + 2.5, b)
    ridge = 0.25 * np.exp(-0.5 * ((depth - (-1.2 if glass.refraction == "liquid" else w + 1.2 +
                                           (4 * w if glass.picture == "bright_between" else 0.0))) / 0.8) ** 2)
    return absorbed - (ridge if glass.refraction != "none" else 0.0)


def film_background(glass: Glass, shape: tuple[int, int] = (160, 400), top: float = 30.0, width: float = 100.0,
                    seed: int = 0, frame: int = 0) -> tuple[np.ndarray, float, float]:
    """One frame of the empty channel: (image as float grey levels, top interface row, bottom
    interface row), the rows at the centre column of the image as returned (flipped if asked).
    ``seed`` sets the film (the gradient's direction), ``frame`` the frame's noise."""
    rng = np.random.default_rng(seed)
    rows, cols = shape
    sub = 5
    y = (np.arange(rows * sub) + 0.5) / sub - 0.5
    x = np.arange(cols, dtype=float)
    yy, xx = np.meshgrid(y, x, indexing="ij")
    slope = math.tan(math.radians(glass.tilt_deg))
    centre = (cols - 1) / 2
    # Distance across the tilted walls (perpendicular), from each interface into its glass.
    across = (yy - (xx - centre) * slope) * math.cos(math.radians(glass.tilt_deg))
    cos = math.cos(math.radians(glass.tilt_deg))
    depth_top = top * cos - across
    depth_bottom = across - (top + width) * cos
    transmission = (1 - _glass_absorption(depth_top, glass)) * (1 - _glass_absorption(depth_bottom, glass))
    transmission = transmission.reshape(rows, sub, cols).mean(axis=1)
    angle = rng.uniform(0, 2 * math.pi)
    ramp = (np.cos(angle) * (np.arange(cols)[None, :] / cols - 0.5)
            + np.sin(angle) * (np.arange(rows)[:, None] / rows - 0.5))
    noise = np.random.default_rng([seed, frame]).standard_normal(shape)
    image = 200.0 * transmission * (1 + glass.gradient * ramp) + glass.noise * noise
    image = np.clip(np.rint(image), 0, 255)
    top_row, bottom_row = top, top + width
    if glass.flip:
        image = image[::-1]
        top_row, bottom_row = rows - 1 - bottom_row, rows - 1 - top_row
    return image.astype(np.float32), top_row, bottom_row


def film(glass: Glass, frames: int = 9, **kwargs) -> tuple[np.ndarray, float, float]:
    """A stack of empty-channel frames (independent noise), and the interfaces' rows."""
    images = []
    for k in range(frames):
        image, top, bottom = film_background(glass, frame=k, **kwargs)
        images.append(image)
    return np.stack(images).astype(np.uint8), top, bottom
