"""A 3D branch's end is where Newton-Krylov from the previous steady shape stops converging:
a fold causes that, a hard solve can too. ``add_folds.reconcile_3d_ends`` checks each end
against the database's own rows, solved case by case from a guess: a steady row above the end
means the branch was lost, not ended (the contract the folds test checks for every database:
a fold lies between the last steady row and the first that is not)."""
from __future__ import annotations

import math
import sys

import h5py
import numpy as np

from conftest import REPO

sys.path.insert(0, str(REPO / "scripts"))
import add_folds  # noqa: E402


def _database(path, a_over_l, ca_s, status):
    with h5py.File(path, "w") as f:
        group = f.create_group("NH")
        group["a_over_l"] = np.asarray(a_over_l, float)
        group["Ca_s"] = np.asarray(ca_s, float)
        group["status"] = np.array([s.encode() for s in status])
    return path


def test_an_end_with_steady_rows_above_it_is_a_lost_branch_not_a_fold(tmp_path):
    # a/l 0.6: the branch stops at 0.113 but the rows at 0.12 and 0.15 are steady; a/l 0.9: the
    # rows elongate from 0.15 on, the end at 0.13 is between them, a fold.
    database = _database(tmp_path / "tube.h5", [0.6, 0.6, 0.6, 0.9, 0.9, 0.9], [0.1, 0.12, 0.15, 0.1, 0.12, 0.15],
                         ["steady", "steady", "steady", "steady", "steady", "max_time"])
    rows = {"NH": {"a_over_l": [0.6, 0.9], "Ca_s": [0.113, 0.13], "kind": ["fold", "fold"],
                   "message": ["ends between 0.1125 and 0.1131", "ends between 0.1297 and 0.1303"]}}
    changed = add_folds.reconcile_3d_ends(rows, database)
    law = rows["NH"]
    assert len(changed) == 1 and "a/l 0.6" in changed[0]
    assert math.isnan(law["Ca_s"][0]) and law["kind"][0].startswith("failed: branch lost")
    assert "0.15" in law["kind"][0] and law["message"][0].startswith("ends between 0.1125")
    assert law["kind"][1] == "fold" and law["Ca_s"][1] == 0.13 and law["message"][1] == "ends between 0.1297 and 0.1303"


def test_ends_other_than_folds_are_left_as_the_kernel_wrote_them(tmp_path):
    database = _database(tmp_path / "tube.h5", [0.6, 0.6], [0.1, 0.15], ["steady", "steady"])
    rows = {"NH": {"a_over_l": [0.6], "Ca_s": [math.nan], "kind": ["none: the grid's top reached"],
                   "message": ["none"]}}
    assert add_folds.reconcile_3d_ends(rows, database) == []
    assert rows["NH"]["kind"] == ["none: the grid's top reached"] and math.isnan(rows["NH"]["Ca_s"][0])


def test_branches_from_a_given_ca_cover_the_grids_top_and_reuse_a_longer_branch(tmp_path):
    from capsmech.workflow.grid import load_grid

    grid = load_grid(REPO / "config" / "duct-dev.yaml")
    top = add_folds.fold_branches(grid, ["NH"], from_ca=0.08)
    assert {b.Ca_s for b in top} == {(0.08, 0.1, 0.12, 0.15)} and len(top) == len(grid["tube"]["a_over_l"])
    whole = add_folds.fold_branches(grid, ["NH"])[0]
    # A branch file of the whole grid's Ca_s serves a request over its top; not the other way.
    path = tmp_path / "a0.6.h5"
    with h5py.File(path, "w") as f:
        f.attrs["requested_Ca_s"] = ",".join(f"{ca:g}" for ca in whole.Ca_s)
        f.attrs["code_version"] = "9.9.9"
    assert add_folds._branch_file_is_current(path, top[0], "9.9.9")
    assert not add_folds._branch_file_is_current(path, top[0], "9.9.8")
    with h5py.File(path, "a") as f:
        f.attrs["requested_Ca_s"] = "0.08,0.1,0.12,0.15"
    assert not add_folds._branch_file_is_current(path, whole, "9.9.9")
