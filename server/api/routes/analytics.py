"""Routes: analytics: the bout's events (punches, slips, ducks, blocks and parries, clinches)
and the per-athlete summary, from the analyze stage's artifacts (and ``session.json``'s ring
and round times)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException, Query, status
from fastapi.responses import Response

from server import crud
from server.api.deps import CurrentUser, SessionDep, bout_dir, get_bout_or_404

router = APIRouter(prefix="/sessions/{session_id}", tags=["analytics"])


def _load(db: SessionDep, session_id: int) -> tuple[Any, Any, str, dict[int, str]]:
    from pipeline.io.events_export import load_analytics

    bout = get_bout_or_404(db, session_id)
    try:
        events, series, source = load_analytics(bout_dir(bout))
    except LookupError as e:
        raise HTTPException(status_code=status.HTTP_404_NOT_FOUND, detail=str(e)) from e
    except ValueError as e:  # a malformed artifact (a stale or interrupted write)
        raise HTTPException(status_code=status.HTTP_409_CONFLICT, detail=str(e)) from e
    names = {i.person_id: i.name for i in crud.list_identities(db, bout_id=session_id)}
    return events, series, source, names


@router.get("/events", response_model=None)
def events(
    db: SessionDep,
    _: CurrentUser,
    session_id: int,
    format: Annotated[Literal["json", "csv"], Query(description="json (the README's format) or csv")] = "json",
) -> dict[str, Any] | Response:
    """Punches (type, hand, frames, peak speed, target, outcome), defence (slips, ducks, blocks,
    parries; ``evades``), clinches."""
    from pipeline.io.events_export import events_to_csv, events_to_json

    ev, _, source, names = _load(db, session_id)
    if format == "csv":
        return Response(content=events_to_csv(ev, names), media_type="text/csv",
                        headers={"Content-Disposition": f'attachment; filename="session{session_id}_events.csv"'})  # fmt: skip
    return events_to_json(ev, names, source)


@router.get("/summary")
def summary(db: SessionDep, _: CurrentUser, session_id: int) -> dict[str, Any]:
    """Per-athlete summary: punches by type and outcome, speeds, work rate, defence (slips,
    ducks, blocks, parries), stance, guard, distance, time in the ring zones (when session.json
    gives the ring), and per round (or minute) the fatigue indicators with their trends."""
    from pipeline.schema import SessionConfig
    from pipeline.stages.analyze.summary import summarize

    ev, series, source, names = _load(db, session_id)
    try:
        cfg = SessionConfig.load(bout_dir(get_bout_or_404(db, session_id)))
    except ValueError as e:  # a session.json edited by hand into an invalid one
        raise HTTPException(status_code=status.HTTP_409_CONFLICT, detail=str(e)) from e
    return {**summarize(ev, series, names, ring_xy_m=cfg.ring_xy_m or None, rounds_s=cfg.rounds_s), "source": source}
