"""The datasheet's counts table counts each defence kind (slips, ducks, blocks, parries) on its own."""

from __future__ import annotations

from typing import Any

from pipeline.dataset.datasheet import datasheet


def _meta(sid: str) -> dict[str, Any]:
    return {
        "id": sid, "name": sid, "source": "tracks", "cameras": ["cam1", "cam2"], "fps": 50.0, "n_frames": 100,
        "athletes": [{"id": 0, "name": "Red"}, {"id": 1, "name": "Blue"}], "stages": [],
        "n_detections": 400, "n_detections_identified": 380, "files": [],
    }  # fmt: skip


def _evade(kind: str) -> dict[str, Any]:
    return {"athlete_id": 1, "athlete": "Blue", "kind": kind}


def _counts(sheet: str) -> dict[str, str]:
    rows = sheet.split("## Counts", 1)[1].splitlines()
    return {
        r.split("|")[1].strip(): r.split("|")[2].strip()
        for r in rows
        if r.startswith("| ") and "---" not in r
    }


def test_defence_kinds_are_counted_separately_over_sessions() -> None:
    release = {"format": "cornerman-dataset/1", "created_utc": "2026-01-01T00:00:00Z", "cornerman_version": "0",
               "conventions": {"world": "z-up, metres"}}  # fmt: skip
    events = {
        "a": {"punches": [{}] * 5, "clinches": [{}],
              "evades": [_evade(k) for k in ("slip", "slip", "duck", "block", "block", "block", "parry")]},
        "b": {"punches": [{}] * 2, "clinches": [], "evades": [_evade("parry"), _evade("block")]},
    }  # fmt: skip
    notes = {"annotations": [], "note": "none"}
    sheet = datasheet(release, [_meta("a"), _meta("b"), _meta("c")], events, {s: notes for s in "abc"})
    counts = _counts(sheet)
    assert counts["sessions with events"] == "2" and counts["punches"] == "7" and counts["clinches"] == "1"
    assert (counts["slips"], counts["ducks"], counts["blocks"], counts["parries"]) == ("2", "1", "4", "2")
    assert "slips and ducks" not in sheet
    # Without any defence the four rows are there, at 0.
    only_b = _counts(datasheet(release, [_meta("b")], {"b": {**events["b"], "evades": []}}, {"b": notes}))
    assert [only_b[k] for k in ("slips", "ducks", "blocks", "parries")] == ["0"] * 4
