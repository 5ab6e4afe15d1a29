"""Progress within a stage reaches the viewer: a physics re-run through the real API and worker
(a stage process reporting its windows through the queue, the worker writing them to the
database) moves the viewer's progress bar (``webui.jobs.job_fraction``) many times while
physics runs, never backwards, up to 1. The fit's per-iteration reports travel the same path
(``tests/stages/test_fit_progress.py`` checks that the fit makes them)."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("mujoco")

from pipeline.artifacts import ArtifactStore, Manifest  # noqa: E402
from tests.conftest import write_tiny_session  # noqa: E402
from tests.stages.test_physics import _facing_pair  # noqa: E402
from webui.jobs import job_fraction  # noqa: E402

FAST = {"solver": {"window": 5, "commit": 3, "ilqr": {"max_iter": 2, "n_alpha": 3}}}


def test_physics_windows_move_the_viewers_progress_bar(tmp_path: Path) -> None:
    from fastapi.testclient import TestClient
    from sqlmodel import Session

    from server import crud
    from server.app import create_app
    from server.core.config import Settings
    from server.jobs.worker import Worker
    from server.models import UserCreate
    from webui.api_client import ApiClient

    data = tmp_path / "data"
    src = write_tiny_session(data / "bout", stages=("physics",))
    cfg = json.loads((src / "session.json").read_text())
    cfg["stage_config"] = {"physics": FAST}
    (src / "session.json").write_text(json.dumps(cfg))
    settings = Settings(home=tmp_path / "home", allowed_roots=[data], poll_s=0.1, heartbeat_s=0.2)
    app = create_app(settings)
    with Session(app.state.engine, expire_on_commit=False) as db:
        token = crud.issue_token(db, user=crud.create_user(db, user_in=UserCreate(name="a1", role="admin")))
    api = ApiClient("http://testserver/api", token, http=TestClient(app))
    r = api._http.post("/sessions/from-folder", json={"path": str(src), "name": "physics only"})
    assert r.status_code == 201, r.text
    sid, folder = str(r.json()["id"]), Path(r.json()["folder"])
    # the physics stage's input, written by hand as the fit's artifact (40 frames: 13 windows)
    ArtifactStore(folder).write(Manifest(stage="fit", code_version="t", config={}, config_hash="t", inputs={}),
                                {"keypoints3d": _facing_pair(0.3, 40)})  # fmt: skip
    job_id = api.start_job(sid)["id"]

    worker = Worker(settings)
    t = threading.Thread(target=worker.run_until_idle, kwargs={"timeout_s": 240}, daemon=True)
    t.start()
    seen: list[tuple[str | None, float, float | None]] = []  # (current stage, fraction, physics done)
    while t.is_alive():
        job = api.job(job_id)
        done = (job["progress"].get("physics") or {}).get("done")
        seen.append((job["current_stage"], job_fraction(job), done))
        time.sleep(0.05)
    t.join()
    job = api.job(job_id)
    assert job["status"] == "done", job.get("error")
    assert job_fraction(job) == 1.0
    fractions = [f for _, f, _ in seen]
    assert fractions == sorted(fractions), "the bar went backwards"
    during = sorted({f for stage, f, _ in seen if stage == "physics"})
    assert len(during) >= 3, f"the bar hardly moved while physics ran: {during}"
    assert 0.0 <= during[0] < during[-1] <= 1.0  # physics is the only stage: it starts at 0
    windows = {d for stage, _, d in seen if stage == "physics" and d}
    assert len(windows) >= 3  # several window counts reached the database, not only start and end
    assert job["progress"]["physics"]["status"] == "ran"
