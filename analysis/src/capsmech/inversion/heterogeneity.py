"""One material or several: is the scatter of a batch's per-capsule G_s that of one material?

A batch is often polydisperse, and two materials in one batch (say capsules of G_s 0.03 and
0.06 N/m) have a mean G_s that describes neither. Two tests on x_i = ln G_s_i, each capsule
with its own uncertainty s_i (the contour fit's, ``fit-tube``'s ``G_s_shape_error`` over
G_s; the velocity's error is not in it):

- **scatter** against the uncertainties: chi2 = sum (x_i - x_w)^2 / s_i^2 about the weighted
  mean x_w, n - 1 degrees of freedom (p-value ``chi2_p``). A significant chi2 says the capsules
  differ by more than their contours allow, which the velocity's error alone can also do: it
  is necessary for "not one material", not sufficient;
- **one component against two**: x_i ~ N(mu, s_i^2 + tau^2) (one material, its spread tau
  fitted: tau takes up the velocity's error and any continuous polydispersity), against a
  mixture of two such components with a shared tau (means mu_1, mu_2, weight w), fitted by
  maximum likelihood (EM from splits of the sorted values). The gain in BIC,
  2 (l_2 - l_1) - 2 ln n (two parameters more), must exceed ``BIC_THRESHOLD``, each group
  must hold ``MIN_GROUP`` capsules (a lone outlier is a bad capsule, not a material), and the
  two G_s must differ by ``MIN_RATIO`` (10 %) at least: a smaller split is within what the
  errors no capsule's uncertainty holds (the velocity's, the calibration's) can make of a few
  capsules, and a material is not told apart by less than a batch's G_s interval (3-4 % at
  10-16 capsules).

The threshold is calibrated by simulation of one-material batches (``false_alarm_rate``, 2000
batches each): normal ln G_s with per-capsule uncertainties of 1.3-5 % (the contour fits' at
0.45-1.35 px of tracing noise) or none, and a spread of 0-10 % beyond them (the velocity's 1.5 %,
a polydisperse material), 5-40 capsules. Without the ratio rule the BIC gain's 97.5th
percentile lies at 7.0 for 5 capsules without uncertainties, 6.1 for 6, 3.4 for 13 and below
2.1 from 24 on (with uncertainties: below 2.9), hence ``BIC_THRESHOLD`` = 7. With every rule,
the false alarms measured are at most 2.3 % (5 capsules, no uncertainties, a 10 % spread;
1.0-1.5 % at 6-13 capsules with it, at most 0.15 % at spreads of 2-3 %). Power on 6 capsules at
0.03 and 7 at 0.06 N/m: 100 % with or without uncertainties; at 0.04 and 0.05 N/m, 92 % with
them and 100 % without (module tests: ``tests/python/test_heterogeneity.py``).

Verdict "not one material": the two groups, each with its members, its G_s (the weighted mean
of ln G_s over its members, exp) and a 95 % interval (Student t over the members, never
narrower than their own uncertainties allow, with the databases' shared accuracy in
quadrature). Without per-capsule uncertainties (s_i = 0: the diagnosis's contour fits) the
mixture test stands alone; its threshold holds there too (tau then is the whole scatter).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy import stats

#: Fewest capsules with a G_s for the test.
MIN_CAPSULES = 5
#: Fewest capsules in each group of a two-material verdict.
MIN_GROUP = 2
#: Significance of the scatter test.
ALPHA = 0.05
#: BIC gain of two components over one above which the batch is not one material (module).
BIC_THRESHOLD = 7.0
#: Smallest ratio of the two groups' G_s of a two-material verdict.
MIN_RATIO = 1.1
#: Smallest variance of a capsule's ln G_s (0.1 %^2): keeps a component from collapsing onto
#: capsules without uncertainties.
VARIANCE_FLOOR = 1e-6
#: Most EM iterations (a batch of tens of capsules converges in far fewer; checked every
#: ``CHECK_EVERY``, to ``TOLERANCE`` in the responsibilities).
ITERATIONS = 100
CHECK_EVERY = 10
TOLERANCE = 1e-5
#: EM starts: splits of the sorted values at this many evenly spaced ranks, and at the
#: largest gap.
STARTS = 6
#: Level of the groups' G_s intervals.
LEVEL = 0.95


def _log_normal(x: np.ndarray, mean: np.ndarray, variance: np.ndarray) -> np.ndarray:
    return -0.5 * (np.log(2 * np.pi * variance) + (x - mean) ** 2 / variance)


def _tau2_step(x: np.ndarray, s2: np.ndarray, weights: np.ndarray, means: np.ndarray, tau2: np.ndarray) -> np.ndarray:
    """One fixed-point step of the shared spread tau^2 (the score equation of the normal
    likelihood with variances s_i^2 + tau^2, responsibilities ``weights``; ``tau2`` broadcast
    against the last two axes, which the step sums over), not below 0."""
    w = 1.0 / np.maximum(s2 + tau2, VARIANCE_FLOOR)
    w2 = weights * w ** 2
    excess = (x - means) ** 2 - s2
    update = np.sum(w2 * excess, axis=(-2, -1)) / np.sum(w2, axis=(-2, -1))
    return np.maximum(update, 0.0)


def one_component(x: ArrayLike, s2: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mu, tau^2, log-likelihood) of x ~ N(mu, s2 + tau^2), maximum likelihood, over the last
    axis (any leading axes are independent batches)."""
    x, s2 = np.asarray(x, dtype=float), np.broadcast_to(np.asarray(s2, dtype=float), np.shape(x))
    xs, ss = x[..., None, :], s2[..., None, :]
    ones = np.ones_like(xs)
    tau2 = np.maximum(np.var(x, axis=-1) - np.mean(s2, axis=-1), 0.0)
    for _ in range(ITERATIONS):
        v = np.maximum(ss + tau2[..., None, None], VARIANCE_FLOOR)
        mean = np.sum(xs / v, axis=-1, keepdims=True) / np.sum(1 / v, axis=-1, keepdims=True)
        new = _tau2_step(xs, ss, ones, mean, tau2[..., None, None])
        if np.allclose(new, tau2, rtol=1e-6, atol=1e-12):
            tau2 = new
            break
        tau2 = new
    v = np.maximum(s2 + tau2[..., None], VARIANCE_FLOOR)
    mu = np.sum(x / v, axis=-1) / np.sum(1 / v, axis=-1)
    return mu, tau2, np.sum(_log_normal(x, mu[..., None], v), axis=-1)


def two_components(x: ArrayLike, s2: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The two-component mixture with a shared spread, maximum likelihood over the last axis:
    (means (..., 2), tau^2, log-likelihood, responsibilities (..., n, 2)). EM from ``STARTS``
    splits of the sorted values into a low and a high group and from the split at their
    largest gap; the best start whose hard groups each hold ``MIN_GROUP`` capsules is kept
    (log-likelihood -inf where none does)."""
    x, s2 = np.asarray(x, dtype=float), np.broadcast_to(np.asarray(s2, dtype=float), np.shape(x))
    n = x.shape[-1]
    order = np.sort(x, axis=-1)
    middles = 0.5 * (order[..., :-1] + order[..., 1:])
    ranks = np.unique(np.round(np.linspace(0, n - 2, min(n - 1, STARTS))).astype(int))
    gap = np.argmax(np.diff(order, axis=-1), axis=-1)[..., None]
    # Starts (..., S): each a threshold, the values below it the first group.
    threshold = np.concatenate([middles[..., ranks], np.take_along_axis(middles, gap, axis=-1)], axis=-1)
    xs, ss = x[..., None, :], s2[..., None, :]                               # (..., 1, n)
    first = (xs < threshold[..., None]).astype(float)                        # (..., S, n)
    resp = np.stack([first, 1 - first], axis=-1)                            # (..., S, n, 2)
    xk, sk = xs[..., None], ss[..., None]                                    # (..., 1, n, 1)
    tau2 = np.maximum(0.25 * np.var(x, axis=-1) - np.mean(s2, axis=-1), 0.0)[..., None] * np.ones(threshold.shape[-1])
    for iteration in range(ITERATIONS):
        v = np.maximum(sk + tau2[..., None, None], VARIANCE_FLOOR)
        mean = np.sum(resp * xk / v, axis=-2) / np.maximum(np.sum(resp / v, axis=-2), 1e-300)   # (..., S, 2)
        weight = np.clip(resp.sum(axis=-2) / n, 1e-12, 1.0)
        tau2 = _tau2_step(xk, sk, resp, mean[..., None, :], tau2[..., None, None])
        v = np.maximum(sk + tau2[..., None, None], VARIANCE_FLOOR)
        joint = np.log(weight)[..., None, :] + _log_normal(xk, mean[..., None, :], v)
        # Two components: the first's responsibility is the logistic of the log-odds.
        new = 1.0 / (1.0 + np.exp(np.clip(joint[..., 1] - joint[..., 0], -700, 700)))
        done = iteration % CHECK_EVERY == 0 and float(np.max(np.abs(new - resp[..., 0]), initial=0.0)) < TOLERANCE
        resp = np.stack([new, 1 - new], axis=-1)
        if done:
            break
    v = np.maximum(sk + tau2[..., None, None], VARIANCE_FLOOR)
    weight = np.clip(resp.sum(axis=-2) / n, 1e-12, 1.0)
    joint = np.log(weight)[..., None, :] + _log_normal(xk, mean[..., None, :], v)
    loglik = np.sum(np.logaddexp(joint[..., 0], joint[..., 1]), axis=-1)   # (..., S)
    members = (resp[..., 0] > 0.5).sum(axis=-1)
    loglik = np.where((members >= MIN_GROUP) & (n - members >= MIN_GROUP), loglik, -np.inf)
    best = np.argmax(loglik, axis=-1)
    pick = np.expand_dims(best, -1)
    take = np.take_along_axis
    return (take(mean, pick[..., None], axis=-2)[..., 0, :], take(tau2, pick, axis=-1)[..., 0],
            take(loglik, pick, axis=-1)[..., 0], take(resp, pick[..., None, None], axis=-3)[..., 0, :, :])


def mixture_test(x: ArrayLike, s2: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """(BIC of one component less that of the two-component mixture, positive where two fit
    better; |mu_2 - mu_1|, the two components' distance in ln G_s), over the last axis."""
    x = np.asarray(x, dtype=float)
    n = x.shape[-1]
    _, _, one = one_component(x, s2)
    means, _, two, _ = two_components(x, s2)
    return 2 * (two - one) - 2 * math.log(n), np.abs(means[..., 1] - means[..., 0])


def bic_gain(x: ArrayLike, s2: ArrayLike) -> np.ndarray:
    """BIC of one component less that of the two-component mixture, over the last axis."""
    return mixture_test(x, s2)[0]


def several_materials(x: ArrayLike, s2: ArrayLike) -> np.ndarray:
    """Whether each batch (last axis: its capsules' ln G_s, ``s2`` their variances, 0 where
    unknown) is "not one material": the mixture wins by ``BIC_THRESHOLD`` with groups
    ``MIN_RATIO`` apart and, where every variance is known, the scatter test agrees."""
    x, s2 = np.asarray(x, dtype=float), np.broadcast_to(np.asarray(s2, dtype=float), np.shape(x))
    gain, distance = mixture_test(x, s2)
    several = (gain > BIC_THRESHOLD) & (distance > math.log(MIN_RATIO))
    known = np.all(s2 > 0, axis=-1)
    scatter_p = scatter_chi2(x, np.where(known[..., None], s2, 1.0))[1]
    return several & (~known | (scatter_p < ALPHA))


def scatter_chi2(x: ArrayLike, s2: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """(chi2, p-value) of x about its weighted mean against the variances s2, n - 1 degrees of
    freedom, over the last axis."""
    x, s2 = np.asarray(x, dtype=float), np.asarray(s2, dtype=float)
    mean = np.sum(x / s2, axis=-1, keepdims=True) / np.sum(1 / s2, axis=-1, keepdims=True)
    chi2 = np.sum((x - mean) ** 2 / s2, axis=-1)
    return chi2, stats.chi2.sf(chi2, x.shape[-1] - 1)


def false_alarm_rate(capsules: int, errors: ArrayLike, spread: float, draws: int = 2000, seed: int = 1) -> float:
    """Fraction of ``draws`` one-material batches of ``capsules`` called "not one material":
    ln G_s normal with each capsule's standard deviation drawn from ``errors`` (relative) and
    a ``spread`` beyond them; the scatter test where the errors are positive."""
    rng = np.random.default_rng(seed)
    s = rng.choice(np.asarray(errors, dtype=float), size=(draws, capsules))
    x = rng.normal(0.0, np.sqrt(s ** 2 + spread ** 2))
    return float(several_materials(x, s ** 2).mean())


@dataclass(frozen=True)
class Group:
    """One material of a batch: its capsules, G_s [N/m] and 95 % interval [N/m]."""

    members: tuple[str, ...]
    g_s: float
    interval: tuple[float, float]

    def as_dict(self) -> dict[str, Any]:
        return {"G_s": self.g_s, "G_s_interval": list(self.interval), "members": list(self.members)}


@dataclass(frozen=True)
class Heterogeneity:
    """The two tests on a batch's per-capsule G_s (see the module).

    Attributes
    ----------
    capsules : int
        Capsules with a G_s.
    chi2, chi2_dof, chi2_p : float, int, float
        Scatter of ln G_s against the capsules' own uncertainties (NaN without them).
    spread : float
        The one-material fit's spread tau of ln G_s beyond the uncertainties (relative).
    bic_gain : float
        BIC of one component less that of two (NaN below ``MIN_CAPSULES``; -inf where no two
        groups of ``MIN_GROUP`` capsules fit: the values gather around one mean).
    one_material : bool
        False when both tests (the mixture alone without uncertainties) say two materials.
    groups : tuple of Group
        The two materials, low G_s first (empty when one material).
    """

    capsules: int
    chi2: float
    chi2_dof: int
    chi2_p: float
    spread: float
    bic_gain: float
    one_material: bool
    groups: tuple[Group, ...] = ()

    @property
    def assessed(self) -> bool:
        return self.capsules >= MIN_CAPSULES

    def line(self) -> str:
        """The verdict in words."""
        if not self.assessed:
            return f"one material or several: not assessed ({self.capsules} capsules with a G_s, the test needs {MIN_CAPSULES})"
        scatter = (f"scatter chi2/dof {self.chi2 / self.chi2_dof:.2f} against the capsules' own uncertainties "
                   f"(p = {self.chi2_p:.2g})" if math.isfinite(self.chi2) else "no per-capsule uncertainties")
        mixture = (f"BIC gain {self.bic_gain:.1f} (threshold {BIC_THRESHOLD:g})" if math.isfinite(self.bic_gain)
                   else f"no two groups of {MIN_GROUP} capsules or more")
        evidence = f"{scatter}; two components against one: {mixture}"
        if self.one_material:
            return f"one material: {evidence}; spread beyond the uncertainties {100 * self.spread:.1f} %"
        groups = "; ".join(f"G_s = {g.g_s:.4g} N/m [{g.interval[0]:.4g}, {g.interval[1]:.4g}] ({len(g.members)}: "
                           + ", ".join(g.members) + ")" for g in self.groups)
        return f"not one material: {groups}; {evidence}"

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON-ready data (null, never NaN)."""
        def number(value: float) -> float | None:
            return float(value) if math.isfinite(value) else None

        return {"verdict": ("not assessed" if not self.assessed else
                            "one material" if self.one_material else "not one material"),
                "capsules": self.capsules, "chi2": number(self.chi2), "chi2_dof": self.chi2_dof,
                "chi2_p": number(self.chi2_p), "spread_rel": number(self.spread),
                "bic_gain": number(self.bic_gain), "bic_threshold": BIC_THRESHOLD, "alpha": ALPHA,
                "groups": [g.as_dict() for g in self.groups]}


def _group(ids: Sequence[str], x: np.ndarray, s2: np.ndarray, tau2: float, systematic_rel: float) -> Group:
    """A group's G_s and interval from its members' ln G_s (module)."""
    v = np.maximum(s2 + tau2, VARIANCE_FLOOR)
    mean = float(np.sum(x / v) / np.sum(1 / v))
    m = len(x)
    spread = max(float(np.std(x, ddof=1)) / math.sqrt(m), math.sqrt(1 / float(np.sum(1 / v))))
    half = math.hypot(float(stats.t.ppf(0.5 + LEVEL / 2, m - 1)) * spread, systematic_rel)
    return Group(members=tuple(ids), g_s=math.exp(mean), interval=(math.exp(mean - half), math.exp(mean + half)))


def heterogeneity(ids: Sequence[str], g_s: ArrayLike, g_s_error: ArrayLike | None = None,
                  systematic_rel: float = 0.0) -> Heterogeneity:
    """Test a batch's per-capsule G_s [N/m] (``g_s_error``: one standard deviation each [N/m],
    NaN or absent where unknown) for one material against two (module). ``systematic_rel``:
    the databases' accuracy shared by every capsule, relative, in the groups' intervals.
    Capsules without a positive G_s are left out."""
    g = np.asarray(g_s, dtype=float)
    e = np.full_like(g, np.nan) if g_s_error is None else np.asarray(g_s_error, dtype=float)
    keep = np.isfinite(g) & (g > 0)
    names = [str(i) for i, k in zip(ids, keep) if k]
    x = np.log(g[keep])
    rel = e[keep] / g[keep]
    known = bool(len(x)) and bool(np.all(np.isfinite(rel) & (rel > 0)))
    s2 = rel ** 2 if known else np.zeros_like(x)
    n = len(x)
    if n < MIN_CAPSULES:
        return Heterogeneity(capsules=n, chi2=math.nan, chi2_dof=max(n - 1, 0), chi2_p=math.nan, spread=math.nan,
                             bic_gain=math.nan, one_material=True)
    chi2, chi2_p = (float(v) for v in scatter_chi2(x, s2)) if known else (math.nan, math.nan)
    _, tau2_one, _ = one_component(x, s2)
    gain = float(bic_gain(x, s2))
    two = bool(several_materials(x, s2))
    groups: tuple[Group, ...] = ()
    if two:
        means, tau2, _, resp = two_components(x, s2)
        first = resp[:, 0] > 0.5
        parts = sorted((first, ~first), key=lambda part: float(np.mean(x[part])))
        groups = tuple(_group([names[i] for i in np.flatnonzero(part)], x[part], s2[part], float(tau2),
                              systematic_rel) for part in parts)
    return Heterogeneity(capsules=n, chi2=chi2, chi2_dof=n - 1, chi2_p=chi2_p, spread=math.sqrt(float(tau2_one)),
                         bic_gain=gain, one_material=not two, groups=groups)
