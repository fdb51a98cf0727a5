"""Plausible ranges of the physical inputs, so that a unit slip is caught where it enters.

A value typed in the wrong unit (a viscosity in Pa s under a ``[mPa s]`` header, lengths in
mm under ``[um]``) reads as a valid number and gives a G_s that is off by the slip's factor,
with nothing else to betray it. Every measured quantity of a capsule experiment lies in a
range that physics and practice bound:

- viscosity: no liquid at room temperature is below about 0.2 mPa s (water is 0.9 mPa s,
  a liquid at 37 degC 0.7 mPa s) and a capsule suspension that still flows through a
  capillary is at most some 100 Pa s (glycerol 1.4 Pa s, the paper's 0.92 Pa s);
- lengths: capsules and cells from about 1 um to a few mm, channels alike;
- velocities: from um/s (a creeping capillary) to a few m/s (real-time deformability
  cytometry runs at 0.1-0.3 m/s);
- shear rates of a Couette rheometer: 1e-2 to 1e5 1/s;
- G_s of a capsule's membrane: 1e-4 to 10 N/m; the paper's section 3 quotes 0.05-1 N/m
  (Gubspun et al. 2016), soft hydrogel capsules reach down to 1e-3 N/m. A red cell's 2.5-10 uN/m
  lies below this range, and its warning is then expected.

A value outside its plausible range is a warning that names the unit slip that would bring it
back; a value so far outside (a factor 1e6 beyond either bound) that no slip explains it is an
error.
"""
from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass


@dataclass(frozen=True)
class Plausible:
    """A quantity's plausible range in SI units, and how its usual unit slips read."""

    low: float
    high: float
    unit: str
    #: Each slip as (factor the value is off by, words that name it).
    slips: tuple[tuple[float, str], ...]

    def contains(self, value: float) -> bool:
        return self.low <= value <= self.high

    def absurd(self, value: float) -> bool:
        """Outside the range by more than any unit slip: a factor 1e6 beyond a bound."""
        return value < self.low * 1e-6 or value > self.high * 1e6


_VISCOSITY = Plausible(2e-4, 100.0, "Pa s", ((1e-3, "values in Pa s under an [mPa s] or [cP] header"),
                                           (1e3, "values in mPa s under a [Pa s] header")))
_LENGTH = Plausible(5e-7, 1e-2, "m", ((1e-3, "values in um under an [mm] header, or in mm under [m]"),
                                      (1e3, "values in mm under a [um] header"),
                                      (1e-6, "values in um under an [m] header")))
_VELOCITY = Plausible(1e-7, 10.0, "m/s", ((1e-3, "values in mm/s under an [m/s] header, or in um/s under [mm/s]"),
                                          (1e3, "values in m/s under an [mm/s] header, or in mm/s under [um/s]")))
_RATE = Plausible(1e-2, 1e5, "1/s", ((1e-3, "a rate in 1/ms"), (1e3, "a rate in 1/ks")))
_PIXEL = Plausible(1e-8, 1e-4, "m", ((1e-3, "a pixel size in um under an [mm] header"),
                                     (1e3, "a pixel size in mm under a [um] header")))

#: Measurement column -> its plausible range (columns not named here are not checked).
COLUMNS: dict[str, Plausible] = {
    "mu": _VISCOSITY, "L_z": _LENGTH, "L_p": _LENGTH, "tube_radius": _LENGTH, "half_width": _LENGTH, "L1": _LENGTH, "L2": _LENGTH,
    "v_c": _VELOCITY, "V": _VELOCITY, "shear_rate": _RATE, "pixel_size": _PIXEL,
}

#: A capsule membrane's shear modulus [N/m] (a red cell's few uN/m is below it, see the module docstring).
SHEAR_MODULUS = Plausible(1e-4, 10.0, "N/m", ((1e-3, "a viscosity in Pa s under an [mPa s] header, or a velocity "
                                                    "in mm/s under an [m/s] header"),
                                              (1e3, "a viscosity in mPa s under a [Pa s] header, or a velocity in "
                                                    "m/s under an [mm/s] header")))


def slip_hint(quantity: Plausible, value: float) -> str:
    """The unit slip that brings ``value`` back into range (``'; perhaps ...'``), or ``''``."""
    for factor, words in quantity.slips:
        if quantity.contains(value / factor):
            return f"; perhaps {words} (x{1 / factor:g} gives {value / factor:.3g} {quantity.unit})"
    return ""


def out_of_range(name: str, quantity: Plausible, values: Iterable[float], where: str) -> str | None:
    """One sentence on the values of ``name`` outside the plausible range, or None when all are in it.

    ``where`` names the rows (``'lines 2-14'``); the typical (median) value out of range is quoted,
    with the slip that would explain it.
    """
    outside = sorted(v for v in values if math.isfinite(v) and not quantity.contains(v))
    if not outside:
        return None
    typical = outside[len(outside) // 2]
    side = "below" if typical < quantity.low else "above"
    return (f"{name} {typical:.3g} {quantity.unit} ({where}) is {side} the plausible range "
            f"{quantity.low:g}-{quantity.high:g} {quantity.unit}{slip_hint(quantity, typical)}")
