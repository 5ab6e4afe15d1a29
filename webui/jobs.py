"""Follow a re-run job through the API until it ends (a background thread per job)."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Mapping

from webui.api_client import TERMINAL_JOB_STATES, ApiClient, ApiError
from webui.staleness import stage_progress_text

log = logging.getLogger(__name__)


FINISHED_STATUSES = ("ran", "skipped", "done", "fresh")
"""A stage's progress status once it is over (the worker writes ``ran`` / ``skipped``)."""


def job_fraction(job: dict, weights: Mapping[str, float] | None = None) -> float:
    """Fraction of the job done, in [0, 1]: finished stages count fully, the running one by its
    own ``done / total`` (L-BFGS iterations of the fit, windows of physics).

    ``weights``: stage -> expected seconds (e.g. the previous run's ``duration_s``), so that a
    long stage fills the bar in proportion; stages without one count as the mean of the others.
    None: every stage counts the same.
    """
    prog = job.get("progress") or {}
    if job.get("status") == "done":
        return 1.0
    if not prog:
        return 0.0
    known = [float(w) for s, w in (weights or {}).items() if s in prog and w and w > 0]
    default = sum(known) / len(known) if known else 1.0
    acc = total = 0.0
    for stage, p in prog.items():
        w = float((weights or {}).get(stage) or 0.0)
        w = w if w > 0 else default
        total += w
        st = p.get("status")
        if st in FINISHED_STATUSES:
            acc += w
        elif st == "running" and p.get("total"):
            acc += w * min(1.0, max(0.0, float(p.get("done") or 0) / float(p["total"])))
    return acc / total if total > 0 else 0.0


def job_summary(job: dict) -> str:
    """One line: the job's id and state, the running stage with its progress, or its error."""
    st = job.get("status", "?")
    cur = job.get("current_stage")
    txt = f"Re-run job {job.get('id')}: **{st}**"
    if cur and st == "running":
        txt += f" ({cur}: {stage_progress_text(job, cur)})"
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
