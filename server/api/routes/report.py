"""HTML page: the bout report (``GET /sessions/{id}/report``), a printable page of the
analyze stage's results (``pipeline.report``). Any signed-in user may read it (coaches
too), with the bearer token or the browser's sign-in cookie (``server.api.deps.get_token``);
without either it answers 401.
"""

from __future__ import annotations

from html import escape
from typing import Annotated, Any

from fastapi import APIRouter, Query, status
from fastapi.responses import HTMLResponse

from server import crud
from server.api.deps import CurrentUser, SessionDep, bout_dir, get_bout_or_404

router = APIRouter(tags=["pages"], include_in_schema=False)

NOT_ANALYSED = (
    "run the analyze stage first (cornerman run SESSION --to-stage analyze, or a job up to analyze)"
)
"""The 404 message of a session without analytics."""


def _error_page(code: int, title: str, detail: str) -> HTMLResponse:
    html = (
        f'<!doctype html><html lang="en"><head><meta charset="utf-8"><title>{escape(title)}</title></head>'
        f'<body style="font-family:system-ui,sans-serif;margin:2rem"><h1 style="font-size:1.3rem">{escape(title)}</h1>'
        f'<p>{escape(detail)}</p><p><a href="/">sessions</a></p></body></html>'
    )
    return HTMLResponse(html, status_code=code)


@router.get("/sessions/{session_id}/report", response_class=HTMLResponse)
def bout_report(
    db: SessionDep,
    _: CurrentUser,
    session_id: int,
    period_s: Annotated[
        float, Query(gt=0, description="summary period when the rounds are not known (s)")
    ] = 60.0,
    bin_s: Annotated[float, Query(gt=0, description="work-rate bin (s)")] = 10.0,
) -> Any:
    """The bout report (HTML); 404 with "run the analyze stage" before the analyze stage has run."""
    from pipeline.report import ReportOptions, load_report_data, render_report

    bout = get_bout_or_404(db, session_id)
    idents = crud.list_identities(db, bout_id=session_id)
    names = {i.person_id: i.name for i in idents if i.name}
    colors = {i.person_id: i.color for i in idents if i.color}
    try:
        data = load_report_data(bout_dir(bout), names=names, colors=colors, date=bout.date)
    except LookupError as e:
        return _error_page(
            status.HTTP_404_NOT_FOUND, f"{bout.name}: no bout report yet", f"{NOT_ANALYSED}. ({e})"
        )
    except ValueError as e:  # a malformed session.json or artifact (a stale or interrupted write)
        return _error_page(status.HTTP_409_CONFLICT, f"{bout.name}: the report cannot be built", str(e))
    return HTMLResponse(render_report(data, ReportOptions(period_s=period_s, bin_s=bin_s)))
