"""Route: start (or reuse) the interactive viewer of a session (``webui.launcher``).

One viser process per session, on a loopback port, serves every signed-in user; each
websocket the proxy opens to it carries a token minted for that user and that connection
(``viewer_proxy``), so each client's edits carry its user's name and are checked against
its user's role. The browser reaches it only through ``/viewer/{session}/``. A viewer
without clients for ``Settings.viewer_idle_s`` exits and is started again on the next visit.
"""

from __future__ import annotations

import importlib
from typing import Any
from urllib.parse import urlsplit

from fastapi import APIRouter, HTTPException, Request, status
from starlette.requests import HTTPConnection

from server.api.deps import CurrentUser, SessionDep, bout_dir, get_bout_or_404
from server.core.config import Settings
from server.models import Bout

router = APIRouter(tags=["viewer"])


def viewer_path(session_id: int) -> str:
    """The path under which the app serves a session's viewer (trailing slash included)."""
    return f"/viewer/{session_id}/"


def local_api_url(conn: HTTPConnection) -> str:
    """The API's base URL as this machine reaches it: the address the request arrived on."""
    server = conn.scope.get("server")
    if server is None or server[1] is None:
        return str(conn.base_url).rstrip("/") + "/api"
    host, port = server
    host = {"0.0.0.0": "127.0.0.1", "::": "::1", "": "127.0.0.1"}.get(host, host)
    return f"http://{f'[{host}]' if ':' in host else host}:{port}/api"


def ensure_viewer(settings: Settings, bout: Bout, api_url: str) -> int:
    """Loopback port of the viewer of ``bout`` (started when none runs).

    ``HTTPException`` 503 when the viewer is not installed or does not start.
    """
    try:
        launcher = importlib.import_module("webui.launcher")
    except ImportError as e:
        raise HTTPException(status_code=status.HTTP_503_SERVICE_UNAVAILABLE,
                            detail=f"the viewer is not available in this installation (webui.launcher: {e})") from e
    assert bout.id is not None
    try:
        url = launcher.start_viewer(session_id=str(bout.id), session_dir=bout_dir(bout), api_url=api_url,
                                    idle_s=settings.viewer_idle_s)
    except ValueError as e:
        raise HTTPException(status_code=status.HTTP_503_SERVICE_UNAVAILABLE, detail=str(e)) from e
    port = urlsplit(str(url)).port
    if port is None:
        raise HTTPException(status_code=status.HTTP_503_SERVICE_UNAVAILABLE, detail=f"viewer URL without a port: {url}")
    return port


@router.post("/sessions/{session_id}/viewer")
def open_viewer(request: Request, db: SessionDep, user: CurrentUser, session_id: int) -> dict[str, Any]:
    """Start (or reuse) the viewer of this session; returns its URL under this server
    (``/viewer/{id}/``), which a browser opens after signing in at ``/login``."""
    bout = get_bout_or_404(db, session_id)
    ensure_viewer(request.app.state.settings, bout, local_api_url(request))
    return {"url": str(request.base_url).rstrip("/") + viewer_path(session_id)}
