"""Which of the viewer's layers are out of date while a re-run after an edit is under way.

An edit makes its consuming stage and every later one stale (``stale_from``, from the API).
The viewer keeps showing the artifacts it has loaded; a layer is *stale* while one of its
stages at or after ``stale_from`` has not been rewritten since the edit, and *fresh* again
once the viewer has loaded that stage's new artifact. Pure functions: no viser, no I/O.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime

from pipeline.runner.registry import STAGE_ORDER

LAYERS: dict[str, tuple[str, ...]] = {
    "2D labels": ("track", "associate"),
    "3D (filtered)": ("triangulate",),
    "fit": ("fit",),
    "physics": ("physics",),
    "analytics": ("analyze", "evaluate"),
}
"""Layer name -> the stages whose artifacts it shows (the identity labels in the camera images,
the triangulated skeleton, the body meshes, the physics geoms, the plots / events / problem marks)."""

SOURCE_LAYER: dict[str, str] = {"filtered": "3D (filtered)", "fit": "fit", "physics": "physics"}
"""3D keypoint source shown by the skeleton (``pipeline.schema.sources``) -> its layer."""

STAGE_UNITS: dict[str, str] = {"fit": "iteration", "physics": "window", "detect2d": "frame"}
"""What a stage's ``done / total`` progress counts (other stages: steps)."""


def _rank(stage: str) -> int:
    try:
        return STAGE_ORDER.index(stage)
    except ValueError:
        raise ValueError(f"unknown stage {stage!r}; known: {list(STAGE_ORDER)}") from None


def stale_stages(order: Iterable[str], stale_from: str | None, finished: Iterable[str]) -> tuple[str, ...]:
    """Stages of ``order`` (the session's enabled stages) at or after ``stale_from`` in the
    pipeline order that are not in ``finished`` (rewritten since the edit); ``()`` when
    ``stale_from`` is None. ``ValueError`` for a stage name the pipeline does not know."""
    order = tuple(order)
    for s in order:
        _rank(s)
    if stale_from is None:
        return ()
    first = _rank(stale_from)
    done = set(finished)
    return tuple(s for s in order if _rank(s) >= first and s not in done)


def stale_layers(order: Iterable[str], stale_from: str | None, finished: Iterable[str]) -> frozenset[str]:
    """Names of the ``LAYERS`` with at least one stale stage (see ``stale_stages``)."""
    stale = set(stale_stages(order, stale_from, finished))
    return frozenset(name for name, stages in LAYERS.items() if stale.intersection(stages))


def rewritten_since(stamps: Mapping[str, float], since_unix_s: float) -> frozenset[str]:
    """Stages whose loaded manifest was created after ``since_unix_s`` (Unix seconds)."""
    return frozenset(s for s, t in stamps.items() if t > since_unix_s)


def unix_time(value: str | float | datetime | None) -> float:
    """Unix seconds of an API timestamp (ISO 8601; a naive one is UTC); ``ValueError`` when unreadable."""
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, str):
        try:
            value = datetime.fromisoformat(value.replace("Z", "+00:00"))
        except ValueError:
            raise ValueError(f"not an ISO 8601 time: {value!r}") from None
    if not isinstance(value, datetime):
        raise ValueError(f"not a time: {value!r}")
    return (value if value.tzinfo else value.replace(tzinfo=UTC)).timestamp()


def stage_progress_text(job: Mapping, stage: str) -> str:
    """``"window 3/12"`` for a running stage that reports a total, else its last message."""
    p = (job.get("progress") or {}).get(stage) or {}
    total, done = p.get("total"), p.get("done") or 0
    if total and float(total) > 1:
        return f"{STAGE_UNITS.get(stage, 'step')} {float(done):.0f}/{float(total):.0f}"
    return str(p.get("message") or "starting")


def job_activity(job: Mapping | None) -> str:
    """What the re-run is doing, for a stale layer's label: queued, which stage with its progress,
    or how it ended."""
    if job is None:
        return "re-run not started"
    st = job.get("status")
    if st == "queued":
        return "re-run queued"
    if st == "running":
        cur = job.get("current_stage")
        return f"re-running {cur} ({stage_progress_text(job, cur)})" if cur else "re-running"
    if st == "done":
        return "loading the new results"
    if st == "failed":
        err = str(job.get("error") or "").splitlines()
        return "re-run failed" + (f": {err[0]}" if err else "")
    return f"re-run {st}"


@dataclass
class StaleMark:
    """A re-run the viewer is waiting for: from which stage, since when, and the job's last state.

    Fields:
        stale_from: first stale stage (the API's ``stale_from`` or the job's ``from_stage``).
        since_unix_s: time of the edit (Unix s); artifacts written later are the re-run's.
        job_id: the re-run job (None when the edit queued none).
        job: the job's last ``GET /api/jobs/{id}`` body (None before the first poll).
    """

    stale_from: str
    since_unix_s: float
    job_id: int | None = None
    job: dict | None = field(default=None)


def layer_states(order: Iterable[str], mark: StaleMark | None, stamps: Mapping[str, float]) -> dict[str, str]:
    """Layer name -> ``""`` (fresh) or why it is out of date, given the loaded manifests' ``stamps``."""
    if mark is None:
        return {name: "" for name in LAYERS}
    stale = stale_layers(order, mark.stale_from, rewritten_since(stamps, mark.since_unix_s))
    why = job_activity(mark.job) if mark.job_id is not None else "no re-run queued"
    return {name: (why if name in stale else "") for name in LAYERS}


def layers_markdown(states: Mapping[str, str]) -> str:
    """The GUI's layer block: one line per layer, ``⚠ out of date — <why>`` or ``✓ up to date``;
    empty when every layer is up to date."""
    if not any(states.values()):
        return ""
    lines = [f"- **{name}**: " + (f"⚠ out of date — {why}" if why else "✓ up to date") for name, why in states.items()]
    return "**Layers after the edit**\n\n" + "\n".join(lines)
