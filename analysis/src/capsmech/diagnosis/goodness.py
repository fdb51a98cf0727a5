"""Goodness of fit after a diagnosis (issue 19, item 2): does what the chosen explanation leaves
look like tracing noise, or is something still missing?

A candidate is chosen because it explains the batch *better* than the others; that does not
make it a good explanation. A batch made with a membrane no database holds (a Skalak law of
C = 5) was "explained" by pre-stress with a chi2 of about 40 a capsule where a batch explained
by its true effect has 14-16, and a distortion no candidate describes was "explained" by a
tube-radius error. So after the diagnosis the batch's residual is tested against the noise,
three ways, each at ``ALPHA``:

- **size** (chi2 against the measured noise): each capsule's chi2 sums ``PROFILE_POINTS``
  squared residuals, each divided by the capsule's own noise level sigma_i (measured from its
  contour's two halves, ``capsmech.diagnosis.scoring.noise_levels``) combined with the
  databases' own accuracy at the point (``MODEL_FLOOR_REL`` of the capsule's length; from a
  sharp parachute edge to the rear pole the rim's accuracy,
  ``capsmech.inversion.sharp_edge.profile_floor``). With the fit's
  parameters (a/l, Ca_s) removed it has ``DOF`` degrees of freedom, and since sigma_i is
  itself an estimate (from ``NOISE_DOF`` effectively independent points), chi2_i / DOF follows
  an F(DOF, NOISE_DOF) distribution when the model is right, not a chi2: the batch's total is
  referred to the sum of such variates (Monte Carlo, fixed seed: the p-value is reproducible).
- **structure** (a pattern shared by the capsules): the batch's mean residual profile (px)
  against the sign-flip distribution of the capsules' profiles (under noise alone each
  capsule's profile is as likely with either sign; a missing effect moves every capsule the
  same way). It counts only when the mean profile also exceeds the databases' own accuracy
  (its rms in units of each point's floor above 1): a pattern smaller than that is the model's
  discretisation, not a missing effect.
- **drift**: G_s still varying with the elongation Delta (``capsmech.inversion.population.law_drift``).

A batch that fails any of them is **unexplained**: the report names the candidate that came
closest, how far it falls short (its chi2 per degree of freedom against the threshold), and
shows the remaining residual profile.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from capsmech.inversion.noise import (
    DOF,
    DRAWS,
    GOODNESS_ALPHA,
    MODEL_FLOOR_REL,
    NOISE_DOF,
    SEED,
    chi2_reference,
    chi2_test,
)
from capsmech.inversion.population import law_drift

__all__ = ["ALPHA", "DOF", "MODEL_FLOOR_REL", "NOISE_DOF", "GoodnessOfFit", "chi2_reference", "goodness_of_fit",
           "sign_flip_p_value"]

#: Significance of each of the three tests (the law verdict's too).
ALPHA = GOODNESS_ALPHA
# The noise model (DOF, NOISE_DOF, MODEL_FLOOR_REL, the reference draws) is the law verdict's
# too: ``capsmech.inversion.noise``.


@dataclass
class GoodnessOfFit:
    """What a fit of the batch leaves, tested against the tracing noise (see the module)."""

    capsules: int
    chi2: float
    dof: int
    #: chi2 per degree of freedom, and the value above which the size test fails at ALPHA.
    reduced_chi2: float
    reduced_chi2_limit: float
    chi2_p_value: float
    #: The batch's mean residual profile [px] along the meridian (front pole first), its
    #: standard error, its rms, and the model floor [px] the rms is compared with.
    profile: np.ndarray = field(repr=False)
    profile_error: np.ndarray = field(repr=False)
    structure_rms_px: float = math.nan
    structure_floor_px: float = math.nan
    structure_p_value: float = math.nan
    drift_p_value: float = math.nan

    @property
    def failures(self) -> list[str]:
        """The tests the batch fails, each in words (empty: consistent with noise)."""
        out = []
        if self.chi2_p_value < ALPHA:
            out.append(f"chi2 per degree of freedom {self.reduced_chi2:.2f} over {self.capsules} capsules, above the "
                       f"{self.reduced_chi2_limit:.2f} that noise reaches at p = {ALPHA:g} (p = {self.chi2_p_value:.2g})")
        if self.structure_p_value < ALPHA and self.structure_rms_px > self.structure_floor_px:
            out.append(f"a residual pattern shared by the capsules: rms {self.structure_rms_px:.2f} px along the "
                       f"meridian (p = {self.structure_p_value:.2g}; the databases' own accuracy: "
                       f"{self.structure_floor_px:.2f} px)")
        if self.drift_p_value < ALPHA:
            out.append(f"G_s still drifts with the elongation (p = {self.drift_p_value:.2g})")
        return out

    @property
    def consistent(self) -> bool:
        """Whether the batch's residual is consistent with the tracing noise (no failure)."""
        return not self.failures

    def summary(self) -> str:
        """One line: the statistics and their p-values."""
        return (f"chi2/dof {self.reduced_chi2:.2f} (p = {self.chi2_p_value:.2g}, limit {self.reduced_chi2_limit:.2f}), "
                f"shared pattern {self.structure_rms_px:.2f} px (p = {self.structure_p_value:.2g}, floor "
                f"{self.structure_floor_px:.2f} px), drift p = {self.drift_p_value:.2g}")

    def as_dict(self) -> dict:
        """The statistics as plain numbers (for ``--json``)."""
        return {"capsules": self.capsules, "chi2": self.chi2, "dof": self.dof, "reduced_chi2": self.reduced_chi2,
                "reduced_chi2_limit": self.reduced_chi2_limit, "chi2_p_value": self.chi2_p_value,
                "structure_rms_px": self.structure_rms_px, "structure_floor_px": self.structure_floor_px,
                "structure_p_value": self.structure_p_value, "drift_p_value": self.drift_p_value,
                "consistent": self.consistent, "failures": self.failures,
                "residual_profile_px": [float(v) for v in self.profile],
                "residual_profile_error_px": [float(v) for v in self.profile_error]}


def sign_flip_p_value(residual: np.ndarray, draws: int = DRAWS, seed: int = SEED) -> float:
    """p-value of the batch's mean profile (sum of squares over the points) against random sign
    flips of whole capsule profiles (rows)."""
    rng = np.random.default_rng(seed)
    observed = float(np.sum(residual.mean(axis=0) ** 2))
    signs = rng.choice([-1.0, 1.0], size=(draws, residual.shape[0]))
    flipped = np.sum((signs @ residual / residual.shape[0]) ** 2, axis=1)
    return float((1 + np.sum(flipped >= observed)) / (1 + draws))


def goodness_of_fit(residual_px: np.ndarray, sigma_px: np.ndarray, length_px: np.ndarray,
                    g_s: np.ndarray | None = None, delta: np.ndarray | None = None,
                    floor_px: np.ndarray | None = None) -> GoodnessOfFit:
    """Test a batch's fit against the tracing noise (see the module). Per capsule: the residual
    profile [px] (``PROFILE_POINTS`` points), the tracing-noise level sigma [px] of one point,
    the length L_z [px]; G_s and Delta for the drift. Each point's variance is sigma^2 plus the
    square of the databases' own accuracy (``MODEL_FLOOR_REL`` L_z): a batch is not declared
    unexplained for what the databases themselves cannot resolve (measured: a batch of the
    right law, simulated on a finer mesh than the databases', left chi2/dof 1.46-1.54 against
    noise alone and 0.93-0.99 with the floor). ``floor_px`` (capsules, points), where given,
    replaces that floor point by point (``capsmech.inversion.sharp_edge.profile_floor``: more
    behind a sharp parachute edge). Capsules without a fit (NaN) are left out."""
    keep = np.all(np.isfinite(residual_px), axis=1) & np.isfinite(sigma_px) & (sigma_px > 0)
    n = int(keep.sum())
    if n < 2:
        raise ValueError(f"goodness of fit needs at least 2 fitted capsules, got {n}")
    residual = residual_px[keep]
    if floor_px is None:
        floor = np.repeat((MODEL_FLOOR_REL * length_px[keep])[:, None], residual.shape[1], axis=1)
    else:
        floor = floor_px[keep]
    chi2 = np.sum(residual ** 2 / (sigma_px[keep, None] ** 2 + floor ** 2), axis=1)
    total = float(np.sum(chi2))
    p_chi2, limit = chi2_test(total, n, ALPHA)
    mean = residual.mean(axis=0)
    error = residual.std(axis=0, ddof=1) / math.sqrt(n)
    drift = math.nan
    if g_s is not None and delta is not None:
        ok = keep & np.isfinite(g_s) & np.isfinite(delta)
        if ok.sum() >= 3 and np.ptp(delta[ok]) > 0:
            drift = law_drift("batch", delta[ok], g_s[ok]).p_value
    # The shared pattern is weighed against the floor point by point: its rms in units of each
    # point's floor (the capsules' median there) against 1, reported as the rms against the
    # floor that ratio implies (with one floor everywhere, that floor itself).
    rms = float(np.sqrt(np.mean(mean ** 2)))
    ratio = float(np.sqrt(np.mean((mean / np.median(floor, axis=0)) ** 2)))
    effective_floor = rms / ratio if ratio > 0 else float(np.median(floor))
    return GoodnessOfFit(n, total, n * DOF, total / (n * DOF), limit, p_chi2, mean, error,
                         rms, effective_floor, sign_flip_p_value(residual), drift)
