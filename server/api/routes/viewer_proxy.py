"""The viewer under the app's origin: ``/viewer/{session}/`` proxies the signed-in user's viser process.

viser's web client opens its websocket at its own page URL without the query and the
trailing slash (``getDefaultServerFromUrl`` in viser's ``client/src/App.tsx``), so the page
at ``/viewer/3/`` connects to ``ws(s)://<host>/viewer/3``; both are served here, and the
viser process itself listens on 127.0.0.1 only. Both the page (and its files) and the
websocket need the login cookie: without it the page redirects to ``/login`` (other files
get 401) and the websocket handshake is refused (403). A cross-origin websocket is refused
too. One viewer process serves every user of a session; for each websocket the proxy
mints a token of the signed-in user (``ApiToken`` labelled ``viewer:<session>``), sends it
to the viewer in the ``x-cornerman-viewer-token`` header of its own handshake with viser
(loopback only, never in a URL), and revokes it when the connection ends. The viewer acts
for that client with that token only, so a coach's client cannot edit while an annotator's
client of the same viewer can (``docs/design/viewer-sessions.md``).
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any
from urllib.parse import quote

import httpx
import websockets
from fastapi import APIRouter, HTTPException, Request, WebSocket, WebSocketDisconnect, status
from fastapi.responses import RedirectResponse, Response
from sqlalchemy.engine import Engine
from sqlmodel import Session
from starlette.concurrency import run_in_threadpool
from websockets.asyncio.client import ClientConnection, connect
from websockets.typing import Subprotocol

from server import crud
from server.api.deps import (
    SESSION_COOKIE,
    VIEWER_LABEL_PREFIX,
    CookieUser,
    SessionDep,
    get_bout_or_404,
    same_origin,
    user_of_token,
)
from server.api.routes.viewer import ensure_viewer, local_api_url, viewer_path
from server.models import Bout, User

log = logging.getLogger(__name__)
router = APIRouter(tags=["viewer"], include_in_schema=False)

PASSED_RESPONSE_HEADERS: tuple[str, ...] = ("content-type", "content-encoding", "cache-control", "last-modified", "etag")
"""Headers of viser's HTTP answers that reach the browser (hop-by-hop and length headers do not)."""
WS_MAX_MESSAGE_BYTES = 64 * 1024 * 1024
"""Largest websocket message relayed from the viewer (viser sends images and meshes; its own limit is 50 MiB)."""
POLICY_VIOLATION = 1008
VIEWER_TOKEN_HEADER = "x-cornerman-viewer-token"
"""Handshake header of the proxy's websocket to viser carrying the connection's token (``webui.clients.TOKEN_HEADER``)."""


def _login_redirect(session_id: int) -> RedirectResponse:
    return RedirectResponse("/login?next=" + quote(viewer_path(session_id), safe="/"),
                            status_code=status.HTTP_303_SEE_OTHER)


@router.get("/viewer/{session_id}", include_in_schema=False)
def viewer_no_slash(session_id: int) -> RedirectResponse:
    """viser's client resolves its websocket from the page URL: the page must end with ``/``."""
    return RedirectResponse(viewer_path(session_id), status_code=status.HTTP_308_PERMANENT_REDIRECT)


@router.api_route("/viewer/{session_id}/{path:path}", methods=["GET", "HEAD"])
async def viewer_http(request: Request, db: SessionDep, user: CookieUser, session_id: int, path: str) -> Any:
    """viser's page and files, fetched from the user's viewer (started on the first visit)."""
    if user is None:
        if path in ("", "index.html"):
            return _login_redirect(session_id)
        raise HTTPException(status_code=status.HTTP_401_UNAUTHORIZED, detail="sign in at /login to open the viewer")
    bout = get_bout_or_404(db, session_id)
    port = await run_in_threadpool(ensure_viewer, request.app.state.settings, bout, local_api_url(request))
    url = f"http://127.0.0.1:{port}/{path}"
    headers = {"accept-encoding": request.headers.get("accept-encoding", "identity")}
    async with httpx.AsyncClient(timeout=30.0) as client:
        req = client.build_request(request.method, url, params=request.query_params, headers=headers)
        try:
            upstream = await client.send(req, stream=True)
            try:
                body = b"".join([chunk async for chunk in upstream.aiter_raw()])  # still encoded: passed as is
            finally:
                await upstream.aclose()
        except httpx.HTTPError as e:
            raise HTTPException(status_code=status.HTTP_502_BAD_GATEWAY,
                                detail=f"viewer of session {session_id} did not answer: {e}") from e
    passed = {k: v for k, v in upstream.headers.items() if k.lower() in PASSED_RESPONSE_HEADERS}
    passed["x-content-type-options"] = "nosniff"
    return Response(content=body if request.method == "GET" else b"", status_code=upstream.status_code, headers=passed)


def _mint_connection_token(engine: Engine, user: User, session_id: int) -> str:
    """A token of ``user`` for one viewer connection (revoked by ``_revoke`` when it ends)."""
    with Session(engine, expire_on_commit=False) as db:
        return crud.issue_token(db, user=user, label=f"{VIEWER_LABEL_PREFIX}{session_id}")


def _revoke(engine: Engine, token: str) -> None:
    with Session(engine, expire_on_commit=False) as db:
        crud.revoke_token(db, token=token)


def _ws_user_and_bout(ws: WebSocket, session_id: int) -> tuple[User | None, Bout | None]:
    token = ws.cookies.get(SESSION_COOKIE)
    if not token:
        return None, None
    with Session(ws.app.state.engine, expire_on_commit=False) as db:
        user = user_of_token(db, token, ws.app.state.settings)
        return user, (crud.get_bout(db, bout_id=session_id) if user is not None else None)


@router.websocket("/viewer/{session_id}")
async def viewer_websocket(websocket: WebSocket, session_id: int) -> None:
    """Relay the viser websocket between the browser and the user's viewer, both ways, until either closes."""
    if not same_origin(websocket.headers, websocket.url.scheme):
        await websocket.close(code=POLICY_VIOLATION, reason="cross-origin websocket")
        return
    user, bout = await run_in_threadpool(_ws_user_and_bout, websocket, session_id)
    if user is None or bout is None:  # closing before accept: the handshake gets HTTP 403
        await websocket.close(code=POLICY_VIOLATION, reason="sign in at /login" if user is None else "no such session")
        return
    engine = websocket.app.state.engine
    try:
        port = await run_in_threadpool(ensure_viewer, websocket.app.state.settings, bout, local_api_url(websocket))
    except HTTPException as e:
        log.warning("viewer of session %s for %s unavailable: %s", session_id, user.name, e.detail)
        await websocket.close(code=1011, reason="viewer unavailable")
        return
    offered = [Subprotocol(p) for p in websocket.scope.get("subprotocols", [])]
    token = await run_in_threadpool(_mint_connection_token, engine, user, session_id)
    try:
        upstream_cm = connect(f"ws://127.0.0.1:{port}/", subprotocols=offered or None, max_size=WS_MAX_MESSAGE_BYTES,
                              compression=None, open_timeout=30, additional_headers={VIEWER_TOKEN_HEADER: token})
        async with upstream_cm as upstream:
            await websocket.accept(subprotocol=upstream.subprotocol)
            await _relay(websocket, upstream)
    except (OSError, websockets.exceptions.InvalidHandshake) as e:
        log.warning("viewer of session %s for %s refused the websocket: %s", session_id, user.name, e)
        await websocket.close(code=1011, reason="viewer unavailable")
    finally:
        await run_in_threadpool(_revoke, engine, token)


async def _relay(client: WebSocket, upstream: ClientConnection) -> None:
    async def to_viewer() -> None:
        while True:
            msg = await client.receive()
            if msg["type"] == "websocket.disconnect":
                return
            data = msg.get("bytes")
            await upstream.send(data if data is not None else msg.get("text") or "")

    async def to_browser() -> None:
        async for data in upstream:
            if isinstance(data, bytes):
                await client.send_bytes(data)
            else:
                await client.send_text(data)

    tasks = [asyncio.create_task(to_viewer()), asyncio.create_task(to_browser())]
    try:
        done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        for t in done:
            exc = None if t.cancelled() else t.exception()
            if exc is not None and not isinstance(exc, (websockets.exceptions.ConnectionClosed, WebSocketDisconnect)):
                log.warning("viewer websocket relay stopped: %r", exc)
    finally:
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        await upstream.close()
        try:
            await client.close()
        except (RuntimeError, WebSocketDisconnect):  # the browser has gone already
            pass
