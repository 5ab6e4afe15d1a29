"""HTML page: the annotate page of a session (``GET /sessions/{id}/annotate``), CVAT-style review
of the 2D identities: one large camera image with its detections, click to select, hotkeys, every
identity and track edit, and the edit history with undo and redo.

The page is ``server/static/annotate/annotate.html`` (filled in here) with one script and one
stylesheet served by the app (``/static/annotate/…``): no build step, nothing fetched from
elsewhere. It reads the JSON of ``frames.py`` and writes through the annotations API with the
login cookie (same origin). Without the cookie the browser is sent to ``/login``. A coach gets
the page without its edit controls (and the API refuses a coach's edits anyway).
"""

from __future__ import annotations

from functools import cache
from html import escape
from pathlib import Path
from string import Template
from typing import Any
from urllib.parse import quote

from fastapi import APIRouter, HTTPException, status
from fastapi.responses import HTMLResponse, RedirectResponse, Response

from server.api.deps import CookieUser, SessionDep, get_bout_or_404
from server.api.routes.viewer import viewer_path
from server.core.security import role_at_least

router = APIRouter(tags=["pages"], include_in_schema=False)

STATIC_DIR = Path(__file__).resolve().parents[2] / "static" / "annotate"
"""The page's files: ``annotate.html`` (a ``string.Template``), ``edit.html`` (the edit controls,
left out for a coach), ``annotate.js`` and ``annotate.css``."""
ASSETS = {"annotate.js": "text/javascript; charset=utf-8", "annotate.css": "text/css; charset=utf-8"}


@cache
def _text(name: str) -> str:
    return (STATIC_DIR / name).read_text(encoding="utf-8")


@router.get("/static/annotate/{name}")
def annotate_asset(name: str) -> Response:
    """The page's script and stylesheet (no session data: served without sign-in)."""
    if name not in ASSETS:
        raise HTTPException(status_code=status.HTTP_404_NOT_FOUND, detail=f"no such file {name!r}; files: {sorted(ASSETS)}")
    return Response(_text(name), media_type=ASSETS[name], headers={"Cache-Control": "no-cache"})


@router.get("/sessions/{session_id}/annotate", response_class=HTMLResponse)
def annotate_page(db: SessionDep, user: CookieUser, session_id: int) -> Any:
    """The annotate page; a coach's copy has no edit controls."""
    if user is None:
        return RedirectResponse(f"/login?next={quote(f'/sessions/{session_id}/annotate')}",
                                status_code=status.HTTP_303_SEE_OTHER)
    bout = get_bout_or_404(db, session_id)
    can_edit = role_at_least(user.role, "annotator")
    html = Template(_text("annotate.html")).substitute(
        session_id=session_id,
        title=escape(bout.name),
        user=escape(user.name),
        role=escape(user.role),
        can_edit="1" if can_edit else "0",
        viewer=viewer_path(session_id),
        edit_controls=_text("edit.html") if can_edit else
        '<p class="readonly" id="readonly">Read-only: a coach reviews the bout; annotators and admins edit it.</p>',
    )
    return HTMLResponse(html, headers={"Cache-Control": "no-store"})
