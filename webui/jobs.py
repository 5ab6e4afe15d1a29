"""Follow a re-run job through the API until it ends (a background thread per job)."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from webui.api_client import TERMINAL_JOB_STATES, ApiClient, ApiError

log = logging.getLogger(__name__)


def job_fraction(job: dict) -> float:
    """Fraction of the job's stages done (running stages count by their own done/total)."""
    prog = job.get("progress") or {}
    if job.get("status") == "done":
        return 1.0
    if not prog:
        return 0.0
    acc = 0.0
    for p in prog.values():
        st = p.get("status")
        if st in ("done", "skipped", "fresh"):
            acc += 1.0
        elif st == "running" and p.get("total"):
            acc += min(1.0, float(p.get("done") or 0) / float(p["total"]))
    return acc / len(prog)


def job_summary(job: dict) -> str:
    st = job.get("status", "?")
    cur = job.get("current_stage")
    txt = f"Re-run job {job.get('id')}: **{st}**"
    if cur and st == "running":
        txt += f" ({cur})"
    if st == "failed" and job.get("error"):
        txt += f": {job['error']}"
    return txt


class JobWatcher:
    """Polls ``GET /api/jobs/{id}``; ``on_update(job)`` on every change, ``on_end(job)`` once at the end."""

    def __init__(
        self,
        api: ApiClient,
        job_id: str | int,
        on_update: Callable[[dict], None],
        on_end: Callable[[dict], None],
        poll_s: float = 0.5,
        timeout_s: float = 3600.0,
    ) -> None:
        self.api, self.job_id = api, job_id
        self.on_update, self.on_end = on_update, on_end
        self.poll_s, self.timeout_s = poll_s, timeout_s
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name=f"job-{job_id}", daemon=True)

    def start(self) -> JobWatcher:
        self.thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()

    def _run(self) -> None:
        last: dict | None = None
        waited = 0.0
        while not self._stop.is_set() and waited < self.timeout_s:
            try:
                job = self.api.job(self.job_id)
            except ApiError as e:
                log.warning("cannot follow job %s: %s", self.job_id, e)
                if e.status in (401, 403, 404):
                    return
                job = None
            if job is not None:
                if job != last:
                    self.on_update(job)
                    last = job
                if job.get("status") in TERMINAL_JOB_STATES:
                    self.on_end(job)
                    return
            self._stop.wait(self.poll_s)
            waited += self.poll_s
        log.warning("stopped following job %s after %.0f s", self.job_id, waited)
