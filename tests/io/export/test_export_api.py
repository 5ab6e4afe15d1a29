"""``GET /api/sessions/{id}/export?format=`` for the csv, trc, c3d and mujoco formats, with the real
FastAPI app (temporary SQLite, an admin token): 200 with the registry's bytes, 404 when the stage
has not run, 422 for an unknown format or bad ``frames``."""

from __future__ import annotations

import io
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from pipeline.io.export import ExportSelection, export_files
from tests.conftest import write_tiny_session
from tests.io.export.export_session import FIRST_FRAME, write_export_artifacts


@pytest.fixture(scope="module")
def api(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[object, dict[str, str], dict[str, str]]]:
    from fastapi.testclient import TestClient
    from sqlmodel import Session

    from server import crud
    from server.app import create_app
    from server.core.config import Settings
    from server.models import UserCreate

    root = tmp_path_factory.mktemp("api")
    write_tiny_session(root / "data" / "bout")
    app = create_app(Settings(home=root / "home", allowed_roots=[root / "data"], poll_s=0.1, heartbeat_s=0.2))
    with Session(app.state.engine, expire_on_commit=False) as db:
        token = crud.issue_token(
            db, user=crud.create_user(db, user_in=UserCreate(name="admin1", role="admin"))
        )
    headers = {"Authorization": f"Bearer {token}"}
    with TestClient(app) as client:
        ids: dict[str, str] = {}
        for name in ("done", "kinematic", "empty"):  # the server copies the inputs, not the artifacts
            r = client.post(
                "/api/sessions/from-folder",
                json={"path": str(root / "data" / "bout"), "name": name},
                headers=headers,
            )
            assert r.status_code == 201, r.text
            ids[name], ids[f"{name}_folder"] = str(r.json()["id"]), r.json()["folder"]
        write_export_artifacts(Path(ids["done_folder"]))
        write_export_artifacts(Path(ids["kinematic_folder"]), physics=False)
        yield client, headers, ids


def _get(api: tuple, session: str, **params: object):  # noqa: ANN202
    client, headers, ids = api
    return client.get(f"/api/sessions/{ids[session]}/export", params=params, headers=headers)


def _registry(api: tuple, session: str, fmt: str, **kw: object) -> dict[str, bytes]:
    folder = Path(api[2][f"{session}_folder"])
    return export_files(ExportSelection(folder, names={0: "Red", 1: "Blue"}, **kw), fmt)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("fmt", "media"), [("csv", "text/csv"), ("trc", "text/plain"), ("c3d", "application/octet-stream")]
)
def test_single_file_formats_are_the_registry_bytes(api: tuple, fmt: str, media: str) -> None:
    r = _get(api, "done", format=fmt)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"].startswith(media)
    assert f'filename="keypoints3d_fit.{fmt}"' in r.headers["content-disposition"]
    assert r.content == _registry(api, "done", fmt)[f"keypoints3d_fit.{fmt}"]
    r = _get(api, "done", format=fmt, athlete=1, frames=f"{FIRST_FRAME + 1}:{FIRST_FRAME + 3}")
    assert r.status_code == 200, r.text
    want = _registry(api, "done", fmt, athletes=(1,), frames=(FIRST_FRAME + 1, FIRST_FRAME + 3))
    assert r.content == want[f"keypoints3d_fit.{fmt}"]
    if fmt == "csv":
        lines = r.text.splitlines()
        assert len(lines) == 1 + 2 * 23 and all(",1,Blue," in ln for ln in lines[1:])


def test_mujoco_is_a_zip_of_the_frames_asked_for(api: tuple) -> None:
    r = _get(api, "done", format="mujoco", frames=f"{FIRST_FRAME + 2}:{FIRST_FRAME + 5}")
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/zip" and ".zip" in r.headers["content-disposition"]
    with zipfile.ZipFile(io.BytesIO(r.content)) as z:
        assert sorted(z.namelist()) == ["motion.npz", "replay.py", "scene.xml"]
        motion = np.load(io.BytesIO(z.read("motion.npz")))
        assert z.read("scene.xml").decode().startswith("<mujoco")
    assert motion["frame_indices"].tolist() == [FIRST_FRAME + 2, FIRST_FRAME + 3, FIRST_FRAME + 4]


def test_a_stage_not_run_is_404(api: tuple) -> None:
    r = _get(api, "kinematic", format="mujoco")
    assert r.status_code == 404 and "physics" in r.json()["detail"]
    for fmt in ("csv", "trc", "c3d"):
        r = _get(api, "empty", format=fmt)
        assert r.status_code == 404 and "no 3D keypoints" in r.json()["detail"], (fmt, r.text)


@pytest.mark.parametrize(
    ("params", "why"),
    [
        ({"format": "xlsx"}, "unknown export format 'xlsx'"),
        ({"format": "csv", "frames": "5"}, "FIRST:STOP"),
        ({"format": "trc", "frames": "9:3"}, "FIRST < STOP"),
        ({"format": "c3d", "frames": "0:10"}, "no frame"),
        ({"format": "mujoco", "frames": "a:b"}, "whole frame numbers"),
        ({"format": "csv", "athlete": 7}, "--athlete [7]"),
    ],
)
def test_bad_format_or_selection_is_422(api: tuple, params: dict, why: str) -> None:
    r = _get(api, "done", **params)
    assert r.status_code == 422 and why in r.json()["detail"], r.text
