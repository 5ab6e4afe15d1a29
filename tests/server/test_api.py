"""API against a real SQLite file, with jobs run by a real worker (stages in child processes)."""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
from fastapi.testclient import TestClient

from server.core.config import Settings
from server.demo import available_stages, make_session
from tests.server.conftest import auth, make_bout, run_jobs


def test_health_needs_no_token(client: TestClient) -> None:
    r = client.get("/api/health")
    assert r.status_code == 200 and r.json()["status"] == "ok"


def test_session_job_results_lifecycle(client: TestClient, tokens: dict, bout_folder: Path, settings: Settings) -> None:
    admin = auth(tokens["admin"])
    bout = make_bout(client, tokens["admin"], bout_folder)
    sid = bout["id"]
    assert bout["n_cameras"] == 3 and bout["cameras"] == ["cam0", "cam1", "cam2"] and bout["fps"] == 50.0
    assert Path(bout["folder"]).is_relative_to(settings.sessions_dir.resolve())
    stages = list(available_stages())
    assert client.get(f"/api/sessions/{sid}/status", headers=admin).json()["stages"] == {s: "missing" for s in stages}
    ids = client.get(f"/api/sessions/{sid}/identities", headers=admin).json()
    assert [(i["person_id"], i["name"], i["corner"]) for i in ids] == [(0, "Red", "red"), (1, "Blue", "blue")]

    r = client.post("/api/jobs", json={"session_id": sid, "from_stage": "nope"}, headers=admin)
    assert r.status_code == 422 and "nope" in r.json()["detail"]
    r = client.post("/api/jobs", json={"session_id": sid}, headers=admin)
    assert r.status_code == 201
    job_id = r.json()["id"]
    assert client.get(f"/api/sessions/{sid}", headers=admin).json()["status"] == "queued"
    assert run_jobs(settings) == 1
    job = client.get(f"/api/jobs/{job_id}", headers=admin).json()
    assert job["status"] == "done", job
    assert [job["progress"][s]["status"] for s in stages] == ["ran"] * len(stages)
    assert job["attempts"] == 1 and "running stage detect2d" in job["log_tail"]
    assert client.get(f"/api/sessions/{sid}", headers=admin).json()["status"] == "done"
    assert client.get(f"/api/sessions/{sid}/status", headers=admin).json()["stages"] == {s: "fresh" for s in stages}
    assert client.get("/api/jobs", params={"session_id": sid, "status": "done"}, headers=admin).json()[0]["id"] == job_id
    assert client.get("/api/jobs", params={"status": "queued"}, headers=admin).json() == []

    metrics = client.get(f"/api/sessions/{sid}/metrics", headers=admin).json()
    assert metrics["detect2d"]["detections"] == 3 * 60 * 2
    r = client.get(f"/api/sessions/{sid}/results/detect2d/manifest.json", headers=admin)
    assert r.status_code == 200 and r.json()["stage"] == "detect2d"
    r = client.get(f"/api/sessions/{sid}/results/detect2d/detections.npz", headers=admin)
    assert r.status_code == 200 and r.content[:2] == b"PK"
    assert client.get(f"/api/sessions/{sid}/results/detect2d/nothing.npz", headers=admin).status_code == 404
    if "triangulate" in stages:
        r = client.get(f"/api/sessions/{sid}/results/keypoints3d", params={"source": "filtered"}, headers=admin)
        assert r.status_code == 200, r.text
        d = r.json()
        assert d["fps"] == 50.0 and [p["name"] for p in d["persons"]] == ["Red", "Blue"]
        assert len(d["persons"][0]["joints"]) == 60 and len(d["joint_names"]) == 23
        r = client.get(f"/api/sessions/{sid}/results/keypoints3d", params={"format": "npz"}, headers=admin)
        assert r.status_code == 200 and r.content[:2] == b"PK"
    assert client.get(f"/api/sessions/{sid}/results/keypoints3d", params={"source": "physics"},
                      headers=admin).status_code == 404

    # a forced re-run from "track" re-runs track and later, never detect2d
    r = client.post("/api/jobs", json={"session_id": sid, "from_stage": "track"}, headers=admin)
    run_jobs(settings)
    prog = client.get(f"/api/jobs/{r.json()['id']}", headers=admin).json()["progress"]
    assert prog["detect2d"]["status"] == "skipped" and prog["track"]["status"] == "ran"

    folder = Path(bout["folder"])
    assert client.delete(f"/api/sessions/{sid}", headers=admin).status_code == 204
    assert not folder.exists() and bout_folder.exists()  # the source folder is only read
    assert client.get(f"/api/sessions/{sid}", headers=admin).status_code == 404
    assert client.get("/api/jobs", params={"session_id": sid}, headers=admin).json() == []


def test_annotations_undo_redo_and_rerun_only_later_stages(client: TestClient, tokens: dict, bout_folder: Path,
                                                           settings: Settings) -> None:
    admin, ann = auth(tokens["admin"]), auth(tokens["annotator"])
    sid = make_bout(client, tokens["admin"], bout_folder)["id"]
    client.post("/api/jobs", json={"session_id": sid}, headers=admin)
    run_jobs(settings)
    folder = Path(client.get(f"/api/sessions/{sid}", headers=admin).json()["folder"])
    before = {s: json.loads((folder / "artifacts" / s / "manifest.json").read_text()) for s in available_stages()}

    bad = client.post(f"/api/sessions/{sid}/annotations", json={"annotation": {"kind": "merge_tracks", "view": "cam0"}},
                      headers=ann)
    assert bad.status_code == 422 and "missing fields" in bad.json()["detail"]
    edit = {"kind": "split_track", "view": "cam1", "track": 0, "frame": 30}
    r = client.post(f"/api/sessions/{sid}/annotations", json={"annotation": edit, "rerun": False}, headers=ann)
    assert r.status_code == 201, r.text
    res = r.json()
    a_id = res["annotation"]["id"]
    assert res["stale_from"] == "track" and res["job"] is None and res["annotation"]["author"] == "annotator1"
    assert json.loads((folder / "annotations.json").read_text()) == [edit]
    status = client.get(f"/api/sessions/{sid}/status", headers=admin).json()["stages"]
    assert status["detect2d"] == "fresh" and status["track"] == "stale"

    # undo: the edit leaves annotations.json, stays in the history; the stages are fresh again
    r = client.post(f"/api/annotations/{a_id}/undo", json={"rerun": False}, headers=ann)
    assert r.status_code == 200 and r.json()["annotation"]["active"] is False
    assert json.loads((folder / "annotations.json").read_text()) == []
    assert set(client.get(f"/api/sessions/{sid}/status", headers=admin).json()["stages"].values()) == {"fresh"}
    assert client.get(f"/api/sessions/{sid}/annotations", headers=admin).json() == []
    hist = client.get(f"/api/sessions/{sid}/annotations", params={"include_superseded": True}, headers=admin).json()
    assert [h["kind"] for h in hist] == ["split_track", "undo"] and hist[0]["superseded_by"] == hist[1]["id"]
    assert client.post(f"/api/annotations/{a_id}/undo", headers=ann).status_code == 409

    # redo with a re-run: only track and later stages run again
    r = client.post(f"/api/annotations/{a_id}/redo", json={"rerun": True}, headers=ann)
    assert r.status_code == 200, r.text
    job = r.json()["job"]
    assert job is not None and job["from_stage"] == "track" and job["requested_by"] == "annotator1"
    assert json.loads((folder / "annotations.json").read_text()) == [edit]
    run_jobs(settings)
    prog = client.get(f"/api/jobs/{job['id']}", headers=admin).json()["progress"]
    assert prog["detect2d"]["status"] == "skipped"
    assert all(prog[s]["status"] == "ran" for s in available_stages() if s != "detect2d")
    after = {s: json.loads((folder / "artifacts" / s / "manifest.json").read_text()) for s in available_stages()}
    assert after["detect2d"]["created_unix_s"] == before["detect2d"]["created_unix_s"]
    assert after["track"]["outputs"] != before["track"]["outputs"]
    assert after["track"]["metrics"]["edits_applied"] == 1

    # auto_rerun (session default) queues a job; a second edit joins the still-queued job
    e2 = {"kind": "mark_invalid", "view": "cam0", "frame": 3, "track": 0}
    j1 = client.post(f"/api/sessions/{sid}/annotations", json={"annotation": e2}, headers=ann).json()["job"]
    e3 = {"kind": "mark_invalid", "view": "cam0", "frame": 4, "track": 0}
    j2 = client.post(f"/api/sessions/{sid}/annotations", json={"annotation": e3}, headers=ann).json()["job"]
    assert j1 is not None and j2 is not None and j1["id"] == j2["id"]
    # replace: a new row supersedes the old one
    e4 = {"kind": "mark_invalid", "view": "cam0", "frame": 5, "track": 0}
    old_id = client.get(f"/api/sessions/{sid}/annotations", headers=admin).json()[-1]["id"]
    r = client.put(f"/api/annotations/{old_id}", json={"annotation": e4, "rerun": False}, headers=ann)
    assert r.status_code == 200
    assert json.loads((folder / "annotations.json").read_text()) == [edit, e2, e4]


def test_identities_update(client: TestClient, tokens: dict, bout_folder: Path) -> None:
    sid = make_bout(client, tokens["admin"], bout_folder)["id"]
    r = client.put(f"/api/sessions/{sid}/identities/1", json={"name": "Ali", "color": "#00ff00"},
                   headers=auth(tokens["annotator"]))
    assert r.status_code == 200 and r.json() == {"person_id": 1, "name": "Ali", "color": "#00ff00", "corner": "blue"}
    r = client.put(f"/api/sessions/{sid}/identities/1", json={"color": "green"}, headers=auth(tokens["annotator"]))
    assert r.status_code == 422


def test_upload_session_and_malformed_calibration_fails_job_not_worker(client: TestClient, tokens: dict,
                                                                        bout_folder: Path, settings: Settings) -> None:
    admin = auth(tokens["admin"])
    calib = (bout_folder / "inputs" / "calibration.toml").read_bytes()
    tracks = (bout_folder / "inputs" / "tracks2d.npz").read_bytes()
    bad = client.post("/api/sessions", data={"name": "broken", "stages": "detect2d,track"}, headers=admin,
                      files=[("calibration", ("calibration.toml", b"[cam0]\nmatrix = 'not a matrix'\n")),
                             ("tracks", ("tracks2d.npz", tracks))])
    assert bad.status_code == 201, bad.text
    good = client.post("/api/sessions", data={"name": "uploaded", "stages": "detect2d,track", "athletes": "A,B"},
                       headers=admin, files=[("calibration", ("calibration.toml", calib)), ("tracks", ("tracks2d.npz", tracks))])
    assert good.status_code == 201, good.text
    assert good.json()["athletes"] == ["A", "B"] and good.json()["n_cameras"] == 3
    jb = client.post("/api/jobs", json={"session_id": bad.json()["id"]}, headers=admin).json()
    jg = client.post("/api/jobs", json={"session_id": good.json()["id"]}, headers=admin).json()
    assert run_jobs(settings) == 2  # the same worker goes on after the failure
    failed = client.get(f"/api/jobs/{jb['id']}", headers=admin).json()
    assert failed["status"] == "failed" and "calibration.toml" in failed["error"] and "Traceback" in failed["error"]
    assert failed["progress"]["detect2d"]["status"] == "failed"
    assert client.get(f"/api/jobs/{jg['id']}", headers=admin).json()["status"] == "done"
    assert client.get(f"/api/sessions/{bad.json()['id']}", headers=admin).json()["status"] == "failed"


def test_batch_creates_sessions_and_jobs_all_or_nothing(client: TestClient, tokens: dict, bout_folder: Path,
                                                        settings: Settings) -> None:
    admin = auth(tokens["admin"])
    other = make_session(settings.allowed_roots[0] / "bout2", n_frames=20, seed=1, stages=("detect2d", "track"),
                         use_synthetic=False)
    r = client.post("/api/batch", json={"sessions": [{"path": str(bout_folder), "name": "a"}, {"path": str(other)}],
                                        "to_stage": "track"}, headers=admin)
    assert r.status_code == 201, r.text
    res = r.json()
    assert len(res["sessions"]) == 2 and len(res["jobs"]) == 2
    n_before = len(client.get("/api/sessions", headers=admin).json())
    r = client.post("/api/batch", json={"sessions": [{"path": str(other)}, {"path": "/etc"}]}, headers=admin)
    assert r.status_code == 403
    r = client.post("/api/batch", json={"sessions": [{"path": str(other)}, {"path": str(settings.allowed_roots[0])}]},
                    headers=admin)
    assert r.status_code == 422 and "no session.json" in r.json()["detail"]
    # A session.json whose stage_config holds a wrong type is refused at submission, naming the
    # file and the key (before, the job failed when the worker reached that stage).
    bad = settings.allowed_roots[0] / "bout_badcfg"
    shutil.copytree(other, bad)
    meta = json.loads((bad / "session.json").read_text())
    meta["stage_config"] = {"track": {"sync_tolerance_frames": "two"}}
    (bad / "session.json").write_text(json.dumps(meta))
    r = client.post("/api/batch", json={"sessions": [{"path": str(other)}, {"path": str(bad)}]}, headers=admin)
    assert r.status_code == 422, r.text
    assert r.json()["detail"] == (f"{bad}/session.json: stage_config.track.sync_tolerance_frames must be float, "
                                  "got 'two' (str)")
    assert len(client.get("/api/sessions", headers=admin).json()) == n_before
    assert len(list(settings.sessions_dir.iterdir())) == n_before  # no leftover folders
    run_jobs(settings)
    for jid in res["jobs"]:
        job = client.get(f"/api/jobs/{jid}", headers=admin).json()
        assert job["status"] == "done" and set(job["progress"]) >= {"detect2d", "track"}
        assert all(p["status"] in ("ran", "pending") for p in job["progress"].values())


def test_cancel_queued_job(client: TestClient, tokens: dict, bout_folder: Path, settings: Settings) -> None:
    admin = auth(tokens["admin"])
    sid = make_bout(client, tokens["admin"], bout_folder)["id"]
    jid = client.post("/api/jobs", json={"session_id": sid}, headers=admin).json()["id"]
    r = client.post(f"/api/jobs/{jid}/cancel", headers=auth(tokens["annotator"]))
    assert r.status_code == 403  # not the requester
    r = client.post(f"/api/jobs/{jid}/cancel", headers=admin)
    assert r.status_code == 200 and r.json()["status"] == "cancelled"
    assert client.post(f"/api/jobs/{jid}/cancel", headers=admin).status_code == 409
    assert run_jobs(settings) == 0


def test_sse_streams_until_terminal(client: TestClient, tokens: dict, bout_folder: Path, settings: Settings) -> None:
    admin = auth(tokens["admin"])
    sid = make_bout(client, tokens["admin"], bout_folder)["id"]
    jid = client.post("/api/jobs", json={"session_id": sid, "to_stage": "track"}, headers=admin).json()["id"]
    run_jobs(settings)
    with client.stream("GET", f"/api/jobs/{jid}/events", headers=admin) as r:
        assert r.headers["content-type"].startswith("text/event-stream")
        events = [json.loads(line[len("data: "):]) for line in r.iter_lines() if line.startswith("data: ")]
    assert events[-1]["status"] == "done" and events[-1]["id"] == jid


def test_picker_page_lists_sessions(client: TestClient, tokens: dict, bout_folder: Path) -> None:
    make_bout(client, tokens["admin"], bout_folder, name="Final <b>bout</b>")
    assert client.get("/", follow_redirects=False).headers["location"] == "/login"  # not signed in
    r = client.post("/login", data={"name": "coach1", "token": tokens["coach"]})  # -> 303 to the picker
    assert r.status_code == 200 and "Open viewer" in r.text
    assert "Final &lt;b&gt;bout&lt;/b&gt;" in r.text  # escaped
    assert 'href="/viewer/' in r.text and tokens["coach"] not in r.text
    client.cookies.clear()
    assert client.get("/", follow_redirects=False).status_code == 303


def test_viewer_route_503_without_launcher_or_url(client: TestClient, tokens: dict, bout_folder: Path,
                                                  monkeypatch) -> None:  # noqa: ANN001
    import importlib
    import sys
    import types

    sid = make_bout(client, tokens["admin"], bout_folder)["id"]
    calls = []
    fake = types.ModuleType("webui.launcher")
    fake.start_viewer = lambda **kw: calls.append(kw) or "http://127.0.0.1:8099/"  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "webui.launcher", fake)
    r = client.post(f"/api/sessions/{sid}/viewer", headers=auth(tokens["coach"]))
    assert r.status_code == 200 and r.json() == {"url": f"http://testserver/viewer/{sid}/"}  # under the app
    # one viewer per session, for every user: no token or role is handed to it (each connection brings its own)
    assert sorted(calls[0]) == ["api_url", "idle_s", "session_dir", "session_id"]
    assert calls[0]["session_id"] == str(sid) and calls[0]["idle_s"] == client.app.state.settings.viewer_idle_s  # type: ignore[attr-defined]
    assert calls[0]["api_url"].endswith("/api")
    monkeypatch.setitem(sys.modules, "webui.launcher", None)  # import fails
    importlib.invalidate_caches()
    r = client.post(f"/api/sessions/{sid}/viewer", headers=auth(tokens["coach"]))
    assert r.status_code == 503 and "viewer is not available" in r.json()["detail"]


def test_keypoints_json_names_follow_identities(client: TestClient, tokens: dict, bout_folder: Path,
                                                settings: Settings) -> None:
    assert "triangulate" in available_stages()
    admin = auth(tokens["admin"])
    sid = make_bout(client, tokens["admin"], bout_folder)["id"]
    client.post("/api/jobs", json={"session_id": sid}, headers=admin)
    run_jobs(settings)
    client.put(f"/api/sessions/{sid}/identities/0", json={"name": "Usyk"}, headers=auth(tokens["annotator"]))
    d = client.get(f"/api/sessions/{sid}/results/keypoints3d", params={"source": "raw"}, headers=admin).json()
    assert d["persons"][0]["name"] == "Usyk"
    xyz = np.array([[j if j is not None else [np.nan] * 3 for j in f] for f in d["persons"][0]["joints"]])
    assert np.nanmax(np.abs(xyz)) < 5.0  # metres, inside the ring


def test_malformed_video_fails_the_job_readably(client: TestClient, tokens: dict, bout_folder: Path,
                                                settings: Settings) -> None:
    admin = auth(tokens["admin"])
    calib = (bout_folder / "inputs" / "calibration.toml").read_bytes()
    files = [("calibration", ("calibration.toml", calib))] + [
        ("videos", (f"cam{i}.mp4", b"this is not an mp4 file")) for i in range(3)]
    r = client.post("/api/sessions", data={"name": "bad video", "stages": "detect2d,track"}, files=files, headers=admin)
    assert r.status_code == 201, r.text
    assert r.json()["cameras"] == ["cam0", "cam1", "cam2"]
    jid = client.post("/api/jobs", json={"session_id": r.json()["id"]}, headers=admin).json()["id"]
    ok = client.post("/api/jobs", json={"session_id": make_bout(client, tokens["admin"], bout_folder)["id"],
                                        "to_stage": "track"}, headers=admin).json()["id"]
    assert run_jobs(settings) == 2
    job = client.get(f"/api/jobs/{jid}", headers=admin).json()
    assert job["status"] == "failed" and job["error"].splitlines()[0].strip()  # first line: "<Error>: <message>"
    assert "Traceback" in job["error"]
    assert client.get(f"/api/jobs/{ok}", headers=admin).json()["status"] == "done"


def test_a_session_whose_two_cameras_face_each_other_carries_the_layout_advice(
    client: TestClient, tokens: dict, bout_folder: Path, settings: Settings
) -> None:
    admin = auth(tokens["admin"])
    two = make_session(settings.allowed_roots[0] / "two", n_frames=5, n_cameras=2, stages=(), use_synthetic=False)
    r = client.post("/api/batch", json={"sessions": [{"path": str(two)}, {"path": str(bout_folder)}]}, headers=admin)
    assert r.status_code == 201, r.text
    two_id, three_id = r.json()["sessions"]
    advice = client.get(f"/api/sessions/{two_id}", headers=admin).json()["layout_advice"]
    assert advice.startswith("cam0 and cam1 look ") and "(facing each other)" in advice
    assert client.get(f"/api/sessions/{three_id}", headers=admin).json()["layout_advice"] == ""
    listed = {s["id"]: s["layout_advice"] for s in client.get("/api/sessions", headers=admin).json()}
    assert listed == {two_id: advice, three_id: ""}


def test_a_pose2sim_project_folder_is_an_inputs_folder(client: TestClient, tokens: dict, bout_folder: Path,
                                                       settings: Settings) -> None:
    """calibration/ and videos/ subfolders, as the Pose2Sim sample and Pose2Sim projects keep them."""

    admin = auth(tokens["admin"])
    proj = settings.allowed_roots[0] / "project"
    (proj / "calibration").mkdir(parents=True)
    (proj / "videos").mkdir()
    shutil.copy(bout_folder / "inputs" / "calibration.toml", proj / "calibration" / "Calib.toml")
    for cam in ("cam0", "cam1", "cam2"):
        (proj / "videos" / f"{cam}.mp4").write_bytes(b"videos are decoded by the job, not at creation")
    r = client.post("/api/sessions/from-folder", json={"path": str(proj)}, headers=admin)
    assert r.status_code == 201, r.text
    assert r.json()["cameras"] == ["cam0", "cam1", "cam2"]
    cfg = json.loads((Path(r.json()["folder"]) / "session.json").read_text())
    assert cfg["calibration"] == str(proj / "calibration" / "Calib.toml")
    assert cfg["videos"] == {c: str(proj / "videos" / f"{c}.mp4") for c in ("cam0", "cam1", "cam2")}
    shutil.rmtree(proj / "videos")
    r = client.post("/api/sessions/from-folder", json={"path": str(proj)}, headers=admin)
    assert r.status_code == 422 and "no video in it or in its videos/ subfolder" in r.text, r.text
    shutil.rmtree(proj / "calibration")
    r = client.post("/api/sessions/from-folder", json={"path": str(proj)}, headers=admin)
    assert r.status_code == 422 and "calibration/ subfolder, found 0" in r.text, r.text


def test_a_folder_of_openpose_cameras_is_an_inputs_folder(client: TestClient, tokens: dict, bout_folder: Path,
                                                          settings: Settings) -> None:
    """As Shelf keeps its detections (``keypoints2d/cam0`` ...) or Pose2Sim (``pose/cam01_json``):
    one OpenPose folder per camera, matched to the calibration's cameras by loose name; the
    request's ``fps`` sets the frame rate (the calibration has none)."""
    admin = auth(tokens["admin"])
    proj = settings.allowed_roots[0] / "shelf_like"
    proj.mkdir()
    shutil.copy(bout_folder / "inputs" / "calibration.toml", proj / "calibration.toml")
    for name in ("CAM_0", "cam1_json", "cam2"):
        (proj / "pose" / name).mkdir(parents=True)  # the job parses the JSON files, not the creation
    r = client.post("/api/batch", json={"sessions": [{"path": str(proj), "fps": 25}], "to_stage": "track"},
                    headers=admin)  # fmt: skip
    assert r.status_code == 201, r.text
    sid = r.json()["sessions"][0]
    assert client.get(f"/api/sessions/{sid}", headers=admin).json()["fps"] == 25
    folder = Path(client.get(f"/api/sessions/{sid}", headers=admin).json()["folder"])
    cfg = json.loads((folder / "session.json").read_text())
    assert cfg["source"] == "keypoints" and cfg["fps"] == 25
    assert cfg["keypoints"] == {"cam0": str(proj / "pose" / "CAM_0"), "cam1": str(proj / "pose" / "cam1_json"),
                                "cam2": str(proj / "pose" / "cam2")}  # fmt: skip
    (proj / "pose" / "side").mkdir()
    r = client.post("/api/sessions/from-folder", json={"path": str(proj)}, headers=admin)
    assert r.status_code == 422 and "['side'] named after no camera" in r.text, r.text
    r = client.post("/api/sessions/from-folder", json={"path": str(proj), "fps": 0}, headers=admin)
    assert r.status_code == 422, r.text
    # an entry that links outside the allowed roots is refused like a session.json path would be
    (proj / "pose" / "side").rmdir()
    outside = Path(tempfile.mkdtemp())
    try:
        (proj / "pose" / "cam2").rmdir()
        (proj / "pose" / "cam2").symlink_to(outside, target_is_directory=True)
        r = client.post("/api/sessions/from-folder", json={"path": str(proj), "fps": 25}, headers=admin)
        assert r.status_code == 403 and "outside the allowed roots" in r.text, r.text
    finally:
        shutil.rmtree(outside)
