"""HTML page: the session picker (sessions, their jobs with live status, "Open viewer").

Server-rendered, minimal CSS, no build step. It needs the login cookie (``/login``);
without it the browser is sent to ``/login``. "Open viewer" links to ``/viewer/{id}/``.
"""

from __future__ import annotations

from html import escape
from typing import Any

from fastapi import APIRouter, status
from fastapi.responses import HTMLResponse, RedirectResponse

from server import crud
from server.api.deps import CookieUser, SessionDep
from server.api.routes.report import router as report_router
from server.api.routes.viewer import viewer_path
from server.models import Job

router = APIRouter(tags=["pages"], include_in_schema=False)
router.include_router(report_router)  # GET /sessions/{id}/report: the printable bout report

CSS = """
body{font-family:system-ui,sans-serif;margin:2rem;color:#222;background:#fafafa}
h1{font-size:1.4rem;margin:0 0 .3rem}.who{color:#666;margin-bottom:1rem}
table{border-collapse:collapse;width:100%;background:#fff}th,td{padding:.4rem .6rem;border-bottom:1px solid #e3e3e3;text-align:left;vertical-align:top}
th{background:#f0f0f0;font-weight:600}.st{font-weight:600}.queued{color:#8a6d00}.running{color:#0b63c5}.done{color:#1a7f37}
.failed{color:#c62828}.cancelled,.new{color:#777}progress{width:9rem}button{padding:.3rem .8rem;cursor:pointer}
.err{color:#c62828;white-space:pre-wrap;font-size:.8rem;max-width:40rem}.stage{font-size:.8rem;color:#555}
"""

SCRIPT = """
setInterval(()=>{if(!document.hidden)location.reload();},5000);
"""


def _job_cell(job: Job | None) -> str:
    if job is None:
        return '<span class="st new">no job</span>'
    prog = job.progress or {}
    n = len(prog)
    done = sum(1 for p in prog.values() if p.get("status") in ("ran", "skipped"))
    cur = job.current_stage
    frac = ""
    if cur and cur in prog and prog[cur].get("total"):
        frac = f' {prog[cur].get("done", 0):.0f}/{prog[cur]["total"]:.0f}'
    parts = [f'<span class="st {escape(job.status)}">#{job.id} {escape(job.status)}</span>']
    if n:
        parts.append(f'<progress max="{n}" value="{done}"></progress> <span class="stage">{done}/{n} stages</span>')
    if cur:
        parts.append(f'<div class="stage">running {escape(cur)}{escape(frac)}</div>')
    if job.error:
        parts.append(f'<div class="err">{escape(job.error.splitlines()[0] if job.error else "")}</div>')
    return " ".join(parts)


@router.get("/", response_class=HTMLResponse)
def session_picker(db: SessionDep, user: CookieUser) -> Any:
    if user is None:
        return RedirectResponse("/login", status_code=status.HTTP_303_SEE_OTHER)
    bouts = crud.list_bouts(db)
    jobs = crud.list_jobs(db)
    latest: dict[int, Job] = {}
    for j in jobs:
        latest[j.session_id] = j
    rows = []
    for b in bouts:
        assert b.id is not None
        rows.append(
            f"<tr><td>{b.id}</td><td>{escape(b.name)} (<a href='/sessions/{b.id}/report'>report</a>)</td><td>{escape(b.date)}</td>"
            f"<td>{escape(', '.join(b.athletes))}</td><td>{b.n_cameras}</td><td>{b.fps:g}</td>"
            f"<td>{_job_cell(latest.get(b.id))}</td>"
            f'<td><a id="v{b.id}" href="{viewer_path(b.id)}" target="_blank" rel="noopener">Open viewer</a></td></tr>'
        )
    recent = sorted(jobs, key=lambda j: j.id or 0, reverse=True)[:30]
    job_rows = [
        f"<tr><td>{j.id}</td><td>{j.session_id}</td><td>{_job_cell(j)}</td>"
        f"<td>{escape(j.from_stage or '')}→{escape(j.to_stage or '')}</td><td>{escape(j.reason)}</td>"
        f"<td>{escape(j.requested_by)}</td><td>{j.created_at:%Y-%m-%d %H:%M:%S}</td></tr>"
        for j in recent
    ]
    html = f"""<!doctype html><html><head><meta charset="utf-8"><title>cornerman sessions</title>
<style>{CSS}</style></head><body>
<h1>cornerman — sessions</h1><div class="who">signed in as {escape(user.name)} ({escape(user.role)}) ·
<a href="/docs">API docs</a> ·
<form method="post" action="/logout" style="display:inline"><button type="submit">Sign out</button></form></div>
<table><tr><th>id</th><th>bout</th><th>date</th><th>athletes</th><th>cams</th><th>fps</th><th>latest job</th><th></th></tr>
{''.join(rows) or '<tr><td colspan="8">no sessions yet</td></tr>'}</table>
<h2 style="font-size:1.1rem;margin-top:2rem">Recent jobs</h2>
<table><tr><th>job</th><th>session</th><th>status</th><th>stages</th><th>reason</th><th>by</th><th>created (UTC)</th></tr>
{''.join(job_rows) or '<tr><td colspan="7">no jobs yet</td></tr>'}</table>
<script>{SCRIPT}</script></body></html>"""
    return HTMLResponse(html)
