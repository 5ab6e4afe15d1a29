"""End to end: real uvicorn + real worker processes, the synthetic bout over HTTP.

Submit, follow progress over SSE, post an identity swap, check that only the stages
after the edit re-ran and that the downloaded 3D result changed accordingly.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from server.cli import create_user
from server.demo import available_stages, make_session
from server.loadtest import running_server

pytestmark = pytest.mark.e2e


def follow(client: httpx.Client, job_id: int, timeout_s: float = 120.0) -> list[dict[str, Any]]:
    """All SSE job snapshots until the job is terminal."""
    events = []
    with client.stream("GET", f"/api/jobs/{job_id}/events", timeout=timeout_s) as r:
        assert r.status_code == 200
        for line in r.iter_lines():
            if line.startswith("data: "):
                events.append(json.loads(line[6:]))
    return events


def joints(d: dict, person: int) -> np.ndarray:
    p = d["persons"][person]
    return np.array([[j if j is not None else [np.nan] * 3 for j in frame] for frame in p["joints"]], dtype=float)


def test_synthetic_bout_over_http_with_identity_swap(tmp_path: Path) -> None:
    stages = available_stages()
    assert {"associate", "triangulate"} <= set(stages)
    bout = make_session(tmp_path / "data" / "bout", n_frames=60, n_cameras=3, seed=0)
    home = tmp_path / "home"
    admin = create_user("admin", "admin", home=home)
    annot = create_user("ann", "annotator", home=home)
    with running_server(home, n_workers=1, allowed_roots=[tmp_path / "data"],
                        extra_env={"CORNERMAN_POLL_S": "0.1", "CORNERMAN_HEARTBEAT_S": "0.3"}) as srv:
        a = httpx.Client(base_url=srv.url, headers={"Authorization": f"Bearer {admin}"}, timeout=60)
        n = httpx.Client(base_url=srv.url, headers={"Authorization": f"Bearer {annot}"}, timeout=60)
        files = [("calibration", ("calibration.toml", (bout / "inputs" / "calibration.toml").read_bytes())),
                 ("tracks", ("tracks2d.npz", (bout / "inputs" / "tracks2d.npz").read_bytes()))]
        r = a.post("/api/sessions", data={"name": "synthetic", "stages": ",".join(stages), "fps": "50"}, files=files)
        assert r.status_code == 201, r.text
        sid = r.json()["id"]
        job = a.post("/api/jobs", json={"session_id": sid}).json()
        events = follow(a, job["id"])
        assert events[-1]["status"] == "done", events[-1]
        assert any(e["status"] == "running" for e in events) or len(events) == 1
        assert [events[-1]["progress"][s]["status"] for s in stages] == ["ran"] * len(stages)
        manifests = {s: a.get(f"/api/sessions/{sid}/results/{s}/manifest.json").json() for s in stages}
        before = a.get(f"/api/sessions/{sid}/results/keypoints3d", params={"source": "raw"}).json()

        swap_at = 30
        r = n.post(f"/api/sessions/{sid}/annotations", json={
            "annotation": {"kind": "swap_identities", "frame": swap_at, "person_a": 0, "person_b": 1}, "rerun": True})
        assert r.status_code == 201, r.text
        res = r.json()
        assert res["stale_from"] == "associate" and res["job"] is not None
        events = follow(n, res["job"]["id"])
        final = events[-1]
        assert final["status"] == "done", final
        prog = final["progress"]
        assert prog["detect2d"]["status"] == prog["track"]["status"] == "skipped"
        assert prog["associate"]["status"] == prog["triangulate"]["status"] == "ran"
        for s in ("detect2d", "track"):  # untouched: same files, same creation time
            m = a.get(f"/api/sessions/{sid}/results/{s}/manifest.json").json()
            assert m["created_unix_s"] == manifests[s]["created_unix_s"] and m["outputs"] == manifests[s]["outputs"]
        for s in ("associate", "triangulate"):
            m = a.get(f"/api/sessions/{sid}/results/{s}/manifest.json").json()
            assert m["created_unix_s"] > manifests[s]["created_unix_s"]
        assert set(a.get(f"/api/sessions/{sid}/status").json()["stages"].values()) == {"fresh"}
        after = a.get(f"/api/sessions/{sid}/results/keypoints3d", params={"source": "raw"}).json()
        a.close()
        n.close()

    b0, b1, a0, a1 = joints(before, 0), joints(before, 1), joints(after, 0), joints(after, 1)
    # Before the swap frame nothing changed; from it on, the two athletes traded places.
    pre = slice(0, swap_at - 2)
    post = slice(swap_at + 2, None)
    np.testing.assert_allclose(a0[pre], b0[pre], atol=1e-3, equal_nan=True)
    np.testing.assert_allclose(a1[pre], b1[pre], atol=1e-3, equal_nan=True)
    ok = np.isfinite(a0[post]) & np.isfinite(b1[post])
    assert ok.mean() > 0.5
    close = np.abs(a0[post] - b1[post])[ok] < 0.01
    assert close.mean() > 0.95, f"after the swap, person 0 should be the former person 1 ({close.mean():.2f})"
    far = np.linalg.norm(np.nan_to_num(a0[post] - b0[post]), axis=-1)
    assert np.median(far) > 0.3  # and really moved (the athletes stand apart)
