"""Annotators' event edits through the API on a really analysed session: a correction re-runs
the analyze stage (only), GET /events shows it with its marker, undo takes it away, a bad edit
is a 422 with its reason, an edit whose event is gone is counted, and the dataset release
carries the edits with their authors and the marked events."""

from __future__ import annotations

import json
from pathlib import Path

from fastapi.testclient import TestClient

from pipeline.artifacts import ArtifactStore
from pipeline.cli.dataset import annotation_histories
from pipeline.dataset import export_release, validate_release
from server.core.config import Settings
from server.demo import make_session
from tests.server.conftest import auth, make_bout, run_jobs

STAGES = ("detect2d", "track", "associate", "triangulate", "analyze")


def _events(client: TestClient, sid: int, token: str) -> dict:
    r = client.get(f"/api/sessions/{sid}/events", headers=auth(token))
    assert r.status_code == 200, r.text
    return r.json()


def _post(client: TestClient, sid: int, token: str, edit: dict) -> dict:
    r = client.post(
        f"/api/sessions/{sid}/annotations", json={"annotation": edit, "rerun": True}, headers=auth(token)
    )
    assert r.status_code == 201, r.text
    return r.json()


def _key(p: dict) -> tuple:
    return (p["athlete_id"], p["hand"], p["peak_frame"], p["type"], p["outcome"], p["source"])


def test_event_corrections_through_the_api(
    client: TestClient, tokens: dict, settings: Settings, tmp_path: Path
) -> None:
    folder = make_session(settings.allowed_roots[0] / "b", n_frames=150, n_cameras=3, seed=0, stages=STAGES)
    sid = make_bout(client, tokens["admin"], folder)["id"]
    client.post("/api/jobs", json={"session_id": sid}, headers=auth(tokens["admin"]))
    run_jobs(settings)
    folder = Path(client.get(f"/api/sessions/{sid}", headers=auth(tokens["admin"])).json()["folder"])
    store = ArtifactStore(folder)
    coach, ann = tokens["coach"], tokens["annotator"]
    before = _events(client, sid, coach)
    assert len(before["punches"]) >= 2 and {p["source"] for p in before["punches"]} == {"detector"}
    first, second = before["punches"][0], before["punches"][1]
    new_type = "rear_uppercut" if first["type"] != "rear_uppercut" else "lead_hook"
    new_outcome = "landed" if first["outcome"] != "landed" else "blocked"
    upstream = {s: store.manifest(s).created_unix_s for s in STAGES[:-1]}  # type: ignore[union-attr]

    # correct the first punch's type and outcome, 1 frame off its strike
    fix = {"kind": "correct_event", "person": first["athlete_id"], "event": "punch", "frame": first["peak_frame"] + 1,
           "punch_type": new_type, "outcome": new_outcome}  # fmt: skip
    res = _post(client, sid, ann, fix)
    assert res["stale_from"] == "analyze" and res["job"] is not None and res["job"]["from_stage"] == "analyze"
    run_jobs(settings)
    after = _events(client, sid, coach)
    assert _key(after["punches"][0]) == (first["athlete_id"], first["hand"], first["peak_frame"], new_type,
                                         new_outcome, "corrected")  # fmt: skip
    assert [_key(p) for p in after["punches"][1:]] == [_key(p) for p in before["punches"][1:]]
    assert after["punches"][0]["peak_speed_mps"] == first["peak_speed_mps"]
    assert {s: store.manifest(s).created_unix_s for s in STAGES[:-1]} == upstream  # type: ignore[union-attr]
    m = store.manifest("analyze")
    assert m is not None and m.metrics["corrections_applied"] == 1 and m.metrics["corrections_unmatched"] == 0
    csv_text = client.get(f"/api/sessions/{sid}/events", params={"format": "csv"}, headers=auth(coach)).text
    assert f"{new_type},{first['peak_speed_mps']}" in csv_text and csv_text.splitlines()[0].endswith(
        ",source"
    )

    # delete the second punch (its evasions go with it), then an edit whose punch is not there
    gone = _post(client, sid, ann, {"kind": "delete_event", "person": second["athlete_id"], "event": "punch",
                                    "frame": second["peak_frame"]})  # fmt: skip
    far = max(p["end_frame"] for p in before["punches"]) + 10
    _post(
        client,
        sid,
        ann,
        {"kind": "correct_event", "person": 0, "event": "punch", "frame": far, "outcome": "landed"},
    )
    run_jobs(settings)
    doc = _events(client, sid, coach)
    assert len(doc["punches"]) == len(before["punches"]) - 1
    assert all(
        p["peak_frame"] != second["peak_frame"] or p["athlete_id"] != second["athlete_id"]
        for p in doc["punches"]
    )
    n_of_second = sum(e["punch"] == 1 for e in before["evades"])
    assert len(doc["evades"]) == len(before["evades"]) - n_of_second
    m = store.manifest("analyze")
    assert m is not None and m.metrics["corrections_unmatched"] == 1 and m.metrics["corrections_applied"] == 2
    assert f"frame {far}" in m.metrics["corrections_unmatched_edits"][0]

    # the history reads the new kinds
    hist = client.get(f"/api/sessions/{sid}/annotations/history", headers=auth(coach)).json()
    summaries = [h["summary"] for h in hist]
    assert summaries[2] == (f"correct {'Red (#0)' if first['athlete_id'] == 0 else 'Blue (#1)'} punch at frame "
                            f"{first['peak_frame'] + 1}: type → {new_type}, outcome → {new_outcome}")  # fmt: skip
    assert summaries[1].startswith("delete ") and f"punch at frame {second['peak_frame']}" in summaries[1]

    # undo the correction: the detector's punch is back
    r = client.post(
        f"/api/annotations/{res['annotation']['id']}/undo", json={"rerun": True}, headers=auth(ann)
    )
    assert r.status_code == 200, r.text
    run_jobs(settings)
    undone = _events(client, sid, coach)
    assert _key(undone["punches"][0]) == _key(first)

    # bad edits: 422 with the reason, nothing stored
    for bad, reason in (
        ({**fix, "outcome": "knockout"}, "outcome 'knockout' is not one of"),
        ({**fix, "frame": 150}, "frame 150 is outside the bout"),
        ({**fix, "person": 5}, "person 5 is not a person of this session"),
        (
            {"kind": "add_event", "person": 0, "event": "punch", "frame_start": 10, "frame_end": 20},
            "needs punch_type",
        ),
    ):
        r = client.post(
            f"/api/sessions/{sid}/annotations", json={"annotation": bad, "rerun": False}, headers=auth(ann)
        )
        assert r.status_code == 422 and reason in r.json()["detail"], (bad, r.text)
    assert len(json.loads((folder / "annotations.json").read_text())) == 2

    # the release carries the edits (with authors) and the marked events
    out = tmp_path / "release"
    export_release([folder], out, histories=annotation_histories(settings.home, [folder]))
    assert validate_release(out).ok
    (sdir,) = (out / "sessions").iterdir()
    rows = json.loads((sdir / "annotations.json").read_text())["annotations"]
    kinds = {(r["edit"]["kind"], r["active"], r["author"]) for r in rows}
    assert {
        ("correct_event", False, "annotator1"),
        ("delete_event", True, "annotator1"),
        ("undo", False, "annotator1"),
    } <= kinds
    released = json.loads((sdir / "events.json").read_text())
    assert [_key(p) for p in released["punches"]] == [_key(p) for p in undone["punches"]]
    assert gone["annotation"]["active"] and len(released["punches"]) == len(before["punches"]) - 1
