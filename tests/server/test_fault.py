"""Fault test: kill the worker mid-job; a new worker finishes it and no earlier artifact is lost."""

from __future__ import annotations

import json
import signal
import time
from pathlib import Path

import httpx
import pytest

from server.cli import create_user
from server.demo import make_session
from server.loadtest import running_server

pytestmark = [pytest.mark.e2e, pytest.mark.slow]  # slow: kept out of the 3-minute fast tier


def test_killed_worker_job_is_requeued_and_resumes(tmp_path: Path) -> None:
    stages = ("detect2d", "track", "associate", "triangulate")
    from server.demo import available_stages

    assert set(stages) <= set(available_stages())
    bout = make_session(tmp_path / "data" / "bout", n_frames=40, n_cameras=3, stages=stages, use_synthetic=False)
    home = tmp_path / "home"
    token = create_user("admin", "admin", home=home)
    env = {"CORNERMAN_STAGE_DELAY_S": "1.0", "CORNERMAN_HEARTBEAT_S": "0.3", "CORNERMAN_JOB_TIMEOUT_S": "3",
           "CORNERMAN_POLL_S": "0.1"}
    with running_server(home, n_workers=1, allowed_roots=[tmp_path / "data"], extra_env=env) as srv:
        c = httpx.Client(base_url=srv.url, headers={"Authorization": f"Bearer {token}"}, timeout=30)
        sid = c.post("/api/sessions/from-folder", json={"path": str(bout)}).json()["id"]
        # force=True: the resumed attempt must still not recompute the stages completed before the kill
        jid = c.post("/api/jobs", json={"session_id": sid, "force": True}).json()["id"]
        t_end = time.monotonic() + 60
        while True:
            job = c.get(f"/api/jobs/{jid}").json()
            if job["progress"].get(stages[1], {}).get("status") == "ran" and job["current_stage"] in (None, stages[2]):
                break
            assert time.monotonic() < t_end, job
            time.sleep(0.05)
        victim = srv.workers[0]
        victim.send_signal(signal.SIGKILL)
        victim.wait(10)
        folder = Path(c.get(f"/api/sessions/{sid}").json()["folder"])
        kept = {s: json.loads((folder / "artifacts" / s / "manifest.json").read_text()) for s in stages[:2]}
        assert c.get(f"/api/jobs/{jid}").json()["status"] == "running"  # nobody noticed yet

        srv.start_worker()
        t_end = time.monotonic() + 90
        while (job := c.get(f"/api/jobs/{jid}").json())["status"] not in ("done", "failed", "cancelled"):
            assert time.monotonic() < t_end, job
            time.sleep(0.2)
        status = c.get(f"/api/sessions/{sid}/status").json()["stages"]
        c.close()
    assert job["status"] == "done", job
    assert job["attempts"] == 2
    assert "re-queued" in job["log_tail"] and "resuming" in job["log_tail"]
    for s in stages[:2]:  # completed before the kill: kept as they were, not recomputed
        m = json.loads((folder / "artifacts" / s / "manifest.json").read_text())
        assert m["created_unix_s"] == kept[s]["created_unix_s"] and m["outputs"] == kept[s]["outputs"]
    assert set(status.values()) == {"fresh"}
    assert not list((folder / "artifacts").glob(".tmp-*"))
