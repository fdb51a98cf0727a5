"""The paper's two methods on the same capsules, redone with the viscosity ratio of its shear
experiment (issue 7, item 5).

The paper (section 4.3) measures the ovalbumin capsules twice: in the tube (microfluidics,
inner and outer fluid both in the steady profile's frame, so the viscosity ratio does not
enter the steady shape) and in a Couette cell (microrheometry: an aqueous core, ~1 mPa s, in
glycerol, 0.756 Pa s, so lambda ~ 1.3e-3). Its shear analysis reads D12 against a database
made for lambda = 1, and names the viscosity ratio as an effect that analysis lacks.

Here the same reading is done with two shear databases: the paper grid's (lambda = 1) and the
microrheometry grid's (config/microrheometry.yaml, lambda = 0.001). For one capsule with
measured semi-axes L1, L2 and shear rate, the fitted modulus is

    G_s = mu gamma_dot a / Ca_s(D12),   a = sqrt(L1 L2 (L3/a)(D12)),

so at fixed measurements the ratio of the two analyses depends on D12 only:

    r(D12) = [Ca_s,1(D12) / Ca_s,lambda(D12)] * sqrt[(L3/a)_lambda(D12) / (L3/a)_1(D12)].

The paper publishes the population's mean G_s per law and its D12 range (0.35-0.5), not the
capsules' values: the population's correction is r averaged over that range (its extremes
bound it), applied to the published means. The paper's section 4.3 capsule (D12 = 0.38, a =
45 um given) is refitted directly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capsmech.inversion.fitting import shear_inverter
from capsmech.inversion.inverters import ShearInverter
from capsmech.io.database import ShearDatabase

#: The section 4.3 capsule: D12, radius [m], shear rate [1/s], outer viscosity [Pa s].
PAPER_EXAMPLE = {"D12": 0.38, "a": 45e-6, "shear_rate": 350.0, "mu": 0.756}
#: The paper's G_s for it [N/m], per law (section 4.3).
PAPER_EXAMPLE_G_S = {"NH": 0.044, "GH_nu0.5": 0.024, "GH_nu0.2": 0.038}
#: D12 range of the paper's 25 microrheometry capsules (section 4.4).
PAPER_D12_RANGE = (0.35, 0.5)
#: Microrheometry population: mean G_s and its standard deviation [N/m] (section 4.4).
PAPER_MICRORHEOMETRY = {"NH": (0.039, 0.01), "GH_nu0.5": (0.021, 0.007), "GH_nu0.2": (0.033, 0.01)}
#: Microfluidics on the same capsules [N/m]: NH mean and deviation; GH nu_s 0.5 the range at
#: large deformation (Delta > 1.10), given as its midpoint and half-width; GH nu_s 0.2 has no
#: value (G_s decreases with deformation and scatters, section 4.4).
PAPER_MICROFLUIDICS = {"NH": (0.043, 0.004), "GH_nu0.5": (0.021, 0.006)}
#: Viscosity ratio of the paper's Couette experiment: water (1e-3 Pa s) in glycerol (0.756 Pa s).
PAPER_LAMBDA = 1e-3 / 0.756


def modulus_ratio(base: ShearInverter, effect: ShearInverter, d12: np.ndarray) -> np.ndarray:
    """G_s from the ``effect`` database over G_s from the ``base`` one, at the same measured
    semi-axes and shear rate, for each D12 (NaN where either database does not cover it)."""
    ratios = []
    for value in np.atleast_1d(np.asarray(d12, dtype=float)):
        fb, fe = base.fit(D12=value), effect.fit(D12=value)
        if not (fb.ok and fe.ok):
            ratios.append(np.nan)
            continue
        ratios.append(fb.Ca_s / fe.Ca_s * np.sqrt(fe.L3_over_a / fb.L3_over_a))
    return np.array(ratios)


@dataclass
class MethodComparison:
    """One law's comparison of the two methods, before and after the viscosity ratio."""

    law: str
    example_before: float
    example_after: float
    d12_range: tuple[float, float]
    ratio_mean: float
    ratio_range: tuple[float, float]
    shear_before: tuple[float, float]
    shear_after: tuple[float, float]
    tube: tuple[float, float] | None

    def disagreement(self, shear: tuple[float, float]) -> float:
        """(shear - tube) / tube of the population means, NaN without a tube value."""
        return np.nan if self.tube is None else shear[0] / self.tube[0] - 1.0


def compare_methods(base: ShearDatabase, with_lambda: ShearDatabase, effect_suffix: str,
                    laws: tuple[str, ...] = ("NH", "GH_nu0.5", "GH_nu0.2"),
                    d12_range: tuple[float, float] = PAPER_D12_RANGE, samples: int = 31
                    ) -> list[MethodComparison]:
    """Redo the paper's comparison of its shear and tube moduli with the viscosity ratio.

    Parameters
    ----------
    base, with_lambda : ShearDatabase
        The lambda = 1 database and the one with the experiment's viscosity ratio, whose law
        keys are the base laws followed by ``effect_suffix`` (e.g. ``+lambda0.001``).
    laws : tuple of str
        Base law keys present in both.
    d12_range : tuple of float
        D12 range of the measured population; the correction is averaged over it.
    samples : int
        Points of the average (uniform in D12).

    Returns
    -------
    list of MethodComparison
    """
    rows = []
    for law in laws:
        inv_base = shear_inverter(base, law)
        inv_lambda = shear_inverter(with_lambda, law + effect_suffix)
        # The population's range, clipped to where both steady branches reach (GH nu_s 0.5
        # at lambda = 1 stops at D12 0.476 by Ca_s = 1).
        lo = max(d12_range[0], inv_base.D12_range[0], inv_lambda.D12_range[0])
        hi = min(d12_range[1], inv_base.D12_range[1], inv_lambda.D12_range[1])
        if not lo < hi:
            raise ValueError(f"{law}: the databases share no D12 in {d12_range[0]}-{d12_range[1]}")
        d12 = np.linspace(lo, hi, samples)
        example = {key: PAPER_EXAMPLE[key] for key in ("a", "shear_rate", "mu")}
        before = inv_base.modulus(D12=PAPER_EXAMPLE["D12"], **example).G_s
        after = inv_lambda.modulus(D12=PAPER_EXAMPLE["D12"], **example).G_s
        ratio = modulus_ratio(inv_base, inv_lambda, d12)
        mean, spread = PAPER_MICRORHEOMETRY[law]
        r = float(ratio.mean())
        rows.append(MethodComparison(law, before, after, (lo, hi), r, (float(ratio.min()), float(ratio.max())),
                                     (mean, spread), (mean * r, spread * r), PAPER_MICROFLUIDICS.get(law)))
    return rows


def comparison_table(rows: list[MethodComparison]) -> str:
    """The comparison as a Markdown table (moduli in N/m)."""
    lines = ["| law | section 4.3 capsule G_s: paper, lambda = 1 -> 0.001 (ours) | correction: D12 range, "
             "mean [extremes] | microrheometry G_s: paper -> "
             "corrected | microfluidics G_s (paper) | shear - tube: before -> after |",
             "|---|---|---|---|---|---|"]
    for row in rows:
        tube = "—" if row.tube is None else f"{row.tube[0]:.3f} ± {row.tube[1]:.3f}"
        gap = ("—" if row.tube is None else
               f"{100 * row.disagreement(row.shear_before):+.0f} % -> {100 * row.disagreement(row.shear_after):+.0f} %")
        lines.append(
            f"| {row.law} | {PAPER_EXAMPLE_G_S[row.law]:.3f}: {row.example_before:.4f} -> {row.example_after:.4f} "
            f"| {row.d12_range[0]:.2f}-{row.d12_range[1]:.2f}: ×{row.ratio_mean:.3f} "
            f"[{row.ratio_range[0]:.3f}, {row.ratio_range[1]:.3f}] "
            f"| {row.shear_before[0]:.3f} ± {row.shear_before[1]:.3f} -> {row.shear_after[0]:.3f} ± "
            f"{row.shear_after[1]:.3f} | {tube} | {gap} |")
    return "\n".join(lines)
