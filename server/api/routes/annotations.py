"""Routes: annotations (append-only typed edits): list, create, replace, undo, redo.

Every change rewrites ``<session>/annotations.json`` with the active edits, which makes
the consuming stage and every later one stale; with ``rerun`` (or the session's
``auto_rerun``) a job is queued that re-runs only the stale stages.
"""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException, status
from sqlmodel import Session, col, select

from server import crud
from server.api.deps import AnnotatorUser, CurrentUser, SessionDep, bout_dir, get_bout_or_404
from server.models import (
    Annotation,
    AnnotationCreate,
    AnnotationHistoryEntry,
    AnnotationPublic,
    AnnotationResult,
    AnnotationState,
    AnnotationUpdate,
    Bout,
    Job,
    JobCreate,
    JobPublic,
    UndoRequest,
    User,
)
from server.storage import session_lock, stale_from, write_annotations_file

router = APIRouter(tags=["annotations"])


def to_public(a: Annotation) -> AnnotationPublic:
    return AnnotationPublic(**a.model_dump(), active=a.superseded_by is None and a.kind != "undo")


def _validated_payload(db: Session, raw: dict[str, Any], bout: Bout) -> dict[str, Any]:
    """The edit as stored; 422 with the reason when it is malformed or refers outside the
    session (frames, cameras, tracks and detections, persons: the athletes, the association's
    and the named identities; ``pipeline.schema.annotation_checks.check_annotation``)."""
    from pipeline.runner.annotation_bounds import annotation_bounds
    from pipeline.schema.annotation_checks import check_annotation
    from pipeline.schema.annotations import annotation_from_dict, annotation_to_dict

    assert bout.id is not None
    named = [i.person_id for i in crud.list_identities(db, bout_id=bout.id)]
    try:
        a = annotation_from_dict(raw)
        check_annotation(a, annotation_bounds(bout_dir(bout), extra_person_ids=named))
    except (TypeError, ValueError) as e:
        raise HTTPException(status_code=422, detail=f"invalid annotation: {e}") from e
    return annotation_to_dict(a)


def _queued_job_covering(db: Session, bout_id: int, stage: str, order: list[str]) -> Job | None:
    """A queued (not started) job of the session that will re-run ``stage`` anyway."""
    for job in db.exec(select(Job).where(Job.session_id == bout_id, Job.status == "queued").order_by(col(Job.id))).all():
        if job.to_stage is not None:
            continue
        if job.from_stage is None or order.index(job.from_stage) <= order.index(stage):
            return job
    return None


def _after_change(db: Session, bout: Bout, kind: str, rerun: bool | None, user: User, row: Annotation,
                  reason: str) -> AnnotationResult:
    """Rewrite annotations.json from the database, then queue the re-run if asked."""
    from pipeline.runner.registry import STAGE_ORDER

    assert bout.id is not None
    folder = bout_dir(bout)
    with session_lock(folder):
        write_annotations_file(folder, crud.active_payloads(db, bout_id=bout.id))
    first = stale_from(folder, kind)
    job = None
    if first is not None and (rerun if rerun is not None else bout.auto_rerun):
        job = _queued_job_covering(db, bout.id, first, list(STAGE_ORDER))
        if job is None:
            job = crud.create_job(db, job_in=JobCreate(session_id=bout.id, from_stage=first), requested_by=user.name,
                                  reason=reason)
    return AnnotationResult(annotation=to_public(row), job=JobPublic.model_validate(job) if job else None,
                            stale_from=first)


def _annotation_or_404(db: Session, annotation_id: int) -> Annotation:
    a = crud.get_annotation(db, annotation_id=annotation_id)
    if a is None:
        raise HTTPException(status_code=status.HTTP_404_NOT_FOUND, detail=f"annotation {annotation_id} not found")
    return a


@router.get("/sessions/{session_id}/annotations", response_model=list[AnnotationPublic])
def list_annotations(db: SessionDep, _: CurrentUser, session_id: int, include_superseded: bool = False) -> Any:
    """Active edits in order; ``include_superseded=true`` gives the full history (undo markers too)."""
    get_bout_or_404(db, session_id)
    return [to_public(a) for a in crud.list_annotations(db, bout_id=session_id, include_superseded=include_superseded)]


def _summary(row: Annotation, by_id: dict[int, Annotation], names: dict[int, str]) -> str:
    from pipeline.schema.annotation_text import describe_annotation
    from pipeline.schema.annotations import annotation_from_dict

    if row.kind == "undo":
        target = by_id.get(row.undoes) if row.undoes is not None else None
        return f"undo of #{row.undoes}" + (f" ({_summary(target, by_id, names)})" if target is not None else "")
    try:
        return describe_annotation(annotation_from_dict(dict(row.payload)), names)
    except (TypeError, ValueError) as e:  # a row stored before a field was renamed: still listed
        return f"{row.kind} (unreadable: {e})"


def history_entries(db: Session, bout_id: int) -> list[AnnotationHistoryEntry]:
    """The session's edit history, newest first, with each edit's state and summary."""
    rows = crud.annotation_history(db, bout_id=bout_id)
    by_id = {r.id: r for r in rows if r.id is not None}
    names = {i.person_id: i.name for i in crud.list_identities(db, bout_id=bout_id)}
    out = []
    for r in rows:
        assert r.id is not None
        nxt = by_id.get(r.superseded_by) if r.superseded_by is not None else None
        state: AnnotationState = "undo" if r.kind == "undo" else "active" if nxt is None else "undone" if nxt.kind == "undo" else "replaced"
        undone = nxt if state == "undone" else None
        out.append(AnnotationHistoryEntry(
            id=r.id, kind=r.kind, payload=r.payload, author=r.author, created_at=r.created_at,
            summary=_summary(r, by_id, names), state=state, active=state == "active", superseded_by=r.superseded_by,
            undoes=r.undoes, undone_by=undone.author if undone else None, undone_at=undone.created_at if undone else None,
        ))  # fmt: skip
    return out


@router.get("/sessions/{session_id}/annotations/history", response_model=list[AnnotationHistoryEntry])
def annotation_history(db: SessionDep, _: CurrentUser, session_id: int) -> Any:
    """Every edit of the session, newest first: author, time, kind, a one-line summary and its state
    (active, undone, replaced, or an undo marker). Any active entry can be undone with
    ``POST /annotations/{id}/undo`` (not only the newest), an undone one re-applied with ``.../redo``."""
    get_bout_or_404(db, session_id)
    return history_entries(db, session_id)


@router.post("/sessions/{session_id}/annotations", response_model=AnnotationResult, status_code=status.HTTP_201_CREATED)
def create_annotation(db: SessionDep, user: AnnotatorUser, session_id: int, body: AnnotationCreate) -> Any:
    bout = get_bout_or_404(db, session_id)
    payload = _validated_payload(db, body.annotation, bout)
    row = crud.add_annotation(db, bout_id=session_id, payload=payload, author=user.name)
    return _after_change(db, bout, payload["kind"], body.rerun, user, row, f"annotation #{row.id}")


@router.get("/annotations/{annotation_id}", response_model=AnnotationPublic)
def get_annotation(db: SessionDep, _: CurrentUser, annotation_id: int) -> Any:
    return to_public(_annotation_or_404(db, annotation_id))


@router.put("/annotations/{annotation_id}", response_model=AnnotationResult)
def replace_annotation(db: SessionDep, user: AnnotatorUser, annotation_id: int, body: AnnotationUpdate) -> Any:
    """Replace an active edit: the new row supersedes it (the old one stays in the history)."""
    old = _annotation_or_404(db, annotation_id)
    bout = get_bout_or_404(db, old.session_id)
    payload = _validated_payload(db, body.annotation, bout)
    try:
        row = crud.add_annotation(db, bout_id=old.session_id, payload=payload, author=user.name, supersedes=old)
    except ValueError as e:
        raise HTTPException(status_code=status.HTTP_409_CONFLICT, detail=str(e)) from e
    # the replaced edit's consumer may come earlier than the new one's
    from pipeline.runner.registry import STAGE_ORDER
    from pipeline.schema.annotations import CONSUMED_BY

    kind = min((old.kind, payload["kind"]), key=lambda k: STAGE_ORDER.index(CONSUMED_BY[k]))
    return _after_change(db, bout, kind, body.rerun, user, row, f"annotation #{row.id} replaces #{old.id}")


def _undo(db: Session, user: User, annotation_id: int, rerun: bool | None) -> AnnotationResult:
    a = _annotation_or_404(db, annotation_id)
    bout = get_bout_or_404(db, a.session_id)
    try:
        row = crud.undo_annotation(db, annotation=a, author=user.name)
    except ValueError as e:
        raise HTTPException(status_code=status.HTTP_409_CONFLICT, detail=str(e)) from e
    return _after_change(db, bout, a.kind, rerun, user, row, f"undo of annotation #{a.id}")


@router.post("/annotations/{annotation_id}/undo", response_model=AnnotationResult)
def undo_annotation(db: SessionDep, user: AnnotatorUser, annotation_id: int, body: UndoRequest | None = None) -> Any:
    """Revert an edit (it stays in the history with ``superseded_by`` set)."""
    return _undo(db, user, annotation_id, body.rerun if body else None)


@router.delete("/annotations/{annotation_id}", response_model=AnnotationResult)
def delete_annotation(db: SessionDep, user: AnnotatorUser, annotation_id: int) -> Any:
    """Same as undo (annotations are append-only: nothing is erased)."""
    return _undo(db, user, annotation_id, None)


@router.post("/annotations/{annotation_id}/redo", response_model=AnnotationResult)
def redo_annotation(db: SessionDep, user: AnnotatorUser, annotation_id: int, body: UndoRequest | None = None) -> Any:
    """Re-apply an undone edit (as a new row at the end of the edit order)."""
    a = _annotation_or_404(db, annotation_id)
    bout = get_bout_or_404(db, a.session_id)
    try:
        row = crud.redo_annotation(db, annotation=a, author=user.name)
    except ValueError as e:
        raise HTTPException(status_code=status.HTTP_409_CONFLICT, detail=str(e)) from e
    return _after_change(db, bout, a.kind, body.rerun if body else None, user, row, f"redo of annotation #{a.id}")
