"""HTML page: the session picker (sessions, their jobs with live status, "Open viewer", and the
actions: create from an upload or a server folder, run, cancel, delete, job details).

Server-rendered, inline CSS and a few lines of inline script, no build step and nothing fetched
from elsewhere. It needs the login cookie (``/login``); without it the browser is sent to
``/login``. "Open viewer" links to ``/viewer/{id}/``. The action forms post to the page routes
of ``admin_pages`` (which check the role, and the ``Origin`` against cross-site posts); a
user sees only the actions their role allows.
"""

from __future__ import annotations

from html import escape
from typing import Any

from fastapi import APIRouter, status
from fastapi.responses import HTMLResponse, RedirectResponse

from server import crud
from server.api.deps import CookieUser, SessionDep, SettingsDep
from server.api.routes.admin_pages import candidate_folders
from server.api.routes.admin_pages import router as admin_router
from server.api.routes.report import router as report_router
from server.api.routes.viewer import viewer_path
from server.core.security import role_at_least
from server.models import JOB_TERMINAL, Bout, Job, User

router = APIRouter(tags=["pages"], include_in_schema=False)
router.include_router(report_router)  # GET /sessions/{id}/report: the printable bout report
router.include_router(admin_router)  # create, run, cancel, delete, job detail

CSS = """
body{font-family:system-ui,sans-serif;margin:2rem;color:#222;background:#fafafa}
h1{font-size:1.4rem;margin:0 0 .3rem}.who{color:#666;margin-bottom:1rem}
table{border-collapse:collapse;width:100%;background:#fff}th,td{padding:.4rem .6rem;border-bottom:1px solid #e3e3e3;text-align:left;vertical-align:top}
th{background:#f0f0f0;font-weight:600}.st{font-weight:600}.queued{color:#8a6d00}.running{color:#0b63c5}.done{color:#1a7f37}
.failed{color:#c62828}.cancelled,.new{color:#777}progress{width:9rem}button{padding:.3rem .8rem;cursor:pointer}
.err{color:#c62828;white-space:pre-wrap;font-size:.8rem;max-width:40rem}.stage{font-size:.8rem;color:#555}
.msg{background:#e8f4ea;border:1px solid #b5d8bd;padding:.4rem .8rem;margin-bottom:1rem}form.inline{display:inline}
.actions a,.actions form{margin-right:.4rem}fieldset{background:#fff;border:1px solid #ddd;margin:.6rem 0;max-width:46rem}
fieldset label{display:inline-block;min-width:9rem;margin:.25rem 0}fieldset input[type=text]{width:28rem}
.small{font-size:.8rem;color:#666}
"""

SCRIPT = """
// Live status: reload every 5 s, unless the tab is hidden or a new-session form is being filled in.
setInterval(()=>{
  if(document.hidden)return;
  const busy=[...document.querySelectorAll('form.new input:not([type=hidden]),form.new select')]
    .some(i=>i===document.activeElement||(i.type==='file'?i.files.length>0:(i.type!=='checkbox'&&i.value!==i.defaultValue)));
  if(!busy)location.reload();
},5000);
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
    parts = [f'<a href="/jobs/{job.id}" class="st {escape(job.status)}">#{job.id} {escape(job.status)}</a>']
    if n:
        parts.append(f'<progress max="{n}" value="{done}"></progress> <span class="stage">{done}/{n} stages</span>')
    if cur:
        parts.append(f'<div class="stage">running {escape(cur)}{escape(frac)}</div>')
    if job.error:
        parts.append(f'<div class="err">{escape(job.error.splitlines()[0] if job.error else "")}</div>')
    return " ".join(parts)


def _actions(b: Bout, job: Job | None, user: User) -> str:
    """The row's buttons the user's role allows: viewer, run, cancel (own job or admin), delete."""
    out = [f'<a id="v{b.id}" href="{viewer_path(b.id or 0)}" target="_blank" rel="noopener">Open viewer</a>',
           f'<a id="an{b.id}" href="/sessions/{b.id}/annotate">Annotate</a>']
    busy = job is not None and job.status not in JOB_TERMINAL
    if role_at_least(user.role, "annotator") and not busy:
        out.append(f'<form class="inline" method="post" action="/sessions/{b.id}/run">'
                   f'<button id="run{b.id}" type="submit">Run</button></form>')
    if busy and job is not None and (role_at_least(user.role, "admin") or
                                     (role_at_least(user.role, "annotator") and job.requested_by == user.name)):
        out.append(f'<form class="inline" method="post" action="/jobs/{job.id}/cancel">'
                   f'<button id="cancel{b.id}" type="submit">Cancel job {job.id}</button></form>')
    if role_at_least(user.role, "admin"):
        out.append(f'<a id="del{b.id}" href="/sessions/{b.id}/delete">Delete…</a>')
    return f'<td class="actions">{" ".join(out)}</td>'


def _new_session_forms(folders: list[str], roots: list[str]) -> str:
    """The admin's two create forms: a server folder (with the session folders found under the
    allowed roots as suggestions) and an upload (calibration + videos or keypoints)."""
    options = "".join(f'<option value="{escape(f)}">' for f in folders)
    return f"""<h2 style="font-size:1.1rem;margin-top:2rem">New session</h2>
<form class="new" method="post" action="/sessions/new/folder"><fieldset><legend>From a server folder</legend>
<label for="folder-path">Folder</label><input type="text" id="folder-path" name="path" list="folders" required
 placeholder="/path/with/session.json"><datalist id="folders">{options}</datalist><br>
<label for="folder-name">Name (optional)</label><input type="text" id="folder-name" name="name"><br>
<label for="folder-date">Bout date</label><input type="text" id="folder-date" name="date" placeholder="YYYY-MM-DD"><br>
<label for="folder-fps">fps (optional)</label><input type="text" id="folder-fps" name="fps" inputmode="decimal"
 placeholder="default: the session.json's, else the calibration's, else the videos'"><br>
<span class="small">A folder with a session.json, or one calibration and videos or OpenPose keypoints (as Pose2Sim
 projects and Shelf keep them: see the API docs).</span><br>
<span class="small">Allowed roots (CORNERMAN_ALLOWED_ROOTS): {escape(", ".join(roots))}</span><br>
<button type="submit" id="create-folder">Create from folder</button></fieldset></form>
<form class="new" method="post" action="/sessions/new/upload" enctype="multipart/form-data"><fieldset>
<legend>From an upload</legend>
<label for="up-name">Name</label><input type="text" id="up-name" name="name" required><br>
<label for="up-cal">Calibration</label><input type="file" id="up-cal" name="calibration" required>
<span class="small">TOML, Qualisys .qca.txt, Campus/Shelf JSON</span><br>
<label for="up-videos">Videos</label><input type="file" id="up-videos" name="videos" multiple>
<span class="small">one per camera, named &lt;camera&gt;.mp4</span><br>
<label for="up-kp">or keypoints</label><input type="file" id="up-kp" name="keypoints" multiple>
<select name="keypoint_format"><option>openpose</option><option>coco</option></select>
<span class="small">one JSON per camera, named &lt;camera&gt;.json</span><br>
<label for="up-athletes">Athletes</label><input type="text" id="up-athletes" name="athletes" value="Red,Blue"><br>
<label for="up-fps">fps (0 = from the calibration)</label><input type="text" id="up-fps" name="fps" value="0"><br>
<label for="up-date">Bout date</label><input type="text" id="up-date" name="date" placeholder="YYYY-MM-DD"><br>
<button type="submit" id="create-upload">Upload and create</button></fieldset></form>"""


def _layout_mark(b: Bout) -> str:
    """A mark under the camera count whose tooltip holds the session's layout advice ("" if none)."""
    if not b.layout_advice:
        return ""
    return f"<div class='stage layout' title='{escape(b.layout_advice, quote=True)}'>⚠ layout</div>"


@router.get("/", response_class=HTMLResponse)
def session_picker(db: SessionDep, settings: SettingsDep, user: CookieUser, msg: str = "") -> Any:
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
            f"<tr id='s{b.id}'><td>{b.id}</td><td>{escape(b.name)} (<a href='/sessions/{b.id}/report'>report</a>)</td>"
            f"<td>{b.created_at:%Y-%m-%d %H:%M}<div class='stage'>{escape(b.created_by)}</div></td><td>{escape(b.date)}</td>"
            f"<td>{escape(', '.join(b.athletes))}</td><td>{b.n_cameras}{_layout_mark(b)}</td><td>{b.fps:g}</td>"
            f"<td>{_job_cell(latest.get(b.id))}</td>{_actions(b, latest.get(b.id), user)}</tr>"
        )
    recent = sorted(jobs, key=lambda j: j.id or 0, reverse=True)[:30]
    job_rows = [
        f"<tr><td><a href='/jobs/{j.id}'>{j.id}</a></td><td>{j.session_id}</td><td>{_job_cell(j)}</td>"
        f"<td>{escape(j.from_stage or '')}→{escape(j.to_stage or '')}</td><td>{escape(j.reason)}</td>"
        f"<td>{escape(j.requested_by)}</td><td>{j.created_at:%Y-%m-%d %H:%M:%S}</td></tr>"
        for j in recent
    ]
    flash = f'<div class="msg" id="msg">{escape(msg)}</div>' if msg else ""
    admin = role_at_least(user.role, "admin")
    forms = _new_session_forms(candidate_folders(settings), [str(r) for r in settings.resolved_roots()]) if admin else ""
    html = f"""<!doctype html><html><head><meta charset="utf-8"><title>cornerman sessions</title>
<style>{CSS}</style></head><body>
<h1>cornerman — sessions</h1><div class="who">signed in as {escape(user.name)} ({escape(user.role)}) ·
<a href="/docs">API docs</a> ·
<form method="post" action="/logout" style="display:inline"><button type="submit">Sign out</button></form></div>{flash}
<table><tr><th>id</th><th>bout</th><th>created (UTC)</th><th>bout date</th><th>athletes</th><th>cams</th><th>fps</th>
<th>latest job</th><th></th></tr>
{''.join(rows) or '<tr><td colspan="9">no sessions yet</td></tr>'}</table>
{forms}
<h2 style="font-size:1.1rem;margin-top:2rem">Recent jobs</h2>
<table><tr><th>job</th><th>session</th><th>status</th><th>stages</th><th>reason</th><th>by</th><th>created (UTC)</th></tr>
{''.join(job_rows) or '<tr><td colspan="7">no jobs yet</td></tr>'}</table>
<script>{SCRIPT}</script></body></html>"""
    return HTMLResponse(html)
