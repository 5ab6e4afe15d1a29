"""Database entities as SQLModel families: Base / Create / Update / table / Public.

Tables: ``user``, ``apitoken``, ``session`` (a bout; the Python class is ``Bout`` so
that it does not shadow the database ``Session``), ``identity``, ``job``,
``annotation``. Timestamps are timezone-aware UTC datetimes.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated, Any, Literal

from pydantic import StringConstraints
from sqlalchemy import JSON, Column, UniqueConstraint
from sqlmodel import Field, SQLModel

Role = Literal["coach", "annotator", "admin"]
JobStatus = Literal["queued", "running", "done", "failed", "cancelled"]
JOB_TERMINAL: tuple[str, ...] = ("done", "failed", "cancelled")
Corner = Literal["red", "blue", ""]
NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9._-]*$"
UserName = Annotated[str, StringConstraints(pattern=NAME_PATTERN, min_length=1, max_length=64)]
ColorHex = Annotated[str, StringConstraints(pattern=r"^#[0-9a-fA-F]{6}$")]


def utcnow() -> datetime:
    return datetime.now(UTC)


# ---------------------------------------------------------------- users / tokens
class UserBase(SQLModel):
    name: str = Field(index=True, unique=True, min_length=1, max_length=64)
    role: str = Field(default="coach")


class UserCreate(UserBase):
    name: UserName
    role: Role = "coach"


class UserUpdate(SQLModel):
    role: Role | None = None


class User(UserBase, table=True):
    id: int | None = Field(default=None, primary_key=True)
    created_at: datetime = Field(default_factory=utcnow)


class UserPublic(UserBase):
    id: int
    role: Role
    created_at: datetime


class UserWithToken(UserPublic):
    token: str


class ApiToken(SQLModel, table=True):
    """One API token of a user (only its sha256 is stored)."""

    id: int | None = Field(default=None, primary_key=True)
    user_id: int = Field(foreign_key="user.id", ondelete="CASCADE", index=True)
    token_hash: str = Field(index=True, unique=True)
    label: str = ""
    created_at: datetime = Field(default_factory=utcnow)


# ---------------------------------------------------------------- sessions (bouts)
class BoutBase(SQLModel):
    name: str = Field(min_length=1, max_length=200)
    date: str = Field(default="", max_length=32, description="Bout date (free text, ISO recommended).")
    auto_rerun: bool = Field(default=True, description="Queue a re-run of the stale stages after each annotation.")


class BoutCreate(BoutBase):
    pass


class BoutUpdate(SQLModel):
    name: str | None = Field(default=None, min_length=1, max_length=200)
    date: str | None = Field(default=None, max_length=32)
    auto_rerun: bool | None = None


class Bout(BoutBase, table=True):
    __tablename__ = "session"

    id: int | None = Field(default=None, primary_key=True)
    folder: str = ""
    status: str = Field(default="new", index=True)
    n_cameras: int = 0
    fps: float = 0.0
    cameras: list[str] = Field(default_factory=list, sa_column=Column(JSON, nullable=False))
    athletes: list[str] = Field(default_factory=list, sa_column=Column(JSON, nullable=False))
    created_at: datetime = Field(default_factory=utcnow)
    created_by: str = ""
    layout_advice: str = ""
    """Why the session's cameras see depth poorly and what to change (``pipeline.geometry.layout``);
    "" when two of them are 45-135 deg apart or the calibration could not be read. Set when the
    session is created, and with the cameras and fps again when a job starts on a changed calibration."""


class BoutPublic(BoutBase):
    id: int
    folder: str
    status: str
    n_cameras: int
    fps: float
    cameras: list[str]
    athletes: list[str]
    created_at: datetime
    created_by: str
    layout_advice: str = Field(default="", description="Why the cameras see depth poorly and what to change; '' when fine.")


class FolderSessionCreate(SQLModel):
    path: str = Field(min_length=1, description="Server-side folder under an allowed root.")
    name: str | None = Field(default=None, max_length=200)
    date: str = ""
    auto_rerun: bool = True
    fps: float | None = Field(default=None, gt=0, description="Frame rate in Hz; default: the session.json's, "
                              "else the calibration's, else the videos'.")  # fmt: skip


# ---------------------------------------------------------------- identities
class IdentityBase(SQLModel):
    person_id: int = Field(ge=0)
    name: str = Field(default="", max_length=64)
    color: str = Field(default="#7f7f7f")
    corner: str = ""


class IdentityUpdate(SQLModel):
    name: str | None = Field(default=None, max_length=64)
    color: ColorHex | None = None
    corner: Corner | None = None


class Identity(IdentityBase, table=True):
    __table_args__ = (UniqueConstraint("session_id", "person_id"),)

    id: int | None = Field(default=None, primary_key=True)
    session_id: int = Field(foreign_key="session.id", ondelete="CASCADE", index=True)


class IdentityPublic(IdentityBase):
    corner: Corner


# ---------------------------------------------------------------- jobs
class JobBase(SQLModel):
    session_id: int
    from_stage: str | None = None
    to_stage: str | None = None
    force: bool = False


class JobCreate(JobBase):
    pass


class Job(JobBase, table=True):
    id: int | None = Field(default=None, primary_key=True)
    session_id: int = Field(foreign_key="session.id", ondelete="CASCADE", index=True)
    status: str = Field(default="queued", index=True)
    progress: dict[str, Any] = Field(default_factory=dict, sa_column=Column(JSON, nullable=False))
    current_stage: str | None = None
    log_tail: str = ""
    error: str | None = None
    reason: str = ""
    created_at: datetime = Field(default_factory=utcnow)
    started_at: datetime | None = None
    finished_at: datetime | None = None
    requested_by: str = ""
    worker_id: str | None = None
    heartbeat_unix_s: float | None = None
    attempts: int = 0
    cancel_requested: bool = False


class JobPublic(JobBase):
    id: int
    status: JobStatus
    progress: dict[str, Any]
    current_stage: str | None
    log_tail: str
    error: str | None
    reason: str
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    requested_by: str
    worker_id: str | None
    attempts: int


# ---------------------------------------------------------------- annotations
class AnnotationBase(SQLModel):
    kind: str
    payload: dict[str, Any] = Field(default_factory=dict, sa_column=Column(JSON, nullable=False))


class AnnotationCreate(SQLModel):
    annotation: dict[str, Any] = Field(description="An edit of pipeline.schema.annotations, e.g. "
                                       '{"kind": "swap_identities", "frame": 120, "person_a": 0, "person_b": 1}.')
    rerun: bool | None = Field(default=None, description="Queue a re-run of the stale stages "
                               "(default: the session's auto_rerun).")


class AnnotationUpdate(AnnotationCreate):
    """Replace an annotation: a new row supersedes the old one (append-only)."""


class UndoRequest(SQLModel):
    rerun: bool | None = None


class Annotation(AnnotationBase, table=True):
    id: int | None = Field(default=None, primary_key=True)
    session_id: int = Field(foreign_key="session.id", ondelete="CASCADE", index=True)
    author: str = ""
    created_at: datetime = Field(default_factory=utcnow)
    superseded_by: int | None = Field(default=None, foreign_key="annotation.id")
    undoes: int | None = Field(default=None, description="For an 'undo' marker row: the annotation it reverts.")


class AnnotationPublic(AnnotationBase):
    id: int
    session_id: int
    author: str
    created_at: datetime
    superseded_by: int | None
    undoes: int | None
    active: bool


AnnotationState = Literal["active", "undone", "replaced", "undo"]


class AnnotationHistoryEntry(SQLModel):
    """One row of a session's edit history (``GET /sessions/{id}/annotations/history``)."""

    id: int
    kind: str = Field(description="The edit kind, or 'undo' for the marker row an undo writes.")
    payload: dict[str, Any]
    author: str
    created_at: datetime
    summary: str = Field(description="One line of text: what the edit does, with the persons' names.")
    state: AnnotationState = Field(description="active (in force), undone, replaced (by the edit in "
                                   "superseded_by), or undo (an undo marker row).")
    active: bool
    superseded_by: int | None
    undoes: int | None
    undone_by: str | None = Field(default=None, description="Who undid this edit (state 'undone').")
    undone_at: datetime | None = Field(default=None, description="When this edit was undone (state 'undone').")


class AnnotationResult(SQLModel):
    annotation: AnnotationPublic
    job: JobPublic | None
    stale_from: str | None


class BatchItem(SQLModel):
    path: str = Field(min_length=1)
    name: str | None = None
    fps: float | None = Field(default=None, gt=0, description="Frame rate in Hz; default: the session.json's, "
                              "else the calibration's, else the videos'.")  # fmt: skip


class BatchCreate(SQLModel):
    sessions: list[BatchItem] = Field(min_length=1, max_length=1000)
    from_stage: str | None = None
    to_stage: str | None = None
    force: bool = False


class BatchResult(SQLModel):
    sessions: list[int]
    jobs: list[int]
