"""Fixtures: a real viser server on a free port, the real FastAPI app (tmp SQLite), a token per
role, and a registered test session."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import viser

from tests.webui.fixtures import build_session
from webui.launcher import free_port


@pytest.fixture
def server() -> Iterator[viser.ViserServer]:
    """A viser server on a free local port, stopped after the test."""
    s = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    yield s
    s.stop()


@dataclass
class ApiEnv:
    app: object
    settings: object
    client: object  # fastapi TestClient
    tokens: dict[str, str]
    session_id: str
    session_dir: Path


@pytest.fixture
def api_env(tmp_path: Path) -> Iterator[ApiEnv]:
    pytest.importorskip("server.app")
    from fastapi.testclient import TestClient
    from sqlmodel import Session

    from server import crud
    from server.app import create_app
    from server.core.config import Settings
    from server.models import UserCreate

    (tmp_path / "data").mkdir()
    settings = Settings(home=tmp_path / "home", allowed_roots=[tmp_path / "data"], poll_s=0.1, heartbeat_s=0.2)
    app = create_app(settings)
    tokens = {}
    with Session(app.state.engine, expire_on_commit=False) as db:
        for role in ("coach", "annotator", "admin"):
            user = crud.create_user(db, user_in=UserCreate(name=f"{role}1", role=role))
            tokens[role] = crud.issue_token(db, user=user)
    src = build_session(tmp_path / "data", n_frames=12)
    with TestClient(app) as client:
        r = client.post(
            "/api/sessions/from-folder",
            json={"path": str(src), "name": "webui test"},
            headers={"Authorization": f"Bearer {tokens['admin']}"},
        )
        assert r.status_code == 201, r.text
        body = r.json()
        yield ApiEnv(app, settings, client, tokens, str(body["id"]), Path(body["folder"]))


def api_client(env: ApiEnv, role: str):  # noqa: ANN201
    """An ``ApiClient`` talking to the in-process app with ``role``'s token."""
    from fastapi.testclient import TestClient

    from webui.api_client import ApiClient

    return ApiClient("http://testserver/api", env.tokens[role], http=TestClient(env.app))
