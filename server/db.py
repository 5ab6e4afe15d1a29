"""SQLite engine: WAL journal, foreign keys on, busy timeout, schema-version check.

Migrations: the schema version lives in SQLite's ``PRAGMA user_version``. A new
database is created at ``SCHEMA_VERSION``; an older one is upgraded step by step
through ``MIGRATIONS`` (v1 -> v2: ``session.layout_advice``), and a newer one is
refused with a clear error.

Transactions use the sqlite3 module's default: a write transaction starts at the
first INSERT/UPDATE/DELETE, and plain SELECTs do not hold a read lock, so the API
processes and workers never hit "database is locked" by upgrading a stale read
transaction; writers queue on the 30 s busy timeout instead.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sqlalchemy import event, text
from sqlalchemy.engine import Engine
from sqlmodel import Session, SQLModel, create_engine

from server import models  # noqa: F401  (registers the tables)

log = logging.getLogger(__name__)

SCHEMA_VERSION = 2
"""Version of the tables this build writes (``PRAGMA user_version``)."""


def _v1_layout_advice(conn: Any) -> None:
    """v1 -> v2: sessions get ``layout_advice``, filled in from each folder's calibration (""
    where it cannot be read; ``server.storage.session_meta``)."""
    from server.storage import session_meta

    conn.exec_driver_sql("ALTER TABLE session ADD COLUMN layout_advice VARCHAR NOT NULL DEFAULT ''")
    for sid, folder in conn.exec_driver_sql("SELECT id, folder FROM session").fetchall():
        try:
            advice = session_meta(Path(folder))["layout_advice"] if folder else ""
        except (ValueError, OSError, KeyError, TypeError) as e:  # a missing or broken session.json
            log.warning("session %s: layout advice left empty (%s)", sid, e)
            advice = ""
        if advice:
            conn.exec_driver_sql("UPDATE session SET layout_advice = ? WHERE id = ?", (advice, sid))


MIGRATIONS: dict[int, Callable[[Any], None]] = {1: _v1_layout_advice}
"""Version -> function upgrading a connection from that version to the next."""
BUSY_TIMEOUT_S = 30.0


def _on_connect(dbapi_conn: Any, _record: Any) -> None:
    cur = dbapi_conn.cursor()
    cur.execute("PRAGMA journal_mode=WAL")
    cur.execute("PRAGMA foreign_keys=ON")
    cur.execute("PRAGMA synchronous=NORMAL")
    cur.execute(f"PRAGMA busy_timeout={int(BUSY_TIMEOUT_S * 1000)}")
    cur.close()


def make_engine(db_path: Path) -> Engine:
    """Engine for the SQLite file ``db_path`` (created with its folder if absent)."""
    db_path = Path(db_path)
    db_path.parent.mkdir(parents=True, exist_ok=True)
    engine = create_engine(
        f"sqlite:///{db_path}",
        connect_args={"check_same_thread": False, "timeout": BUSY_TIMEOUT_S},
        pool_size=20,
        max_overflow=40,
    )
    event.listen(engine, "connect", _on_connect)
    return engine


def init_db(engine: Engine) -> None:
    """Create the tables of a new database, or check/upgrade an existing one's version."""
    with engine.connect() as conn:
        version = int(conn.exec_driver_sql("PRAGMA user_version").scalar() or 0)
        has_tables = conn.exec_driver_sql(
            "SELECT count(*) FROM sqlite_master WHERE type='table' AND name='job'"
        ).scalar()
    if version == 0 and not has_tables:
        SQLModel.metadata.create_all(engine)
        with engine.begin() as conn:
            conn.exec_driver_sql(f"PRAGMA user_version={SCHEMA_VERSION}")
        log.info("created database %s (schema v%d)", engine.url.database, SCHEMA_VERSION)
        return
    if version == 0:
        raise ValueError(
            f"{engine.url.database}: has cornerman tables but no schema version; "
            "it was not created by this server (move it away to start fresh)"
        )
    if version > SCHEMA_VERSION:
        raise ValueError(
            f"{engine.url.database}: schema version {version} is newer than this build's {SCHEMA_VERSION}; upgrade cornerman"
        )
    while version < SCHEMA_VERSION:
        step = MIGRATIONS.get(version)
        if step is None:
            raise ValueError(f"{engine.url.database}: no migration from schema version {version}")
        with engine.begin() as conn:
            # One transaction holding the write lock: the API and the workers start together, and
            # only the first to get here upgrades; the others then read the new version and skip.
            conn.exec_driver_sql("BEGIN IMMEDIATE")
            now = int(conn.exec_driver_sql("PRAGMA user_version").scalar() or 0)
            if now == version:
                step(conn)
                conn.exec_driver_sql(f"PRAGMA user_version={version + 1}")
                log.info("upgraded database %s to schema v%d", engine.url.database, version + 1)
        version = max(now, version + 1)
    SQLModel.metadata.create_all(engine)  # no-op for existing tables


def check_integrity(engine: Engine) -> dict[str, Any]:
    """``PRAGMA integrity_check`` + ``foreign_key_check`` (used by the load test)."""
    with engine.connect() as conn:
        integrity = conn.execute(text("PRAGMA integrity_check")).scalar()
        fk_rows = conn.execute(text("PRAGMA foreign_key_check")).fetchall()
        mode = conn.execute(text("PRAGMA journal_mode")).scalar()
    return {"integrity": integrity, "foreign_key_violations": len(fk_rows), "journal_mode": mode}


def get_session(engine: Engine) -> Session:
    return Session(engine, expire_on_commit=False)
