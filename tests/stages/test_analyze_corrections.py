"""Annotators' event edits in the analyze stage (pure): correcting a punch's type or outcome,
adding and deleting punches, slips, ducks and clinches, edits whose event is gone, and the
``source`` marker through the artifact and the exports."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from pipeline.dataset.schemas import edit_schema, json_schemas
from pipeline.io.events_export import events_to_csv, events_to_json
from pipeline.schema import save_npz
from pipeline.schema.analytics import BoutEvents
from pipeline.schema.annotations import AddEvent, Annotation, CorrectEvent, DeleteEvent, annotation_to_dict
from pipeline.schema.base import load_npz
from pipeline.stages.analyze import AnalyzeInputs, AnalyzeOutput, run
from tests.stages.analyze_fixtures import FPS, J, keypoints, profile, straight, throw, two_boxers

GUARD_L = np.array([0.3, 0.12, 1.45])
N = 150


def _bout(feint: bool = False, duck_m: float = 0.0) -> np.ndarray:
    """Athlete 0 jabs at athlete 1's guard at 0.6 s (peak ~frame 35); with ``feint``, a 9 cm
    feint at 2.0 s the detector ignores; athlete 1's head drops ``duck_m`` around the jab."""
    xyz = two_boxers(N, distance_m=1.0)
    head = np.array([1.0, 0.0, 1.62])
    jab = straight(GUARD_L, head - np.array([0.215, 0.0, 0.0]))(profile(N, 0.6, 0.1))
    if feint:
        jab += profile(N, 2.0, 0.08)[:, None] * np.array([0.09, 0.0, 0.0])
    throw(xyz, 0, "left", np.zeros(N), lambda _: jab)
    if duck_m:
        drop = np.sin(np.pi * np.clip((np.arange(N) / FPS - 0.45) / 0.45, 0, 1)) ** 2
        for name in ("nose", "left_eye", "right_eye", "left_ear", "right_ear"):
            xyz[:, 1, J[name], 2] -= duck_m * drop
    return xyz


def _run(xyz: np.ndarray, *edits: Annotation) -> AnalyzeOutput:
    return run(AnalyzeInputs(keypoints(xyz), corrections=edits))


def test_correct_type_and_outcome_keep_the_measurements() -> None:
    xyz = _bout()
    before = _run(xyz).events
    assert before.n_punches == 1 and before.punch_outcome[0] != "landed" and before.punch_type[0] == "jab"
    assert before.punch_source.tolist() == ["detector"]
    peak = int(before.punch_peak_frame[0])
    out = _run(
        xyz, CorrectEvent(person=0, event="punch", frame=peak + 2, punch_type="cross", outcome="landed")
    )
    ev = out.events
    assert ev.punch_type.tolist() == ["cross"] and ev.punch_outcome.tolist() == ["landed"]
    assert ev.punch_source.tolist() == ["corrected"]
    assert (
        ev.punch_peak_frame.tolist() == [peak]
        and ev.punch_peak_speed_mps[0] == before.punch_peak_speed_mps[0]
    )
    assert (
        out.stats["landed"] == 1
        and out.stats["corrections_applied"] == 1
        and out.stats["corrections_unmatched"] == 0
    )
    only = _run(xyz, CorrectEvent(person=0, event="punch", frame=peak - 1, outcome="landed")).events
    assert only.punch_type.tolist() == ["jab"] and only.punch_outcome.tolist() == ["landed"]


def test_delete_a_punch_takes_its_evasion_and_work_rate_with_it() -> None:
    xyz = _bout(duck_m=0.2)
    before = _run(xyz)
    # the jab stops on the guard (a block) and the head drops (a duck)
    assert sorted(before.events.evade_kind.tolist()) == ["block", "duck"] and before.events.evade_punch.tolist() == [0, 0]
    assert before.series.punches_per_min[:, 0].max() > 0
    peak = int(before.events.punch_peak_frame[0])
    out = _run(xyz, DeleteEvent(person=0, event="punch", frame=peak))
    assert out.events.n_punches == 0 and out.events.n_evades == 0
    assert out.series.punches_per_min[:, 0].max() == 0 and out.stats["punches"] == 0
    duck = int(before.events.evade_peak_frame[before.events.evade_kind == "duck"][0])
    kept = _run(xyz, DeleteEvent(person=1, event="duck", frame=duck - 2))
    assert kept.events.n_punches == 1 and kept.events.evade_kind.tolist() == ["block"]


def test_add_a_punch_measured_on_the_3d() -> None:
    xyz = _bout(feint=True)
    before = _run(xyz).events
    assert before.n_punches == 1  # the feint is not a punch to the detector
    # the feint: out over frames 100-104, held to ~106, back by ~114
    out = _run(
        xyz,
        AddEvent(person=0, event="punch", frame_start=99, frame_end=115, punch_type="jab", outcome="missed"),
    )
    ev = out.events
    assert ev.n_punches == 2 and ev.punch_source.tolist() == ["detector", "annotator"]
    assert ev.punch_hand[1] == "left" and ev.punch_type[1] == "jab" and ev.punch_outcome[1] == "missed"
    assert (
        ev.punch_start_frame[1] == 99
        and ev.punch_end_frame[1] == 115
        and 104 <= ev.punch_peak_frame[1] <= 106
    )
    wrist = xyz[99:107, 0, J["left_wrist"]]  # the fastest frame-to-frame step on the way out
    assert ev.punch_peak_speed_mps[1] == pytest.approx(
        np.linalg.norm(np.diff(wrist, axis=0), axis=1).max() * FPS
    )
    assert ev.punch_peak_speed_mps[1] == pytest.approx(
        1.875 * 0.09 / 0.08, rel=0.2
    )  # min-jerk, sampled at 50 Hz
    sh, el, wr = (xyz[:, 0, J[f"left_{j}"]] for j in ("shoulder", "elbow", "wrist"))
    arm_m = np.median(np.linalg.norm(sh - el, axis=1) + np.linalg.norm(el - wr, axis=1))
    k = int(ev.punch_peak_frame[1])
    assert ev.punch_extension[1] == pytest.approx(np.linalg.norm(wr[k] - sh[k]) / arm_m)
    assert ev.punch_confidence[1] == 1.0
    assert out.series.punches_per_min[-1, 0] > _run(xyz).series.punches_per_min[-1, 0]
    # an edit on the added punch finds it; it stays the annotator's
    fixed = _run(xyz, AddEvent(person=0, event="punch", frame_start=99, frame_end=115, frame=105, hand="right",
                               punch_type="jab", outcome="missed"),
                 CorrectEvent(person=0, event="punch", frame=106, punch_type="lead_uppercut")).events  # fmt: skip
    assert fixed.punch_hand[1] == "right" and fixed.punch_peak_frame[1] == 105
    assert fixed.punch_type[1] == "lead_uppercut" and fixed.punch_source[1] == "annotator"


def test_add_a_duck_and_clinches() -> None:
    xyz = _bout(duck_m=0.06)  # below the detector's 0.12 m
    before = _run(xyz).events
    assert before.evade_kind.tolist() == ["block"] and before.n_clinches == 0 and before.n_punches == 1
    out = _run(xyz, AddEvent(person=1, event="duck", frame_start=22, frame_end=45),
               AddEvent(person=0, event="clinch", frame_start=100, frame_end=120),
               AddEvent(person=1, event="clinch", frame_start=115, frame_end=130))  # fmt: skip
    ev = out.events
    d = ev.evade_kind == "duck"
    assert sorted(ev.evade_kind.tolist()) == ["block", "duck"]
    assert ev.evade_person[d].tolist() == [1] and ev.evade_punch[d].tolist() == [0]
    assert ev.evade_source[d].tolist() == ["annotator"] and ev.evade_displacement_m[d][0] == pytest.approx(
        0.06, abs=0.005
    )
    assert abs(int(ev.evade_peak_frame[d][0]) - 34) <= 1  # the head is lowest at 0.675 s
    assert list(zip(ev.clinch_start_frame.tolist(), ev.clinch_end_frame.tolist(), strict=True)) == [
        (100, 130)
    ]
    assert ev.clinch_source.tolist() == ["corrected"]  # two annotated spans merged
    assert out.stats["clinch_frames"] == 31
    gone = _run(xyz, AddEvent(person=0, event="clinch", frame_start=100, frame_end=120),
                DeleteEvent(person=1, event="clinch", frame=110)).events  # fmt: skip
    assert gone.n_clinches == 0


def test_edits_whose_event_is_gone_are_reported_not_raised() -> None:
    xyz = _bout()
    before = _run(xyz).events
    out = _run(
        xyz,
        CorrectEvent(person=0, event="punch", frame=int(before.punch_peak_frame[0]) + 3, outcome="landed"),
        CorrectEvent(person=1, event="punch", frame=int(before.punch_peak_frame[0]), outcome="landed"),
        DeleteEvent(person=1, event="slip", frame=60),
        AddEvent(person=1, event="slip", frame_start=120, frame_end=140),
        AddEvent(person=7, event="punch", frame_start=10, frame_end=20, punch_type="jab", outcome="missed"),
        CorrectEvent(person=0, event="punch", frame=int(before.punch_peak_frame[0]), outcome="knockout"),
    )
    assert out.stats["corrections_unmatched"] == 6 and out.stats["corrections_applied"] == 0
    lines = out.stats["corrections_unmatched_edits"]
    assert "no punch of person 0 within ±2 frames" in lines[0] and "no slip of person 1" in lines[2]
    assert "no punch of the opponent" in lines[3] and "person 7" in lines[4]
    assert "outcome 'knockout' is not one of" in lines[5]  # an annotations.json written by hand
    for f in (
        "punch_type",
        "punch_outcome",
        "punch_peak_frame",
        "punch_source",
        "evade_kind",
        "clinch_start_frame",
    ):
        assert getattr(out.events, f).tolist() == getattr(before, f).tolist()


def test_the_source_marker_in_the_artifact_exports_and_dataset_schemas(tmp_path: Path) -> None:
    xyz = _bout(feint=True)
    peak = int(_run(xyz).events.punch_peak_frame[0])
    edits: list[Annotation] = [
        CorrectEvent(person=0, event="punch", frame=peak, outcome="landed"),
        AddEvent(person=0, event="punch", frame_start=99, frame_end=115, punch_type="jab", outcome="missed"),
        DeleteEvent(person=0, event="clinch", frame=3),
    ]
    ev = _run(xyz, *edits).events
    save_npz(tmp_path / "events.npz", ev)
    back = load_npz(tmp_path / "events.npz", BoutEvents)
    assert back.punch_source.tolist() == ["corrected", "annotator"]
    doc = events_to_json(back, {0: "Red", 1: "Blue"}, "fit")
    assert [p["source"] for p in doc["punches"]] == ["corrected", "annotator"]
    assert [p["outcome"] for p in doc["punches"]] == ["landed", "missed"]
    rows = list(csv.DictReader(io.StringIO(events_to_csv(back))))
    assert [r["source"] for r in rows if r["event"] == "punch"] == ["corrected", "annotator"]
    schemas = json_schemas()
    jsonschema.validate(doc, schemas["events"])
    bad = {**doc, "punches": [{**doc["punches"][0], "source": "robot"}]}
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, schemas["events"])
    for a in edits:
        jsonschema.validate(annotation_to_dict(a), edit_schema())
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(
            {"kind": "correct_event", "person": 0, "event": "punch", "frame": 3, "outcome": 1}, edit_schema()
        )
    # an artifact written before the marker existed loads with every event the detector's
    with np.load(tmp_path / "events.npz") as z:
        old = {k: z[k] for k in z.files if not k.endswith("_source")}
    np.savez(tmp_path / "old.npz", **old)
    assert load_npz(tmp_path / "old.npz", BoutEvents).punch_source.tolist() == ["detector", "detector"]
