import json
from pathlib import Path

import httpx
import pytest

from pipeline.schema.annotations import SwapIdentities
from tests.webui.conftest import ApiEnv, api_client
from webui.api_client import ApiClient, ApiError
from webui.colors import IdentityPalette
from webui.editing import EditHistory


def test_bearer_token_and_error_detail() -> None:
    seen = {}

    def handler(req: httpx.Request) -> httpx.Response:
        seen["auth"] = req.headers.get("authorization")
        seen["url"] = str(req.url)
        return httpx.Response(403, json={"detail": "role coach may not annotate"})

    api = ApiClient("http://x:1", "tok", transport=httpx.MockTransport(handler))
    with pytest.raises(ApiError) as e:
        api.add_annotation("3", {"kind": "swap_identities", "frame": 1, "person_a": 0, "person_b": 1})
    assert e.value.status == 403 and "role coach" in e.value.detail
    assert seen == {"auth": "Bearer tok", "url": "http://x:1/api/sessions/3/annotations"}


def test_connection_error_is_an_api_error() -> None:
    api = ApiClient("http://127.0.0.1:9", "tok", timeout_s=0.5)
    with pytest.raises(ApiError, match="connection failed"):
        api.health()


def test_against_the_real_app(api_env: ApiEnv) -> None:
    ann = api_client(api_env, "annotator")
    assert ann.me()["role"] == "annotator"
    assert ann.find_session_id(api_env.session_dir) == api_env.session_id
    pal = IdentityPalette.from_api(ann.identities(api_env.session_id))
    assert pal.get(0).color_hex == "#d62728" and pal.get(1).color_hex == "#1f77b4"

    hist = EditHistory(ann, api_env.session_id)
    res = hist.submit(SwapIdentities(frame=6, person_a=0, person_b=1, view="cam1"))
    assert res["annotation"]["payload"]["frame"] == 6
    assert res["job"] is not None and res["job"]["session_id"] == int(api_env.session_id)
    # the server (not the viewer) wrote the overlay file
    on_disk = json.loads((Path(api_env.session_dir) / "annotations.json").read_text())
    assert on_disk == [{"kind": "swap_identities", "frame": 6, "person_a": 0, "person_b": 1, "view": "cam1"}]
    assert hist.count() == 1
    hist.undo()
    assert hist.count() == 0
    assert json.loads((Path(api_env.session_dir) / "annotations.json").read_text()) == []
    hist.redo()
    assert hist.count() == 1
    assert hist.redo() is None  # nothing left to redo


def test_roles_are_enforced_by_the_server(api_env: ApiEnv) -> None:
    coach = api_client(api_env, "coach")
    assert coach.me()["role"] == "coach"
    with pytest.raises(ApiError) as e:
        coach.add_annotation(api_env.session_id, {"kind": "swap_identities", "frame": 1, "person_a": 0, "person_b": 1})
    assert e.value.status == 403
    bad = ApiClient("http://testserver/api", "nope", http=__import__("fastapi.testclient").testclient.TestClient(api_env.app))
    with pytest.raises(ApiError) as e2:
        bad.me()
    assert e2.value.status == 401
