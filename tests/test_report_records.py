"""REPORT.json is written from a tree of records: each record's keys, their order and the optional ones."""

from __future__ import annotations

import json

from warpbridge.model.diagnosis.report import (
    Candidate,
    CandidateRound,
    CarryNote,
    ErrorModelSummary,
    InitialState,
    SplitInfo,
)
from warpbridge.model.diagnosis.selection import Dropped
from warpbridge.model.diagnosis.transfer import Transfer


def test_a_skipped_candidate_says_why_and_a_tried_one_what_it_did():
    skipped = Candidate(effect="aero_load", parameters=["aero_gain_per_kpa"], in_verdict=False, tried=False,
                        reason="the log has no airspeed")
    assert list(skipped.to_dict()) == ["effect", "parameters", "in_verdict", "tried", "reason", "confidence"]
    rnd = CandidateRound(1, [], {"delay": {"delay_s": 0.02}}, 0.05, 0.001, 0.01, 0.4, 0.9)
    tried = Candidate(effect="delay", parameters=["delay_s"], in_verdict=False, tried=True, rounds=[rnd],
                      fitted={"delay_s": 0.02}, confidence=0.9)
    d = tried.to_dict()
    assert list(d) == ["effect", "parameters", "in_verdict", "tried", "rounds", "at_bound", "fitted", "confidence"]
    assert d["rounds"][0]["with"] == [] and "with_" not in d["rounds"][0]  # a field renamed to its key
    json.dumps(d)


def test_optional_keys_are_left_out_only_when_absent():
    assert Dropped(effect="friction", reason="r").to_dict() == {"effect": "friction", "reason": "r"}
    kept = Dropped(effect="backlash", gain_ms_when_kept=0.1, p_value=0.2, share_when_kept=0.0, reason="r")
    assert list(kept.to_dict()) == ["effect", "gain_ms_when_kept", "p_value", "share_when_kept", "reason"]
    assert kept.to_dict()["share_when_kept"] == 0.0  # a zero is a value, not an absence
    tr = Transfer(0.01, 0.002, 0.001, 0.0001)
    note = CarryNote(nominal=tr, short=tr.short, raised_by_ms=0.0, known_error_deg=0.05).to_dict()
    assert list(note) == ["nominal", "short", "raised_by_ms", "known_error_deg"]
    assert note["nominal"] == tr.to_dict() and "alpha" not in note["nominal"]
    assert ErrorModelSummary(False, False).to_dict() == {"present": False, "used": False}
    assert "slack_taken_up_by" not in InitialState(0.1).to_dict()
    assert InitialState(0.1, slack_taken_up_by="pulled").to_dict()["slack_taken_up_by"] == "pulled"


def test_the_split_says_its_scheme_first():
    d = SplitInfo([2, 5, 7, 10], 12, 500, 400, 96).to_dict()
    assert list(d)[0] == "scheme" and d["scored_blocks"] == [2, 5, 7, 10] and d["score_chunks"] == 96
