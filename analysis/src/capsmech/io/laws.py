"""Membrane law keys: the one place their names are parsed and checked.

A law key is a database's group name and maps to kernel flags:
``NH`` -> ``--law NH``; ``SK_C1`` -> ``--law SK --C 1``; ``GH_nu0.5`` -> ``--law GH --nu-s 0.5``.
A key may add effects beyond the base model, each a further database dimension:
``NH+prestress0.05`` -> ``--law NH --prestress 0.05``, ``NH+kb0.01`` -> ``--law NH --kb 0.01``
(``EFFECTS`` lists those the kernel has).

The grids of the database workflow, the inversion (small-deformation slopes), the diagnosis
(synthetic batches run with the kernel) and the case-file reader all read keys through
:func:`parse_law`, so that one spelling and one set of ranges holds everywhere; it sits at the
bottom of the package (``io``), below the workflow that used to hold it.
"""
from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass

from capsmech.errors import CapsmechError

#: The kernel's membrane laws (``capsim --law``): neo-Hookean, Skalak, generalised Hooke.
KERNEL_LAWS = ("NH", "SK", "GH")

_NUMBER = r"-?[0-9]+(?:\.[0-9]+)?"
_LAW_KEY = re.compile(rf"^(?:NH|SK_C(?P<C>{_NUMBER})|GH_nu(?P<nu_s>{_NUMBER}))(?P<effects>(?:\+[a-z_]+{_NUMBER})*)$")
_EFFECT = re.compile(rf"\+(?P<name>[a-z_]+)(?P<value>{_NUMBER})")

#: Effects a law key may add: name -> (kernel flag, range check, the range in words).
EFFECTS: dict[str, tuple[str, Callable[[float], bool], str]] = {
    "prestress": ("--prestress", lambda v: 0.0 <= v <= 0.5, "in [0, 0.5]"),
    "lambda": ("--lambda", lambda v: 0.0 < v <= 1e6, "in (0, 1e6]"),
    "kb": ("--kb", lambda v: 0.0 <= v <= 1.0, "in [0, 1]"),
    "offset": ("--offset", lambda v: 0.0 < v < 0.9, "in (0, 0.9)"),
}


class LawKeyError(CapsmechError, ValueError):
    """A law key of no known form, or with a parameter outside the kernel's range (named)."""


@dataclass(frozen=True)
class Law:
    """A membrane law as named by a database key.

    Attributes
    ----------
    key : str
        Database group name, e.g. ``'GH_nu0.5'``.
    name : str
        Kernel law: 'NH', 'SK' or 'GH'.
    nu_s : float or None
        Surface Poisson ratio [-] (GH only).
    C : float or None
        Skalak area-dilatation parameter [-] (SK only).
    effects : tuple of (str, float)
        Effects beyond the base model, e.g. ``(('prestress', 0.05),)``.
    """

    key: str
    name: str
    nu_s: float | None = None
    C: float | None = None
    effects: tuple[tuple[str, float], ...] = ()

    def kernel_args(self) -> list[str]:
        """Return the capsim flags that select this law (and its effects)."""
        args = ["--law", self.name]
        if self.C is not None:
            args += ["--C", f"{self.C:g}"]
        if self.nu_s is not None:
            args += ["--nu-s", f"{self.nu_s:g}"]
        for name, value in self.effects:
            args += [EFFECTS[name][0], repr(value)]
        return args


def parse_law(key: str) -> Law:
    """Return the :class:`Law` named by a database law key.

    Parameters
    ----------
    key : str
        ``NH``, ``SK_C<C>`` or ``GH_nu<nu_s>``, optionally followed by effects ``+<name><value>``.

    Raises
    ------
    LawKeyError
        If the key has another form or its parameter is outside the kernel's range
        (-1 < nu_s < 1, C > -0.5, each effect's ``EFFECTS`` range).
    """
    match = _LAW_KEY.match(key)
    if match is None:
        raise LawKeyError(f"unknown law key {key!r}: expected NH, SK_C<C> or GH_nu<nu_s>, "
                          f"optionally followed by effects +<name><value> ({', '.join(EFFECTS)})")
    effects: list[tuple[str, float]] = []
    for effect in _EFFECT.finditer(match["effects"]):
        name, value = effect["name"], float(effect["value"])
        if name not in EFFECTS:
            raise LawKeyError(f"law key {key!r}: unknown effect {name!r} (the kernel has {', '.join(EFFECTS)})")
        if any(name == seen for seen, _ in effects):
            raise LawKeyError(f"law key {key!r}: effect {name!r} given twice")
        if not EFFECTS[name][1](value):
            raise LawKeyError(f"law key {key!r}: {name} must lie {EFFECTS[name][2]}")
        effects.append((name, value))
    if match["C"] is not None:
        C = float(match["C"])
        if not C > -0.5:
            raise LawKeyError(f"law key {key!r}: Skalak C must be > -0.5")
        return Law(key, "SK", C=C, effects=tuple(effects))
    if match["nu_s"] is not None:
        nu_s = float(match["nu_s"])
        if not -1.0 < nu_s < 1.0:
            raise LawKeyError(f"law key {key!r}: nu_s must lie in (-1, 1)")
        return Law(key, "GH", nu_s=nu_s, effects=tuple(effects))
    return Law(key, "NH", effects=tuple(effects))
