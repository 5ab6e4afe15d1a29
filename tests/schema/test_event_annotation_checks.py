"""Annotators' event edits (correct_event, add_event, delete_event) are checked against the
session and the analytics vocabularies; each bad case names its reason."""

from __future__ import annotations

import pytest

from pipeline.schema.annotation_checks import AnnotationBounds, check_annotation
from pipeline.schema.annotation_text import describe_annotation
from pipeline.schema.annotations import CONSUMED_BY, annotation_from_dict

BOUNDS = AnnotationBounds(n_frames=100, person_ids=(0, 1))
PUNCH = {"kind": "add_event", "person": 0, "event": "punch", "frame_start": 10, "frame_end": 20,
         "punch_type": "jab", "outcome": "landed"}  # fmt: skip

GOOD = [
    {"kind": "correct_event", "person": 0, "event": "punch", "frame": 15, "punch_type": "rear_hook"},
    {"kind": "correct_event", "person": 1, "event": "punch", "frame": 99, "outcome": "blocked"},
    PUNCH,
    {**PUNCH, "frame": 14, "hand": "right"},
    {"kind": "add_event", "person": 1, "event": "slip", "frame_start": 10, "frame_end": 20},
    {"kind": "add_event", "person": 0, "event": "clinch", "frame_start": 50, "frame_end": 80},
    {"kind": "delete_event", "person": 1, "event": "duck", "frame": 0},
]

BAD = [
    (
        {"kind": "correct_event", "person": 0, "event": "punch", "frame": 100, "outcome": "landed"},
        "outside the bout",
    ),
    (
        {"kind": "correct_event", "person": 2, "event": "punch", "frame": 5, "outcome": "landed"},
        "person 2 is not a person",
    ),
    (
        {"kind": "correct_event", "person": 0, "event": "punch", "frame": 5, "punch_type": "haymaker"},
        "punch_type 'haymaker'",
    ),
    (
        {"kind": "correct_event", "person": 0, "event": "punch", "frame": 5, "outcome": "knockout"},
        "outcome 'knockout'",
    ),
    ({"kind": "correct_event", "person": 0, "event": "punch", "frame": 5}, "give punch_type and/or outcome"),
    (
        {"kind": "correct_event", "person": 0, "event": "slip", "frame": 5, "outcome": "landed"},
        "only a punch's type",
    ),
    (
        {"kind": "correct_event", "person": 0, "event": "punch", "frame": 5, "outcome": 3},
        "outcome must be a string",
    ),
    ({**PUNCH, "outcome": None}, "needs outcome"),
    ({**PUNCH, "hand": "both"}, "hand 'both'"),
    ({**PUNCH, "frame": 25}, "frame 25 (the peak) is outside frames 10–20"),
    ({**PUNCH, "frame_start": 30}, "frame_start 30 is after frame_end 20"),
    ({**PUNCH, "frame_end": 120}, "frame_end 120 is outside the bout"),
    (
        {"kind": "add_event", "person": 1, "event": "duck", "frame_start": 1, "frame_end": 9, "hand": "left"},
        "hand only apply to a punch",
    ),
    ({"kind": "delete_event", "person": 0, "event": "feint", "frame": 5}, "event 'feint' is not one of"),
    ({"kind": "delete_event", "person": -1, "event": "punch", "frame": 5}, "person -1 is not a person"),
]


@pytest.mark.parametrize("d", GOOD)
def test_good_event_edits_pass_and_read_as_text(d: dict) -> None:
    a = annotation_from_dict(d)
    check_annotation(a, BOUNDS)
    assert CONSUMED_BY[a.kind] == "analyze"
    text = describe_annotation(a, {0: "Red", 1: "Blue"})
    assert ("Red" if d["person"] == 0 else "Blue") in text and (d.get("punch_type") or d["event"]) in text


@pytest.mark.parametrize(("d", "reason"), BAD)
def test_bad_event_edits_name_the_reason(d: dict, reason: str) -> None:
    with pytest.raises(ValueError) as e:
        check_annotation(annotation_from_dict(d), BOUNDS)
    assert reason in str(e.value)


def test_history_text() -> None:
    a = annotation_from_dict({"kind": "correct_event", "person": 0, "event": "punch", "frame": 42,
                              "punch_type": "rear_hook", "outcome": "landed"})  # fmt: skip
    assert (
        describe_annotation(a, {0: "Red"})
        == "correct Red (#0) punch at frame 42: type → rear_hook, outcome → landed"
    )
    assert describe_annotation(annotation_from_dict({**PUNCH, "frame": 14, "hand": "left"}), {}) == (
        "add person 0 left jab, frames 10–20, peak at frame 14, landed"
    )
    d = {"kind": "delete_event", "person": 1, "event": "clinch", "frame": 7}
    assert describe_annotation(annotation_from_dict(d), {1: "Blue"}) == "delete Blue (#1) clinch at frame 7"
