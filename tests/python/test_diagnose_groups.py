"""The diagnosis report's "one material or several" section names each group's capsules by id,
with the group's G_s and each member's, on a batch of the independent generator
(``independent_batches``: numpy, h5py and the kernel only) whose capsules are two materials:
c01-c06 at G_s 0.03 N/m, c07-c13 at 0.06 N/m.
"""
from __future__ import annotations

import json
import re

import independent_batches as ib
import numpy as np

from capsmech.diagnosis.diagnose import diagnose
from capsmech.diagnosis.record import diagnosis_record
from capsmech.diagnosis.report import write_report
from capsmech.io.catalog import database_path
from capsmech.io.database import load_database
from capsmech.io.measurements import read_measurements

TRUTH = [0.03] * 6 + [0.06] * 7


def test_the_report_lists_each_groups_capsules_by_id(tmp_path):
    drawn = ib.draw_batch(ib.load_pool(), "NH", tmp_path, "two", seed=7, n=13, g_s=TRUTH)
    capsules = read_measurements(drawn.csv, "tube")
    # No candidate: the base law's contour fits carry the per-capsule G_s.
    diagnosis = diagnose(capsules, load_database(database_path("tube-paper")), "NH", candidates=[])
    assert diagnosis.ids == [c.id for c in capsules]
    text = write_report(diagnosis, tmp_path / "report.md", figures=False).read_text()
    section = text.split("## One material or several", 1)[1]
    groups = re.findall(r"^- group (\d): G_s = ([0-9.]+) N/m \[([0-9.]+), ([0-9.]+)\], (\d+) capsules: (.*)$",
                        section, flags=re.MULTILINE)
    assert [g[0] for g in groups] == ["1", "2"], section
    for (_, g_s, low, high, count, members), ids, truth in zip(
            groups, ([f"c{k:02d}" for k in range(1, 7)], [f"c{k:02d}" for k in range(7, 14)]), (0.03, 0.06)):
        assert float(low) < truth < float(high), section
        assert int(count) == len(ids)
        each = dict(re.findall(r"(c\d\d) \(([0-9.]+)\)", members))
        assert list(each) == ids, members
        # Each member's own G_s is its material's (the contour fits: a few % of noise).
        assert np.allclose([float(v) for v in each.values()], truth, rtol=0.12), members
        assert min(float(v) for v in each.values()) <= float(g_s) <= max(float(v) for v in each.values())
    record = json.loads(json.dumps(diagnosis_record(diagnosis), allow_nan=False))["heterogeneity"]
    assert [g["members"] for g in record["groups"]] == [[f"c{k:02d}" for k in range(1, 7)],
                                                        [f"c{k:02d}" for k in range(7, 14)]]
