"""The session picker's actions through its HTML forms (signed in with the login cookie):
create from a server folder and from an upload, run, the job page with its log and error,
cancel, delete after a confirmation; role checks; cross-site posts refused."""

from __future__ import annotations

import json
import re
from pathlib import Path

from fastapi.testclient import TestClient

from server.core.config import Settings
from server.demo import make_session
from tests.server.conftest import auth, run_jobs

EVIL = {"Origin": "http://evil.example"}


def _sign_in(client: TestClient, role: str, tokens: dict) -> None:
    r = client.post("/login", data={"name": f"{role}1", "token": tokens[role]}, follow_redirects=False)
    assert r.status_code == 303, r.text


def _session_ids(client: TestClient, tokens: dict) -> list[int]:
    return [s["id"] for s in client.get("/api/sessions", headers=auth(tokens["admin"])).json()]


def test_folder_session_run_job_page_and_delete(client: TestClient, tokens: dict, settings: Settings) -> None:
    folder = make_session(settings.allowed_roots[0] / "bout", n_frames=30, n_cameras=3, seed=0,
                          stages=("detect2d", "track"), use_synthetic=False)
    _sign_in(client, "admin", tokens)
    page = client.get("/").text
    assert 'action="/sessions/new/folder"' in page and 'enctype="multipart/form-data"' in page
    assert f'<option value="{folder}">' in page  # the folder is offered under the allowed root
    assert "<script src" not in page and "<link" not in page  # nothing fetched from elsewhere

    assert 'name="fps"' in page
    r = client.post("/sessions/new/folder", data={"path": str(folder), "name": "picked", "date": "2026-11-01",
                                                  "fps": "25"}, follow_redirects=False)  # fmt: skip
    assert r.status_code == 303 and r.headers["location"].startswith("/?msg=created%20session")
    assert "deg%20apart" not in r.headers["location"]  # three cameras a third of a turn apart: no layout advice
    (sid,) = _session_ids(client, tokens)
    page = client.get("/").text
    row = re.search(rf"<tr id='s{sid}'>.*?</tr>", page, re.S)
    assert row is not None
    created = client.get(f"/api/sessions/{sid}", headers=auth(tokens["admin"])).json()["created_at"]
    assert client.get(f"/api/sessions/{sid}", headers=auth(tokens["admin"])).json()["fps"] == 25
    assert created[:10] in row.group(0) and created[11:16] in row.group(0) and "2026-11-01" in row.group(0)
    assert "⚠ layout" not in row.group(0)
    assert f'action="/sessions/{sid}/run"' in row.group(0) and f'href="/sessions/{sid}/delete"' in row.group(0)

    r = client.post(f"/sessions/{sid}/run", follow_redirects=False)
    assert r.status_code == 303
    job_id = int(r.headers["location"].rsplit("/", 1)[1])
    job_page = client.get(f"/jobs/{job_id}").text
    assert 'id="job-status">queued<' in job_page and 'id="cancel"' in job_page
    run_jobs(settings)
    job_page = client.get(f"/jobs/{job_id}").text
    assert 'id="job-status">done<' in job_page and 'id="cancel"' not in job_page
    assert re.search(r"<td>detect2d</td><td class=\"st ran\">ran</td>", job_page)
    log_tail = client.get(f"/api/jobs/{job_id}", headers=auth(tokens["admin"])).json()["log_tail"]
    assert log_tail and log_tail.splitlines()[-1].replace("'", "&#x27;") in job_page

    # a failing job shows its error (the session reads the source folder's calibration)
    cfg = json.loads((Path(client.get(f"/api/sessions/{sid}", headers=auth(tokens["admin"])).json()["folder"])
                      / "session.json").read_text())
    Path(cfg["calibration"]).write_text("[cam0]\nmatrix = 'broken'\n")
    r = client.post(f"/sessions/{sid}/run", follow_redirects=False)
    failed_id = int(r.headers["location"].rsplit("/", 1)[1])
    run_jobs(settings)
    failed = client.get(f"/api/jobs/{failed_id}", headers=auth(tokens["admin"])).json()
    assert failed["status"] == "failed" and "calibration" in failed["error"]
    job_page = client.get(f"/jobs/{failed_id}").text
    assert 'id="job-error"' in job_page and "calibration" in job_page.split('id="job-error"')[1]

    # delete: a confirmation page first; a post without its confirmation does nothing
    r = client.post(f"/sessions/{sid}/delete", follow_redirects=False)
    assert r.status_code == 422 and _session_ids(client, tokens) == [sid]
    confirm = client.get(f"/sessions/{sid}/delete").text
    assert 'id="confirm-delete"' in confirm and f'name="confirm" value="{sid}"' in confirm
    session_dir = Path(client.get(f"/api/sessions/{sid}", headers=auth(tokens["admin"])).json()["folder"])
    r = client.post(f"/sessions/{sid}/delete", data={"confirm": str(sid)}, follow_redirects=False)
    assert r.status_code == 303 and "deleted%20session" in r.headers["location"]
    assert _session_ids(client, tokens) == [] and not session_dir.exists() and folder.exists()


def test_upload_form_creates_a_keypoint_session(client: TestClient, tokens: dict, settings: Settings) -> None:
    src = make_session(settings.allowed_roots[0] / "b", n_frames=5, n_cameras=3, stages=("detect2d",),
                       use_synthetic=False)
    _sign_in(client, "admin", tokens)
    kp = [{"image_id": f, "category_id": 1, "score": 0.9, "keypoints": [10.0, 20.0, 1.0] * 17} for f in range(5)]
    files = [("calibration", ("calibration.toml", (src / "inputs" / "calibration.toml").read_bytes()))]
    files += [("keypoints", (f"cam{i}.json", json.dumps(kp).encode())) for i in range(3)]
    files += [("videos", ("", b""))]  # the empty video input a browser sends
    r = client.post("/sessions/new/upload", data={"name": "up", "athletes": "Ann,Bea", "keypoint_format": "coco",
                                                  "fps": "25"}, files=files, follow_redirects=False)
    assert r.status_code == 303, r.text
    (sid,) = _session_ids(client, tokens)
    s = client.get(f"/api/sessions/{sid}", headers=auth(tokens["admin"])).json()
    assert s["athletes"] == ["Ann", "Bea"] and s["n_cameras"] == 3 and s["fps"] == 25 and s["created_by"] == "admin1"
    cfg = json.loads((Path(s["folder"]) / "session.json").read_text())
    assert cfg["source"] == "keypoints" and cfg["keypoint_format"] == "coco"
    assert cfg["keypoints"] == {f"cam{i}": f"inputs/cam{i}.json" for i in range(3)}
    # no data besides the calibration: an error page naming it, no session
    r = client.post("/sessions/new/upload", data={"name": "none"}, files=files[:1])
    assert r.status_code == 422 and "needs videos, keypoints" in r.text and "<html>" in r.text
    r = client.post("/sessions/new/folder", data={"path": "/etc"})
    assert r.status_code == 403 and "outside the allowed roots" in r.text
    assert _session_ids(client, tokens) == [sid]
    # the empty frame-rate field a browser sends keeps the folder's own rate
    r = client.post("/sessions/new/folder", data={"path": str(src), "fps": ""}, follow_redirects=False)
    assert r.status_code == 303, r.text
    new = [i for i in _session_ids(client, tokens) if i != sid]
    assert len(new) == 1 and client.get(f"/api/sessions/{new[0]}", headers=auth(tokens["admin"])).json()["fps"] == 50


def test_roles_and_cross_site_posts(client: TestClient, tokens: dict, settings: Settings) -> None:
    folder = make_session(settings.allowed_roots[0] / "bout", n_frames=20, n_cameras=3, stages=("detect2d",),
                          use_synthetic=False)
    assert client.post("/sessions/new/folder", data={"path": str(folder)}).status_code == 401  # no cookie
    _sign_in(client, "admin", tokens)
    r = client.post("/sessions/new/folder", data={"path": str(folder)}, headers=EVIL)
    assert r.status_code == 403 and "cross-origin" in r.text and _session_ids(client, tokens) == []
    client.post("/sessions/new/folder", data={"path": str(folder)})
    (sid,) = _session_ids(client, tokens)
    assert client.post(f"/sessions/{sid}/run", headers=EVIL).status_code == 403
    r = client.post(f"/sessions/{sid}/run", follow_redirects=False)  # the admin's job
    job_id = int(r.headers["location"].rsplit("/", 1)[1])
    assert client.post(f"/sessions/{sid}/delete", data={"confirm": str(sid)}, headers=EVIL).status_code == 403

    client.cookies.clear()
    _sign_in(client, "coach", tokens)
    page = client.get("/").text
    assert "/sessions/new/folder" not in page and f"/sessions/{sid}/run" not in page and "Delete" not in page
    assert client.post(f"/sessions/{sid}/run").status_code == 403
    assert client.get(f"/jobs/{job_id}").status_code == 200  # anyone signed in may read a job

    client.cookies.clear()
    _sign_in(client, "annotator", tokens)
    page = client.get("/").text
    assert "/sessions/new/folder" not in page and "Delete" not in page
    assert f'action="/jobs/{job_id}/cancel"' not in page  # not their job
    r = client.post(f"/jobs/{job_id}/cancel")
    assert r.status_code == 403 and "requester" in r.text
    assert client.post(f"/sessions/{sid}/delete", data={"confirm": str(sid)}).status_code == 403
    assert client.post("/sessions/new/folder", data={"path": str(folder)}).status_code == 403

    client.cookies.clear()
    _sign_in(client, "admin", tokens)
    assert f'action="/jobs/{job_id}/cancel"' in client.get("/").text
    r = client.post(f"/jobs/{job_id}/cancel", follow_redirects=False)
    assert r.status_code == 303
    assert client.get(f"/api/jobs/{job_id}", headers=auth(tokens["admin"])).json()["status"] == "cancelled"
    assert 'id="job-status">cancelled<' in client.get(f"/jobs/{job_id}").text
    assert _session_ids(client, tokens) == [sid]


def test_a_new_session_whose_two_cameras_face_each_other_gets_the_layout_advice(
    client: TestClient, tokens: dict, settings: Settings
) -> None:
    folder = make_session(settings.allowed_roots[0] / "two", n_frames=5, n_cameras=2, stages=(), use_synthetic=False)
    _sign_in(client, "admin", tokens)
    r = client.post("/sessions/new/folder", data={"path": str(folder)}, follow_redirects=False)
    assert r.status_code == 303
    page = client.get(r.headers["location"]).text
    assert "created session" in page and "cam0 and cam1 look" in page and "(facing each other)" in page
    assert "about a quarter turn" in page
    row = re.search(r"<tr id='s\d+'>.*?</tr>", page, re.S)
    assert row is not None and "⚠ layout" in row.group(0) and "(facing each other)" in row.group(0)  # the tooltip
