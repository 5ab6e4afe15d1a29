"""Bounded load test of a real server on loopback (``cornerman bench server``).

Starts uvicorn and worker processes on a temporary home, then ``n_submissions`` clients
concurrently create a session (from a server-side folder) and submit a job, while
``n_pollers`` clients poll job lists. It waits for every job to finish and checks:
no job lost, none claimed twice, every job done, one job per session, and SQLite's
integrity and foreign-key checks. ``run_bench`` returns table rows; ``print_table``
shows them.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class ServerProcs:
    """A running server: uvicorn + workers as subprocesses of this process."""

    home: Path
    url: str
    env: dict[str, str]
    api: subprocess.Popen[bytes]
    workers: list[subprocess.Popen[bytes]] = field(default_factory=list)
    log_dir: Path | None = None

    def start_worker(self) -> subprocess.Popen[bytes]:
        assert self.log_dir is not None
        out = open(self.log_dir / f"worker{len(self.workers)}.log", "wb")  # noqa: SIM115  (closed with the process)
        p = subprocess.Popen([sys.executable, "-m", "server.jobs"], env=self.env, stdout=out, stderr=subprocess.STDOUT)
        self.workers.append(p)
        return p

    def stop(self) -> None:
        for p in [*self.workers, self.api]:
            if p.poll() is None:
                p.terminate()
        for p in [*self.workers, self.api]:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(5)


@contextmanager
def running_server(home: Path, n_workers: int = 1, allowed_roots: list[Path] | None = None,
                   extra_env: dict[str, str] | None = None, startup_timeout_s: float = 60.0) -> Iterator[ServerProcs]:
    """Start ``uvicorn`` (one process) and ``n_workers`` worker processes on ``home``."""
    home.mkdir(parents=True, exist_ok=True)
    port = free_port()
    env = dict(os.environ)
    env.update({"CORNERMAN_HOME": str(home), "OMP_NUM_THREADS": "1"})
    if allowed_roots is not None:
        env["CORNERMAN_ALLOWED_ROOTS"] = "[" + ",".join(f'"{p}"' for p in allowed_roots) + "]"
    env.update(extra_env or {})
    log_dir = home / "logs"
    log_dir.mkdir(exist_ok=True)
    api_log = open(log_dir / "api.log", "wb")  # noqa: SIM115
    # Create the database before the processes race to create it.
    from server.core.config import Settings
    from server.db import init_db, make_engine

    init_db(make_engine(Settings(home=home).db_path))
    api = subprocess.Popen(
        [sys.executable, "-m", "uvicorn", "--factory", "server.app:_app_from_env", "--host", "127.0.0.1",
         "--port", str(port), "--log-level", "warning"],
        env=env, stdout=api_log, stderr=subprocess.STDOUT,
    )
    procs = ServerProcs(home=home, url=f"http://127.0.0.1:{port}", env=env, api=api, log_dir=log_dir)
    try:
        t_end = time.monotonic() + startup_timeout_s
        while True:
            if api.poll() is not None:
                raise RuntimeError(f"uvicorn exited with {api.returncode}: {(log_dir / 'api.log').read_text()[-2000:]}")
            try:
                if httpx.get(procs.url + "/api/health", timeout=1.0).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > t_end:
                raise TimeoutError(f"server did not start within {startup_timeout_s} s")
            time.sleep(0.2)
        for _ in range(n_workers):
            procs.start_worker()
        yield procs
    finally:
        procs.stop()
        api_log.close()


def _timed(client: httpx.Client, lat: list[float], lock: threading.Lock, method: str, url: str, **kw: Any) -> httpx.Response:
    t0 = time.perf_counter()
    r = client.request(method, url, **kw)
    dt = time.perf_counter() - t0
    with lock:
        lat.append(dt)
    return r


def run_load(url: str, token: str, bout_path: Path, n_submissions: int = 50, n_pollers: int = 4,
             timeout_s: float = 300.0) -> dict[str, Any]:
    """Submit ``n_submissions`` session+job pairs concurrently and poll until all jobs end."""
    headers = {"Authorization": f"Bearer {token}"}
    lat: list[float] = []
    lock = threading.Lock()
    errors: list[str] = []
    done_submitting = threading.Event()

    def submit(i: int) -> int | None:
        with httpx.Client(base_url=url, headers=headers, timeout=60.0) as c:
            r = _timed(c, lat, lock, "POST", "/api/sessions/from-folder", json={"path": str(bout_path), "name": f"load-{i}"})
            if r.status_code != 201:
                errors.append(f"create session {i}: {r.status_code} {r.text[:200]}")
                return None
            r2 = _timed(c, lat, lock, "POST", "/api/jobs", json={"session_id": r.json()["id"]})
            if r2.status_code != 201:
                errors.append(f"submit job {i}: {r2.status_code} {r2.text[:200]}")
                return None
            return int(r2.json()["id"])

    def poll() -> None:
        with httpx.Client(base_url=url, headers=headers, timeout=60.0) as c:
            while not done_submitting.is_set():
                r = _timed(c, lat, lock, "GET", "/api/jobs", params={"limit": 1000})
                if r.status_code != 200:
                    errors.append(f"poll: {r.status_code}")
                time.sleep(0.05)

    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=n_submissions + n_pollers) as pool:
        pollers = [pool.submit(poll) for _ in range(n_pollers)]
        job_ids = list(pool.map(submit, range(n_submissions)))
        t_submit = time.perf_counter() - t0
        ids = [j for j in job_ids if j is not None]
        # Keep polling (as a UI would) until every submitted job is terminal.
        jobs: dict[int, dict[str, Any]] = {}
        with httpx.Client(base_url=url, headers=headers, timeout=60.0) as c:
            t_end = time.monotonic() + timeout_s
            while time.monotonic() < t_end:
                r = _timed(c, lat, lock, "GET", "/api/jobs", params={"limit": 10000})
                jobs = {j["id"]: j for j in r.json()}
                if all(jobs.get(i, {}).get("status") in ("done", "failed", "cancelled") for i in ids):
                    break
                time.sleep(0.25)
        done_submitting.set()
        for p in pollers:
            p.result()
    wall = time.perf_counter() - t0
    lat_sorted = sorted(lat)
    p95 = lat_sorted[int(0.95 * (len(lat_sorted) - 1))] if lat_sorted else float("nan")
    mine = [jobs[i] for i in ids if i in jobs]
    return {
        "submissions": n_submissions,
        "requests": len(lat),
        "submit_s": round(t_submit, 2),
        "wall_s": round(wall, 2),
        "requests_per_s": round(len(lat) / wall, 1),
        "p50_ms": round(1000 * lat_sorted[len(lat_sorted) // 2], 1) if lat_sorted else float("nan"),
        "p95_ms": round(1000 * p95, 1),
        "jobs_submitted": len(ids),
        "jobs_completed": sum(1 for j in mine if j["status"] == "done"),
        "jobs_failed": sum(1 for j in mine if j["status"] == "failed"),
        "jobs_claimed_twice": sum(1 for j in mine if j["attempts"] > 1),
        "jobs_lost": len(ids) - len(mine),
        "errors": len(errors),
        "first_errors": "; ".join(errors[:3]),
    }


def run_bench(n_submissions: int = 50, n_workers: int = 2, n_pollers: int = 4, n_frames: int = 30,
              timeout_s: float = 300.0, home: Path | None = None) -> list[dict[str, Any]]:
    """Start a server + ``n_workers`` workers on a temporary home, load it, check consistency."""
    from sqlmodel import Session, col, func, select

    from server.cli import create_user
    from server.db import check_integrity, make_engine
    from server.demo import make_session
    from server.models import Bout, Job

    tmp = Path(tempfile.mkdtemp(prefix="cornerman-load-")) if home is None else home
    try:
        bout = make_session(tmp / "data" / "bout", n_frames=n_frames, n_cameras=3, stages=("detect2d", "track"))
        server_home = tmp / "home"
        token = create_user("loadtest", "admin", home=server_home)
        with running_server(server_home, n_workers=n_workers, allowed_roots=[tmp / "data"]) as srv:
            res = run_load(srv.url, token, bout, n_submissions=n_submissions, n_pollers=n_pollers, timeout_s=timeout_s)
        engine = make_engine(server_home / "cornerman.db")
        res.update(check_integrity(engine))
        with Session(engine) as db:
            res["db_sessions"] = int(db.exec(select(func.count()).select_from(Bout)).one())
            res["db_jobs"] = int(db.exec(select(func.count()).select_from(Job)).one())
            per_session = db.exec(select(Job.session_id, func.count()).group_by(col(Job.session_id))).all()
            res["sessions_with_one_job"] = sum(1 for _sid, n in per_session if n == 1)
        res["workers"] = n_workers
        return [res]
    finally:
        if home is None:
            shutil.rmtree(tmp, ignore_errors=True)


def print_table(rows: list[dict[str, Any]]) -> None:
    """One column per run, one line per figure."""
    from rich.console import Console
    from rich.table import Table

    keys = ["submissions", "workers", "requests", "requests_per_s", "p50_ms", "p95_ms", "submit_s", "wall_s",
            "jobs_submitted", "jobs_completed", "jobs_failed", "jobs_claimed_twice", "jobs_lost", "errors",
            "db_sessions", "db_jobs", "sessions_with_one_job", "integrity", "foreign_key_violations", "journal_mode"]
    t = Table(title="cornerman server load test (loopback)")
    t.add_column("figure")
    for i in range(len(rows)):
        t.add_column(f"run {i + 1}", justify="right")
    for k in keys:
        t.add_row(k, *[str(r.get(k, "")) for r in rows])
    Console().print(t)
