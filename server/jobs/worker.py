"""The worker process: claim queued jobs, supervise their stage process, heartbeat, re-queue lost jobs.

One worker runs up to ``concurrency`` jobs at once, each in an executor process
(``LocalExecutor`` by default). While a job runs, its supervising thread

- writes progress per stage, the current stage and a log tail to the database,
- refreshes the job's heartbeat every ``heartbeat_s``,
- kills the stage process when the job is cancelled or taken away from this worker.

Every worker also re-queues running jobs whose heartbeat is older than
``job_timeout_s`` (their worker died). A re-queued job resumes from the first stage
that did not complete: stages finished before the crash are fresh (their artifacts
were written atomically) and are skipped, even when the job forced them.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
import uuid
from collections import deque
from pathlib import Path
from typing import Any

from sqlalchemy.engine import Engine
from sqlmodel import Session

from server import crud
from server.core.config import Settings
from server.db import init_db, make_engine
from server.jobs.executors import Executor, JobSpec, make_executor
from server.models import Bout, Job
from server.storage import rig_changes

log = logging.getLogger(__name__)

DONE_STATUSES = ("ran", "skipped")


def resume_plan(job: Job, enabled: list[str]) -> tuple[str | None, bool]:
    """``(from_stage, force)`` to run now, given the stages this job already completed.

    A range resumes at its first stage not completed by an earlier attempt, still forced when
    the job is (``force`` applies from ``from_stage`` on), so completed stages are neither
    re-run nor lost.
    """
    if not (job.from_stage or job.force):
        return None, False
    done = {s for s, p in (job.progress or {}).items() if p.get("status") in DONE_STATUSES}
    start = enabled.index(job.from_stage) if job.from_stage in enabled else 0
    end = enabled.index(job.to_stage) + 1 if job.to_stage in enabled else len(enabled)
    forced = enabled[start:end]
    if not done:
        return job.from_stage, job.force
    remaining = [s for s in forced if s not in done]
    if not remaining:
        return None, False
    return remaining[0], job.force


class Worker:
    """Claims and runs jobs from the database at ``settings.db_path``."""

    def __init__(self, settings: Settings, executor: Executor | None = None, concurrency: int = 1,
                 worker_id: str | None = None, engine: Engine | None = None) -> None:
        if concurrency < 1:
            raise ValueError(f"worker concurrency must be >= 1, got {concurrency}")
        self.settings = settings
        self.executor = executor or make_executor("local")
        self.concurrency = concurrency
        self.worker_id = worker_id or f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:6]}"
        self.engine = engine or make_engine(settings.db_path)
        init_db(self.engine)
        warm_up = getattr(self.executor, "warm_up", None)
        if warm_up is not None:
            warm_up()
        self.stop = threading.Event()
        self._wake = threading.Event()  # set when a job ends, so the next one is claimed at once
        self._threads: list[threading.Thread] = []
        self._last_reap = 0.0

    # ------------------------------------------------------------ main loop
    def run_forever(self) -> None:
        log.info("worker %s started (executor=%s, concurrency=%d)", self.worker_id, self.executor.name, self.concurrency)
        try:
            while not self.stop.is_set():
                self.reap()
                self._threads = [t for t in self._threads if t.is_alive()]
                started = False
                if len(self._threads) < self.concurrency:
                    job = self.claim()
                    if job is not None:
                        t = threading.Thread(target=self._supervise_and_wake, args=(job,), name=f"job-{job.id}",
                                             daemon=True)
                        t.start()
                        self._threads.append(t)
                        started = True
                if not started:
                    self._wake.wait(self.settings.poll_s)
                    self._wake.clear()
        finally:
            for t in self._threads:
                t.join(timeout=5)
            self.executor.close()
            log.info("worker %s stopped", self.worker_id)

    def _supervise_and_wake(self, job: Job) -> None:
        try:
            self.supervise(job)
        finally:
            self._wake.set()

    def run_until_idle(self, timeout_s: float = 60.0) -> int:
        """Run queued jobs one by one in this thread until none is left (tests, CLI one-shot)."""
        n, t_end = 0, time.monotonic() + timeout_s
        while time.monotonic() < t_end:
            self.reap()
            job = self.claim()
            if job is None:
                return n
            self.supervise(job)
            n += 1
        raise TimeoutError(f"worker still had queued jobs after {timeout_s} s")

    def reap(self) -> list[int]:
        now = time.monotonic()
        if now - self._last_reap < max(self.settings.heartbeat_s, 0.5):
            return []
        self._last_reap = now
        with Session(self.engine, expire_on_commit=False) as db:
            ids = crud.requeue_lost_jobs(db, timeout_s=self.settings.job_timeout_s, max_attempts=self.settings.max_attempts,
                                         except_worker=self.worker_id)
        if ids:
            log.warning("re-queued/closed jobs whose worker died: %s", ids)
        return ids

    def claim(self) -> Job | None:
        with Session(self.engine, expire_on_commit=False) as db:
            return crud.claim_job(db, worker_id=self.worker_id)

    # ------------------------------------------------------------ one job
    def supervise(self, job: Job) -> str:
        """Run ``job`` to its end; returns its final status (or ``"lost"``)."""
        assert job.id is not None
        job_id = job.id
        with Session(self.engine, expire_on_commit=False) as db:
            bout = db.get(Bout, job.session_id)
        if bout is None:
            return self._finish(job_id, "failed", {"error": f"session {job.session_id} no longer exists"})
        session_dir = Path(bout.folder)
        progress: dict[str, Any] = {k: dict(v) for k, v in (job.progress or {}).items()}
        logs: deque[str] = deque(job.log_tail.splitlines() if job.log_tail else [], maxlen=self.settings.log_tail_lines)
        if changes := rig_changes(bout):  # a calibration replaced since the session was made
            with Session(self.engine) as db:
                if (row := db.get(Bout, bout.id)) is not None:
                    crud.update_bout(db, bout=row, changes=changes)
            logs.append(f"[worker {self.worker_id}] the calibration changed: updated the session's {', '.join(changes)}")
        try:
            from server.storage import enabled_stage_names

            enabled = enabled_stage_names(session_dir)
            from_stage, force = resume_plan(job, enabled)
        except (ValueError, OSError) as e:
            return self._finish(job_id, "failed", {"error": f"{type(e).__name__}: {e}"})
        if job.attempts > 1:
            logs.append(f"[worker {self.worker_id}] attempt {job.attempts}: resuming (from_stage={from_stage}, force={force})")
        for s in enabled:
            progress.setdefault(s, {"status": "pending", "done": 0, "total": None, "message": ""})
        spec = JobSpec(job_id=job_id, session_dir=session_dir, from_stage=from_stage, to_stage=job.to_stage, force=force,
                       worker_pid=os.getpid(), stage_delay_s=self.settings.stage_delay_s)
        try:
            handle = self.executor.start(spec)
        except (OSError, ValueError, RuntimeError) as e:
            return self._finish(job_id, "failed", {"error": f"could not start the job: {type(e).__name__}: {e}"})
        current: str | None = None
        error: str | None = None
        got_done = False
        last_write = last_beat = 0.0
        dirty = True
        while True:
            # exit status first: whatever the process sent before exiting is then already queued
            exitcode = handle.exitcode()
            events = handle.drain(0.2 if exitcode is None else 0.05)
            for ev in events:
                kind = ev[0]
                if kind == "started":
                    current = ev[1]
                    progress[ev[1]] = {"status": "running", "done": 0, "total": ev[2], "message": ""}
                elif kind == "progress":
                    progress[ev[1]] = {"status": "running", "done": ev[2], "total": ev[3], "message": ev[4]}
                elif kind == "finished":
                    p = progress.get(ev[1], {})
                    total = p.get("total")
                    progress[ev[1]] = {"status": ev[2], "done": total if total else 1, "total": total if total else 1,
                                       "message": "", "duration_s": round(ev[3], 3), "metrics": ev[4]}
                    current = None
                elif kind == "log":
                    logs.append(ev[1])
                elif kind == "error":
                    error = f"{ev[1]}\n\n{ev[2]}"
                    logs.append(ev[1])
                elif kind == "done":
                    got_done = True
                dirty = True
            now = time.monotonic()
            if dirty and exitcode is None and now - last_write > 0.25:  # the final state is written by _finish
                owned = self._write(job_id, {"progress": dict(progress), "current_stage": current, "log_tail": "\n".join(logs)})
                last_write, dirty = now, False
                if not owned:
                    handle.cancel()
                    log.warning("job %s was taken from worker %s; stopped its process", job_id, self.worker_id)
                    return "lost"
            if now - last_beat > self.settings.heartbeat_s:
                with Session(self.engine) as db:
                    owned, cancel = crud.heartbeat(db, job_id=job_id, worker_id=self.worker_id)
                last_beat = now
                if not owned:
                    handle.cancel()
                    return "lost"
                if cancel:
                    handle.cancel()
                    logs.append(f"[worker {self.worker_id}] cancelled by request")
                    if current:
                        progress[current]["status"] = "cancelled"
                    return self._finish(job_id, "cancelled", {"progress": progress, "log_tail": "\n".join(logs)})
            if self.stop.is_set() and exitcode is None:
                handle.cancel()
                with Session(self.engine) as db:
                    crud.release_job(db, job_id=job_id, worker_id=self.worker_id, changes={
                        "progress": dict(progress), "log_tail": "\n".join([*logs, f"[worker {self.worker_id}] stopping: job re-queued"])})
                return "released"
            if exitcode is not None:
                break
        if exitcode == 0 and got_done:
            return self._finish(job_id, "done", {"progress": progress, "log_tail": "\n".join(logs)})
        if error is None:
            error = f"the stage process exited with code {exitcode} (killed or crashed) during stage {current!r}"
        if current:
            progress[current]["status"] = "failed"
        return self._finish(job_id, "failed", {"progress": progress, "log_tail": "\n".join(logs), "error": error})

    def _write(self, job_id: int, changes: dict[str, Any]) -> bool:
        with Session(self.engine, expire_on_commit=False) as db:
            return crud.update_job_running(db, job_id=job_id, worker_id=self.worker_id, changes=changes)

    def _finish(self, job_id: int, status: str, changes: dict[str, Any]) -> str:
        with Session(self.engine, expire_on_commit=False) as db:
            ok = crud.finish_job(db, job_id=job_id, worker_id=self.worker_id, status=status, changes=changes)
        log.info("job %s %s", job_id, status if ok else f"{status} (not recorded: job no longer owned)")
        return status if ok else "lost"


def run_worker(settings: Settings, executor: str = "local", ray_address: str | None = None, concurrency: int = 1) -> None:
    """Blocking worker loop (``cornerman worker``); stops on SIGINT/SIGTERM."""
    import signal

    w = Worker(settings, make_executor(executor, ray_address), concurrency=concurrency)  # type: ignore[arg-type]

    def _stop(signum: int, _frame: Any) -> None:
        log.info("worker %s: signal %d, finishing", w.worker_id, signum)
        w.stop.set()
        w._wake.set()

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    w.run_forever()
