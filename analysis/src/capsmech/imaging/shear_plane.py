"""Capsules in the shear plane of a Couette rheometer: frame -> closed outline -> ellipse (paper §4.3).

The paper traces each capsule by hand (ImageJ) and fits the outline with an ellipse whose
semi-axes L1 >= L2 give the Taylor deformation D12 = (L1 - L2)/(L1 + L2), and whose major axis
makes the angle theta with the flow direction. Here the same is done from the image:

1. **Level**: the frame divided by its background (an image of the empty field, or a smooth
   quadratic surface fitted to the frame with the objects clipped out), minus 1: the relative
   contrast.
2. **Find**: on a band-pass of that contrast, pixels darker (or brighter) than its noise (MAD)
   allows; closed rings filled; each filled ring with one interior is one capsule. Objects cut
   by the image edge, solid objects (no interior), capsules in contact and specks are left out
   with their reason. There are no walls in the shear plane.
3. **Trace**: one ray per pixel of perimeter from the object's centre; on each, the ring's
   darkest point to sub-pixel (a parabola through the profile around its minimum): the
   membrane's mid-line, the line the paper traces. Two biases of that line are measured on the
   object and corrected (``ring_profile``, ``correct_for_blur``): the brightness step between
   interior and liquid, and the blur's pull of a curved line towards its centre of curvature.
4. **Fit**: a direct algebraic fit (``skimage.measure.EllipseModel``, Halir & Flusser) starts a
   least-squares fit of the radial distances (``scipy.optimize.least_squares``): the points are
   measured along their rays, so the radial residual is their error, and the fit's Jacobian
   gives the covariance of (centre, L1, L2, angle).
5. **Uncertainty**: the covariance scaled by the residuals' variance (the contour's fuzziness:
   noise, blur, and whatever of the outline is no ellipse) and by the residuals' integrated
   autocorrelation along the outline (neighbouring rays see the same blurred noise, so n points
   are worth fewer independent ones), and the uncertainties of the two corrections, propagated
   to D12 and theta. Stated at a coverage factor of 2 (about 95 %).

Angles: theta is the major axis's angle from the flow direction, counter-clockwise as seen on
the screen (image rows point down, so "up" is -row), folded into (-90, 90] degrees; a capsule in
simple shear leans into the extensional quadrant, so |theta| is what ``fit-shear`` and
``diagnose-shear`` read, and the sign says the shear's sense on the screen.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.optimize import least_squares
from scipy.special import erf
from skimage.measure import EllipseModel, label, regionprops

from capsmech.errors import ExtractionError
from capsmech.io.atomic import atomic_path, write_text_atomically
from capsmech.io.measurements import Capsule

#: Coverage factor of the stated uncertainties (two standard deviations: about 95 %).
COVERAGE = 2.0
#: Threshold of the detection, in noise standard deviations of the smoothed levelled frame.
DETECTION_SIGMAS = 4.0
#: Smoothing of the levelled frame before detection and tracing [px]: the ring's scale, not finer.
SMOOTHING_PX = 1.0
#: Scale of the surroundings a ring is compared with to be found [px]: wider than a membrane's
#: line, narrower than a capsule.
RING_SURROUNDING_PX = 5.0
#: Samples per pixel along a ray.
RAY_SAMPLING = 4
#: A traced point is an outlier beyond this many robust standard deviations of the residuals.
OUTLIER_SIGMAS = 4.0
#: Share of points that may be outliers before the outline is judged not traced.
MAX_OUTLIER_SHARE = 0.2


@dataclass(frozen=True)
class ShearSettings:
    """What the extraction needs to know about the images.

    Attributes
    ----------
    line : {'dark', 'bright'}
        The membrane's ring is darker (bright field) or brighter than the liquid.
    flow_angle_deg : float
        Direction of the flow on the screen, counter-clockwise from the image's +x axis
        (0: horizontal; 90: vertical).
    min_radius_px : float
        Smaller objects (equivalent radius of the filled outline) are specks, not capsules.
    detection_sigmas : float
        Detection threshold in noise standard deviations.
    """

    line: str = "dark"
    flow_angle_deg: float = 0.0
    min_radius_px: float = 6.0
    detection_sigmas: float = DETECTION_SIGMAS

    def __post_init__(self) -> None:
        if self.line not in ("dark", "bright"):
            raise ExtractionError(f"line: 'dark' or 'bright', got {self.line!r}")
        for name in ("flow_angle_deg", "min_radius_px", "detection_sigmas"):
            if not math.isfinite(getattr(self, name)):
                raise ExtractionError(f"{name}: need a finite number, got {getattr(self, name)}")
        if self.min_radius_px <= 0 or self.detection_sigmas <= 0:
            raise ExtractionError("min_radius_px and detection_sigmas must be positive")


@dataclass(frozen=True)
class EllipseFit:
    """A least-squares ellipse through a traced outline, with its uncertainties.

    Lengths in px; angles in degrees (see the module docstring); ``*_err`` at the coverage
    factor ``COVERAGE``; ``*_sys`` the part of them that the blur's and the ring's corrections
    contribute (the same in every frame of one capsule: it does not average out).
    """

    x_px: float
    y_px: float
    L1_px: float
    L2_px: float
    L1_err_px: float
    L2_err_px: float
    D12: float
    D12_err: float
    theta_deg: float
    theta_err_deg: float
    residual_rms_px: float
    correlation: float
    points: int
    outliers: int
    L1_sys_px: float = 0.0
    L2_sys_px: float = 0.0
    D12_sys: float = 0.0


@dataclass(frozen=True)
class ShearObject:
    """One object of one frame: its ellipse, or the reason it has none.

    Attributes
    ----------
    frame : int
        Index of the frame in the stack.
    source : str
        The frame's file (and page).
    x_px, y_px : float
        Centre of the filled outline (column, row).
    fit : EllipseFit or None
        None when the object was not measured.
    flag : str
        Empty when measured, else the reason in words.
    contour : array (n, 2)
        The traced mid-line points (column, row) [px]; empty when none.
    """

    frame: int
    source: str
    x_px: float
    y_px: float
    fit: EllipseFit | None
    flag: str = ""
    contour: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))


def level_frame(frame: np.ndarray, background: np.ndarray | None = None) -> np.ndarray:
    """The frame's relative contrast ``frame / background - 1``.

    Without a background image, the background is a quadratic surface fitted to the frame with
    the pixels that stand out (the capsules) clipped away: a Couette image has no walls, only an
    illumination that varies smoothly across the field.
    """
    image = np.asarray(frame, dtype=float)
    if background is None:
        surface = _smooth_background(image)
    else:
        surface = np.asarray(background, dtype=float)
        if surface.shape != image.shape:
            raise ExtractionError(f"background: {surface.shape[1]}x{surface.shape[0]} px, the frames are "
                                  f"{image.shape[1]}x{image.shape[0]} px")
    if np.any(surface <= 0):
        # A dark background (fluorescence) has no ratio: its difference is the contrast.
        scale = float(np.median(np.abs(surface))) or 1.0
        return (image - surface) / scale
    return image / surface - 1.0


def _smooth_background(image: np.ndarray, clip_sigmas: float = 3.0) -> np.ndarray:
    """A quadratic surface through the frame's background pixels (those that do not stand out)."""
    rows, cols = image.shape
    yy, xx = np.mgrid[0:rows, 0:cols]
    u, v = (xx - cols / 2) / cols, (yy - rows / 2) / rows
    basis = np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=-1).reshape(-1, 6)
    values = image.reshape(-1)
    # A sparse grid of pixels is enough for six coefficients, and keeps a 2k x 2k frame cheap.
    step = max(1, int(math.sqrt(rows * cols / 40_000)))
    sample = np.zeros(image.shape, dtype=bool)
    sample[::step, ::step] = True
    keep = sample.reshape(-1).copy()
    surface = np.full(values.shape, float(np.median(values)))
    for _ in range(4):
        coefficients, *_ = np.linalg.lstsq(basis[keep], values[keep], rcond=None)
        surface = basis @ coefficients
        deviation = values - surface
        spread = 1.4826 * float(np.median(np.abs(deviation[keep] - np.median(deviation[keep]))))
        # A frame without noise (drawn, or averaged) still has its grey levels' rounding.
        spread = max(spread, 1e-3 * abs(float(np.median(values))), 1e-12)
        clipped = sample.reshape(-1) & (np.abs(deviation) < clip_sigmas * spread)
        if np.count_nonzero(clipped) < 6 * basis.shape[1]:
            break           # too few pixels left to trust: keep the last surface
        keep = clipped
    return surface.reshape(image.shape)


def measure_frame(frame: np.ndarray, settings: ShearSettings = ShearSettings(), *, index: int = 0,
                  source: str = "", background: np.ndarray | None = None) -> list[ShearObject]:
    """Every capsule of one frame: found, traced and fitted with an ellipse (or why not)."""
    levelled = level_frame(frame, background)
    signed = levelled if settings.line == "bright" else -levelled
    smooth = ndimage.gaussian_filter(signed, SMOOTHING_PX)
    # The ring is found on a band-pass of the frame: a thin line stands out of it, a capsule's
    # interior that is uniformly darker (or brighter) than the liquid does not, so the ring
    # still has its hole to fill.
    band = smooth - ndimage.gaussian_filter(signed, RING_SURROUNDING_PX)
    # The threshold from the band's own noise (robust, the capsules are few pixels of the
    # frame), with a floor at the grey levels' quantisation for frames without noise.
    band_noise = 1.4826 * float(np.median(np.abs(band - np.median(band))))
    quantisation = 0.29 / max(float(np.median(np.abs(frame))), 1.0) / (2 * math.sqrt(math.pi) * SMOOTHING_PX)
    on_ring = band > settings.detection_sigmas * max(band_noise, quantisation)
    on_ring = ndimage.binary_closing(on_ring, structure=np.ones((3, 3)), border_value=0)
    filled = ndimage.binary_fill_holes(on_ring)
    objects = []
    labels = label(filled, connectivity=2)
    rows, cols = filled.shape
    for region in regionprops(labels):
        radius = math.sqrt(region.area / math.pi)
        if radius < settings.min_radius_px:
            continue    # a speck of noise or dirt: not worth a line in the report
        row, col = region.centroid
        r0, c0, r1, c1 = region.bbox
        # The closing's erosion leaves the frame's outermost pixels empty: one pixel in is the edge.
        if r0 <= 1 or c0 <= 1 or r1 >= rows - 1 or c1 >= cols - 1:
            objects.append(ShearObject(index, source, col, row, None, "cut by the image edge"))
            continue
        ring_area = int(np.count_nonzero(on_ring[labels == region.label]))
        if ring_area > 0.9 * region.area:
            objects.append(ShearObject(index, source, col, row, None,
                                       "no interior: a solid object or a ring not closed"))
            continue
        mask = labels == region.label
        interiors = _interiors(mask & ~on_ring)
        if interiors > 1:
            objects.append(ShearObject(index, source, col, row, None,
                                       f"touching outlines: {interiors} interiors in one ring (capsules in contact)"))
            continue
        thickness = ring_area / max(region.perimeter, 1.0)
        contour, ring = trace_midline(smooth, mask, (row, col), thickness, region.perimeter)
        try:
            fit = correct_for_blur(fit_ellipse(contour, settings.flow_angle_deg), ring)
        except ExtractionError as err:
            objects.append(ShearObject(index, source, col, row, None, str(err), contour))
            continue
        flag = ""
        if fit.outliers > MAX_OUTLIER_SHARE * (fit.points + fit.outliers):
            flag = (f"outline not traced: {fit.outliers} of {fit.points + fit.outliers} points off the ellipse "
                    "(overlapping objects or a broken ring)")
        objects.append(ShearObject(index, source, fit.x_px, fit.y_px, None if flag else fit, flag, contour))
    return objects


def _interiors(holes: np.ndarray) -> int:
    """How many interiors a filled ring has: its holes of at least a tenth of the largest's area
    (gaps in a noisy ring's line are a few pixels; two capsules in contact have two interiors)."""
    labelled, count = ndimage.label(holes)
    if count <= 1:
        return count
    sizes = np.bincount(labelled.ravel())[1:]
    return int(np.count_nonzero(sizes >= 0.1 * sizes.max()))


def trace_midline(smooth: np.ndarray, mask: np.ndarray, centre: tuple[float, float], thickness: float,
                  perimeter: float) -> tuple[np.ndarray, RingProfile]:
    """The ring's mid-line as points (column, row): on each ray from ``centre``, the extremum of
    the (signed, smoothed) profile inside the object's outer edge, to sub-pixel, moved by the
    ring's offset (``ring_profile``); and that ring profile.

    ``smooth`` is positive on the ring; ``mask`` the filled object; ``thickness`` the ring's
    mean width [px] from the detection, which sizes the window searched inside the edge.
    """
    row0, col0 = centre
    rows, cols = mask.shape
    count = int(np.clip(round(perimeter), 64, 2048))
    angles = np.linspace(0.0, 2 * math.pi, count, endpoint=False)
    # Far enough to leave the object: its farthest pixel, and the ring's width beyond.
    filled_rows, filled_cols = np.nonzero(mask)
    reach = float(np.max(np.hypot(filled_rows - row0, filled_cols - col0))) + 2.0 * thickness + 3.0
    radii = np.arange(0.0, reach, 1.0 / RAY_SAMPLING)
    cos, sin = np.cos(angles)[:, None], np.sin(angles)[:, None]
    ray_rows, ray_cols = row0 - radii * sin, col0 + radii * cos
    inside_image = (ray_rows >= 0) & (ray_rows <= rows - 1) & (ray_cols >= 0) & (ray_cols <= cols - 1)
    on_mask = ndimage.map_coordinates(mask.astype(float), [ray_rows, ray_cols], order=0, cval=0.0) > 0.5
    on_mask &= inside_image
    profile = ndimage.map_coordinates(smooth, [ray_rows, ray_cols], order=1, mode="nearest")
    half = int(round(max(1.0, 0.5 * thickness) * RAY_SAMPLING))
    rays, peaks = [], []
    for k in range(count):
        inside = np.flatnonzero(on_mask[k])
        if inside.size == 0:
            continue
        edge = inside[-1]
        start = max(0, int(edge - (2.0 * thickness + 3.0) * RAY_SAMPLING))
        window = profile[k, start:edge + RAY_SAMPLING + 1]
        rays.append(k)
        peaks.append(start + int(np.argmax(window)))
    vertices = parabola_vertices(profile[rays], np.asarray(peaks, dtype=int), half)
    ring = ring_profile(profile[rays], vertices, thickness)
    radius = vertices / RAY_SAMPLING + ring.offset_px
    ray_angles = angles[rays]
    return np.column_stack([col0 + radius * np.cos(ray_angles), row0 - radius * np.sin(ray_angles)]), ring


def parabola_vertices(profiles: np.ndarray, peaks: np.ndarray, half: int) -> np.ndarray:
    """Per row of ``profiles``: the vertex [samples] of the least-squares parabola through the
    samples within ``half`` of its ``peak``; the peak itself where the parabola opens the wrong
    way or its vertex leaves the window."""
    offsets = np.arange(-half, half + 1)
    columns = np.clip(peaks[:, None] + offsets[None, :], 0, profiles.shape[1] - 1)
    values = np.take_along_axis(profiles, columns, axis=1)
    # One design matrix for every ray: the fit is a fixed linear map of the window's samples.
    design = np.column_stack([offsets.astype(float) ** 2, offsets, np.ones_like(offsets, dtype=float)])
    a, b, _ = np.linalg.pinv(design) @ values.T
    with np.errstate(divide="ignore", invalid="ignore"):
        vertex = -b / (2 * a)
    good = (a < 0) & (np.abs(vertex) <= half)
    return peaks + np.where(good, vertex, 0.0)


@dataclass(frozen=True)
class RingProfile:
    """The membrane's ring across its width, from all of an object's rays together [px].

    Attributes
    ----------
    offset_px : float
        Added to each parabola's vertex to reach the ring's centre (see ``ring_profile``).
    offset_sd_px : float
        Standard uncertainty of that offset.
    width_px : float
        The ring's Gaussian width (standard deviation) as imaged, blur included.
    """

    offset_px: float = 0.0
    offset_sd_px: float = 0.0
    width_px: float = float("nan")


def ring_profile(profiles: np.ndarray, vertices: np.ndarray, thickness: float) -> RingProfile:
    """The rays' profiles [samples], aligned at their parabolas' vertices and averaged, fitted
    with a Gaussian dip (the ring) on a blurred step (interior to liquid) centred with it.

    A capsule's interior is seldom as bright as the liquid outside: the step at the membrane
    tilts the ring's profile and pulls each parabola's vertex towards the darker side (a few
    tenths of a pixel: L1 and L2 alike, D12 by -2 D12 offset/(L1 + L2)). The step's blur is the
    optics' alone, no wider than the imaged ring (which has the membrane's width too) and, on a
    camera, not much narrower: the fit is done with the step's blur at the ring's width and at
    half of it, and the mean of the two centres is the offset, half their difference its
    uncertainty.
    """
    reach = (3.0 * max(thickness, 1.0) + 3.0) * RAY_SAMPLING
    u = np.arange(-reach, reach + 1.0)
    samples = np.arange(profiles.shape[1], dtype=float)
    mean = np.mean([np.interp(v + u, samples, p) for p, v in zip(profiles, vertices)], axis=0)
    peak = float(np.max(mean))
    if not (np.all(np.isfinite(mean)) and peak > max(mean[0], mean[-1])):
        return RingProfile()
    centres, widths = [], []
    for blur_share in (1.0, 0.5):
        def model(p: np.ndarray, blur_share: float = blur_share) -> np.ndarray:
            centre, inner, outer, depth, width = p
            step = 0.5 * (1 + erf((u - centre) / (math.sqrt(2) * blur_share * abs(width) + 1e-9)))
            return inner + (outer - inner) * step + depth * np.exp(-0.5 * ((u - centre) / width) ** 2)

        start = np.array([0.0, mean[0], mean[-1], peak - min(mean[0], mean[-1]), thickness * RAY_SAMPLING / 2])
        fit = least_squares(lambda p, model=model: model(p) - mean, start, method="lm")
        if not (fit.success and abs(fit.x[0]) < thickness * RAY_SAMPLING and fit.x[3] > 0):
            return RingProfile()     # no dip to fit: nothing corrected
        centres.append(float(fit.x[0]))
        widths.append(abs(float(fit.x[4])))
    return RingProfile(offset_px=(centres[0] + centres[1]) / 2 / RAY_SAMPLING,
                       offset_sd_px=abs(centres[0] - centres[1]) / 2 / RAY_SAMPLING,
                       width_px=float(np.mean(widths)) / RAY_SAMPLING)


def _radial_residuals(params: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Each point's distance from the centre minus the ellipse's radius in its direction."""
    xc, yc, a, b, angle = params
    dx, dy = x - xc, y - yc
    phi = np.arctan2(dy, dx) - angle
    radius = a * b / np.sqrt((b * np.cos(phi)) ** 2 + (a * np.sin(phi)) ** 2)
    return np.hypot(dx, dy) - radius


def integrated_autocorrelation(residuals: np.ndarray) -> float:
    """1 + 2 sum of the residuals' autocorrelations around the closed outline, summed while they
    stay positive: how many neighbouring points one independent measurement is worth."""
    r = residuals - residuals.mean()
    n = len(r)
    spectrum = np.fft.rfft(r)
    acf = np.fft.irfft(spectrum * np.conj(spectrum), n)     # circular: the outline is closed
    if acf[0] <= 0:
        return 1.0
    acf = acf / acf[0]
    tau = 1.0
    for k in range(1, n // 4):
        if acf[k] <= 0:
            break
        tau += 2 * acf[k]
    return float(tau)


def fit_ellipse(points: np.ndarray, flow_angle_deg: float = 0.0) -> EllipseFit:
    """A least-squares ellipse through an outline's points (column, row) [px], with uncertainties.

    Raises
    ------
    ExtractionError
        When the points are too few or no ellipse goes through them.
    """
    points = np.asarray(points, dtype=float)
    if len(points) < 12:
        raise ExtractionError(f"outline of {len(points)} points: too few for an ellipse")
    # Work with y up, so that angles are counter-clockwise as seen on the screen.
    x, y = points[:, 0], -points[:, 1]
    keep = np.ones(len(points), dtype=bool)
    params = _algebraic_start(x, y)
    for _ in range(2):
        solution = least_squares(_radial_residuals, params, args=(x[keep], y[keep]), method="lm")
        params = solution.x
        residuals = _radial_residuals(params, x, y)
        spread = 1.4826 * float(np.median(np.abs(residuals[keep] - np.median(residuals[keep]))))
        limit = max(OUTLIER_SIGMAS * spread, 0.5)
        new_keep = np.abs(residuals) <= limit
        if np.array_equal(new_keep, keep) or new_keep.sum() < 12:
            break
        keep = new_keep
    solution = least_squares(_radial_residuals, params, args=(x[keep], y[keep]), method="lm")
    params, residuals, jacobian = solution.x, solution.fun, solution.jac
    n = int(keep.sum())
    variance = float(residuals @ residuals) / max(n - 5, 1)
    correlation = integrated_autocorrelation(residuals)
    try:
        covariance = np.linalg.inv(jacobian.T @ jacobian) * variance * correlation
    except np.linalg.LinAlgError:
        raise ExtractionError("outline: no unique ellipse through its points") from None
    xc, yc, a, b, angle = params
    a, b = abs(a), abs(b)
    if not (np.all(np.isfinite(params)) and a > 0 and b > 0):
        raise ExtractionError("outline: no ellipse through its points")
    if b > a:
        # Name the longer semi-axis L1; the covariance's a and b swap with them.
        a, b, angle = b, a, angle + math.pi / 2
        order = [0, 1, 3, 2, 4]
        covariance = covariance[np.ix_(order, order)]
    d12 = (a - b) / (a + b)
    gradient = np.array([0.0, 0.0, 2 * b / (a + b) ** 2, -2 * a / (a + b) ** 2, 0.0])
    d12_sd = math.sqrt(max(float(gradient @ covariance @ gradient), 0.0))
    theta = (math.degrees(angle) - flow_angle_deg + 90.0) % 180.0 - 90.0
    theta = 90.0 if theta == -90.0 else theta
    sd = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    return EllipseFit(x_px=float(xc), y_px=float(-yc), L1_px=float(a), L2_px=float(b),
                      L1_err_px=COVERAGE * float(sd[2]), L2_err_px=COVERAGE * float(sd[3]),
                      D12=float(d12), D12_err=COVERAGE * d12_sd, theta_deg=float(theta),
                      theta_err_deg=min(COVERAGE * math.degrees(float(sd[4])), 90.0),
                      residual_rms_px=float(math.sqrt(np.mean(residuals ** 2))), correlation=correlation,
                      points=n, outliers=len(points) - n)


def correct_for_blur(fit: EllipseFit, ring: RingProfile) -> EllipseFit:
    """The ellipse of a traced ring, corrected for what the blur does to a curved line, with the
    uncertainties of the ring's corrections added.

    A blurred curved line peaks inside its true position, by s^2/(2R) for a blur of variance s^2
    and a radius of curvature R: at the tips (R = L2^2/L1) that shortens L1 by s^2 L1/(2 L2^2), at
    the flanks (R = L1^2/L2) L2 by s^2 L2/(2 L1^2). The blur's variance lies between a quarter of
    the imaged ring's variance and all of it (see ``ring_profile``): the middle is corrected, half
    the range is its uncertainty. The ring's offset (``ring_profile``) moves the whole outline,
    L1 and L2 alike, by its uncertainty.
    """
    if not math.isfinite(ring.width_px):
        return fit
    a, b = fit.L1_px, fit.L2_px
    variance, variance_sd = 0.625 * ring.width_px ** 2, 0.375 * ring.width_px ** 2
    da, db = a / (2 * b * b), b / (2 * a * a)
    a_new, b_new = a + variance * da, b + variance * db
    d12 = (a_new - b_new) / (a_new + b_new)
    # dD12/dL1 = 2 L2/(L1 + L2)^2, dD12/dL2 = -2 L1/(L1 + L2)^2; each correction moves both axes at once.
    def d12_change(shift_a: float, shift_b: float) -> float:
        return 2 * (b_new * shift_a - a_new * shift_b) / (a_new + b_new) ** 2

    d12_sys = math.hypot(d12_change(variance_sd * da, variance_sd * db),
                         d12_change(ring.offset_sd_px, ring.offset_sd_px))
    l1_sys, l2_sys = math.hypot(variance_sd * da, ring.offset_sd_px), math.hypot(variance_sd * db, ring.offset_sd_px)
    return replace(fit, L1_px=a_new, L2_px=b_new, D12=d12,
                   D12_err=COVERAGE * math.hypot(fit.D12_err / COVERAGE, d12_sys),
                   L1_err_px=COVERAGE * math.hypot(fit.L1_err_px / COVERAGE, l1_sys),
                   L2_err_px=COVERAGE * math.hypot(fit.L2_err_px / COVERAGE, l2_sys),
                   L1_sys_px=COVERAGE * l1_sys, L2_sys_px=COVERAGE * l2_sys, D12_sys=COVERAGE * d12_sys)


def _algebraic_start(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(xc, yc, a, b, angle) of the direct algebraic fit (Halir & Flusser), or of a circle."""
    model = EllipseModel()
    if model.estimate(np.column_stack([x, y])) and model.params is not None and np.all(np.isfinite(model.params)):
        return np.asarray(model.params, dtype=float)
    xc, yc = float(x.mean()), float(y.mean())
    r = float(np.mean(np.hypot(x - xc, y - yc)))
    return np.array([xc, yc, r, r, 0.0])


@dataclass(frozen=True)
class ShearCapsule:
    """One capsule's result: from one object, or several frames of the same capsule combined.

    ``objects`` are the measured objects it comes from; the values and ``*_err`` (coverage
    factor ``COVERAGE``) as in ``EllipseFit``, lengths in px.
    """

    id: str
    objects: tuple[ShearObject, ...]
    L1_px: float
    L2_px: float
    L1_err_px: float
    L2_err_px: float
    D12: float
    D12_err: float
    theta_deg: float
    theta_err_deg: float


def capsule_of(capsule_id: str, obj: ShearObject) -> ShearCapsule:
    """The capsule one measured object is."""
    fit = obj.fit
    if fit is None:
        raise ValueError("capsule_of: the object was not measured")
    return ShearCapsule(capsule_id, (obj,), fit.L1_px, fit.L2_px, fit.L1_err_px, fit.L2_err_px, fit.D12,
                        fit.D12_err, fit.theta_deg, fit.theta_err_deg)


def combine_frames(capsule_id: str, objects: Sequence[ShearObject]) -> ShearCapsule:
    """Frames of one capsule combined: the mean of each value, and an uncertainty from each
    frame's own random part (its fuzziness: independent between frames), the scatter between
    frames (what the capsule and the focus did meanwhile) and the corrections' part, which every
    frame shares: u^2 = sum(r_i^2)/n^2 + s^2/n + mean(c_i)^2."""
    fits = [o.fit for o in objects if o.fit is not None]
    if not fits:
        raise ValueError("combine_frames: no measured object")
    if len(fits) == 1:
        return replace(capsule_of(capsule_id, objects[0]), objects=tuple(objects))

    def mean_and_error(values: list[float], errors: list[float], shared: list[float]) -> tuple[float, float]:
        n = len(values)
        own = math.sqrt(sum(max(e * e - c * c, 0.0) for e, c in zip(errors, shared))) / COVERAGE / n
        scatter = float(np.std(values, ddof=1)) / math.sqrt(n)
        common = float(np.mean(shared)) / COVERAGE
        return float(np.mean(values)), COVERAGE * math.sqrt(own ** 2 + scatter ** 2 + common ** 2)

    l1 = mean_and_error([f.L1_px for f in fits], [f.L1_err_px for f in fits], [f.L1_sys_px for f in fits])
    l2 = mean_and_error([f.L2_px for f in fits], [f.L2_err_px for f in fits], [f.L2_sys_px for f in fits])
    d12 = mean_and_error([f.D12 for f in fits], [f.D12_err for f in fits], [f.D12_sys for f in fits])
    theta = mean_and_error([f.theta_deg for f in fits], [f.theta_err_deg for f in fits], [0.0] * len(fits))
    return ShearCapsule(capsule_id, tuple(objects), l1[0], l2[0], l1[1], l2[1], d12[0], d12[1], theta[0], theta[1])


#: Columns of ``ShearExtraction.capsule_rows`` and their units.
CAPSULE_UNITS = {"id": "", "frames": "1", "L1": "um", "L1_err": "um", "L2": "um", "L2_err": "um", "D12": "1",
                 "D12_err": "1", "theta": "deg", "theta_err": "deg"}


@dataclass
class ShearExtraction:
    """What ``measure_stack`` found: every object of every frame, and the capsules measured.

    Attributes
    ----------
    objects : list of ShearObject
        In frame order, then by column.
    capsules : list of ShearCapsule
        One per measured object, or one for the whole stack (``one_capsule``).
    ids : dict
        Position in ``objects`` -> id of the capsule the object belongs to.
    pixel_size_um : float
        The calibration used.
    flow_angle_deg : float
        The flow's direction on the screen that theta is measured from.
    frames : sequence of 2-D arrays
        The frames measured (for overlays).
    """

    objects: list[ShearObject]
    capsules: list[ShearCapsule]
    ids: dict[int, str]
    pixel_size_um: float
    flow_angle_deg: float = 0.0
    frames: Sequence[np.ndarray] = ()

    def capsule_rows(self) -> list[dict[str, object]]:
        """One row per capsule (``CAPSULE_UNITS``), lengths in um, uncertainties at ``COVERAGE``."""
        um = self.pixel_size_um
        return [{"id": c.id, "frames": len(c.objects), "L1": c.L1_px * um, "L1_err": c.L1_err_px * um,
                 "L2": c.L2_px * um, "L2_err": c.L2_err_px * um, "D12": c.D12, "D12_err": c.D12_err,
                 "theta": c.theta_deg, "theta_err": c.theta_err_deg} for c in self.capsules]

    def measurements(self, shear_rate: float, mu: float) -> list[Capsule]:
        """The capsules as ``fit_shear`` takes them (SI units: m, 1/s, Pa s; theta as its size;
        D12_err, at ``COVERAGE``, as the CSV that ``write_shear_measurements`` writes has it)."""
        return [Capsule(c.id, {"L1": c.L1_px * self.pixel_size_um * 1e-6, "L2": c.L2_px * self.pixel_size_um * 1e-6,
                               "theta": math.radians(abs(c.theta_deg)), "shear_rate": shear_rate, "mu": mu,
                               "D12_err": c.D12_err if 0 <= c.D12_err < 1 else math.nan}, line=0)
                for c in self.capsules]


def measure_stack(frames: Sequence[np.ndarray], labels: Sequence[str], pixel_size_um: float,
                  settings: ShearSettings = ShearSettings(), *, stem: str = "capsule", one_capsule: bool = False,
                  background: np.ndarray | None = None,
                  progress: Callable[[int, int], None] | None = None) -> ShearExtraction:
    """Every frame measured (``measure_frame``) and the objects named as capsules.

    Each measured object is a capsule of its own (ids ``stem``, or ``stem-1``, ``stem-2``, ... in
    frame order, then by column), unless ``one_capsule``: then the frames show one capsule, the
    largest measured object of each frame is it (any other is flagged), and its frames are
    combined (``combine_frames``).
    """
    objects: list[ShearObject] = []
    for index, frame in enumerate(frames):
        found = measure_frame(frame, settings, index=index, source=labels[index], background=background)
        objects.extend(sorted(found, key=lambda o: o.x_px))
        if progress is not None:
            progress(index + 1, len(frames))
    measured = [k for k, o in enumerate(objects) if o.fit is not None]
    ids: dict[int, str] = {}
    capsules: list[ShearCapsule] = []
    if one_capsule:
        chosen = []
        for index in sorted({objects[k].frame for k in measured}):
            in_frame = [k for k in measured if objects[k].frame == index]
            best = max(in_frame, key=lambda k: _area(objects[k]))
            chosen.append(best)
            for k in in_frame:
                if k != best:
                    objects[k] = replace(objects[k], fit=None,
                                         flag="another object: one capsule per stack asked for, the largest is it")
        if chosen:
            ids = dict.fromkeys(chosen, stem)
            capsules = [combine_frames(stem, [objects[k] for k in chosen])]
    else:
        names = [stem] if len(measured) == 1 else [f"{stem}-{n + 1}" for n in range(len(measured))]
        ids = dict(zip(measured, names))
        capsules = [capsule_of(ids[k], objects[k]) for k in measured]
    return ShearExtraction(objects, capsules, ids, pixel_size_um, settings.flow_angle_deg, frames)


def _area(obj: ShearObject) -> float:
    return 0.0 if obj.fit is None else obj.fit.L1_px * obj.fit.L2_px


#: Columns of the per-object report and their units.
REPORT_COLUMNS = {"frame": "", "source": "", "id": "", "x": "px", "y": "px", "L1": "px", "L1_err": "px",
                  "L2": "px", "L2_err": "px", "D12": "1", "D12_err": "1", "theta": "deg", "theta_err": "deg",
                  "residual_rms": "px", "correlation": "1", "points": "1", "flag": ""}


def report_rows(extraction: ShearExtraction) -> list[dict[str, object]]:
    """One row per object (``REPORT_COLUMNS``), and one per capsule combined from several frames
    (frame ``combined``): lengths in px, uncertainties at ``COVERAGE``."""
    rows: list[dict[str, object]] = []
    for k, obj in enumerate(extraction.objects):
        fit = obj.fit
        row: dict[str, object] = {"frame": obj.frame, "source": obj.source, "id": extraction.ids.get(k, ""),
                                  "x": obj.x_px, "y": obj.y_px, "flag": obj.flag}
        if fit is not None:
            row.update({"L1": fit.L1_px, "L1_err": fit.L1_err_px, "L2": fit.L2_px, "L2_err": fit.L2_err_px,
                        "D12": fit.D12, "D12_err": fit.D12_err, "theta": fit.theta_deg,
                        "theta_err": fit.theta_err_deg, "residual_rms": fit.residual_rms_px,
                        "correlation": fit.correlation, "points": fit.points})
        rows.append(row)
    for cap in extraction.capsules:
        if len(cap.objects) > 1:
            rows.append({"frame": "combined", "source": f"{len(cap.objects)} frames", "id": cap.id,
                         "L1": cap.L1_px, "L1_err": cap.L1_err_px, "L2": cap.L2_px, "L2_err": cap.L2_err_px,
                         "D12": cap.D12, "D12_err": cap.D12_err, "theta": cap.theta_deg,
                         "theta_err": cap.theta_err_deg, "flag": ""})
    return rows


def _cell(value: object) -> str:
    if isinstance(value, float):
        return "" if not math.isfinite(value) else f"{value:.6g}"
    text = str(value)
    return f'"{text}"' if any(c in text for c in ',"\n') or text.startswith("#") else text


def _write(path: Path, lines: list[str]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_text_atomically(path, "\n".join(lines) + "\n")


def write_report(path: str | Path, rows: Sequence[dict[str, object]]) -> Path:
    """The per-object report: every object found, its ellipse and uncertainties, or its flag."""
    header = ",".join(f"{k} [{u}]" if u else k for k, u in REPORT_COLUMNS.items())
    return _write(Path(path), [header] + [",".join(_cell(row.get(k, math.nan)) for k in REPORT_COLUMNS)
                                          for row in rows])


def write_shear_measurements(path: str | Path, extraction: ShearExtraction, shear_rate: float, mu: float,
                             report: str | Path | None = None, source: str = "") -> Path:
    """The measurement CSV that ``fit-shear`` reads (``capsmech.io.measurements``: id, L1, L2,
    theta, shear_rate [1/s], mu [Pa s], D12_err at ``COVERAGE``, which fit-shear turns into G_s's
    spread); every uncertainty is in the report, named in a comment."""
    lines = [f"# capsmech extract-shear{': ' + source if source else ''}"]
    if report is not None:
        lines.append(f"# ellipses, D12 and theta with their uncertainties ({COVERAGE:g} sigma): {report}")
    lines.append(f"# D12_err: D12's uncertainty at {COVERAGE:g} standard deviations")
    lines.append("id,L1 [um],L2 [um],theta [deg],shear_rate [1/s],mu [Pa s],D12_err [1]")
    um = extraction.pixel_size_um
    for cap in extraction.capsules:
        # fit-shear reads theta as the inclination in (0, 90) deg: its size; the sign is the screen's.
        theta = abs(cap.theta_deg)
        lines.append(",".join([_cell(cap.id), f"{cap.L1_px * um:.6g}", f"{cap.L2_px * um:.6g}",
                               f"{theta:.6g}" if 0 < theta < 90 else "", f"{shear_rate:.6g}", f"{mu:.6g}",
                               # An error of 1 or more says nothing of D12 in [0, 1): left empty.
                               _cell(float(cap.D12_err)) if 0 <= cap.D12_err < 1 else ""]))
    return _write(Path(path), lines)


def write_shear_overlay(path: str | Path, extraction: ShearExtraction, frame: int) -> Path:
    """A PNG of one frame with its objects: the traced points, the fitted ellipse, and the
    capsule's id, D12 and theta with their uncertainties (or the object's flag)."""
    from matplotlib.figure import Figure  # no pyplot: no GUI backend needed
    from matplotlib.patches import Ellipse

    objects = [(k, o) for k, o in enumerate(extraction.objects) if o.frame == frame]
    fig = Figure(figsize=(6.4, 4.8), dpi=100)
    ax = fig.add_subplot()
    image = extraction.frames[frame] if frame < len(extraction.frames) else None
    if image is not None:
        ax.imshow(image, cmap="gray", interpolation="nearest")
    for k, obj in objects:
        if len(obj.contour):
            ax.plot(obj.contour[:, 0], obj.contour[:, 1], ".", ms=1.5, color="tab:orange")
        fit = obj.fit
        if fit is None:
            ax.text(obj.x_px, obj.y_px, obj.flag, fontsize=6, color="tab:red", ha="center")
            continue
        # The fit's angle is counter-clockwise on the screen; matplotlib's, with rows down, clockwise.
        angle = fit.theta_deg + extraction.flow_angle_deg
        ax.add_patch(Ellipse((fit.x_px, fit.y_px), 2 * fit.L1_px, 2 * fit.L2_px, angle=-angle, fill=False,
                             color="tab:cyan", lw=0.8))
        ax.text(fit.x_px, fit.y_px, f"{extraction.ids.get(k, '')}\nD12 {fit.D12:.3f} ± {fit.D12_err:.3f}\n"
                f"theta {fit.theta_deg:.1f} ± {fit.theta_err_deg:.1f} deg", fontsize=6, color="tab:cyan",
                ha="center", va="center")
    if image is None:
        ax.invert_yaxis()
    ax.set_aspect("equal")
    ax.set_title(f"frame {frame}: {objects[0][1].source if objects else ''}", fontsize=8)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return path
