"""Functions behind ``cornerman serve``, ``cornerman worker`` and ``cornerman user create``.

The typer commands in ``pipeline.cli`` only parse options and call these.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
from pathlib import Path
from typing import Any

from rich.console import Console
from sqlmodel import Session, select

from server import crud
from server.core.config import Settings
from server.db import init_db, make_engine
from server.models import Bout, JobCreate, UserCreate

log = logging.getLogger(__name__)
DEFAULT_USERS: tuple[tuple[str, str], ...] = (("admin", "admin"), ("annotator", "annotator"), ("coach", "coach"))


def _settings(home: Path | None, export: bool = True) -> Settings:
    if home is None:
        return Settings()
    if export:
        os.environ["CORNERMAN_HOME"] = str(Path(home).resolve())  # worker processes inherit it
    return Settings(home=Path(home).resolve())


def create_user(name: str, role: str, home: Path | None = None) -> str:
    """Create user ``name`` with ``role`` (coach, annotator, admin) if needed and return a new API token."""
    settings = _settings(home, export=False)
    engine = make_engine(settings.db_path)
    init_db(engine)
    with Session(engine, expire_on_commit=False) as db:
        user = crud.get_user_by_name(db, name=name)
        if user is None:
            user = crud.create_user(db, user_in=UserCreate(name=name, role=role))  # type: ignore[arg-type]
        elif user.role != role:
            raise ValueError(f"user {name!r} exists with role {user.role!r}, not {role!r}")
        return crud.issue_token(db, user=user, label="cli")


def _default_tokens(settings: Settings, fresh: bool) -> dict[str, str]:
    """Tokens to print at start-up: new ones for the default users when the database has no
    users yet, or when ``fresh`` (``--print-tokens``)."""
    engine = make_engine(settings.db_path)
    init_db(engine)
    out: dict[str, str] = {}
    with Session(engine, expire_on_commit=False) as db:
        first_run = not crud.list_users(db)
        if not (first_run or fresh):
            return out
        for name, role in DEFAULT_USERS:
            user = crud.get_user_by_name(db, name=name)
            if user is None:
                user = crud.create_user(db, user_in=UserCreate(name=name, role=role))  # type: ignore[arg-type]
            out[name] = crud.issue_token(db, user=user, label="serve")
    return out


def register_demo(settings: Settings, demo_session: Path) -> int:
    """Register the demo session folder in place (once); queue a job only if a stage is not fresh.

    ``cornerman demo`` has already run the pipeline there, so copying the folder would
    only make the worker compute everything again.
    """
    from pipeline.runner import stage_status
    from server.storage import session_meta

    demo_session = Path(demo_session).resolve()
    engine = make_engine(settings.db_path)
    init_db(engine)
    with Session(engine, expire_on_commit=False) as db:
        bout = next((b for b in db.exec(select(Bout)).all() if b.created_by == f"demo:{demo_session}"), None)
        if bout is None:
            meta = session_meta(demo_session)
            bout = crud.create_bout(db, bout=Bout(name=meta["name"], folder=str(demo_session), n_cameras=meta["n_cameras"],
                                                  cameras=meta["cameras"], fps=meta["fps"], athletes=meta["athletes"],
                                                  auto_rerun=meta["auto_rerun"], created_by=f"demo:{demo_session}"))
        assert bout.id is not None
        if any(st != "fresh" for st in stage_status(demo_session).values()):
            crud.create_job(db, job_in=JobCreate(session_id=bout.id), requested_by="serve", reason="demo session")
        return bout.id


def _die_with_parent() -> None:
    """Linux: get SIGTERM when the ``serve`` process dies, even by a signal that skips its cleanup
    (uvicorn re-raises SIGTERM after shutdown, so ``serve``'s ``finally`` does not run)."""
    try:
        import ctypes
        import signal

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        PR_SET_PDEATHSIG = 1
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):
        log.debug("PR_SET_PDEATHSIG unavailable; workers outlive a killed server")


def _worker_entry(home: str, executor: str, ray_address: str | None) -> None:
    _die_with_parent()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s worker %(name)s: %(message)s")
    os.environ["CORNERMAN_HOME"] = home
    from server.jobs.worker import run_worker

    run_worker(Settings(), executor=executor, ray_address=ray_address)


def start_workers(settings: Settings, n: int, executor: str = "local", ray_address: str | None = None) -> list[Any]:
    ctx = mp.get_context("spawn")
    procs = []
    for i in range(n):
        p = ctx.Process(target=_worker_entry, args=(str(settings.home.resolve()), executor, ray_address),
                        name=f"cornerman-worker-{i}")
        p.start()
        procs.append(p)
    return procs


def serve(host: str = "127.0.0.1", port: int = 8000, workers: int = 1, home: Path | None = None,
          demo_session: Path | None = None, open_tokens_print: bool = False) -> None:
    """Run the API (uvicorn) plus ``workers`` worker processes until interrupted.

    Prints the URLs and, on the first start (or with ``open_tokens_print``), fresh tokens
    for the default users admin / annotator / coach.
    """
    import uvicorn

    from server.app import create_app

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    settings = _settings(home)
    app = create_app(settings)
    tokens = _default_tokens(settings, open_tokens_print)
    demo_id = register_demo(settings, demo_session) if demo_session is not None else None
    console = Console()
    base = f"http://{host}:{port}"
    console.print(f"[bold]cornerman server[/bold] home={settings.home.resolve()}")
    console.print(f"  API      {base}/api   (docs: {base}/docs)")
    for name, tok in tokens.items():
        console.print(f"  {name:<10} token {tok}   picker: {base}/?token={tok}", soft_wrap=True)
    if not tokens:
        console.print("  tokens: existing users kept; `cornerman serve --print-tokens` or `cornerman user create NAME --role ROLE`")
    if demo_id is not None:
        console.print(f"  demo     session id {demo_id}: {base}/?token={tokens.get('annotator', '<annotator token>')}", soft_wrap=True)
    procs = start_workers(settings, workers)
    console.print(f"  workers  {len(procs)} started (pids {[p.pid for p in procs]})")
    try:
        uvicorn.run(app, host=host, port=port, log_level="info")
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            p.join(10)
            if p.is_alive():
                p.kill()


def worker(home: Path | None = None, executor: str = "local", ray_address: str | None = None, concurrency: int = 1) -> None:
    """Run one worker process in the foreground (``cornerman worker``)."""
    from server.jobs.worker import run_worker

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    run_worker(_settings(home), executor=executor, ray_address=ray_address, concurrency=concurrency)
