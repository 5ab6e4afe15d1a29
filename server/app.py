"""``create_app(settings)``: the FastAPI application (API under ``/api``, sign-in at ``/login``, HTML picker at
``/``, each session's viewer proxied under ``/viewer/{id}/``)."""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request, status
from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from pipeline import __version__
from server.api.main import api_router
from server.api.routes import annotate, frames, login, pages, viewer_proxy
from server.core.config import Settings, get_settings
from server.core.security import install_log_redaction
from server.db import init_db, make_engine
from server.storage import PathNotAllowed

log = logging.getLogger(__name__)


class BodyTooLarge(Exception):
    pass


class BodyLimitMiddleware:
    """413 for request bodies over ``limit`` bytes: by Content-Length up front, and by
    counting the streamed body otherwise (chunked uploads)."""

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app, self.limit = app, limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = dict(scope.get("headers") or [])
        length = headers.get(b"content-length")
        if length is not None and length.isdigit() and int(length) > self.limit:
            await self._reject(send, int(length))
            return
        seen = 0
        exceeded = started = False

        async def counting_receive() -> Message:
            nonlocal seen, exceeded
            msg = await receive()
            if msg["type"] == "http.request":
                seen += len(msg.get("body", b""))
                if seen > self.limit:
                    exceeded = True
                    raise BodyTooLarge()
            return msg

        async def tracking_send(msg: Message) -> None:
            # The body parser may turn our exception into its own 400: answer 413 instead.
            nonlocal started
            if exceeded:
                if msg["type"] == "http.response.start" and not started:
                    started = True
                    await self._reject(send, seen)
                return
            if msg["type"] == "http.response.start":
                started = True
            await send(msg)

        try:
            await self.app(scope, counting_receive, tracking_send)
        except BodyTooLarge:
            if not started:
                started = True
                await self._reject(send, seen)

    async def _reject(self, send: Send, size: int) -> None:
        resp = JSONResponse(
            status_code=status.HTTP_413_CONTENT_TOO_LARGE,
            content={"detail": f"request body of {size} bytes exceeds the upload limit of {self.limit} bytes "
                               "(CORNERMAN_MAX_UPLOAD_MB)"},
        )
        await resp({"type": "http"}, _empty_receive, send)


async def _empty_receive() -> Message:
    return {"type": "http.disconnect"}


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the app; opens (creating if needed) the SQLite database under ``settings.home``."""
    settings = settings or get_settings()
    settings.home.mkdir(parents=True, exist_ok=True)
    settings.sessions_dir.mkdir(parents=True, exist_ok=True)
    engine = make_engine(settings.db_path)
    init_db(engine)
    app = FastAPI(
        title="cornerman",
        version=__version__,
        description="Multi-person 3D motion capture for combat sports: sessions, jobs, identities, annotations, "
        "results. Authenticate with `Authorization: Bearer <token>` (every route except /api/health); browsers "
        "sign in at /login instead (an HttpOnly session cookie). Tokens never go in URLs.",
    )
    app.state.settings = settings
    app.state.engine = engine

    @app.exception_handler(PathNotAllowed)
    async def _forbidden_path(_request: Request, exc: PathNotAllowed) -> JSONResponse:
        return JSONResponse(status_code=status.HTTP_403_FORBIDDEN, content={"detail": str(exc)})

    @app.exception_handler(ValueError)
    async def _bad_value(_request: Request, exc: ValueError) -> JSONResponse:
        # Domain validation errors (malformed session.json, bad stage names, unsafe file names...).
        return JSONResponse(status_code=422, content={"detail": str(exc)})

    app.include_router(api_router, prefix="/api")
    app.include_router(login.router)
    app.include_router(pages.router)
    app.include_router(viewer_proxy.router)
    app.include_router(frames.router, prefix="/api")  # the annotate page's frames and detections
    app.include_router(annotate.router)  # GET /sessions/{id}/annotate and its script and stylesheet
    install_log_redaction()  # uvicorn's access log never shows a token, even from an old ``?token=`` link
    app.add_middleware(BodyLimitMiddleware, limit=settings.max_upload_bytes)
    return app


def _app_from_env() -> Any:
    """Factory for ``uvicorn --factory server.app:_app_from_env`` (settings from ``CORNERMAN_*``)."""
    return create_app(Settings())
