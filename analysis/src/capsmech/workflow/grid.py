"""Parameter grids of the database workflow: validation, law keys and the cases they expand to.

A grid (``config/<name>.yaml``) names the cases of one database refill: for each flow
(``tube``, ``shear``) the membrane laws, the parameter values, and the kernel settings
(mesh, time limit) shared by every case of that flow. It is validated against the JSON
schema ``workflow/schemas/grid.schema.yaml`` and then for what a schema cannot say (law
parameters in the kernel's ranges, no duplicate values). Every error names the key.

Law keys are the database's group names (parsed in ``capsmech.io.laws``) and map to kernel flags:
``NH`` -> ``--law NH``; ``SK_C1`` -> ``--law SK --C 1``; ``GH_nu0.5`` -> ``--law GH --nu-s 0.5``.
A key may add effects beyond the base model (issue 6), each a further database dimension:
``NH+prestress0.05`` -> ``--law NH --prestress 0.05``, ``NH+kb0.01`` -> ``--law NH --kb 0.01``
(``capsmech.io.laws.EFFECTS`` lists those the kernel has).

A tube grid with ``settings.branch: true`` computes its cases by continuation: one kernel run
per (law, a/l), a :class:`Branch`, follows the steady branch up the grid's Ca_s and writes
every case file of that (law, a/l) plus a branch file with the critical Ca_s where the steady
branch ends (``capsim --branch-ca``). The case files are the same cases (same names, same
kernel arguments but ``--ca``); only how they are computed differs. The axisymmetric model
follows a branch with any integrator but rk2 (time steps only); the 3D model (tube or duct)
with its steady solver only, ``integrator: newton``, as the kernel requires.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from capsmech.errors import CapsmechError
from capsmech.io import laws
from capsmech.io.laws import Law, LawKeyError
from capsmech.workflow.paths import repo_root

FLOWS = ("tube", "shear")

#: Kernel flag of every per-flow setting a grid may carry (the schema lists the same keys).
SETTING_FLAGS = {
    "tube": {"n_meridian": "--n-meridian", "tube_length": "--tube-length",
             "integrator": "--integrator", "t_max": "--t-max", "model": "--model", "level": "--level",
             "wall_h_far": "--wall-h-far", "wall_h_centre": "--wall-h-centre",
             "channel": "--channel", "aspect": "--aspect"},
    "shear": {"level": "--level", "dt": "--dt", "t_max": "--t-max", "integrator": "--integrator", "k_b": "--kb"},
}


#: Flows where the kernel has each effect (others refuse it).
EFFECT_FLOWS = {"prestress": ("tube", "shear"), "lambda": ("shear", "tube"), "kb": ("tube", "shear"),
                "offset": ("tube",)}
#: Tube models that have each effect (tube.settings.model, default axi): the off-centre capsule
#: exists in the 3D model only, lambda /= 1 in both.
EFFECT_TUBE_MODELS = {"offset": ("3d",), "lambda": ("axi", "3d")}


class GridError(CapsmechError, ValueError):
    """A grid is malformed; the message names the offending key."""


def schema_path() -> Path:
    """Return the path of the grid JSON schema (``workflow/schemas/grid.schema.yaml``)."""
    return repo_root() / "workflow" / "schemas" / "grid.schema.yaml"


def parse_law(key: str) -> Law:
    """``capsmech.io.laws.parse_law`` (where law keys are parsed), its error a ``GridError``:
    in a grid, a bad law key is the grid's error."""
    try:
        return laws.parse_law(key)
    except LawKeyError as err:
        raise GridError(str(err)) from None


@dataclass(frozen=True)
class Case:
    """One kernel run of a grid.

    Attributes
    ----------
    flow : str
        'tube' or 'shear'.
    law : Law
        Membrane law.
    Ca_s : float
        Capillary number [-].
    a_over_l : float or None
        Capsule over tube radius [-] (tube only).
    settings : tuple of (str, Any)
        The flow's kernel settings (mesh, time limit), sorted by name.
    variant : str
        '' for a grid case; ``level<N>`` for the companion of a case on the other mesh level of
        its flow's ``mesh_check`` (:func:`mesh_check_cases`), not a database row of its own.
    """

    flow: str
    law: Law
    Ca_s: float
    a_over_l: float | None
    settings: tuple[tuple[str, Any], ...]
    variant: str = ""

    @property
    def case_id(self) -> str:
        """str: file stem, ``a0.8_Ca0.01`` (tube) or ``Ca0.01`` (shear); a companion case adds its
        variant (``Ca0.3_level4``)."""
        ca = f"Ca{self.Ca_s:g}"
        stem = ca if self.a_over_l is None else f"{size_id(self.a_over_l)}_{ca}"
        return f"{stem}_{self.variant}" if self.variant else stem

    @property
    def relative_path(self) -> str:
        """str: ``<flow>/<law key>/<case_id>.h5``, the case file below the cases directory."""
        return f"{self.flow}/{self.law.key}/{self.case_id}.h5"

    @property
    def effects(self) -> dict[str, float]:
        """dict: the case's effects beyond the base model (kernel names, see
        ``capsmech.io.case.EFFECT_DEFAULTS``): the law key's, and a bending stiffness given as a
        model setting (``k_b``) where the law key names none."""
        settings = dict(self.settings)
        given = {"kb": float(settings["k_b"])} if "k_b" in settings else {}
        return {**given, **dict(self.law.effects)}

    def kernel_args(self) -> list[str]:
        """Return the capsim arguments of this case (without ``--out``, ``--threads``)."""
        args = ["--flow", self.flow, *self.law.kernel_args(), "--ca", repr(self.Ca_s)]
        if self.a_over_l is not None:
            args += ["--a-over-l", repr(self.a_over_l)]
        flags = SETTING_FLAGS[self.flow]
        for name, value in self.settings:
            if name == "k_b" and "kb" in dict(self.law.effects):
                continue  # the law key's bending stiffness is the case's
            args += [flags[name], str(value)]
        return args


def size_id(a_over_l: float) -> str:
    """str: ``a0.8``, the a/l part of a tube case's file stem and the name of its branch file."""
    return f"a{a_over_l:g}"


@dataclass(frozen=True)
class Branch:
    """One kernel run of a branch grid: every Ca_s of one (law, a/l), by continuation.

    Attributes
    ----------
    law : Law
        Membrane law.
    a_over_l : float
        Capsule over tube radius [-].
    Ca_s : tuple of float
        The grid's capillary numbers, increasing (the branch is followed upwards).
    settings : tuple of (str, Any)
        The tube's kernel settings (mesh, time limit of the time-stepped cases).
    """

    law: Law
    a_over_l: float
    Ca_s: tuple[float, ...]
    settings: tuple[tuple[str, Any], ...]

    @property
    def relative_path(self) -> str:
        """str: ``tube/<law key>/a0.8.h5``, the branch file below the branches directory."""
        return f"tube/{self.law.key}/{size_id(self.a_over_l)}.h5"

    @property
    def cases(self) -> list[Case]:
        """The grid's cases this branch computes, in Ca_s order."""
        return [Case("tube", self.law, ca, self.a_over_l, self.settings) for ca in self.Ca_s]

    def kernel_args(self, cases_dir: str | Path, summary: str | Path) -> list[str]:
        """Return the capsim arguments of the branch (without ``--threads``): its case files go
        to ``cases_dir/tube/<law key>/a0.8_Ca<ca>.h5`` (the cases' own paths), the branch file
        to ``summary``."""
        pattern = Path(cases_dir) / "tube" / self.law.key / f"{size_id(self.a_over_l)}_Ca{{ca}}.h5"
        args = ["--flow", "tube", *self.law.kernel_args(), "--a-over-l", repr(self.a_over_l)]
        for name, value in self.settings:
            args += [SETTING_FLAGS["tube"][name], str(value)]
        return args + ["--branch-ca", ",".join(f"{ca:g}" for ca in self.Ca_s),
                       "--branch-summary", str(summary), "--out", str(pattern)]


def uses_branches(grid: Mapping[str, Any]) -> bool:
    """True when the grid's tube cases are computed by continuation (``tube.settings.branch``)."""
    return bool(grid.get("tube", {}).get("settings", {}).get("branch", False))


def follows_branches(settings: Mapping[str, Any]) -> bool:
    """Whether the kernel follows a steady branch with these tube settings: the axisymmetric
    model with any integrator but rk2 (time steps only), the 3D model with its steady solver
    (``integrator: newton``) only (capsim refuses ``--branch-ca`` otherwise)."""
    integrator = settings.get("integrator", "auto")
    if settings.get("model", "axi") == "3d":
        return bool(integrator == "newton")
    return bool(integrator != "rk2")


def by_continuation(settings: Mapping[str, Any] | None) -> dict[str, Any]:
    """Tube settings for cases computed on demand: ``settings`` with ``branch: true`` where the
    model is axisymmetric and the kernel follows a branch with them (``follows_branches``).

    The cases are the same (same files, same kernel arguments but ``--ca``; equal to 3e-7 on the
    Skalak C = 2-8 grid of docs/validation/diagnosis.md); continuation reached them with 1.3
    times fewer CPU seconds there and 1.0-1.9 times over paper-grid law groups (kernel 0.3.4,
    docs/validation/performance.md): less where many cases must be time-stepped all the same.
    The 3D model's cases stay one by one: its branch reports a fold where Newton-Krylov alone
    finds a stable steady shape (tests/workflow/test_branch_3d_workflow.py), so that the
    cases past it would not be the same."""
    out = dict(settings or {})
    if out.get("model", "axi") == "axi" and follows_branches(out):
        out["branch"] = True
    return out


def expand_branches(grid: Mapping[str, Any]) -> list[Branch]:
    """Return the branches of a branch grid, in law, a/l order (empty unless it uses branches)."""
    if not uses_branches(grid):
        return []
    spec = grid["tube"]
    values = tuple(sorted(float(ca) for ca in spec["Ca_s"]))
    settings = case_settings(grid, "tube", values[0])
    return [Branch(parse_law(key), float(a), values, settings) for key in spec["laws"] for a in spec["a_over_l"]]


def _key_path(path: Any) -> str:
    """Format a jsonschema error path as ``tube.Ca_s[2]``."""
    text = ""
    for part in path:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else str(part))
    return text or "(top level)"


def _schema_errors(grid: Mapping[str, Any]) -> list[str]:
    """Return one 'key: reason' line per schema violation, in document order."""
    import jsonschema

    schema = yaml.safe_load(schema_path().read_text())
    validator = jsonschema.Draft202012Validator(schema)
    errors = sorted(validator.iter_errors(grid), key=lambda e: [str(p) for p in e.absolute_path])
    return [f"{_key_path(e.absolute_path)}: {e.message}" for e in errors]


#: The kernel's mesh level (shear, 3D tube) when a grid does not set one (capsim --level).
DEFAULT_LEVEL = 3
#: Tube settings that apply to one tube model only (the kernel's option table says the same).
TUBE_MODEL_SETTINGS = {"n_meridian": ("axi",), "level": ("3d",), "wall_h_far": ("3d",), "wall_h_centre": ("3d",)}
#: Channels of the tube flow (capsim --channel): the circular tube, and the square and rectangular
#: ducts, which exist in the 3D model only; ``aspect`` (height over width) is the rectangle's.
DUCT_CHANNELS = ("square", "rect")


def case_level(case: Case) -> int:
    """The mesh level of a shear or 3D tube case (its ``level`` setting, else the kernel's default)."""
    return int(dict(case.settings).get("level", DEFAULT_LEVEL))


def _channel_problems(spec: Mapping[str, Any]) -> list[str]:
    """What capsim would refuse (exit 2) in a tube grid's channel settings."""
    settings = spec.get("settings", {})
    channel = settings.get("channel", "tube")
    problems = []
    if channel in DUCT_CHANNELS and settings.get("model", "axi") != "3d":
        problems.append(f"tube.settings.channel: a {channel} duct needs tube.settings.model: 3d")
    if "aspect" in settings and channel != "rect" and float(settings["aspect"]) != 1.0:
        problems.append(f"tube.settings.aspect: only for tube.settings.channel: rect (a {channel} has aspect 1)")
    if channel == "rect":
        largest = 0.9 * min(1.0, float(settings.get("aspect", 1.0)))
        too_large = [a for a in spec["a_over_l"] if float(a) > largest]
        if too_large:
            problems.append(f"tube.a_over_l: {too_large} do not fit the duct (a/w <= 0.9 min(1, aspect) = {largest:g})")
    return problems


def _mesh_check_problems(grid: Mapping[str, Any], flow: str) -> list[str]:
    """A flow's ``mesh_check`` against its cases' mesh: shear checks on a finer level; a tube
    check needs the 3D model (the level is its mesh) and another level than the cases'."""
    check = grid[flow].get("mesh_check")
    if not check:
        return []
    settings = grid[flow].get("settings", {})
    level = int(settings.get("level", DEFAULT_LEVEL))
    if flow == "shear":
        problems = []
        if int(check["level"]) <= level:
            problems.append(f"shear.mesh_check.level: {check['level']} is not finer than the cases' level {level}")
        if check.get("rows", "coarse") not in MESH_CHECK_ROWS:
            problems.append(f"shear.mesh_check.rows: {check['rows']!r} is not one of {', '.join(MESH_CHECK_ROWS)}")
        return problems
    if settings.get("model", "axi") != "3d":
        return ["tube.mesh_check: needs tube.settings.model: 3d (the mesh level is the 3D model's)"]
    if int(check["level"]) == level:
        return [f"tube.mesh_check.level: {check['level']} is the cases' own level"]
    return []


def validate_grid(grid: Mapping[str, Any], where: str = "grid") -> None:
    """Check a grid against the schema and the kernel's parameter ranges.

    Parameters
    ----------
    grid : mapping
        The grid as read from YAML (or Snakemake's ``config``).
    where : str
        What to call the grid in messages (its file name).

    Raises
    ------
    GridError
        Listing every violation as ``key: reason``, e.g. ``tube.Ca_s[0]: -0.1 is less
        than or equal to the minimum of 0``.
    """
    problems = _schema_errors(grid)
    if not problems:
        for flow in FLOWS:
            if flow not in grid:
                continue
            for i, key in enumerate(grid[flow]["laws"]):
                try:
                    law = parse_law(key)
                except GridError as exc:
                    problems.append(f"{flow}.laws[{i}]: {exc}")
                    continue
                for name, _ in law.effects:
                    if flow not in EFFECT_FLOWS[name]:
                        problems.append(f"{flow}.laws[{i}]: law key {key!r}: the kernel has {name} only in "
                                        f"{', '.join(EFFECT_FLOWS[name])} flow")
                    elif flow == "tube" and name in EFFECT_TUBE_MODELS:
                        model = grid[flow].get("settings", {}).get("model", "axi")
                        if model not in EFFECT_TUBE_MODELS[name]:
                            problems.append(f"{flow}.laws[{i}]: law key {key!r}: {name} needs "
                                            f"tube.settings.model: {' or '.join(EFFECT_TUBE_MODELS[name])}")
            if flow == "tube" and uses_branches(grid):
                settings = grid[flow].get("settings", {})
                integrator = settings.get("integrator", "auto")
                if not follows_branches(settings) and settings.get("model", "axi") == "3d":
                    problems.append(f"tube.settings.branch: the 3d model follows a branch with its steady solver, "
                                    f"tube.settings.integrator: newton (this grid's is {integrator}); with another "
                                    f"integrator continuation exists for the axisymmetric model only")
                elif not follows_branches(settings):
                    problems.append("tube.settings.branch: continuation finds steady states by Newton's method; "
                                    "integrator rk2 (time steps only) contradicts it")
                texts = [f"{float(ca):g}" for ca in grid[flow]["Ca_s"]]
                if len(set(texts)) != len(texts):
                    problems.append(f"tube.Ca_s: values that print alike ({texts}) would share a case file")
            if flow == "tube":
                # capsim refuses an option that does not apply to the tube model (exit 2): refuse
                # the grid that would ask for it, before any case runs.
                settings = grid[flow].get("settings", {})
                model = settings.get("model", "axi")
                for name in sorted(set(settings) & set(TUBE_MODEL_SETTINGS)):
                    if model not in TUBE_MODEL_SETTINGS[name]:
                        problems.append(f"tube.settings.{name}: applies to tube.settings.model: "
                                        f"{' or '.join(TUBE_MODEL_SETTINGS[name])} only (this grid's model is {model})")
                problems += _channel_problems(grid[flow])
            problems += _mesh_check_problems(grid, flow)
            for name in ("laws", "Ca_s", "a_over_l"):
                values = grid[flow].get(name, [])
                if len(set(values)) != len(values):
                    problems.append(f"{flow}.{name}: duplicate values {values}")
    if problems:
        raise GridError(f"{where}: invalid grid:\n  " + "\n  ".join(problems))


def load_grid(path: str | Path) -> dict[str, Any]:
    """Read and validate a grid file (YAML or JSON).

    Raises
    ------
    GridError
        If the file cannot be read or is not YAML (line named), does not hold a mapping, or
        the grid is invalid (key named).
    """
    path = Path(path)
    try:
        grid = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as err:
        raise GridError(f"{path}: cannot read the grid file: {getattr(err, 'strerror', None) or err}") from None
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark is not None else str(path)
        raise GridError(f"{where}: not YAML: {getattr(err, 'problem', None) or err}") from None
    if not isinstance(grid, dict):
        raise GridError(f"{path}: a grid file must hold a mapping, got {type(grid).__name__}")
    validate_grid(grid, str(path))
    return grid


def flow_settings(grid: Mapping[str, Any], flow: str) -> dict[str, Any]:
    """Return the kernel settings (mesh, time limit) shared by every case of ``flow``."""
    return dict(sorted(grid[flow].get("settings", {}).items()))


def expand_cases(grid: Mapping[str, Any], flow: str) -> list[Case]:
    """Return the cases of one flow, in law, a/l, Ca_s order (empty if the flow is absent)."""
    if flow not in grid:
        return []
    spec = grid[flow]
    sizes = spec["a_over_l"] if flow == "tube" else [None]
    return [
        Case(flow, parse_law(key), float(ca), None if a is None else float(a), case_settings(grid, flow, float(ca)))
        for key in spec["laws"]
        for a in sizes
        for ca in spec["Ca_s"]
    ]


#: Which level a shear row's values come from when the grid has a ``mesh_check``: the cases'
#: level (``coarse``, the finer level only checks it) or the finer level (``finer``, the
#: cases' level then estimates the finer one's error).
MESH_CHECK_ROWS = ("coarse", "finer")


def mesh_check_rows(grid: Mapping[str, Any]) -> str:
    """``'finer'`` when the shear rows take their values from the mesh check's finer level,
    ``'coarse'`` otherwise (also without a mesh check)."""
    check = grid.get("shear", {}).get("mesh_check") or {}
    return str(check.get("rows", "coarse"))


def mesh_check_cases(grid: Mapping[str, Any]) -> dict[str, Case]:
    """The companion cases of ``shear.mesh_check`` and ``tube.mesh_check``: for every case with
    Ca_s_min <= Ca_s <= Ca_s_max, the same case on the check's mesh level (variant ``level<N>``;
    finer in shear, finer or coarser in the 3D tube), keyed by the grid case's relative path.
    Empty when the grid has no mesh check."""
    companions = {}
    for flow in FLOWS:
        check = grid.get(flow, {}).get("mesh_check")
        if not check:
            continue
        level = int(check["level"])
        for case in expand_cases(grid, flow):
            if not float(check.get("Ca_s_min", 0.0)) <= case.Ca_s <= float(check.get("Ca_s_max", math.inf)):
                continue
            settings = tuple(sorted({**dict(case.settings), "level": level}.items()))
            companions[case.relative_path] = Case(flow, case.law, case.Ca_s, case.a_over_l, settings,
                                                  variant=f"level{level}")
    return companions


def case_settings(grid: Mapping[str, Any], flow: str, Ca_s: float) -> tuple[tuple[str, Any], ...]:
    """Return the kernel settings of one case of ``flow``, sorted by name.

    They are the flow's settings with its rules applied; a rule is a setting that is not a
    kernel flag: ``shear.implicit_below_Ca_s`` gives every shear case with Ca_s below it
    ``integrator: implicit`` (ROS2 steps, faster where the explicit step is bound by the
    membrane stiffness). A rule changes exactly the cases it selects (their kernel arguments,
    hence their signature), no others."""
    settings = flow_settings(grid, flow)
    # How the tube cases are computed (by continuation or one by one), not what they are.
    settings.pop("branch", None)
    threshold = settings.pop("implicit_below_Ca_s", None)
    if threshold is not None and Ca_s < threshold:
        settings["integrator"] = "implicit"
    if flow == "shear":
        settings.update(_base_model_choices(settings, Ca_s))
    return tuple(sorted(settings.items()))


#: Below this Ca_s the kernel's ``--integrator auto`` takes implicit steps in shear
#: (run_options.f90, ``shear_implicit_below_ca``); tests/kernel/test_first_run.py checks that
#: the kernel says so.
KERNEL_SHEAR_IMPLICIT_BELOW_CA_S = 0.07


def _base_model_choices(settings: Mapping[str, Any], Ca_s: float) -> dict[str, Any]:
    """The shear model choices a grid leaves open where the kernel's defaults would fill them
    otherwise, stated as the base model: no bending stiffness, and RK2 steps where ``auto``
    would step implicitly. The kernel's shear defaults are the shipped database's (k_b 3e-4,
    implicit steps below Ca_s 0.07) for a run by hand; a grid that names neither still means
    the model its database was made with, and its cases' arguments change only where the
    defaults would have changed the case."""
    stated: dict[str, Any] = {} if "k_b" in settings else {"k_b": 0.0}
    if "integrator" not in settings and Ca_s < KERNEL_SHEAR_IMPLICIT_BELOW_CA_S:
        stated["integrator"] = "rk2"
    return stated


#: Settings of a database grid that are model choices rather than resolution (the mesh level,
#: the time span): a single case run to compare with the database needs them too.
MODEL_CHOICES = ("integrator", "k_b")


def model_choice_flags(grid: Mapping[str, Any], flow: str, Ca_s: float) -> list[str]:
    """The kernel flags of ``grid``'s model choices for one case of ``flow`` at ``Ca_s``
    (``['--integrator', 'implicit', '--kb', '0.0003']`` for a paper shear case below Ca_s 0.07)."""
    settings = dict(case_settings(grid, flow, Ca_s))
    return [item for key in MODEL_CHOICES if key in settings
            for item in (SETTING_FLAGS[flow][key], str(settings[key]))]


def grid_json(grid: Mapping[str, Any]) -> str:
    """Return the grid as canonical JSON (sorted keys): its provenance record and signature."""
    return json.dumps(grid, sort_keys=True, separators=(",", ":"))
