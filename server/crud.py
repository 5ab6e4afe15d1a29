"""Database operations (keyword-only, one transaction each unless noted).

Job state changes made by workers are guarded by ``worker_id`` + ``status='running'``
so that a worker that lost its job (declared dead, job re-queued) can never
overwrite the state written by the job's new owner.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any, TypeVar

from sqlalchemy import bindparam, text
from sqlmodel import Session, SQLModel, col, select
from sqlmodel.sql.sqltypes import UTCDateTime

from server.core.security import hash_token, new_token
from server.models import (
    JOB_TERMINAL,
    Annotation,
    ApiToken,
    Bout,
    Identity,
    Job,
    JobCreate,
    User,
    UserCreate,
    utcnow,
)

DEFAULT_IDENTITY_STYLE: tuple[tuple[str, str], ...] = (("#d62728", "red"), ("#1f77b4", "blue"))
OTHER_COLORS: tuple[str, ...] = ("#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22")


# ---------------------------------------------------------------- users
def create_user(session: Session, *, user_in: UserCreate) -> User:
    if session.exec(select(User).where(User.name == user_in.name)).first() is not None:
        raise ValueError(f"user {user_in.name!r} already exists")
    user = User(name=user_in.name, role=user_in.role)
    session.add(user)
    session.commit()
    session.refresh(user)
    return user


def get_user_by_name(session: Session, *, name: str) -> User | None:
    return session.exec(select(User).where(User.name == name)).first()


def list_users(session: Session) -> Sequence[User]:
    return session.exec(select(User).order_by(col(User.id))).all()


def issue_token(session: Session, *, user: User, label: str = "") -> str:
    """Create a new API token for ``user``; the clear token is returned once, only its hash is kept."""
    token = new_token()
    assert user.id is not None
    session.add(ApiToken(user_id=user.id, token_hash=hash_token(token), label=label))
    session.commit()
    return token


def get_user_by_token(session: Session, *, token: str) -> User | None:
    row = session.exec(
        select(User).join(ApiToken, col(ApiToken.user_id) == col(User.id)).where(ApiToken.token_hash == hash_token(token))
    ).first()
    return row


def get_token_owner(session: Session, *, token: str) -> tuple[User, ApiToken] | None:
    """The user of ``token`` and its ``ApiToken`` row (label, creation time); None when unknown."""
    row = session.exec(
        select(User, ApiToken).join(ApiToken, col(ApiToken.user_id) == col(User.id))
        .where(ApiToken.token_hash == hash_token(token))
    ).first()
    return None if row is None else (row[0], row[1])


def revoke_token(session: Session, *, token: str) -> bool:
    """Delete ``token``; True when it existed."""
    row = session.exec(select(ApiToken).where(ApiToken.token_hash == hash_token(token))).first()
    if row is None:
        return False
    session.delete(row)
    session.commit()
    return True


def revoke_tokens(session: Session, *, user: User, label: str) -> int:
    """Delete every token of ``user`` labelled ``label``; returns how many."""
    rows = session.exec(select(ApiToken).where(ApiToken.user_id == user.id, ApiToken.label == label)).all()
    for row in rows:
        session.delete(row)
    session.commit()
    return len(rows)


# ---------------------------------------------------------------- sessions (bouts)
def create_bout(session: Session, *, bout: Bout) -> Bout:
    """Insert a bout and its default identities (one per athlete: Red, Blue, ...)."""
    session.add(bout)
    session.flush()
    assert bout.id is not None
    for pid, name in enumerate(bout.athletes):
        color, corner = DEFAULT_IDENTITY_STYLE[pid] if pid < 2 else (OTHER_COLORS[(pid - 2) % len(OTHER_COLORS)], "")
        session.add(Identity(session_id=bout.id, person_id=pid, name=name, color=color, corner=corner))
    session.commit()
    session.refresh(bout)
    return bout


def get_bout(session: Session, *, bout_id: int) -> Bout | None:
    return session.get(Bout, bout_id)


def list_bouts(session: Session, *, status: str | None = None, limit: int = 1000, offset: int = 0) -> Sequence[Bout]:
    q = select(Bout)
    if status:
        q = q.where(Bout.status == status)
    return session.exec(q.order_by(col(Bout.id)).offset(offset).limit(limit)).all()


RowT = TypeVar("RowT", bound=SQLModel)


def _save_changes(session: Session, row: RowT, changes: dict[str, Any]) -> RowT:
    """Set ``changes`` on ``row``, commit and return it refreshed."""
    for k, v in changes.items():
        setattr(row, k, v)
    session.add(row)
    session.commit()
    session.refresh(row)
    return row


def update_bout(session: Session, *, bout: Bout, changes: dict[str, Any]) -> Bout:
    return _save_changes(session, bout, changes)


def delete_bout(session: Session, *, bout: Bout) -> None:
    session.delete(bout)
    session.commit()


# ---------------------------------------------------------------- identities
def list_identities(session: Session, *, bout_id: int) -> Sequence[Identity]:
    return session.exec(select(Identity).where(Identity.session_id == bout_id).order_by(col(Identity.person_id))).all()


def upsert_identity(session: Session, *, bout_id: int, person_id: int, changes: dict[str, Any]) -> Identity:
    ident = session.exec(select(Identity).where(Identity.session_id == bout_id, Identity.person_id == person_id)).first()
    if ident is None:
        ident = Identity(session_id=bout_id, person_id=person_id, color=OTHER_COLORS[person_id % len(OTHER_COLORS)])
    return _save_changes(session, ident, changes)


# ---------------------------------------------------------------- jobs
def _sync_bout_status(session: Session, *, bout_id: int) -> None:
    """The bout's status is the status of its newest job."""
    latest = session.exec(select(Job.status).where(Job.session_id == bout_id).order_by(col(Job.id).desc())).first()
    bout = session.get(Bout, bout_id)
    if bout is not None and latest is not None and bout.status != latest:
        bout.status = latest
        session.add(bout)


def create_job(session: Session, *, job_in: JobCreate, requested_by: str, reason: str = "", commit: bool = True) -> Job:
    job = Job(**job_in.model_dump(), requested_by=requested_by, reason=reason, status="queued")
    session.add(job)
    session.flush()
    _sync_bout_status(session, bout_id=job_in.session_id)
    if commit:
        session.commit()
        session.refresh(job)
    return job


def get_job(session: Session, *, job_id: int) -> Job | None:
    return session.get(Job, job_id)


def list_jobs(
    session: Session, *, session_id: int | None = None, status: str | None = None, limit: int = 1000, offset: int = 0
) -> Sequence[Job]:
    q = select(Job)
    if session_id is not None:
        q = q.where(Job.session_id == session_id)
    if status:
        q = q.where(Job.status == status)
    return session.exec(q.order_by(col(Job.id)).offset(offset).limit(limit)).all()


def cancel_job(session: Session, *, job: Job) -> Job:
    """Cancel a queued job now; ask the worker of a running job to stop it.

    ``ValueError`` when the job already finished.
    """
    if job.status in JOB_TERMINAL:
        raise ValueError(f"job {job.id} is already {job.status}")
    # One UPDATE guarded by status, so a concurrent claim cannot slip in between.
    now = utcnow()
    res = session.execute(
        text(
            "UPDATE job SET status = CASE WHEN status='queued' THEN 'cancelled' ELSE status END, "
            "finished_at = CASE WHEN status='queued' THEN :now ELSE finished_at END, "
            "cancel_requested = 1 WHERE id = :id AND status IN ('queued', 'running')"
        ).bindparams(bindparam("now", type_=UTCDateTime())),
        {"now": now, "id": job.id},
    )
    if res.rowcount == 0:  # type: ignore[attr-defined]
        session.rollback()
        raise ValueError(f"job {job.id} finished before it could be cancelled")
    _sync_bout_status(session, bout_id=job.session_id)
    session.commit()
    session.refresh(job)
    return job


def claim_job(session: Session, *, worker_id: str) -> Job | None:
    """Atomically take the oldest queued job whose session has no running job."""
    now = utcnow()
    row = session.execute(
        text(
            "UPDATE job SET status='running', worker_id=:w, heartbeat_unix_s=:hb, "
            "started_at=COALESCE(started_at, :now), attempts=attempts+1 "
            "WHERE id = (SELECT id FROM job WHERE status='queued' AND cancel_requested=0 AND session_id NOT IN "
            "(SELECT session_id FROM job WHERE status='running') ORDER BY id LIMIT 1) AND status='queued' "
            "RETURNING id"
        ).bindparams(bindparam("now", type_=UTCDateTime())),
        {"w": worker_id, "hb": time.time(), "now": now},
    ).first()
    if row is None:
        session.rollback()
        return None
    job = session.get(Job, int(row[0]))
    assert job is not None
    session.refresh(job)
    _sync_bout_status(session, bout_id=job.session_id)
    session.commit()
    session.refresh(job)
    return job


def heartbeat(session: Session, *, job_id: int, worker_id: str) -> tuple[bool, bool]:
    """Refresh a running job's heartbeat. Returns ``(still_owned, cancel_requested)``."""
    res = session.execute(
        text("UPDATE job SET heartbeat_unix_s=:hb WHERE id=:id AND worker_id=:w AND status='running' RETURNING cancel_requested"),
        {"hb": time.time(), "id": job_id, "w": worker_id},
    ).first()
    session.commit()
    if res is None:
        return False, False
    return True, bool(res[0])


def update_job_running(session: Session, *, job_id: int, worker_id: str, changes: dict[str, Any]) -> bool:
    """Write progress/log fields of a job this worker still owns; False if it lost the job."""
    job = session.get(Job, job_id)
    if job is None or job.worker_id != worker_id or job.status != "running":
        session.rollback()
        return False
    for k, v in changes.items():
        setattr(job, k, v)
    job.heartbeat_unix_s = time.time()
    session.add(job)
    session.commit()
    return True


def finish_job(
    session: Session, *, job_id: int, worker_id: str, status: str, changes: dict[str, Any] | None = None
) -> bool:
    if status not in JOB_TERMINAL:
        raise ValueError(f"finish_job: status must be one of {JOB_TERMINAL}, got {status!r}")
    job = session.get(Job, job_id)
    if job is None or job.worker_id != worker_id or job.status != "running":
        session.rollback()
        return False
    for k, v in (changes or {}).items():
        setattr(job, k, v)
    job.status = status
    job.finished_at = utcnow()
    job.current_stage = None
    session.add(job)
    session.flush()
    _sync_bout_status(session, bout_id=job.session_id)
    session.commit()
    return True


def release_job(session: Session, *, job_id: int, worker_id: str, changes: dict[str, Any]) -> bool:
    """Give a running job back to the queue (its worker is shutting down)."""
    job = session.get(Job, job_id)
    if job is None or job.worker_id != worker_id or job.status != "running":
        session.rollback()
        return False
    for k, v in changes.items():
        setattr(job, k, v)
    job.status, job.worker_id, job.current_stage = "queued", None, None
    session.add(job)
    session.flush()
    _sync_bout_status(session, bout_id=job.session_id)
    session.commit()
    return True


def requeue_lost_jobs(session: Session, *, timeout_s: float, max_attempts: int, except_worker: str | None = None) -> list[int]:
    """Running jobs whose heartbeat is older than ``timeout_s``: re-queue them (or fail them
    after ``max_attempts`` claims). Jobs of ``except_worker`` (the caller, alive) are left alone.
    Returns the ids of the jobs touched."""
    cutoff = time.time() - timeout_s
    q = select(Job).where(Job.status == "running", col(Job.heartbeat_unix_s) < cutoff)
    if except_worker is not None:
        q = q.where(col(Job.worker_id) != except_worker)
    lost = session.exec(q).all()
    touched = []
    for job in lost:
        note = f"[server] worker {job.worker_id} stopped sending heartbeats; "
        if job.cancel_requested:
            job.status, job.finished_at = "cancelled", utcnow()
            note += "job cancelled"
        elif job.attempts >= max_attempts:
            job.status, job.finished_at = "failed", utcnow()
            job.error = f"the job's worker died {job.attempts} times (last: {job.worker_id}); giving up"
            note += "giving up"
        else:
            job.status = "queued"
            note += "re-queued (resumes from the last complete stage)"
        job.worker_id = None
        job.current_stage = None
        job.log_tail = (job.log_tail + "\n" + note).strip()
        session.add(job)
        session.flush()
        _sync_bout_status(session, bout_id=job.session_id)
        assert job.id is not None
        touched.append(job.id)
    session.commit()
    return touched


# ---------------------------------------------------------------- annotations
def list_annotations(session: Session, *, bout_id: int, include_superseded: bool = False) -> Sequence[Annotation]:
    q = select(Annotation).where(Annotation.session_id == bout_id)
    if not include_superseded:
        q = q.where(col(Annotation.superseded_by).is_(None), Annotation.kind != "undo")
    return session.exec(q.order_by(col(Annotation.id))).all()


def annotation_history(session: Session, *, bout_id: int) -> Sequence[Annotation]:
    """Every annotation row of the session (edits, replaced and undone ones, undo markers), newest first."""
    q = select(Annotation).where(Annotation.session_id == bout_id)
    return session.exec(q.order_by(col(Annotation.id).desc())).all()


def active_payloads(session: Session, *, bout_id: int) -> list[dict[str, Any]]:
    """The edits in force, in the order they were made (what ``annotations.json`` holds)."""
    return [dict(a.payload) for a in list_annotations(session, bout_id=bout_id)]


def get_annotation(session: Session, *, annotation_id: int) -> Annotation | None:
    return session.get(Annotation, annotation_id)


def add_annotation(
    session: Session, *, bout_id: int, payload: dict[str, Any], author: str, supersedes: Annotation | None = None
) -> Annotation:
    """Append an edit; with ``supersedes``, the new row replaces that (active) one."""
    row = Annotation(session_id=bout_id, kind=str(payload["kind"]), payload=payload, author=author)
    session.add(row)
    session.flush()
    if supersedes is not None:
        _supersede(session, old=supersedes, new_id=row.id)
    session.commit()
    session.refresh(row)
    return row


def _supersede(session: Session, *, old: Annotation, new_id: int | None) -> None:
    res = session.execute(
        text("UPDATE annotation SET superseded_by=:new WHERE id=:id AND superseded_by IS NULL"),
        {"new": new_id, "id": old.id},
    )
    if res.rowcount == 0:  # type: ignore[attr-defined]
        session.rollback()
        raise ValueError(f"annotation {old.id} is not active (already undone or replaced)")


def undo_annotation(session: Session, *, annotation: Annotation, author: str) -> Annotation:
    """Revert an active edit: an 'undo' marker row supersedes it. Returns the reverted row."""
    if annotation.kind == "undo":
        raise ValueError(f"annotation {annotation.id} is an undo marker; redo the original edit instead")
    marker = Annotation(
        session_id=annotation.session_id,
        kind="undo",
        payload={"kind": "undo", "target": annotation.id},
        author=author,
        undoes=annotation.id,
    )
    session.add(marker)
    session.flush()
    _supersede(session, old=annotation, new_id=marker.id)
    session.commit()
    session.refresh(annotation)
    return annotation


def redo_annotation(session: Session, *, annotation: Annotation, author: str) -> Annotation:
    """Re-apply an undone edit: a copy is appended and supersedes the undo marker."""
    if annotation.superseded_by is None:
        raise ValueError(f"annotation {annotation.id} is active; nothing to redo")
    marker = session.get(Annotation, annotation.superseded_by)
    if marker is None or marker.kind != "undo" or marker.superseded_by is not None:
        raise ValueError(f"annotation {annotation.id} was replaced by #{annotation.superseded_by}, not undone")
    copy = Annotation(session_id=annotation.session_id, kind=annotation.kind, payload=dict(annotation.payload), author=author)
    session.add(copy)
    session.flush()
    _supersede(session, old=marker, new_id=copy.id)
    session.commit()
    session.refresh(copy)
    return copy
