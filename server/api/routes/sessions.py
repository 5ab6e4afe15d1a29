"""Routes: sessions (bouts): upload, server-side folder, list, get, update, delete, status, identities."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, File, Form, HTTPException, Query, UploadFile, status

from server import crud
from server.api.deps import (
    AdminUser,
    AnnotatorUser,
    CurrentUser,
    SessionDep,
    SettingsDep,
    bout_dir,
    get_bout_or_404,
)
from server.core.config import Settings
from server.models import (
    Bout,
    BoutPublic,
    BoutUpdate,
    FolderSessionCreate,
    IdentityPublic,
    IdentityUpdate,
)
from server.storage import (
    bout_from_meta,
    new_session_dir,
    resolve_allowed,
    safe_filename,
    session_from_folder,
)

log = logging.getLogger(__name__)
router = APIRouter(prefix="/sessions", tags=["sessions"])


def register_folder(db: SessionDep, settings: Settings, src: Path, name: str | None, date: str, auto_rerun: bool,
                    author: str, fps: float | None = None) -> Bout:
    """Create a session from server-side folder ``src`` (already checked against the allowed roots;
    ``fps`` in Hz overrides the frame rate)."""
    dest = new_session_dir(settings)
    try:
        session_from_folder(src, dest, settings, name, fps)
        bout = bout_from_meta(dest, author, date=date, auto_rerun=auto_rerun)
    except BaseException:
        shutil.rmtree(dest, ignore_errors=True)
        raise
    return crud.create_bout(db, bout=bout)


@router.get("", response_model=list[BoutPublic])
def list_sessions(db: SessionDep, _: CurrentUser, status_: Annotated[str | None, Query(alias="status")] = None,
                  limit: int = 1000, offset: int = 0) -> Any:
    return crud.list_bouts(db, status=status_, limit=limit, offset=offset)


def create_uploaded_session(
    db: SessionDep,
    settings: Settings,
    *,
    author: str,
    name: str,
    calibration: UploadFile,
    videos: list[UploadFile],
    keypoints: list[UploadFile],
    tracks: UploadFile | None,
    keypoint_format: str = "openpose",
    fps: float = 0.0,
    athletes: str = "Red,Blue",
    stages: str = "",
    date: str = "",
    auto_rerun: bool = True,
) -> Bout:
    """A new session from uploaded files: they are copied into ``inputs/`` of a new session folder
    and ``session.json`` is written (the upload route and the picker's form). ``ValueError`` for
    unsafe or duplicate file names, no data source besides the calibration, unknown stages or a
    calibration that does not load; nothing is left behind then."""
    from pipeline.schema.session import SessionConfig

    uploads = [("calibration", calibration)] + [("videos", f) for f in videos] + [("keypoints", f) for f in keypoints]
    if tracks is not None:
        uploads.append(("tracks", tracks))
    names = [safe_filename(f.filename, f"uploaded {field} file name") for field, f in uploads]
    if len(set(names)) != len(names):
        raise ValueError(f"uploaded file names must be distinct, got {names}")
    source = "video" if videos else "keypoints" if keypoints else "tracks" if tracks is not None else ""
    if not source:
        raise ValueError("upload needs videos, keypoints or a tracks npz besides the calibration")
    dest = new_session_dir(settings)
    try:
        (dest / "inputs").mkdir()
        for (_field, f), fname in zip(uploads, names, strict=True):
            with open(dest / "inputs" / fname, "wb") as out:
                shutil.copyfileobj(f.file, out, 1 << 20)
        rel = {fname: f"inputs/{fname}" for fname in names}
        cfg = SessionConfig(
            name=name,
            source=source,  # type: ignore[arg-type]
            calibration=rel[names[0]],
            videos={Path(n).stem: rel[n] for n in names[1 : 1 + len(videos)]},
            keypoints={Path(n).stem: rel[n] for n in names[1 + len(videos) : 1 + len(videos) + len(keypoints)]},
            keypoint_format=keypoint_format,  # type: ignore[arg-type]
            tracks=rel[names[-1]] if tracks is not None else "",
            fps=fps,
            athletes=tuple(a.strip() for a in athletes.split(",") if a.strip()),
            stages=tuple(s.strip() for s in stages.split(",") if s.strip()),
            auto_rerun=auto_rerun,
        )
        from pipeline.runner.registry import STAGE_ORDER

        unknown = [s for s in cfg.stages if s not in STAGE_ORDER]
        if unknown:
            raise ValueError(f"unknown stages {unknown}; known: {list(STAGE_ORDER)}")
        cfg.save(dest)
        bout = bout_from_meta(dest, author, name=name, date=date, auto_rerun=auto_rerun)
    except BaseException:
        shutil.rmtree(dest, ignore_errors=True)
        raise
    return crud.create_bout(db, bout=bout)


def remove_session(db: SessionDep, settings: Settings, bout: Bout) -> None:
    """Delete a session, its jobs and annotations, and its folder when the server created it
    (under the sessions folder); 409 while one of its jobs runs."""
    assert bout.id is not None
    if crud.list_jobs(db, session_id=bout.id, status="running"):
        raise HTTPException(status_code=status.HTTP_409_CONFLICT,
                            detail=f"session {bout.id} has a running job; cancel it first")
    folder = bout_dir(bout).resolve()
    crud.delete_bout(db, bout=bout)
    if folder.is_relative_to(settings.sessions_dir.resolve()) and folder.exists():
        shutil.rmtree(folder, ignore_errors=True)


@router.post("", response_model=BoutPublic, status_code=status.HTTP_201_CREATED)
def upload_session(
    db: SessionDep,
    settings: SettingsDep,
    user: AdminUser,
    name: Annotated[str, Form(min_length=1, max_length=200)],
    calibration: Annotated[UploadFile, File(description="Calibration file (TOML, .qca.txt, Campus/Shelf JSON)")],
    videos: Annotated[list[UploadFile] | None, File(description="One video per camera, named <camera>.<ext>")] = None,
    keypoints: Annotated[list[UploadFile] | None, File(description="2D keypoints per camera, named <camera>.json")] = None,
    tracks: Annotated[UploadFile | None, File(description="A Tracks2D npz (synthetic bouts)")] = None,
    keypoint_format: Annotated[str, Form(pattern="^(openpose|coco)$")] = "openpose",
    fps: Annotated[float, Form(ge=0)] = 0.0,
    athletes: Annotated[str, Form(description="Comma-separated athlete names, by person id")] = "Red,Blue",
    stages: Annotated[str, Form(description="Comma-separated stages to run (default: all)")] = "",
    date: Annotated[str, Form(max_length=32)] = "",
    auto_rerun: Annotated[bool, Form()] = True,
) -> Any:
    """Create a session from uploaded files (admin). The request body is limited to
    ``CORNERMAN_MAX_UPLOAD_MB`` (413 beyond). File names must be plain names (no paths)."""
    return create_uploaded_session(
        db, settings, author=user.name, name=name, calibration=calibration, videos=videos or [],
        keypoints=keypoints or [], tracks=tracks, keypoint_format=keypoint_format, fps=fps, athletes=athletes,
        stages=stages, date=date, auto_rerun=auto_rerun,
    )  # fmt: skip


@router.post("/from-folder", response_model=BoutPublic, status_code=status.HTTP_201_CREATED)
def session_from_server_folder(db: SessionDep, settings: SettingsDep, user: AdminUser, body: FolderSessionCreate) -> Any:
    """Create a session from a server-side folder under an allowed root (admin)."""
    src = resolve_allowed(body.path, settings)
    return register_folder(db, settings, src, body.name, body.date, body.auto_rerun, user.name, body.fps)


@router.get("/{session_id}", response_model=BoutPublic)
def get_session(db: SessionDep, _: CurrentUser, session_id: int) -> Any:
    return get_bout_or_404(db, session_id)


@router.patch("/{session_id}", response_model=BoutPublic)
def update_session(db: SessionDep, _: AdminUser, session_id: int, body: BoutUpdate) -> Any:
    bout = get_bout_or_404(db, session_id)
    return crud.update_bout(db, bout=bout, changes=body.model_dump(exclude_unset=True))


@router.delete("/{session_id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_session(db: SessionDep, settings: SettingsDep, _: AdminUser, session_id: int) -> None:
    """Delete a session, its jobs and annotations, and its server folder (409 while a job runs)."""
    remove_session(db, settings, get_bout_or_404(db, session_id))


@router.get("/{session_id}/status")
def session_status(db: SessionDep, _: CurrentUser, session_id: int) -> dict[str, Any]:
    """Stage status: ``fresh``, ``stale`` or ``missing`` for each enabled stage."""
    from pipeline.runner import stage_status

    bout = get_bout_or_404(db, session_id)
    return {"stages": stage_status(bout_dir(bout))}


@router.get("/{session_id}/identities", response_model=list[IdentityPublic])
def list_identities(db: SessionDep, _: CurrentUser, session_id: int) -> Any:
    get_bout_or_404(db, session_id)
    return crud.list_identities(db, bout_id=session_id)


@router.put("/{session_id}/identities/{person_id}", response_model=IdentityPublic)
def put_identity(db: SessionDep, _: AnnotatorUser, session_id: int, person_id: int, body: IdentityUpdate) -> Any:
    """Name, colour and corner of a global person id (annotator+)."""
    if person_id < 0:
        raise HTTPException(status_code=422, detail=f"person_id must be >= 0, got {person_id}")
    get_bout_or_404(db, session_id)
    return crud.upsert_identity(db, bout_id=session_id, person_id=person_id, changes=body.model_dump(exclude_unset=True))
