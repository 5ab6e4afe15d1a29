"""Functions behind ``cornerman serve``, ``cornerman worker`` and ``cornerman user create``.

The typer commands in ``pipeline.cli`` only parse options and call these.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import socket
import threading
import time
from pathlib import Path
from typing import Any

from rich.console import Console
from sqlmodel import Session, select

from server import crud
from server.core.config import Settings
from server.core.security import install_log_redaction
from server.db import init_db, make_engine
from server.models import Bout, JobCreate, UserCreate

log = logging.getLogger(__name__)
DEFAULT_USERS: tuple[tuple[str, str], ...] = (("coach", "coach"), ("annotator", "annotator"), ("admin", "admin"))
"""(user name, role) created on the first start; also the order their tokens are printed in."""
WORKER_NICENESS = 10
"""How far below the server's the job workers' CPU priority is (Unix niceness increment, 0-19):
on a small machine a running pipeline job leaves the API and the pages responsive."""

ROLE_LABELS: dict[str, str] = {
    "coach": "watch bouts (read-only)",
    "annotator": "watch + fix identities and keypoints",
    "admin": "everything, incl. users and re-runs",
}
"""What each role's printed token lets its holder do."""

STARTUP_TIMEOUT_S = 60.0
"""How long ``serve`` waits for the API to answer before it says it did not start."""


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
    from server.storage import bout_from_meta

    demo_session = Path(demo_session).resolve()
    engine = make_engine(settings.db_path)
    init_db(engine)
    with Session(engine, expire_on_commit=False) as db:
        bout = next((b for b in db.exec(select(Bout)).all() if b.created_by == f"demo:{demo_session}"), None)
        if bout is None:
            bout = crud.create_bout(db, bout=bout_from_meta(demo_session, f"demo:{demo_session}"))
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


def _lower_priority(increment: int) -> None:
    """Raise this process's Unix niceness by ``increment`` (0-19); a platform without ``nice``
    or a refusal leaves it as it is, with a warning."""
    if increment <= 0 or not hasattr(os, "nice"):
        return
    try:
        os.nice(increment)
    except OSError as e:
        log.warning("could not lower the job worker's CPU priority: %s", e)


def _worker_entry(home: str, executor: str, ray_address: str | None) -> None:
    _die_with_parent()
    _lower_priority(WORKER_NICENESS)
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


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that nobody listens on right now (the OS picks it)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def check_port(host: str, port: int) -> None:
    """``ValueError`` naming a free alternative when ``host:port`` cannot be bound (another
    server listens there, or the address is not this machine's); run before any work."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as e:
        raise ValueError(f"--host {host}: not an address of this machine ({e})") from e
    family, _, _, _, addr = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn does: TIME_WAIT is not "busy"
        try:
            s.bind(addr)
        except OSError as e:
            raise ValueError(
                f"cannot serve on {host}:{port}: {e.strerror or e} (another `cornerman serve` or demo running?); "
                f"stop it, or pass --port {free_port(host)} (free now)"
            ) from e


def _local_url(host: str, port: int) -> str:
    """The URL a browser on this machine uses (a wildcard host is reached via loopback)."""
    shown = {"0.0.0.0": "127.0.0.1", "::": "[::1]", "": "127.0.0.1"}.get(host, f"[{host}]" if ":" in host else host)
    return f"http://{shown}:{port}"


def _wait_until_up(server: Any, base: str, timeout_s: float) -> bool:
    """True once uvicorn has started and ``/api/health`` answers 200; False when it gave up."""
    import urllib.error
    import urllib.request

    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end and not server.should_exit:
        if server.started:
            try:
                with urllib.request.urlopen(f"{base}/api/health", timeout=2) as r:
                    if r.status == 200:
                        return True
            except (urllib.error.URLError, OSError):
                pass
        time.sleep(0.1)
    return False


def print_links(console: Console, base: str, tokens: dict[str, str], demo_id: int | None) -> None:
    """The sign-in page, then one line per role (coach first) with its user name and token, the
    demo viewer and the API docs. No link carries a token: a copied link grants nothing."""
    roles = dict(DEFAULT_USERS)
    console.print(f"  {'sign in':<10} {'user name + token below':<40} {base}/login", soft_wrap=True)
    for name, _ in DEFAULT_USERS:
        if name in tokens:
            console.print(f"  {name:<10} {ROLE_LABELS[roles[name]]:<40} token {tokens[name]}", soft_wrap=True)
    if not tokens:
        console.print("  tokens: existing users were kept; `cornerman serve --print-tokens` issues new ones, "
                      "`cornerman user create NAME --role coach` adds a user", soft_wrap=True)
    if demo_id is not None:
        console.print(f"  {'demo bout':<10} {f'session {demo_id} (after signing in)':<40} {base}/viewer/{demo_id}/",
                      soft_wrap=True)
    console.print(f"  {'API docs':<10} {'':<40} {base}/docs", soft_wrap=True)


def _announce(server: Any, settings: Settings, base: str, fresh_tokens: bool, demo_id: int | None,
              n_workers: int) -> None:
    """Issue the tokens and print the links once the API answers (never for a server that
    did not start)."""
    console = Console()
    if not _wait_until_up(server, base, STARTUP_TIMEOUT_S):
        if not server.should_exit:
            console.print(f"[yellow]the API at {base} did not answer within {STARTUP_TIMEOUT_S:.0f} s[/]")
        return
    tokens = _default_tokens(settings, fresh_tokens)
    console.print(f"[bold]cornerman server ready[/] at {base} (home {settings.home.resolve()}, "
                  f"{n_workers} worker(s))", soft_wrap=True)
    print_links(console, base, tokens, demo_id)


def serve(host: str = "127.0.0.1", port: int = 8000, workers: int = 1, home: Path | None = None,
          demo_session: Path | None = None, open_tokens_print: bool = False) -> None:
    """Run the API (uvicorn) plus ``workers`` worker processes until interrupted.

    Checks the port first (``ValueError`` naming a free one when it is taken). Once the API
    answers, prints the sign-in link and, on the first start (or with ``open_tokens_print``),
    fresh tokens for the default users (coach, annotator, admin). ``ValueError`` when
    uvicorn fails to start.
    """
    import uvicorn

    from server.app import create_app

    check_port(host, port)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    settings = _settings(home)
    app = create_app(settings)
    demo_id = register_demo(settings, demo_session) if demo_session is not None else None
    server = uvicorn.Server(uvicorn.Config(app, host=host, port=port, log_level="info"))
    install_log_redaction()  # again after uvicorn's logging set-up: its access log never shows a token
    procs = start_workers(settings, workers)
    log.info("workers started (pids %s)", [p.pid for p in procs])
    threading.Thread(
        target=_announce, args=(server, settings, _local_url(host, port), open_tokens_print, demo_id, len(procs)),
        name="cornerman-announce", daemon=True,
    ).start()
    try:
        server.run()
    except SystemExit as e:  # uvicorn exits with 3 when it cannot bind or start the app
        raise ValueError(f"the API server did not start on {host}:{port} (uvicorn exit code {e.code}; "
                         "see the log above)") from e
    except KeyboardInterrupt:  # Ctrl-C: uvicorn has shut down; stop the workers below, no traceback
        log.info("stopped by Ctrl-C")
    finally:
        server.should_exit = True
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
