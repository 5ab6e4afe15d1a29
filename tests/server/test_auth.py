"""Auth (every role against every route class), path traversal, upload limits."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from server.core.config import Settings
from tests.server.conftest import auth, make_bout

ROLE_ORDER = {"coach": 0, "annotator": 1, "admin": 2}


def _routes(sid: int, folder: Path, aid: int, jid: int) -> list[tuple[str, str, str, dict]]:
    """(min role, method, path, request kwargs) for one route of each kind."""
    swap = {"annotation": {"kind": "swap_identities", "frame": 5, "person_a": 0, "person_b": 1}, "rerun": False}
    return [
        ("coach", "GET", "/api/me", {}),
        ("coach", "GET", "/api/sessions", {}),
        ("coach", "GET", f"/api/sessions/{sid}", {}),
        ("coach", "GET", f"/api/sessions/{sid}/status", {}),
        ("coach", "GET", f"/api/sessions/{sid}/identities", {}),
        ("coach", "GET", f"/api/sessions/{sid}/metrics", {}),
        ("coach", "GET", f"/api/sessions/{sid}/annotations", {}),
        ("coach", "GET", f"/api/annotations/{aid}", {}),
        ("coach", "GET", "/api/jobs", {}),
        ("coach", "GET", f"/api/jobs/{jid}", {}),
        ("coach", "GET", f"/api/sessions/{sid}/results/keypoints3d", {}),
        ("annotator", "PUT", f"/api/sessions/{sid}/identities/0", {"json": {"name": "R"}}),
        ("annotator", "POST", f"/api/sessions/{sid}/annotations", {"json": swap}),
        ("annotator", "POST", f"/api/annotations/{aid}/undo", {"json": {"rerun": False}}),
        ("annotator", "POST", "/api/jobs", {"json": {"session_id": sid, "from_stage": "track"}}),
        # forcing from a stage after the 2D one: the 2D stage is not forced
        ("annotator", "POST", "/api/jobs", {"json": {"session_id": sid, "from_stage": "track", "force": True}}),
        ("admin", "POST", "/api/jobs", {"json": {"session_id": sid, "force": True}}),
        ("admin", "POST", "/api/sessions/from-folder", {"json": {"path": str(folder)}}),
        ("admin", "PATCH", f"/api/sessions/{sid}", {"json": {"date": "2026-11-21"}}),
        ("admin", "POST", "/api/batch", {"json": {"sessions": [{"path": str(folder)}]}}),
        ("admin", "GET", "/api/users", {}),
        ("admin", "POST", "/api/users", {"json": {"name": "newbie", "role": "coach"}}),
        ("admin", "DELETE", f"/api/sessions/{sid}", {}),
    ]


def test_every_role_against_every_route_class(client: TestClient, tokens: dict, bout_folder: Path) -> None:
    sid = make_bout(client, tokens["admin"], bout_folder)["id"]
    aid = client.post(f"/api/sessions/{sid}/annotations", headers=auth(tokens["admin"]), json={
        "annotation": {"kind": "mark_invalid", "view": "cam0", "frame": 1, "track": 0}, "rerun": False}).json()["annotation"]["id"]
    jid = client.post("/api/jobs", json={"session_id": sid}, headers=auth(tokens["admin"])).json()["id"]
    assert client.get("/api/health").status_code == 200
    for need, method, path, kw in _routes(sid, bout_folder, aid, jid):
        r = client.request(method, path, **kw)
        assert r.status_code == 401, (method, path, r.status_code)
        r = client.request(method, path, headers=auth("cm_not-a-token"), **kw)
        assert r.status_code == 401 and r.json()["detail"] == "invalid API token", (method, path)
        for role in ("coach", "annotator", "admin"):
            if path.startswith("/api/annotations/") and path.endswith("/undo") and role != "annotator":
                continue  # an annotation can be undone once; the annotator does it below
            r = client.request(method, path, headers=auth(tokens[role]), **kw)
            if ROLE_ORDER[role] < ROLE_ORDER[need]:
                assert r.status_code == 403, (role, method, path, r.status_code, r.text)
            else:
                assert r.status_code < 400 or r.status_code == 404 and path.endswith("keypoints3d"), (
                    role, method, path, r.status_code, r.text)
            client.cookies.clear()


def test_path_traversal_is_refused(client: TestClient, tokens: dict, settings: Settings, bout_folder: Path,
                                   tmp_path: Path) -> None:
    admin = auth(tokens["admin"])
    root = settings.allowed_roots[0]
    for bad in ["/etc", str(root / ".." / "home"), f"{root}/../../", "relative/path", str(tmp_path)]:
        r = client.post("/api/sessions/from-folder", json={"path": bad}, headers=admin)
        assert r.status_code == 403, (bad, r.status_code, r.text)
        assert "allowed roots" in r.json()["detail"] or "absolute" in r.json()["detail"]
    # a symlink inside the allowed root pointing outside of it
    outside = tmp_path / "outside"
    outside.mkdir()
    os.symlink(outside, root / "escape")
    assert client.post("/api/sessions/from-folder", json={"path": str(root / "escape")}, headers=admin).status_code == 403
    # a session.json whose input paths climb out of the allowed root
    evil = root / "evil"
    evil.mkdir()
    (evil / "session.json").write_text(
        '{"name": "evil", "source": "tracks", "calibration": "../../../../etc/passwd", "tracks": "x.npz"}')
    r = client.post("/api/sessions/from-folder", json={"path": str(evil)}, headers=admin)
    assert r.status_code == 403 and "/etc/passwd" in r.json()["detail"]
    # uploaded file names with paths
    for name in ["../../evil.toml", "/etc/cron.d/x", ".hidden", "a/b.toml", "..", "c\\d.toml"]:
        r = client.post("/api/sessions", data={"name": "x"}, headers=admin,
                        files=[("calibration", (name, b"x")), ("tracks", ("t.npz", b"x"))])
        assert r.status_code == 422, (name, r.status_code, r.text)
    assert not (settings.home / "evil.toml").exists() and not (settings.sessions_dir.parent / "evil.toml").exists()
    assert list(settings.sessions_dir.iterdir()) == []  # nothing left behind
    # artifact names
    sid = make_bout(client, tokens["admin"], bout_folder)["id"]
    for art in ["..%2F..%2Fcornerman.db", "..", ".hashcache.json"]:
        r = client.get(f"/api/sessions/{sid}/results/detect2d/{art}", headers=admin)
        assert r.status_code in (400, 404), (art, r.status_code)
    assert client.get(f"/api/sessions/{sid}/results/..%2Fartifacts/manifest.json", headers=admin).status_code == 404


@pytest.mark.parametrize("chunked", [False, True])
def test_oversized_upload_is_413(client: TestClient, tokens: dict, settings: Settings, chunked: bool) -> None:
    big = b"\0" * (settings.max_upload_bytes + 10)
    files = [("calibration", ("calibration.toml", b"x")), ("tracks", ("tracks2d.npz", big))]
    if chunked:
        import httpx

        req = httpx.Request("POST", "http://testserver/api/sessions", data={"name": "big"}, files=files,
                            headers=auth(tokens["admin"]))
        body = req.read()

        def gen():  # noqa: ANN202
            for i in range(0, len(body), 65536):
                yield body[i : i + 65536]

        r = client.post("/api/sessions", content=gen(), headers={**auth(tokens["admin"]),
                                                                 "content-type": req.headers["content-type"]})
    else:
        r = client.post("/api/sessions", data={"name": "big"}, files=files, headers=auth(tokens["admin"]))
    assert r.status_code == 413 and "upload limit" in r.json()["detail"]
    assert list(settings.sessions_dir.iterdir()) == []


def test_validation_errors_are_clear(client: TestClient, tokens: dict, bout_folder: Path) -> None:
    admin = auth(tokens["admin"])
    r = client.post("/api/sessions/from-folder", json={}, headers=admin)
    assert r.status_code == 422 and "path" in str(r.json()["detail"])
    r = client.post("/api/jobs", json={"session_id": 999}, headers=admin)
    assert r.status_code == 404 and "session 999" in r.json()["detail"]
    r = client.post("/api/users", json={"name": "../root", "role": "admin"}, headers=admin)
    assert r.status_code == 422
    r = client.post("/api/users", json={"name": "x", "role": "superuser"}, headers=admin)
    assert r.status_code == 422
    sid = make_bout(client, tokens["admin"], bout_folder)["id"]
    r = client.post("/api/jobs", json={"session_id": sid, "from_stage": "triangulate", "to_stage": "track"}, headers=admin)
    assert r.status_code == 422 and "comes after" in r.json()["detail"]
    r = client.post(f"/api/sessions/{sid}/annotations", json={"annotation": {"kind": "teleport"}}, headers=admin)
    assert r.status_code == 422 and "unknown annotation kind" in r.json()["detail"]
