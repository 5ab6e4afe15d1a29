"""HTML actions of the session picker: create (upload or server folder), run, cancel, delete,
and the job detail page (its stages, log and error).

Plain HTML forms post to these small page routes, which call the same functions as the REST
routes (``sessions.create_uploaded_session``, ``sessions.register_folder``,
``jobs.submit_job``, ``crud.cancel_job``, ``sessions.remove_session``) and answer with a
303 redirect, or with an HTML page naming the problem. They need the login cookie, whose
SameSite=Strict keeps other sites' forms from carrying it, and they refuse a request whose
``Origin`` is another site (403), as ``/login`` does. Roles: run and cancel need an
annotator (cancel: an admin or the job's requester), create and delete an admin; delete goes
through a confirmation page.
"""

from __future__ import annotations

from html import escape
from typing import Annotated, Any
from urllib.parse import quote

from fastapi import APIRouter, Depends, File, Form, HTTPException, Request, UploadFile, status
from fastapi.responses import HTMLResponse, RedirectResponse

from server import crud
from server.api.deps import SessionDep, SettingsDep, get_bout_or_404, get_cookie_user, same_origin
from server.api.routes.jobs import submit_job
from server.api.routes.sessions import create_uploaded_session, register_folder, remove_session
from server.core.config import Settings
from server.core.security import role_at_least
from server.models import JOB_TERMINAL, Bout, Job, JobCreate, User
from server.storage import PathNotAllowed, resolve_allowed

router = APIRouter(tags=["pages"], include_in_schema=False)

PAGE_CSS = """
body{font-family:system-ui,sans-serif;margin:2rem;color:#222;background:#fafafa;max-width:70rem}
h1{font-size:1.4rem;margin:0 0 .6rem}table{border-collapse:collapse;background:#fff}
th,td{padding:.35rem .6rem;border-bottom:1px solid #e3e3e3;text-align:left;vertical-align:top}th{background:#f0f0f0}
pre{background:#fff;border:1px solid #ddd;padding:.6rem;white-space:pre-wrap;max-height:40rem;overflow:auto;font-size:.8rem}
.err{color:#c62828}.st{font-weight:600}.queued{color:#8a6d00}.running{color:#0b63c5}.done,.ran{color:#1a7f37}
.failed{color:#c62828}.cancelled,.skipped{color:#777}button{padding:.3rem .8rem;cursor:pointer}.danger{color:#fff;background:#c62828;border:0}
"""


def page(title: str, body: str, status_code: int = 200, refresh_s: int = 0) -> HTMLResponse:
    """A minimal HTML page (inline CSS only; ``refresh_s`` > 0 reloads it while the tab is visible)."""
    script = (f"<script>setInterval(()=>{{if(!document.hidden)location.reload();}},{refresh_s * 1000});</script>"
              if refresh_s > 0 else "")
    html = (f'<!doctype html><html><head><meta charset="utf-8"><title>{escape(title)}</title><style>{PAGE_CSS}</style>'
            f'</head><body><p><a href="/">← sessions</a></p>{body}{script}</body></html>')
    return HTMLResponse(html, status_code=status_code)


def error_page(code: int, message: str) -> HTMLResponse:
    return page("cornerman: error", f'<h1>Could not do that</h1><p class="err" id="error">{escape(message)}</p>', code)


class PageProblem(Exception):
    """A page action refused (not signed in, wrong role, cross-site): answered as an HTML page."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code, self.message = code, message


def page_user(request: Request, user: Annotated[User | None, Depends(get_cookie_user)]) -> User:
    """The signed-in browser user of a page action; refuses a cross-site ``Origin`` (CSRF)."""
    if request.method not in ("GET", "HEAD") and not same_origin(request.headers, request.url.scheme):
        raise PageProblem(status.HTTP_403_FORBIDDEN, "cross-origin form post refused")
    if user is None:
        raise PageProblem(status.HTTP_401_UNAUTHORIZED, "sign in first (/login)")
    return user



def _need(user: User, role: str) -> None:
    if not role_at_least(user.role, role):
        raise PageProblem(status.HTTP_403_FORBIDDEN, f"this needs the {role!r} role; {user.name!r} is {user.role!r}")


def _run_action(fn: Any) -> Any:
    """``fn()``, with domain and HTTP errors turned into an HTML error page."""
    try:
        return fn()
    except PageProblem as e:
        return error_page(e.code, e.message)
    except HTTPException as e:
        return error_page(e.status_code, str(e.detail))
    except PathNotAllowed as e:
        return error_page(status.HTTP_403_FORBIDDEN, str(e))
    except ValueError as e:
        return error_page(422, str(e))


def _back(message: str, to: str = "/") -> RedirectResponse:
    return RedirectResponse(f"{to}?msg={quote(message)}", status_code=status.HTTP_303_SEE_OTHER)


def _with_layout(message: str, bout: Bout) -> str:
    """``message`` and, when no two of the new session's cameras see depth well, the advice."""
    return f"{message}. {bout.layout_advice}" if bout.layout_advice else message


def candidate_folders(settings: Settings, limit: int = 200) -> list[str]:
    """Session folders (holding ``session.json``) at most two levels under the allowed roots."""
    out: list[str] = []
    for root in settings.resolved_roots():
        for pattern in ("session.json", "*/session.json", "*/*/session.json"):
            for p in sorted(root.glob(pattern)):
                out.append(str(p.parent))
                if len(out) >= limit:
                    return out
    return out


@router.post("/sessions/new/folder")
def create_from_folder(
    db: SessionDep,
    settings: SettingsDep,
    user: Annotated[User | None, Depends(get_cookie_user)],
    request: Request,
    path: Annotated[str, Form(min_length=1, max_length=4000)],
    name: Annotated[str, Form(max_length=200)] = "",
    date: Annotated[str, Form(max_length=32)] = "",
    fps: Annotated[float, Form(ge=0)] = 0.0,
) -> Any:
    """A session from a server folder under ``CORNERMAN_ALLOWED_ROOTS`` (admin); then its page row.
    ``fps`` (Hz) sets the frame rate; 0 keeps the folder's own."""

    def act() -> Any:
        u = page_user(request, user)
        _need(u, "admin")
        bout = register_folder(db, settings, resolve_allowed(path.strip(), settings), name.strip() or None, date,
                               True, u.name, fps or None)
        return _back(_with_layout(f"created session {bout.id} ({bout.name}) from {path.strip()}", bout))

    return _run_action(act)


@router.post("/sessions/new/upload")
def create_from_upload(
    db: SessionDep,
    settings: SettingsDep,
    user: Annotated[User | None, Depends(get_cookie_user)],
    request: Request,
    name: Annotated[str, Form(min_length=1, max_length=200)],
    calibration: Annotated[UploadFile, File()],
    videos: Annotated[list[UploadFile | str] | None, File()] = None,
    keypoints: Annotated[list[UploadFile | str] | None, File()] = None,
    keypoint_format: Annotated[str, Form(pattern="^(openpose|coco)$")] = "openpose",
    fps: Annotated[float, Form(ge=0)] = 0.0,
    athletes: Annotated[str, Form(max_length=500)] = "Red,Blue",
    date: Annotated[str, Form(max_length=32)] = "",
) -> Any:
    """A session from uploaded calibration + videos or keypoints (admin), as ``POST /api/sessions``."""

    def act() -> Any:
        u = page_user(request, user)
        _need(u, "admin")
        # an empty file input comes as a part with an empty file name (browsers) or none (a plain field)
        vids = [f for f in videos or [] if not isinstance(f, str) and f.filename]
        kps = [f for f in keypoints or [] if not isinstance(f, str) and f.filename]
        if vids and kps:
            raise ValueError("choose videos or keypoint files, not both")
        bout = create_uploaded_session(db, settings, author=u.name, name=name, calibration=calibration, videos=vids,
                                       keypoints=kps, tracks=None, keypoint_format=keypoint_format, fps=fps,
                                       athletes=athletes, date=date)
        return _back(_with_layout(f"created session {bout.id} ({bout.name}) from {1 + len(vids) + len(kps)} uploaded files", bout))

    return _run_action(act)


@router.post("/sessions/{session_id}/run")
def run_session(db: SessionDep, user: Annotated[User | None, Depends(get_cookie_user)], request: Request,
                session_id: int) -> Any:
    """Queue a run of the session's stale and missing stages (annotator+); then the job's page."""

    def act() -> Any:
        u = page_user(request, user)
        _need(u, "annotator")
        job = submit_job(db, u, JobCreate(session_id=session_id), reason="run from the session page")
        return RedirectResponse(f"/jobs/{job.id}", status_code=status.HTTP_303_SEE_OTHER)

    return _run_action(act)


def _job_or_problem(db: SessionDep, job_id: int) -> Job:
    job = crud.get_job(db, job_id=job_id)
    if job is None:
        raise PageProblem(status.HTTP_404_NOT_FOUND, f"job {job_id} not found")
    return job


@router.post("/jobs/{job_id}/cancel")
def cancel_job_page(db: SessionDep, user: Annotated[User | None, Depends(get_cookie_user)], request: Request,
                    job_id: int) -> Any:
    """Cancel a queued job or stop a running one (an admin, or the annotator who asked for it)."""

    def act() -> Any:
        u = page_user(request, user)
        _need(u, "annotator")
        job = _job_or_problem(db, job_id)
        if not role_at_least(u.role, "admin") and job.requested_by != u.name:
            raise PageProblem(status.HTTP_403_FORBIDDEN, "only an admin or the requester may cancel a job")
        crud.cancel_job(db, job=job)
        return RedirectResponse(f"/jobs/{job_id}", status_code=status.HTTP_303_SEE_OTHER)

    return _run_action(act)


@router.get("/sessions/{session_id}/delete", response_class=HTMLResponse)
def delete_confirmation(db: SessionDep, user: Annotated[User | None, Depends(get_cookie_user)], request: Request,
                        session_id: int) -> Any:
    """The confirmation step before a session is deleted (admin)."""

    def act() -> Any:
        if user is None:
            return RedirectResponse(f"/login?next=/sessions/{session_id}/delete", status_code=status.HTTP_303_SEE_OTHER)
        _need(page_user(request, user), "admin")
        bout = get_bout_or_404(db, session_id)
        n_jobs = len(crud.list_jobs(db, session_id=session_id))
        n_edits = len(crud.list_annotations(db, bout_id=session_id, include_superseded=True))
        body = (
            f"<h1>Delete session {bout.id} “{escape(bout.name)}”?</h1>"
            f"<p>This deletes its {n_jobs} jobs, its {n_edits} annotation rows and its results folder "
            f"<code>{escape(bout.folder)}</code>. A server folder it was made from is not touched. "
            "This cannot be undone.</p>"
            f'<form method="post" action="/sessions/{bout.id}/delete"><input type="hidden" name="confirm" '
            f'value="{bout.id}"><button class="danger" id="confirm-delete" type="submit">Delete session {bout.id}'
            '</button> <a href="/">Cancel</a></form>'
        )
        return page(f"delete session {bout.id}", body)

    return _run_action(act)


@router.post("/sessions/{session_id}/delete")
def delete_session_page(db: SessionDep, settings: SettingsDep, user: Annotated[User | None, Depends(get_cookie_user)],
                        request: Request, session_id: int, confirm: Annotated[str, Form(max_length=20)] = "") -> Any:
    """Delete after the confirmation page (its form sends ``confirm`` = the session id)."""

    def act() -> Any:
        u = page_user(request, user)
        _need(u, "admin")
        bout = get_bout_or_404(db, session_id)
        if confirm != str(session_id):
            raise PageProblem(422, f"confirm on the confirmation page (/sessions/{session_id}/delete) first")
        name = bout.name
        remove_session(db, settings, bout)
        return _back(f"deleted session {session_id} ({name})")

    return _run_action(act)


def _fmt(t: Any) -> str:
    return "" if t is None else f"{t:%Y-%m-%d %H:%M:%S} UTC"


def job_detail_html(job: Job, bout_name: str, can_cancel: bool) -> str:
    rows = []
    for stage, p in (job.progress or {}).items():
        done, total = p.get("done"), p.get("total")
        frac = f"{done:g}/{total:g}" if isinstance(done, int | float) and isinstance(total, int | float) else ""
        dur = f"{p['duration_s']:.1f} s" if isinstance(p.get("duration_s"), int | float) else ""
        rows.append(f'<tr><td>{escape(stage)}</td><td class="st {escape(str(p.get("status", "")))}">'
                    f'{escape(str(p.get("status", "")))}</td><td>{frac}</td><td>{dur}</td>'
                    f'<td>{escape(str(p.get("message") or ""))}</td></tr>')
    stages = ("<table id='stages'><tr><th>stage</th><th>status</th><th>progress</th><th>time</th><th>message</th></tr>"
              + "".join(rows) + "</table>") if rows else "<p>No stage has started yet.</p>"
    cancel = (f'<form method="post" action="/jobs/{job.id}/cancel"><button id="cancel" type="submit">'
              f'{"Stop" if job.status == "running" else "Cancel"} job {job.id}</button></form>') if can_cancel else ""
    error = f'<h2>Error</h2><pre class="err" id="job-error">{escape(job.error)}</pre>' if job.error else ""
    span = f"{escape(job.from_stage or 'first stale')} → {escape(job.to_stage or 'last')}"
    return (
        f'<h1>Job {job.id}: <span class="st {escape(job.status)}" id="job-status">{escape(job.status)}</span></h1>'
        f"<table><tr><th>session</th><td>{job.session_id} {escape(bout_name)}</td></tr>"
        f"<tr><th>stages</th><td>{span}{' (forced)' if job.force else ''}</td></tr>"
        f"<tr><th>reason</th><td>{escape(job.reason)}</td></tr><tr><th>requested by</th><td>{escape(job.requested_by)}</td></tr>"
        f"<tr><th>created</th><td>{_fmt(job.created_at)}</td></tr><tr><th>started</th><td>{_fmt(job.started_at)}</td></tr>"
        f"<tr><th>finished</th><td>{_fmt(job.finished_at)}</td></tr><tr><th>current stage</th>"
        f"<td>{escape(job.current_stage or '')}</td></tr><tr><th>worker</th><td>{escape(job.worker_id or '')} "
        f"(attempt {job.attempts})</td></tr></table>{cancel}<h2>Stages</h2>{stages}{error}"
        f'<h2>Log</h2><pre id="job-log">{escape(job.log_tail) or "(empty)"}</pre>'
    )


@router.get("/jobs/{job_id}", response_class=HTMLResponse)
def job_page(db: SessionDep, user: Annotated[User | None, Depends(get_cookie_user)], request: Request,
             job_id: int) -> Any:
    """A job's status, stages, log and error (any signed-in user); reloads every 3 s until it ends."""

    def act() -> Any:
        if user is None:
            return RedirectResponse(f"/login?next=/jobs/{job_id}", status_code=status.HTTP_303_SEE_OTHER)
        job = _job_or_problem(db, job_id)
        bout = crud.get_bout(db, bout_id=job.session_id)
        can_cancel = job.status not in JOB_TERMINAL and (
            role_at_least(user.role, "admin") or (role_at_least(user.role, "annotator") and job.requested_by == user.name))
        return page(f"job {job_id}", job_detail_html(job, bout.name if bout else "(deleted)", can_cancel),
                    refresh_s=0 if job.status in JOB_TERMINAL else 3)

    return _run_action(act)

