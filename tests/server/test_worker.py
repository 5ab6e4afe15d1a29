"""Worker details: resume plan, cancelling a running job, no clobbering of in-flight writes."""

from __future__ import annotations

import dataclasses
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
    assert resume_plan(j, ORDER) == ("associate", True)
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


def test_a_job_refreshes_the_sessions_cameras_from_a_replaced_calibration(
    client: TestClient, tokens: dict, settings: Settings
) -> None:
    """The layout advice stored at creation follows a calibration file replaced later (so do the
    cameras and fps, through the same ``server.storage.rig_changes``)."""
    import numpy as np

    from pipeline.geometry.rotations import look_at_T_world_cam
    from pipeline.io.calibration import load_calibration
    from pipeline.io.calibration_toml import save_toml
    from server.demo import make_session
    from tests.server.conftest import run_jobs

    admin = auth(tokens["admin"])
    two = make_session(settings.allowed_roots[0] / "two", n_frames=5, n_cameras=2, use_synthetic=False)
    bout = make_bout(client, tokens["admin"], two, name="two")
    assert "(facing each other)" in bout["layout_advice"] and bout["fps"] == 50.0
    calib = two / "inputs" / "calibration.toml"
    rig = load_calibration(calib)
    a = 0.3 + np.pi / 2  # cam1 a quarter turn from cam0 instead of opposite it
    T1 = look_at_T_world_cam(np.array([6.5 * np.cos(a), 6.5 * np.sin(a), 2.2]), np.array([0.0, 0.0, 0.9]))
    save_toml(dataclasses.replace(rig, T_world_cam=np.stack([rig.T_world_cam[0], T1])), calib)
    # nothing changes before a job starts
    assert client.get(f"/api/sessions/{bout['id']}", headers=admin).json()["layout_advice"] == bout["layout_advice"]
    jid = client.post("/api/jobs", json={"session_id": bout["id"], "to_stage": "track"}, headers=admin).json()["id"]
    assert run_jobs(settings) == 1
    job = client.get(f"/api/jobs/{jid}", headers=admin).json()
    assert job["status"] == "done", (job["error"], job["log_tail"])
    assert "the calibration changed: updated the session's layout_advice" in job["log_tail"]
    now = client.get(f"/api/sessions/{bout['id']}", headers=admin).json()
    assert (now["layout_advice"], now["fps"], now["cameras"]) == ("", 50.0, ["cam0", "cam1"])


def test_rig_changes_names_what_differs_and_keeps_all_on_an_unreadable_calibration(tmp_path: Path) -> None:
    from server.demo import make_session
    from server.storage import bout_from_meta, rig_changes

    s = make_session(tmp_path / "s", n_frames=3, n_cameras=2, use_synthetic=False)
    bout = bout_from_meta(s, "test")
    assert rig_changes(bout) == {}
    bout.cameras, bout.n_cameras = ["a", "b", "c"], 3
    assert rig_changes(bout) == {"cameras": ["cam0", "cam1"], "n_cameras": 2}
    (s / "inputs" / "calibration.toml").write_text("not = [a toml")
    assert rig_changes(bout) == {}  # a job reading it reports the problem; the stored fields stay
