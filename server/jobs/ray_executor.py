"""Ray executor (``pip install cornerman[ray]``): each stage of a job is a Ray task.

The worker stays the job's owner (claim, heartbeat, progress in the database); the
stages run wherever the Ray cluster schedules them. Every Ray node must see the
session folders at the same paths (shared filesystem), because stages read and write
artifacts there. Stage-level progress (started / finished with metrics) is reported;
progress inside a stage is not streamed back.

``cornerman worker --executor ray --ray-address ray://head:10001`` (or ``auto``);
without an address a local Ray instance is started.
"""

from __future__ import annotations

import logging
import queue
import threading
import traceback
from typing import Any

from server.jobs.executors import Event, JobSpec, QueueSink, RunHandle

log = logging.getLogger(__name__)


def run_stage_task(session_dir: str, stage: str, force_it: bool) -> list[Event]:
    """Body of the Ray task: run one stage (earlier stages are fresh and get skipped)."""
    from pipeline.runner import run

    events: list[Event] = []

    class _ListQueue:
        def put(self, ev: Event) -> None:
            events.append(ev)

    run(session_dir, from_stage=stage if force_it else None, to_stage=stage, progress=QueueSink(_ListQueue()))
    return [e for e in events if e[1] == stage and e[0] != "started"]


class RayHandle:
    def __init__(self, executor: RayExecutor, spec: JobSpec) -> None:
        self.ex, self.spec = executor, spec
        self.events: queue.Queue[Event] = queue.Queue()
        self._exit: int | None = None
        self._cancel = threading.Event()
        self._ref: Any = None
        self._thread = threading.Thread(target=self._run, daemon=True, name=f"ray-job-{spec.job_id}")
        self._thread.start()

    def _run(self) -> None:
        import ray

        from server.storage import enabled_stage_names

        try:
            enabled = enabled_stage_names(self.spec.session_dir)
            last = enabled.index(self.spec.to_stage) if self.spec.to_stage else len(enabled) - 1
            first_forced = 0 if self.spec.force else (
                enabled.index(self.spec.from_stage) if self.spec.from_stage else len(enabled))
            for i, stage in enumerate(enabled[: last + 1]):
                if self._cancel.is_set():
                    self._exit = 2
                    return
                self.events.put(("started", stage, None))  # shown as the current stage while the task runs
                self._ref = self.ex.remote_fn.remote(str(self.spec.session_dir), stage, i >= first_forced)
                while True:
                    ready, _ = ray.wait([self._ref], timeout=0.5)
                    if ready:
                        break
                    if self._cancel.is_set():
                        ray.cancel(self._ref, force=True)
                        self._exit = 2
                        return
                for ev in ray.get(self._ref):
                    self.events.put(ev)
            self.events.put(("done",))
            self._exit = 0
        except Exception as e:  # noqa: BLE001  (a failed task becomes a readable job error)
            cause = getattr(e, "cause", None) or e
            self.events.put(("error", f"{type(cause).__name__}: {cause}", traceback.format_exc()))
            self._exit = 1

    def drain(self, timeout_s: float) -> list[Event]:
        out: list[Event] = []
        try:
            out.append(self.events.get(timeout=timeout_s))
            while True:
                out.append(self.events.get_nowait())
        except queue.Empty:
            pass
        return out

    def exitcode(self) -> int | None:
        return None if self._thread.is_alive() else (self._exit if self._exit is not None else 1)

    def cancel(self) -> None:
        self._cancel.set()
        self._thread.join(10.0)


class RayExecutor:
    """Connects to (or starts) a Ray cluster once per worker process."""

    name = "ray"

    def __init__(self, address: str | None = None, num_cpus: int | None = None) -> None:
        try:
            import ray
        except ImportError as e:
            raise ValueError("the ray executor needs Ray: pip install 'cornerman[ray]'") from e
        if not ray.is_initialized():
            kw: dict[str, Any] = {"ignore_reinit_error": True, "include_dashboard": False, "log_to_driver": False}
            if address:
                kw["address"] = address
            elif num_cpus:
                kw["num_cpus"] = num_cpus
            ray.init(**kw)
        self.remote_fn = ray.remote(max_retries=0)(run_stage_task)

    def start(self, spec: JobSpec) -> RunHandle:
        return RayHandle(self, spec)

    def close(self) -> None:
        pass
