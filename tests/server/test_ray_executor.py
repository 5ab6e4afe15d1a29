"""The Ray executor against a local Ray instance (skipped when the ``ray`` extra is absent)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlmodel import Session

from server import crud
from server.core.config import Settings
from server.demo import make_session
from server.jobs.worker import Worker
from server.models import Bout, Job, JobCreate

pytestmark = pytest.mark.slow
ray = pytest.importorskip("ray", reason="ray extra not installed (pip install 'cornerman[ray]')")


@pytest.fixture(scope="module")
def ray_executor() -> Iterator[object]:
    from server.jobs.ray_executor import RayExecutor

    ex = RayExecutor(num_cpus=1)
    yield ex
    ray.shutdown()


def test_ray_executor_runs_stages_and_reports_errors(tmp_path: Path, ray_executor: object) -> None:
    settings = Settings(home=tmp_path / "home", allowed_roots=[tmp_path], heartbeat_s=0.2, poll_s=0.1)
    folder = make_session(tmp_path / "bout", n_frames=20, stages=("detect2d", "track"), use_synthetic=False)
    broken = make_session(tmp_path / "broken", n_frames=20, stages=("detect2d", "track"), use_synthetic=False)
    (broken / "inputs" / "calibration.toml").write_text("[cam0]\nmatrix = 'nope'\n")
    w = Worker(settings, executor=ray_executor)  # type: ignore[arg-type]
    with Session(w.engine, expire_on_commit=False) as db:
        b = crud.create_bout(db, bout=Bout(name="b", folder=str(folder)))
        bb = crud.create_bout(db, bout=Bout(name="bb", folder=str(broken)))
        assert b.id is not None and bb.id is not None
        j1 = crud.create_job(db, job_in=JobCreate(session_id=b.id), requested_by="t")
        j2 = crud.create_job(db, job_in=JobCreate(session_id=b.id, from_stage="track"), requested_by="t")
        j3 = crud.create_job(db, job_in=JobCreate(session_id=bb.id), requested_by="t")
    assert w.run_until_idle(timeout_s=300) == 3
    with Session(w.engine) as db:
        r1, r2, r3 = (db.get(Job, j.id) for j in (j1, j2, j3))
    assert r1 is not None and r2 is not None and r3 is not None
    assert r1.status == "done" and {p["status"] for p in r1.progress.values()} == {"ran"}
    assert r1.progress["detect2d"]["metrics"]["detections"] == 3 * 20 * 2
    assert r2.status == "done" and r2.progress["detect2d"]["status"] == "skipped" and r2.progress["track"]["status"] == "ran"
    assert r3.status == "failed" and "calibration.toml" in (r3.error or "")
    m = json.loads((folder / "artifacts" / "track" / "manifest.json").read_text())
    assert m["stage"] == "track"
