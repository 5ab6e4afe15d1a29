"""Frame-range swaps through the API (only frames in range change; undo restores), the edit
history (newest first, author, summary, state; undo of an entry that is not the newest), and the
track/person checks a run makes possible (422 with the reason)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from pipeline.schema.annotations import SwapIdentities
from pipeline.schema.detections import Tracks2D
from pipeline.stages.association.edits import apply_identity_edits
from server.core.config import Settings
from server.demo import make_session
from tests.conftest import make_rig, make_tracks
from tests.server.conftest import auth, make_bout, run_jobs

STAGES = ("detect2d", "track", "associate")


def test_range_swap_changes_only_frames_in_range() -> None:
    rig = make_rig()
    tracks, _ = make_tracks(rig, n_frames=20)
    pod = tracks.track_id.astype(np.int64).copy()  # person = track id (0 and 1) before the edit
    conf = np.full(tracks.n_dets, 0.5)
    swap = SwapIdentities(frame=5, person_a=0, person_b=1, frame_end=12, view=rig.names[1])
    new, new_conf, used = apply_identity_edits(tracks, rig.names, pod, conf, [swap])
    inside = (tracks.frame >= 5) & (tracks.frame < 12) & (tracks.view == 1)
    assert inside.sum() > 0 and used == {0, 1}
    assert np.array_equal(new[inside], 1 - pod[inside])
    assert np.array_equal(new[~inside], pod[~inside])
    assert np.all(new_conf[inside] == 1.0) and np.all(new_conf[~inside] == 0.5)
    open_ended, _, _ = apply_identity_edits(tracks, rig.names, pod, conf, [SwapIdentities(5, 0, 1, view=rig.names[1])])
    tail = (tracks.frame >= 5) & (tracks.view == 1)
    assert np.array_equal(open_ended[tail], 1 - pod[tail]) and np.array_equal(open_ended[~tail], pod[~tail])
    with pytest.raises(ValueError, match="frame_end must be after frame"):
        apply_identity_edits(tracks, rig.names, pod, conf, [SwapIdentities(5, 0, 1, frame_end=5)])


@pytest.fixture
def ran(client: TestClient, tokens: dict, settings: Settings) -> tuple[int, Path]:
    folder = make_session(settings.allowed_roots[0] / "b", n_frames=60, n_cameras=3, seed=0, stages=STAGES,
                          use_synthetic=False)
    sid = make_bout(client, tokens["admin"], folder)["id"]
    client.post("/api/jobs", json={"session_id": sid}, headers=auth(tokens["admin"]))
    run_jobs(settings)
    out = Path(client.get(f"/api/sessions/{sid}", headers=auth(tokens["admin"])).json()["folder"])
    return sid, out


def _association(folder: Path) -> tuple[np.ndarray, Tracks2D]:
    from pipeline.schema.base import load_npz

    with np.load(folder / "artifacts" / "associate" / "association.npz", allow_pickle=False) as z:
        pod = z["person_of_det"].copy()
    return pod, load_npz(folder / "artifacts" / "track" / "tracks.npz", Tracks2D)


def test_range_swap_through_the_api_and_undo(client: TestClient, tokens: dict, settings: Settings,
                                             ran: tuple[int, Path]) -> None:
    sid, folder = ran
    ann = auth(tokens["annotator"])
    before, tracks = _association(folder)
    assert {0, 1} <= set(before.tolist())
    swap = {"kind": "swap_identities", "frame": 20, "frame_end": 35, "person_a": 0, "person_b": 1}
    r = client.post(f"/api/sessions/{sid}/annotations", json={"annotation": swap, "rerun": True}, headers=ann)
    assert r.status_code == 201, r.text
    assert json.loads((folder / "annotations.json").read_text()) == [{**swap, "view": ""}]
    run_jobs(settings)
    after, _ = _association(folder)
    inside = (tracks.frame >= 20) & (tracks.frame < 35)
    swapped = np.where(before == 0, 1, np.where(before == 1, 0, before))
    assert np.any(before[inside] >= 0)
    assert np.array_equal(after[inside], swapped[inside])
    assert np.array_equal(after[~inside], before[~inside])
    r = client.post(f"/api/annotations/{r.json()['annotation']['id']}/undo", json={"rerun": True}, headers=ann)
    assert r.status_code == 200, r.text
    run_jobs(settings)
    restored, _ = _association(folder)
    assert np.array_equal(restored, before)
    bad = {**swap, "frame_end": 61}
    r = client.post(f"/api/sessions/{sid}/annotations", json={"annotation": bad, "rerun": False}, headers=ann)
    assert r.status_code == 422 and "frame_end 61 must be after frame 20 and at most 60" in r.text


def test_history_newest_first_and_undo_of_an_older_entry(client: TestClient, tokens: dict,
                                                         ran: tuple[int, Path]) -> None:
    sid, folder = ran
    ann, admin = auth(tokens["annotator"]), auth(tokens["admin"])
    _, tracks = _association(folder)
    t0 = int(tracks.track_id[(tracks.view == 0) & (tracks.frame == 10) & (tracks.track_id >= 0)][0])
    edits = [
        {"kind": "swap_identities", "frame": 10, "frame_end": 20, "person_a": 0, "person_b": 1},
        {"kind": "mark_invalid", "view": "cam0", "frame": 10, "track": t0},
        {"kind": "label_contact", "frame_start": 3, "frame_end": 4, "person_a": 0, "part_a": "left_hand",
         "person_b": 1, "part_b": "head"},
    ]
    ids = []
    for e, who in zip(edits, (ann, admin, ann), strict=True):
        r = client.post(f"/api/sessions/{sid}/annotations", json={"annotation": e, "rerun": False}, headers=who)
        assert r.status_code == 201, r.text
        ids.append(r.json()["annotation"]["id"])
    r = client.post(f"/api/annotations/{ids[0]}/undo", json={"rerun": False}, headers=admin)  # the oldest, not the last
    assert r.status_code == 200, r.text
    hist = client.get(f"/api/sessions/{sid}/annotations/history", headers=auth(tokens["coach"])).json()
    assert [h["id"] for h in hist] == sorted((h["id"] for h in hist), reverse=True)
    assert [h["kind"] for h in hist] == ["undo", "label_contact", "mark_invalid", "swap_identities"]
    by_id = {h["id"]: h for h in hist}
    first = by_id[ids[0]]
    assert first["state"] == "undone" and not first["active"] and first["undone_by"] == "admin1"
    assert first["author"] == "annotator1" and first["undone_at"] >= first["created_at"]
    assert first["summary"] == "swap Red (#0) ↔ Blue (#1), frames 10–19, every view"
    assert by_id[ids[1]]["state"] == "active" and by_id[ids[1]]["author"] == "admin1"
    assert by_id[ids[1]]["summary"] == f"mark cam0 track {t0} invalid at frame 10"
    assert hist[0]["state"] == "undo" and hist[0]["undoes"] == ids[0] and hist[0]["summary"].startswith(f"undo of #{ids[0]} (swap")
    assert [e["kind"] for e in json.loads((folder / "annotations.json").read_text())] == ["mark_invalid", "label_contact"]
    # a renamed athlete shows in the summaries
    client.put(f"/api/sessions/{sid}/identities/1", json={"name": "Ali"}, headers=ann)
    hist = client.get(f"/api/sessions/{sid}/annotations/history", headers=ann).json()
    assert "Ali (#1) head" in {h["id"]: h for h in hist}[ids[2]]["summary"]
    assert client.get("/api/sessions/999/annotations/history", headers=ann).status_code == 404


def test_track_and_person_checks_after_a_run(client: TestClient, tokens: dict, ran: tuple[int, Path]) -> None:
    sid, folder = ran
    ann = auth(tokens["annotator"])
    url = f"/api/sessions/{sid}/annotations"
    _, tracks = _association(folder)
    unknown = int(tracks.track_id.max()) + 5

    def post(edit: dict) -> tuple[int, str]:
        r = client.post(url, json={"annotation": edit, "rerun": False}, headers=ann)
        return r.status_code, r.text

    code, text = post({"kind": "mark_invalid", "view": "cam0", "frame": 10, "track": unknown})
    assert code == 422 and f"track {unknown} is not a track of view 'cam0'" in text
    code, text = post({"kind": "fix_keypoint", "view": "cam1", "frame": 10, "track": 0, "joint": "tail",
                       "x_px": 1.0, "y_px": 1.0})
    assert code == 422 and "joint 'tail' is not one of the keypoints" in text
    code, text = post({"kind": "merge_tracks", "view": "cam2", "track_a": 0, "track_b": unknown})
    assert code == 422 and f"track_b {unknown} is not a track" in text
    t = int(tracks.track_id[(tracks.view == 1) & (tracks.track_id >= 0)][0])
    assign = {"kind": "assign_identity", "view": "cam1", "track": t, "frame_start": 0, "frame_end": 59, "person": 2}
    code, text = post(assign)
    assert code == 422 and "person 2 is not a person of this session (known persons [0, 1]" in text
    # naming person 2 (the referee, say) makes it a person of the session
    assert client.put(f"/api/sessions/{sid}/identities/2", json={"name": "Ref"}, headers=ann).status_code == 200
    code, text = post(assign)
    assert code == 201, text
    assert not any(e.get("track") == unknown for e in json.loads((folder / "annotations.json").read_text()))
