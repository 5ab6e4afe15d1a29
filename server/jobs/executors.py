"""Executors run one job's stages away from the worker's own process.

- ``LocalExecutor`` (default): each job runs in a child process of a local process pool
  (multiprocessing ``forkserver``, pipeline modules preloaded), so a crashing stage
  (bad input, segfault in a native library) never takes the worker down, and
  cancelling a job kills its process. Progress events come back over a queue.
- ``RayExecutor`` (``server.jobs.ray_executor``, optional ``ray`` extra): sends each stage
  as a task to a Ray cluster that sees the same session folders.

Both return a ``RunHandle`` whose events are tuples:
``("started", stage, total)``, ``("progress", stage, done, total, message)``,
``("finished", stage, status, duration_s, metrics)``, ``("log", line)``,
``("error", message, traceback)`` and ``("done",)``.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import multiprocessing as mp
import os
import queue
import signal
import threading
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol

log = logging.getLogger(__name__)

Event = tuple[Any, ...]
ExecutorKind = Literal["local", "ray"]


@dataclass(frozen=True)
class JobSpec:
    """What to run: the runner's arguments plus the supervising worker's pid.

    Fields:
        job_id: database id of the job.
        session_dir: the session folder (must be visible to the executor).
        from_stage: first forced stage (``None``: only stale/missing stages run).
        to_stage: last stage (``None``: the session's last).
        force: force every stage.
        worker_pid: the stage process exits when this process disappears.
        stage_delay_s: pause before each stage (fault-injection tests).
    """

    job_id: int
    session_dir: Path
    from_stage: str | None
    to_stage: str | None
    force: bool
    worker_pid: int
    stage_delay_s: float = 0.0


class RunHandle(Protocol):
    def drain(self, timeout_s: float) -> list[Event]:
        """Events since the last call (waits up to ``timeout_s`` for the first)."""
        ...

    def exitcode(self) -> int | None:
        """None while running; 0 on success, non-zero on failure or kill."""
        ...

    def cancel(self) -> None: ...


class Executor(Protocol):
    name: str

    def start(self, spec: JobSpec) -> RunHandle: ...

    def close(self) -> None: ...


class QueueSink:
    """The runner's ``ProgressSink``, forwarding events to a queue."""

    def __init__(self, q: Any, stage_delay_s: float = 0.0) -> None:
        self.q, self.stage_delay_s = q, stage_delay_s

    def stage_started(self, stage: str, total: float | None) -> None:
        if self.stage_delay_s > 0:
            time.sleep(self.stage_delay_s)
        self.q.put(("started", stage, total))

    def stage_progress(self, stage: str, done: float, total: float | None, message: str) -> None:
        self.q.put(("progress", stage, float(done), None if total is None else float(total), str(message)))

    def stage_finished(self, stage: str, status: str, duration_s: float, metrics: dict[str, Any]) -> None:
        self.q.put(("finished", stage, status, float(duration_s), _jsonable(metrics)))


def _jsonable(d: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, (bool, int, float, str)) or v is None:
            out[str(k)] = v
        elif hasattr(v, "item"):
            out[str(k)] = v.item()
        else:
            out[str(k)] = str(v)
    return out


class _QueueLogHandler(logging.Handler):
    def __init__(self, q: Any) -> None:
        super().__init__(logging.INFO)
        self.q = q
        self.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s", "%H:%M:%S"))

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.q.put(("log", self.format(record)))
        except (ValueError, OSError):  # queue closed while exiting
            pass


def _die_with(worker_pid: int) -> None:
    """Make this stage process exit when the worker that supervises it dies."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG (Linux)

    def watch() -> None:
        while True:
            time.sleep(0.5)
            try:
                os.kill(worker_pid, 0)
            except ProcessLookupError:
                os._exit(3)

    threading.Thread(target=watch, daemon=True, name="worker-watch").start()


def run_job_process(spec: JobSpec, q: Any) -> None:
    """Entry point of a local stage process: ``pipeline.runner.run`` with a queue sink."""
    _die_with(spec.worker_pid)
    root = logging.getLogger()
    root.setLevel(logging.INFO)
    root.addHandler(_QueueLogHandler(q))
    try:
        from pipeline.runner import run

        run(spec.session_dir, from_stage=spec.from_stage, to_stage=spec.to_stage, force=spec.force,
            progress=QueueSink(q, spec.stage_delay_s))
        q.put(("done",))
    except Exception as e:  # noqa: BLE001  (any stage failure becomes a readable job error)
        q.put(("error", f"{type(e).__name__}: {e}", traceback.format_exc()))
        q.close()
        q.join_thread()
        raise SystemExit(1) from None
    q.close()
    q.join_thread()


def _noop() -> None:
    pass


class LocalHandle:
    def __init__(self, proc: Any, q: Any) -> None:
        self.proc, self.q = proc, q

    def drain(self, timeout_s: float) -> list[Event]:
        out: list[Event] = []
        try:
            out.append(self.q.get(timeout=timeout_s))
            while True:
                out.append(self.q.get_nowait())
        except queue.Empty:
            pass
        return out

    def exitcode(self) -> int | None:
        return self.proc.exitcode  # type: ignore[no-any-return]

    def cancel(self) -> None:
        if self.proc.is_alive():
            self.proc.terminate()
            self.proc.join(3.0)
            if self.proc.is_alive():
                self.proc.kill()
        self.proc.join(3.0)


class LocalExecutor:
    """Runs each job in its own process from a forkserver with the pipeline preloaded."""

    name = "local"

    def __init__(self) -> None:
        self.ctx = mp.get_context("forkserver")
        self.ctx.set_forkserver_preload(["numpy", "server.jobs.executors", "server.jobs.preload"])

    def warm_up(self) -> None:
        """Boot the forkserver (it imports every stage once, seconds on a busy machine) before
        the first job, so that job's start-up does not eat into its heartbeat budget."""
        p = self.ctx.Process(target=_noop, name="cornerman-warm-up", daemon=True)
        p.start()
        p.join(120)

    def start(self, spec: JobSpec) -> RunHandle:
        q = self.ctx.Queue()
        proc = self.ctx.Process(target=run_job_process, args=(spec, q), name=f"cornerman-job-{spec.job_id}", daemon=True)
        proc.start()
        return LocalHandle(proc, q)

    def close(self) -> None:
        pass


def make_executor(kind: ExecutorKind = "local", ray_address: str | None = None) -> Executor:
    """``"local"`` (process pool on this machine) or ``"ray"`` (needs ``pip install cornerman[ray]``)."""
    if kind == "local":
        return LocalExecutor()
    if kind == "ray":
        from server.jobs.ray_executor import RayExecutor

        return RayExecutor(ray_address)
    raise ValueError(f"unknown executor {kind!r}; choose 'local' or 'ray'")
