"""Server settings: one pydantic-settings class, environment prefix ``CORNERMAN_``.

Every field can be set from the environment, e.g. ``CORNERMAN_HOME=/srv/cornerman``,
``CORNERMAN_ALLOWED_ROOTS='["/data/bouts"]'``, ``CORNERMAN_MAX_UPLOAD_MB=512``.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    """cornerman server settings (defaults live here and nowhere else)."""

    model_config = SettingsConfigDict(env_prefix="CORNERMAN_", extra="ignore")

    home: Path = Path("./data/server")
    """Server state folder: ``cornerman.db`` and ``sessions/<id>/`` live here."""

    allowed_roots: list[Path] = Field(default_factory=lambda: [Path("./data")])
    """Server-side folders that ``POST /api/sessions/from-folder`` and ``/api/batch`` may read.
    Paths outside them (after resolving symlinks and ``..``) are rejected with 403."""

    max_upload_mb: float = 2048.0
    """Largest accepted request body (multipart uploads) in MiB; larger ones get 413."""

    heartbeat_s: float = 1.0
    """How often a worker refreshes the heartbeat of the job it runs."""

    job_timeout_s: float = 15.0
    """A running job whose heartbeat is older than this is considered lost and re-queued."""

    poll_s: float = 0.5
    """How often an idle worker looks for queued jobs (and SSE streams poll the database)."""

    max_attempts: int = 3
    """A job re-queued this many times (its worker died each time) is failed instead."""

    stage_delay_s: float = 0.0
    """Pause before each stage a worker runs (fault-injection tests and demos only)."""

    log_tail_lines: int = 40
    """Lines of job log kept in the database (``Job.log_tail``)."""

    session_max_age_s: float = 12 * 3600.0
    """Lifetime of a browser login (the ``/login`` session cookie) in seconds, > 0; sign in again after it."""

    cookie_secure: bool = False
    """Mark the session cookie ``Secure`` (HTTPS only) even when the request reached the app over plain HTTP
    (set it behind a TLS-terminating proxy). Requests that arrive over HTTPS always get ``Secure``."""

    viewer_idle_s: float = Field(default=600.0, ge=0.0)
    """A session's viewer process with no client for this many seconds exits (0: never); the next
    visit to ``/viewer/{id}/`` starts a new one."""

    @property
    def db_path(self) -> Path:
        return self.home / "cornerman.db"

    @property
    def sessions_dir(self) -> Path:
        return self.home / "sessions"

    @property
    def max_upload_bytes(self) -> int:
        return int(self.max_upload_mb * 1024 * 1024)

    def resolved_roots(self) -> list[Path]:
        """Allowed server-side roots (resolved, symlinks followed)."""
        return [r.expanduser().resolve() for r in self.allowed_roots]


@lru_cache
def get_settings() -> Settings:
    return Settings()
