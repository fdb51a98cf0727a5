"""``capsmech diagnose`` on the console: what ``--simulate`` computes when it adds a level, and
what the effects line says of G_s by lengths.

The diagnosis itself is replaced here by a stand-in that follows its contract (a candidate
whose law groups no database holds says so in ``needs``, the grid of exactly those groups;
one whose strength lies beyond its levels is flagged at the edge), so that the command's own
loop is tested without kernel runs; the G_s line is tested on a diagnosis record built from
stated numbers.
"""
from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import capsmech.cli.diagnose as diagnose_cli
from capsmech.cli.main import main
from capsmech.diagnosis.diagnose import Diagnosis
from capsmech.diagnosis.goodness import GoodnessOfFit
from capsmech.diagnosis.record import diagnosis_record
from capsmech.diagnosis.scoring import CandidateResult
from capsmech.diagnosis.sequential import SequentialDiagnosis

EXAMPLE = Path(__file__).resolve().parents[2] / "data" / "examples" / "tube_batch_NH.csv"
#: The batch's Skalak C in the stand-in: beyond the default levels 1, 2, 4, 8 and within the
#: first level --simulate adds (8 + 4 = 12).
TRUE_C = 10.0


def test_a_level_added_to_a_family_already_simulated_is_computed(monkeypatch, capsys):
    """--simulate computes the Skalak family's levels 1-8, finds C at the top edge, adds the
    level 12 and must compute that group too: its grid has the name of the family's first one
    (``effects_SK_C``), with another law group. (It was skipped as already simulated, and the
    levels were extended again and again with nothing computed.)"""
    simulated: dict[str, list[str]] = {}

    def fake_simulate(args, candidate, grid, database) -> Path:
        path = Path(f"/nonexistent/{grid['name']}-{len(simulated)}.h5")
        simulated[str(path)] = list(grid["tube"]["laws"])
        return path

    def fake_diagnosis(args, database, effect_databases, levels, family_levels):
        held = {law for path in effect_databases or [] for law in simulated.get(path, [])}
        wanted = [f"SK_C{level:g}" for level in family_levels["SK_C"]]
        missing = [law for law in wanted if law not in held]
        if missing:
            result = SimpleNamespace(name="SK_C", needs={"name": "effects_SK_C", "tube": {"laws": missing}},
                                     edge="", supported=False, theta=math.nan, levels=())
        else:
            top = max(family_levels["SK_C"])
            result = SimpleNamespace(name="SK_C", needs=None, edge="high" if TRUE_C >= top else "", supported=True,
                                     theta=min(TRUE_C, top), levels=tuple(family_levels["SK_C"]))
        return SimpleNamespace(results=[result], excluded=[], offcentre=[], chosen=None, base=None, ids=[],
                               verdict=f"SK_C = {result.theta:g}")

    monkeypatch.setattr(diagnose_cli, "_simulate", fake_simulate)
    monkeypatch.setattr(diagnose_cli, "_diagnose_batch", fake_diagnosis)
    assert main(["diagnose", str(EXAMPLE), "--simulate", "--candidate", "SK_C", "--max-effects", "1"]) == 0
    out = capsys.readouterr().out
    assert list(simulated.values()) == [["SK_C1", "SK_C2", "SK_C4", "SK_C8"], ["SK_C12"]]
    assert out.count("adding the level") == 1 and "adding the level 12" in out
    assert "not bracketed" not in out and "verdict: SK_C = 10" in out


def _diagnosis_with_lengths(lengths_after: tuple[float, float, int]) -> SequentialDiagnosis:
    """One effect found (a contour offset of 0.5 px, 12 capsules, consistent with noise), G_s
    by the contour fits 0.025 +- 0.0005 N/m before and after, by lengths 0.026 +- 0.0015 from
    12 capsules before and ``lengths_after`` after."""
    fit = GoodnessOfFit(capsules=12, chi2=160.0, dof=168, reduced_chi2=0.95, reduced_chi2_limit=1.3,
                        chi2_p_value=0.6, profile=np.zeros(8), profile_error=np.full(8, 0.1))
    chosen = CandidateResult("contour_offset", capsules=12, supported=True, parameter="delta", unit="px",
                             theta=0.5, interval=(0.3, 0.7), g_s_before=(0.025, 0.0005), g_s_after=(0.025, 0.0005),
                             g_s_lengths_before=(0.026, 0.0015, 12), g_s_lengths_after=lengths_after,
                             acts_on="capsules", fit=fit)
    first = Diagnosis("NH", [chosen], chosen, fit=fit)
    return SequentialDiagnosis([first], effects=[("contour_offset", 0.5)], g_s=[(0.025, 0.0005), (0.025, 0.0005)],
                               fit=fit, g_s_lengths=[(0.026, 0.0015, 12), lengths_after],
                               g_s_systematic=[0.0, 0.0], g_s_lengths_systematic=[0.0, 0.0])


@pytest.mark.parametrize(("lengths_after", "left_out"), [
    # twice the contour fits' G_s, intervals disjoint: left out by --json, and on the console
    ((0.052, 0.002, 10), True),
    # the contour fits' within its interval: said
    ((0.0255, 0.0015, 12), False),
])
def test_the_effects_line_says_why_g_s_by_lengths_is_left_out(monkeypatch, capsys, lengths_after, left_out):
    outcome = _diagnosis_with_lengths(lengths_after)
    reason = diagnosis_record(outcome)["g_s"]["lengths"].get("after_left_out")
    assert bool(reason) == left_out
    monkeypatch.setattr(diagnose_cli, "_diagnose_batch", lambda *args: outcome)
    assert main(["diagnose", str(EXAMPLE)]) == 0
    (line,) = [line for line in capsys.readouterr().out.splitlines() if line.startswith("effects found:")]
    if left_out:
        assert f"left out: {reason}" in line and "0.052" not in line.split("left out:")[0]
    else:
        assert "-> 0.0255 N/m (12)" in line and "left out" not in line
    assert "by the contour fits 0.025 -> 0.025 N/m" in line
