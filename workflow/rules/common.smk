# Helpers shared by the rules: paths, the grid's cases, the kernel's code version.
# The grid logic itself lives in the capsmech package (capsmech.workflow.grid), where it is tested.

import sys
from pathlib import Path

from capsmech.workflow.grid import (
    FLOWS,
    expand_branches,
    expand_cases,
    grid_json,
    mesh_check_cases,
    validate_grid,
)
from capsmech.workflow.runner import source_code_version

# Semantic checks the schema cannot express (law parameters, duplicates); names the key.
validate_grid(config, "config")

REPO = Path(workflow.basedir).parent
PYTHON = sys.executable
KERNEL = str(REPO / "bin" / "capsim")
# Every case file records the kernel's code_version; a new version makes every case stale
# (the case rule's params change), a rebuilt binary of the same version does not.
CODE_VERSION = source_code_version(REPO)

RESULTS = config["results_dir"]
CASES_DIR = f"{RESULTS}/cases"
LOGS = f"{RESULTS}/logs"
FIGURES = f"{RESULTS}/figures"
DATABASES = config["databases_dir"]
GRID_RECORD = f"{RESULTS}/grid.json"
BRANCHES_DIR = f"{RESULTS}/branches"

GRID_FLOWS = [flow for flow in FLOWS if flow in config]
# "tube/NH/a0.8_Ca0.01" -> Case, for every case of the grid.
CASES = {
    case.relative_path.removesuffix(".h5"): case
    for flow in GRID_FLOWS
    for case in expand_cases(config, flow)
}
# The companions of shear.mesh_check (the same case on a finer mesh; their D12 goes into the
# database as the row's mesh check): run by the case rule, inputs of the shear database.
CASES.update(
    {
        companion.relative_path.removesuffix(".h5"): companion
        for companion in mesh_check_cases(config).values()
    }
)

# "tube/NH/a0.8" -> Branch, for a grid whose tube cases are computed by continuation
# (tube.settings.branch): one kernel run writes every case file of a (law, a/l).
BRANCHES = {
    branch.relative_path.removesuffix(".h5"): branch
    for branch in expand_branches(config)
}
# The Ca_s of every branch (the same for all), as they appear in case file names.
BRANCH_CA = [f"{ca:g}" for ca in next(iter(BRANCHES.values())).Ca_s] if BRANCHES else []


wildcard_constraints:
    flow="tube|shear",
    law="[A-Za-z0-9_.+-]+",  # + joins effects to a law: NH+lambda0.001
    case="[A-Za-z0-9_.-]+",
    size="a[0-9.]+",


def grid_case(wildcards):
    """The grid's case for a case-file path (a path outside the grid is an error)."""
    key = f"{wildcards.flow}/{wildcards.law}/{wildcards.case}"
    if key not in CASES:
        raise ValueError(f"{key} is not a case of grid {config['name']!r}")
    return CASES[key]


def grid_branch(wildcards):
    """The grid's branch for a branch-file path (a path outside the grid is an error)."""
    key = f"tube/{wildcards.law}/{wildcards.size}"
    if key not in BRANCHES:
        raise ValueError(f"{key} is not a branch of grid {config['name']!r}")
    return BRANCHES[key]


def branch_files(wildcards):
    """Every branch file of the tube flow of a branch grid (none for shear or a case grid)."""
    if wildcards.flow != "tube":
        return []
    return [f"{BRANCHES_DIR}/{key}.h5" for key in BRANCHES]


def kernel_executable(wildcards):
    """The kernel, as ancient input; a clear error when it has not been built."""
    if not Path(KERNEL).is_file():
        raise FileNotFoundError(
            f"{KERNEL} is missing: run `make build` (or `make database`)"
        )
    return ancient(KERNEL)


def case_files(wildcards):
    """Every case file of one flow, in grid order."""
    return [
        f"{CASES_DIR}/{key}.h5"
        for key, case in CASES.items()
        if case.flow == wildcards.flow
    ]


def database_files():
    return [f"{DATABASES}/{flow}.h5" for flow in GRID_FLOWS]


def figure_dirs():
    return [f"{FIGURES}/{flow}" for flow in GRID_FLOWS]
