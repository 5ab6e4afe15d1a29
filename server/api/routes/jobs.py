"""Routes: jobs: submit, list/filter, get, cancel, live progress (Server-Sent Events)."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query, Request, status
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import StreamingResponse
from sqlmodel import Session

from server import crud
from server.api.deps import AnnotatorUser, CurrentUser, SessionDep, SettingsDep, bout_dir, get_bout_or_404
from server.core.security import role_at_least
from server.models import JOB_TERMINAL, Job, JobCreate, JobPublic, User
from server.storage import enabled_stage_names

router = APIRouter(prefix="/jobs", tags=["jobs"])


def validate_stage_range(session_dir: Any, from_stage: str | None, to_stage: str | None) -> None:
    """``ValueError`` unless both stages are enabled in the session and ``from <= to``
    (the runner's own check, ``pipeline.runner.core.stage_range``)."""
    from pipeline.runner.core import stage_range

    stage_range(enabled_stage_names(session_dir), from_stage, to_stage)


def submit_job(db: Session, user: User, job_in: JobCreate, reason: str = "") -> Job:
    bout = get_bout_or_404(db, job_in.session_id)
    validate_stage_range(bout_dir(bout), job_in.from_stage, job_in.to_stage)
    if not role_at_least(user.role, "admin"):
        # Annotators may re-run stale stages and force later stages, never force the 2D stage
        # (``force`` without ``from_stage`` forces every stage).
        first = enabled_stage_names(bout_dir(bout))[0]
        if (job_in.force and job_in.from_stage is None) or job_in.from_stage == first:
            raise HTTPException(status_code=status.HTTP_403_FORBIDDEN,
                                detail=f"annotators may not force a full re-run (force or from_stage={first!r}); ask an admin")
    return crud.create_job(db, job_in=job_in, requested_by=user.name, reason=reason)


@router.post("", response_model=JobPublic, status_code=status.HTTP_201_CREATED)
def create_job(db: SessionDep, user: AnnotatorUser, job_in: JobCreate) -> Any:
    """Queue a run of a session's stages (stale/missing ones; ``from_stage`` on are forced)."""
    return submit_job(db, user, job_in, reason="submitted")


@router.get("", response_model=list[JobPublic])
def list_jobs(
    db: SessionDep,
    _: CurrentUser,
    session_id: int | None = None,
    status_: Annotated[str | None, Query(alias="status", pattern="^(queued|running|done|failed|cancelled)$")] = None,
    limit: Annotated[int, Query(ge=1, le=10000)] = 1000,
    offset: Annotated[int, Query(ge=0)] = 0,
) -> Any:
    return crud.list_jobs(db, session_id=session_id, status=status_, limit=limit, offset=offset)


def _job_or_404(db: Session, job_id: int) -> Job:
    job = crud.get_job(db, job_id=job_id)
    if job is None:
        raise HTTPException(status_code=status.HTTP_404_NOT_FOUND, detail=f"job {job_id} not found")
    return job


@router.get("/{job_id}", response_model=JobPublic)
def get_job(db: SessionDep, _: CurrentUser, job_id: int) -> Any:
    return _job_or_404(db, job_id)


@router.post("/{job_id}/cancel", response_model=JobPublic)
def cancel_job(db: SessionDep, user: AnnotatorUser, job_id: int) -> Any:
    """Cancel a queued job, or stop a running one (its worker kills the stage process)."""
    job = _job_or_404(db, job_id)
    if not role_at_least(user.role, "admin") and job.requested_by != user.name:
        raise HTTPException(status_code=status.HTTP_403_FORBIDDEN, detail="only an admin or the requester may cancel a job")
    try:
        return crud.cancel_job(db, job=job)
    except ValueError as e:
        raise HTTPException(status_code=status.HTTP_409_CONFLICT, detail=str(e)) from e


@router.get("/{job_id}/events")
async def job_events(request: Request, settings: SettingsDep, _: CurrentUser, job_id: int) -> StreamingResponse:
    """Server-Sent Events: ``data: <job json>`` on every change, until the job ends."""
    engine = request.app.state.engine

    def fetch() -> str | None:
        with Session(engine) as db:
            job = crud.get_job(db, job_id=job_id)
            return None if job is None else JobPublic.model_validate(job).model_dump_json()

    first = await run_in_threadpool(fetch)
    if first is None:
        raise HTTPException(status_code=status.HTTP_404_NOT_FOUND, detail=f"job {job_id} not found")

    async def stream() -> AsyncIterator[str]:
        last, idle = "", 0.0
        current: str | None = first
        while current is not None:
            if current != last:
                yield f"data: {current}\n\n"
                last, idle = current, 0.0
                if json.loads(current)["status"] in JOB_TERMINAL:
                    return
            elif idle > 15:
                yield ": keep-alive\n\n"
                idle = 0.0
            if await request.is_disconnected():
                return
            await asyncio.sleep(settings.poll_s)
            idle += settings.poll_s
            current = await run_in_threadpool(fetch)

    return StreamingResponse(stream(), media_type="text/event-stream", headers={"Cache-Control": "no-cache"})
