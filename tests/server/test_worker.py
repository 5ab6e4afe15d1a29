"""Worker details: resume plan, cancelling a running job, no clobbering of in-flight writes."""

from __future__ import annotations

import threading
import time
from pathlib import Path

from fastapi.testclient import TestClient

from server.core.config import Settings
from server.jobs.worker import Worker, resume_plan
from server.models import Job
from tests.server.conftest import auth, make_bout

ORDER = ["detect2d", "track", "associate", "triangulate"]


def _job(**kw: object) -> Job:
    return Job(session_id=1, **kw)  # type: ignore[arg-type]


def test_resume_plan() -> None:
    ran = {"status": "ran"}
    assert resume_plan(_job(), ORDER) == (None, False)  # stale-only runs resume by themselves
    assert resume_plan(_job(force=True), ORDER) == (None, True)
    assert resume_plan(_job(from_stage="track"), ORDER) == ("track", False)
    # forced, killed after detect2d+track: resume at associate, forcing it and later only
    j = _job(force=True, progress={"detect2d": ran, "track": ran, "associate": {"status": "running"}})
    assert resume_plan(j, ORDER) == ("associate", False)
    j = _job(from_stage="track", progress={"detect2d": {"status": "skipped"}, "track": ran})
    assert resume_plan(j, ORDER) == ("associate", False)
    j = _job(from_stage="track", to_stage="associate", progress={"track": ran, "associate": ran})
    assert resume_plan(j, ORDER) == (None, False)


def test_cancel_running_job_kills_stage_and_worker_goes_on(client: TestClient, tokens: dict, bout_folder: Path,
                                                           settings: Settings) -> None:
    admin = auth(tokens["admin"])
    slow = settings.model_copy(update={"stage_delay_s": 3.0})
    sid = make_bout(client, tokens["admin"], bout_folder)["id"]
    jid = client.post("/api/jobs", json={"session_id": sid}, headers=admin).json()["id"]
    w = Worker(slow)
    t = threading.Thread(target=w.run_forever, daemon=True)
    t.start()
    try:
        t_end = time.monotonic() + 30
        while client.get(f"/api/jobs/{jid}", headers=admin).json()["status"] != "running":
            assert time.monotonic() < t_end
            time.sleep(0.05)
        r = client.post(f"/api/jobs/{jid}/cancel", headers=admin)
        assert r.status_code == 200
        t_end = time.monotonic() + 30
        while (job := client.get(f"/api/jobs/{jid}", headers=admin).json())["status"] == "running":
            assert time.monotonic() < t_end
            time.sleep(0.05)
        assert job["status"] == "cancelled" and "cancelled by request" in job["log_tail"]
        folder = Path(client.get(f"/api/sessions/{sid}", headers=admin).json()["folder"])
        assert not (folder / "artifacts" / "detect2d").exists()  # killed during the first stage's pause
        # the worker is still alive and takes the next job
        w.settings = settings
        j2 = client.post("/api/jobs", json={"session_id": sid, "to_stage": "track"}, headers=admin).json()["id"]
        t_end = time.monotonic() + 60
        while (job := client.get(f"/api/jobs/{j2}", headers=admin).json())["status"] in ("queued", "running"):
            assert time.monotonic() < t_end
            time.sleep(0.1)
        assert job["status"] == "done"
    finally:
        w.stop.set()
        t.join(20)


def test_reading_a_session_never_removes_an_inflight_write(tmp_path: Path) -> None:
    """The server opens ArtifactStores (status, results) while a worker writes into them."""
    from pipeline.artifacts import ArtifactStore

    writer = ArtifactStore(tmp_path)
    inflight = writer.root / ".tmp-fit-0123abcd"
    with writer._write_lock(exclusive=False):
        inflight.mkdir()
        ArtifactStore(tmp_path)  # what an API request does
        assert inflight.exists()
    ArtifactStore(tmp_path)  # no writer any more: the leftover of a crash is cleaned
    assert not inflight.exists()
