"""Route: start (or reuse) the interactive viewer of a session (``webui.launcher``)."""

from __future__ import annotations

import importlib
from typing import Any

from fastapi import APIRouter, HTTPException, Request, status

from server.api.deps import CurrentUser, SessionDep, TokenDep, bout_dir, get_bout_or_404

router = APIRouter(tags=["viewer"])


@router.post("/sessions/{session_id}/viewer")
def open_viewer(request: Request, db: SessionDep, user: CurrentUser, token: TokenDep, session_id: int) -> dict[str, Any]:
    """Start a viser viewer process for this session with the caller's token and role; returns its URL."""
    bout = get_bout_or_404(db, session_id)
    try:
        launcher = importlib.import_module("webui.launcher")
    except ImportError as e:
        raise HTTPException(status_code=status.HTTP_503_SERVICE_UNAVAILABLE,
                            detail=f"the viewer is not available in this installation (webui.launcher: {e})") from e
    api_url = str(request.base_url).rstrip("/") + "/api"  # the contract's Base URL
    url = launcher.start_viewer(session_id=str(session_id), session_dir=bout_dir(bout), api_url=api_url, token=token,
                                role=user.role)
    return {"url": str(url)}
