"""SQLite setup: WAL + foreign keys, schema-version check, atomic claims."""

from __future__ import annotations

from pathlib import Path

import pytest
from sqlalchemy import text
from sqlmodel import Session

from server import crud
from server.db import SCHEMA_VERSION, check_integrity, init_db, make_engine
from server.models import Bout, Job, JobCreate


def test_wal_foreign_keys_and_version(tmp_path: Path) -> None:
    engine = make_engine(tmp_path / "c.db")
    init_db(engine)
    with engine.connect() as conn:
        assert conn.execute(text("PRAGMA journal_mode")).scalar() == "wal"
        assert conn.execute(text("PRAGMA foreign_keys")).scalar() == 1
        assert conn.execute(text("PRAGMA user_version")).scalar() == SCHEMA_VERSION
    init_db(engine)  # idempotent on an existing database
    assert check_integrity(engine)["integrity"] == "ok"


def test_newer_schema_is_refused(tmp_path: Path) -> None:
    engine = make_engine(tmp_path / "c.db")
    init_db(engine)
    with engine.begin() as conn:
        conn.exec_driver_sql(f"PRAGMA user_version={SCHEMA_VERSION + 1}")
    with pytest.raises(ValueError, match="newer than this build"):
        init_db(make_engine(tmp_path / "c.db"))


def test_delete_session_cascades(tmp_path: Path) -> None:
    engine = make_engine(tmp_path / "c.db")
    init_db(engine)
    with Session(engine, expire_on_commit=False) as db:
        b = crud.create_bout(db, bout=Bout(name="b", folder=str(tmp_path), athletes=["Red", "Blue"]))
        assert b.id is not None
        crud.create_job(db, job_in=JobCreate(session_id=b.id), requested_by="t")
        crud.add_annotation(db, bout_id=b.id, payload={"kind": "swap_identities", "frame": 3, "person_a": 0,
                                                        "person_b": 1, "view": ""}, author="t")
        assert len(crud.list_identities(db, bout_id=b.id)) == 2
        crud.delete_bout(db, bout=b)
        for table in ("job", "annotation", "identity"):
            assert db.execute(text(f"SELECT count(*) FROM {table}")).scalar() == 0, table
    assert check_integrity(engine)["foreign_key_violations"] == 0


def test_claims_are_exclusive_and_one_job_per_session(tmp_path: Path) -> None:
    engine = make_engine(tmp_path / "c.db")
    init_db(engine)
    with Session(engine, expire_on_commit=False) as db:
        b1 = crud.create_bout(db, bout=Bout(name="b1", folder=str(tmp_path)))
        b2 = crud.create_bout(db, bout=Bout(name="b2", folder=str(tmp_path)))
        assert b1.id and b2.id
        j1 = crud.create_job(db, job_in=JobCreate(session_id=b1.id), requested_by="t")
        j2 = crud.create_job(db, job_in=JobCreate(session_id=b1.id), requested_by="t")
        j3 = crud.create_job(db, job_in=JobCreate(session_id=b2.id), requested_by="t")
        a = crud.claim_job(db, worker_id="w1")
        b = crud.claim_job(db, worker_id="w2")
        c = crud.claim_job(db, worker_id="w3")
        assert a is not None and b is not None
        assert (a.id, b.id) == (j1.id, j3.id)  # j2 waits: its session already has a running job
        assert c is None
        assert crud.finish_job(db, job_id=a.id, worker_id="w1", status="done")  # type: ignore[arg-type]
        assert not crud.finish_job(db, job_id=b.id, worker_id="w1", status="done")  # type: ignore[arg-type]  (not its job)
        d = crud.claim_job(db, worker_id="w3")
        assert d is not None and d.id == j2.id


def test_lost_job_is_requeued_then_failed_after_max_attempts(tmp_path: Path) -> None:
    engine = make_engine(tmp_path / "c.db")
    init_db(engine)
    with Session(engine, expire_on_commit=False) as db:
        bout = crud.create_bout(db, bout=Bout(name="b", folder=str(tmp_path)))
        assert bout.id is not None
        job = crud.create_job(db, job_in=JobCreate(session_id=bout.id), requested_by="t")
        for attempt in (1, 2):
            claimed = crud.claim_job(db, worker_id=f"w{attempt}")
            assert claimed is not None and claimed.attempts == attempt
            assert crud.requeue_lost_jobs(db, timeout_s=60, max_attempts=2) == []  # heartbeat is fresh
            db.execute(text("UPDATE job SET heartbeat_unix_s = 0"))
            db.commit()
            assert crud.requeue_lost_jobs(db, timeout_s=60, max_attempts=2) == [job.id]
        final = db.get(Job, job.id)
        assert final is not None
        db.refresh(final)
        assert final.status == "failed" and "died 2 times" in (final.error or "")


def _v1_database(path: Path, folders: list[Path]) -> None:
    """A database as a v1 server left it, one session row per folder."""
    engine = make_engine(path)
    init_db(engine)
    with Session(engine) as db:
        for folder in folders:
            crud.create_bout(db, bout=Bout(name=folder.name, folder=str(folder)))
    with engine.begin() as conn:
        conn.exec_driver_sql("ALTER TABLE session DROP COLUMN layout_advice")
        conn.exec_driver_sql("PRAGMA user_version=1")
    engine.dispose()


def test_servers_starting_together_upgrade_a_v1_database_once(tmp_path: Path) -> None:
    import threading

    _v1_database(tmp_path / "c.db", [tmp_path / "a", tmp_path / "b"])
    errors: list[BaseException] = []

    def start() -> None:
        try:
            init_db(make_engine(tmp_path / "c.db"))
        except BaseException as e:  # noqa: BLE001  (reported below)
            errors.append(e)

    threads = [threading.Thread(target=start) for _ in range(4)]  # the API and three workers
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert errors == []
    with make_engine(tmp_path / "c.db").connect() as conn:
        assert conn.execute(text("PRAGMA user_version")).scalar() == SCHEMA_VERSION
        cols = [r[1] for r in conn.execute(text("PRAGMA table_info(session)")).fetchall()]
    assert cols.count("layout_advice") == 1


def test_a_failed_upgrade_leaves_the_v1_database_as_it_was(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from server import db as server_db

    _v1_database(tmp_path / "c.db", [tmp_path / "a"])

    def broken(conn) -> None:  # noqa: ANN001
        server_db._v1_layout_advice(conn)
        raise RuntimeError("disk full")

    monkeypatch.setitem(server_db.MIGRATIONS, 1, broken)
    with pytest.raises(RuntimeError, match="disk full"):
        init_db(make_engine(tmp_path / "c.db"))
    with make_engine(tmp_path / "c.db").connect() as conn:
        assert conn.execute(text("PRAGMA user_version")).scalar() == 1
        assert "layout_advice" not in [r[1] for r in conn.execute(text("PRAGMA table_info(session)")).fetchall()]
    monkeypatch.undo()
    init_db(make_engine(tmp_path / "c.db"))  # a later start upgrades it
    with make_engine(tmp_path / "c.db").connect() as conn:
        assert conn.execute(text("PRAGMA user_version")).scalar() == SCHEMA_VERSION


def test_a_v1_database_is_upgraded_with_each_sessions_layout_advice(tmp_path: Path) -> None:
    from server.demo import make_session

    two = make_session(tmp_path / "two", n_frames=5, n_cameras=2, stages=(), use_synthetic=False)
    three = make_session(tmp_path / "three", n_frames=5, n_cameras=3, stages=(), use_synthetic=False)
    _v1_database(tmp_path / "c.db", [two, three, tmp_path / "gone"])  # one folder gone since
    engine = make_engine(tmp_path / "c.db")
    init_db(engine)
    with engine.connect() as conn:
        assert conn.execute(text("PRAGMA user_version")).scalar() == SCHEMA_VERSION == 2
        rows = dict(conn.execute(text("SELECT name, layout_advice FROM session")).fetchall())
    assert rows["two"].startswith("cam0 and cam1 look ") and "(facing each other)" in rows["two"]
    assert rows["three"] == "" and rows["gone"] == ""
    assert check_integrity(engine)["integrity"] == "ok"
