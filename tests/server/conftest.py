"""Server test fixtures: a real SQLite file under tmp, users per role, a tiny bout folder."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlmodel import Session

from server import crud
from server.app import create_app
from server.core.config import Settings
from server.demo import make_session
from server.models import UserCreate

ROLES = ("coach", "annotator", "admin")


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    (tmp_path / "data").mkdir()
    return Settings(home=tmp_path / "home", allowed_roots=[tmp_path / "data"], heartbeat_s=0.2, job_timeout_s=3.0,
                    poll_s=0.1, max_upload_mb=1.0)


@pytest.fixture
def app(settings: Settings):  # noqa: ANN201
    return create_app(settings)


@pytest.fixture
def client(app) -> Iterator[TestClient]:  # noqa: ANN001
    with TestClient(app) as c:
        yield c


@pytest.fixture
def tokens(app) -> dict[str, str]:  # noqa: ANN001
    out = {}
    with Session(app.state.engine, expire_on_commit=False) as db:
        for role in ROLES:
            user = crud.create_user(db, user_in=UserCreate(name=f"{role}1", role=role))
            out[role] = crud.issue_token(db, user=user)
    return out


def auth(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


@pytest.fixture
def bout_folder(settings: Settings) -> Path:
    """A tiny bout (60 frames, 3 cameras) under the allowed data root."""
    return make_session(settings.allowed_roots[0] / "bout", n_frames=60, n_cameras=3, seed=0, use_synthetic=False)


def run_jobs(settings: Settings, timeout_s: float = 120.0) -> int:
    """Run every queued job with a real worker (in this process; stages in child processes)."""
    from server.jobs.worker import Worker

    return Worker(settings).run_until_idle(timeout_s)


def make_bout(client: TestClient, token: str, path: Path, name: str = "bout") -> dict:
    r = client.post("/api/sessions/from-folder", json={"path": str(path), "name": name}, headers=auth(token))
    assert r.status_code == 201, r.text
    return r.json()
