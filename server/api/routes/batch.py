"""Route: batch submission of many server-side sessions + jobs at once."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

from fastapi import APIRouter, status

from server import crud
from server.api.deps import AdminUser, SessionDep, SettingsDep
from server.api.routes.jobs import validate_stage_range
from server.models import BatchCreate, BatchResult, Bout, JobCreate
from server.storage import bout_from_meta, new_session_dir, resolve_allowed, session_from_folder

router = APIRouter(tags=["batch"])


@router.post("/batch", response_model=BatchResult, status_code=status.HTTP_201_CREATED)
def batch(db: SessionDep, settings: SettingsDep, user: AdminUser, body: BatchCreate) -> Any:
    """Create one session and one job per server-side folder (admin). All paths are checked
    first; if any is invalid nothing is created."""
    srcs = [resolve_allowed(item.path, settings) for item in body.sessions]
    made: list[Path] = []
    bouts: list[Bout] = []
    try:
        for item, src in zip(body.sessions, srcs, strict=True):
            dest = new_session_dir(settings)
            made.append(dest)
            session_from_folder(src, dest, settings, item.name, item.fps)
            validate_stage_range(dest, body.from_stage, body.to_stage)
            bouts.append(bout_from_meta(dest, user.name))
    except BaseException:
        for d in made:
            shutil.rmtree(d, ignore_errors=True)
        raise
    session_ids, job_ids = [], []
    for bout in bouts:
        b = crud.create_bout(db, bout=bout)
        assert b.id is not None
        job = crud.create_job(db, job_in=JobCreate(session_id=b.id, from_stage=body.from_stage, to_stage=body.to_stage,
                                                   force=body.force), requested_by=user.name, reason="batch")
        session_ids.append(b.id)
        job_ids.append(job.id)
    return BatchResult(sessions=session_ids, jobs=job_ids)  # type: ignore[arg-type]
