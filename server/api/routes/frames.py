"""Routes: what the annotate page draws: a session's cameras and timeline, one camera frame as
JPEG, and the 2D detections of one camera at one frame (``server.annotate_data``).

Any signed-in user may read them (bearer token or the login cookie). An unknown camera is 404
and a frame outside the bout 422, each with the reason; a session whose artifacts or
calibration cannot be read is 409.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Query, Request, Response, status

from server import crud
from server.annotate_data import AnnotateCache, SessionView, detections_at, palette_for, session_info
from server.api.deps import CurrentUser, SessionDep, bout_dir, get_bout_or_404
from server.core.security import role_at_least

router = APIRouter(tags=["annotate"])

MAX_WIDTH_DEFAULT_PX = 1280
"""Default display width of a served frame (px); frames are never upscaled."""


def get_cache(request: Request) -> AnnotateCache:
    """The app's ``AnnotateCache`` (created on first use, one per app)."""
    cache = getattr(request.app.state, "annotate_cache", None)
    if cache is None:
        cache = request.app.state.annotate_cache = AnnotateCache()
    return cache  # type: ignore[no-any-return]


CacheDep = Annotated[AnnotateCache, Depends(get_cache)]


def _session_view(db: SessionDep, cache: AnnotateCache, session_id: int) -> tuple[SessionView, list[tuple[int, str, str]]]:
    bout = get_bout_or_404(db, session_id)
    idents = [(i.person_id, i.name, i.color) for i in crud.list_identities(db, bout_id=session_id)]
    try:
        return cache.view(bout_dir(bout)), idents
    except (OSError, ValueError) as e:
        raise HTTPException(status_code=status.HTTP_409_CONFLICT, detail=f"session {session_id} cannot be read: {e}") from e


def _http(e: Exception) -> HTTPException:
    if isinstance(e, LookupError):
        return HTTPException(status_code=status.HTTP_404_NOT_FOUND, detail=str(e))
    return HTTPException(status_code=status.HTTP_422_UNPROCESSABLE_CONTENT, detail=str(e))


@router.get("/sessions/{session_id}/frames")
def frames_info(db: SessionDep, user: CurrentUser, cache: CacheDep, session_id: int) -> dict[str, Any]:
    """Cameras (name, image size px, ``video``: a real video backs it, else the rendered stand-in),
    ``n_frames``, ``fps``, the persons (id, name, colour), the detections' joints and bones, whether
    the track and associate stages have run, and whether this user may edit (``can_edit``)."""
    sv, idents = _session_view(db, cache, session_id)
    out = session_info(sv, palette_for(sv.data, idents), [p for p, _, _ in idents])
    out.update(user=user.name, role=user.role, can_edit=role_at_least(user.role, "annotator"))
    return out


@router.get("/sessions/{session_id}/frames/{view}/{frame}.jpg", response_class=Response,
            responses={200: {"content": {"image/jpeg": {}}}})
def frame_jpeg(
    db: SessionDep,
    _: CurrentUser,
    cache: CacheDep,
    session_id: int,
    view: str,
    frame: int,
    max_width: Annotated[int, Query(ge=64, le=4096, description="largest width of the image (px)")] = MAX_WIDTH_DEFAULT_PX,
) -> Response:
    """Frame ``frame`` of camera ``view`` as JPEG, at most ``max_width`` px wide: the video's frame,
    or for cameras without a video the stand-in the viewer shows (floor grid and ring)."""
    sv, _ids = _session_view(db, cache, session_id)
    try:
        body = cache.jpeg(sv.folder, view, frame, max_width)
    except (LookupError, ValueError) as e:
        raise _http(e) from e
    return Response(body, media_type="image/jpeg", headers={"Cache-Control": "private, max-age=60"})


@router.get("/sessions/{session_id}/detections")
def detections(
    db: SessionDep,
    _: CurrentUser,
    cache: CacheDep,
    session_id: int,
    view: Annotated[str, Query(description="camera name")],
    frame: Annotated[int, Query(description="frame index")],
) -> dict[str, Any]:
    """The detections of camera ``view`` at ``frame`` as the last track and associate runs left
    them: track id and span, person, name, colour, confidence, box and keypoints (px of the full
    image); an empty list before the track stage has run."""
    sv, idents = _session_view(db, cache, session_id)
    try:
        return detections_at(sv, view, frame, palette_for(sv.data, idents))
    except (LookupError, ValueError) as e:
        raise _http(e) from e
