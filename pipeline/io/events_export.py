"""Exports of the analytics: the bout's events as JSON or CSV, and the per-athlete summary.

JSON (``events_to_json``)::

    {
      "format": "cornerman.events/v1",
      "fps": 50.0,
      "source": "fit",                       # the 3D result analysed
      "athletes": [{"id": 0, "name": "Red"}, ...],
      "punches": [{"athlete_id", "athlete", "hand", "type", "start_frame", "peak_frame",
                   "end_frame", "start_s", "peak_s", "end_s", "peak_speed_mps", "extension",
                   "target", "outcome", "confidence", "source"}, ...],
      "evades": [{"athlete_id", "athlete", "kind", "start_frame", "peak_frame", "end_frame",
                  "start_s", "peak_s", "end_s", "displacement_m", "punch", "source"}, ...],
      "clinches": [{"start_frame", "end_frame", "start_s", "end_s", "source"}, ...]
    }

Times are seconds from frame 0 (``frame / fps``); ``evades`` are the defence against one
punch: ``kind`` slip, duck, block or parry (``pipeline.schema.analytics.EVADE_KINDS``;
``displacement_m``: a slip's or duck's head displacement, a block's or parry's sideways
deflection of the punching glove); ``punch`` is the index in ``punches`` of the punch defended; ``source`` says who made the event: ``detector``, ``corrected`` (an
annotator changed its type or outcome) or ``annotator`` (added by hand;
``pipeline.schema.analytics.EVENT_SOURCES``). CSV (``events_to_csv``) has one row per event with the union of
those columns and ``event`` = punch, slip, duck, block, parry or clinch.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any, Literal

from pipeline.schema.analytics import AthleteSeries, BoutEvents

EventsFormat = Literal["json", "csv"]
EVENTS_FORMAT_ID = "cornerman.events/v1"
ANALYZE_STAGE = "analyze"
CSV_COLUMNS: tuple[str, ...] = (
    "event", "athlete_id", "athlete", "start_frame", "peak_frame", "end_frame", "start_s", "peak_s", "end_s",
    "hand", "type", "peak_speed_mps", "extension", "target", "outcome", "confidence", "displacement_m", "punch",
    "source",
)  # fmt: skip


def load_analytics(session_dir: Path) -> tuple[BoutEvents, AthleteSeries, str]:
    """(events, series, 3D source analysed) of a session; ``LookupError`` when the analyze
    stage has no complete artifacts."""
    from pipeline.artifacts import ArtifactStore

    store = ArtifactStore(Path(session_dir))
    m = store.manifest(ANALYZE_STAGE)
    if m is None or not store.has(ANALYZE_STAGE, "events.npz") or not store.has(ANALYZE_STAGE, "series.npz"):
        raise LookupError(f"{session_dir}: the analyze stage has not run (cornerman run {session_dir} --to-stage analyze)")
    events = store.load(ANALYZE_STAGE, "events", BoutEvents)
    series = store.load(ANALYZE_STAGE, "series", AthleteSeries)
    return events, series, str(m.metrics.get("source", ""))


def _name(names: dict[int, str], pid: int) -> str:
    return names.get(int(pid), f"athlete {int(pid)}")


def events_to_json(events: BoutEvents, names: dict[int, str] | None = None, source: str = "") -> dict[str, Any]:
    """The JSON document of the module docstring."""
    names = names or {}
    fps = float(events.fps)

    def t(f: Any) -> float:
        return round(int(f) / fps, 3)

    punches = [
        {
            "athlete_id": int(events.punch_person[i]), "athlete": _name(names, events.punch_person[i]),
            "hand": str(events.punch_hand[i]), "type": str(events.punch_type[i]),
            "start_frame": int(events.punch_start_frame[i]), "peak_frame": int(events.punch_peak_frame[i]),
            "end_frame": int(events.punch_end_frame[i]), "start_s": t(events.punch_start_frame[i]),
            "peak_s": t(events.punch_peak_frame[i]), "end_s": t(events.punch_end_frame[i]),
            "peak_speed_mps": round(float(events.punch_peak_speed_mps[i]), 2),
            "extension": round(float(events.punch_extension[i]), 3), "target": str(events.punch_target[i]),
            "outcome": str(events.punch_outcome[i]), "confidence": round(float(events.punch_confidence[i]), 3),
            "source": str(events.punch_source[i]),
        }
        for i in range(events.n_punches)
    ]  # fmt: skip
    evades = [
        {
            "athlete_id": int(events.evade_person[i]), "athlete": _name(names, events.evade_person[i]),
            "kind": str(events.evade_kind[i]), "start_frame": int(events.evade_start_frame[i]),
            "peak_frame": int(events.evade_peak_frame[i]), "end_frame": int(events.evade_end_frame[i]),
            "start_s": t(events.evade_start_frame[i]), "peak_s": t(events.evade_peak_frame[i]),
            "end_s": t(events.evade_end_frame[i]), "displacement_m": round(float(events.evade_displacement_m[i]), 3),
            "punch": int(events.evade_punch[i]), "source": str(events.evade_source[i]),
        }
        for i in range(events.n_evades)
    ]  # fmt: skip
    clinches = [
        {"start_frame": int(s), "end_frame": int(e), "start_s": t(s), "end_s": t(e), "source": str(src)}
        for s, e, src in zip(events.clinch_start_frame, events.clinch_end_frame, events.clinch_source, strict=True)
    ]
    return {
        "format": EVENTS_FORMAT_ID,
        "fps": fps,
        "source": source,
        "athletes": [{"id": int(p), "name": _name(names, p)} for p in events.person_ids],
        "punches": punches,
        "evades": evades,
        "clinches": clinches,
    }


def events_to_csv(events: BoutEvents, names: dict[int, str] | None = None) -> str:
    """One row per event (punches, slips, ducks, blocks, parries, clinches), ordered by start frame."""
    doc = events_to_json(events, names)
    rows: list[dict[str, Any]] = [{"event": "punch", **p} for p in doc["punches"]]
    rows += [{"event": e["kind"], **{k: v for k, v in e.items() if k != "kind"}} for e in doc["evades"]]
    rows += [{"event": "clinch", **c} for c in doc["clinches"]]
    rows.sort(key=lambda r: (r["start_frame"], r["event"]))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(CSV_COLUMNS), lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow(r)
    return buf.getvalue()


def export_events(events: BoutEvents, fmt: EventsFormat, names: dict[int, str] | None = None, source: str = "") -> str:
    """The events as text in ``fmt``; ``ValueError`` for another format."""
    if fmt == "json":
        return json.dumps(events_to_json(events, names, source), indent=1)
    if fmt == "csv":
        return events_to_csv(events, names)
    raise ValueError(f"events format must be json or csv, got {fmt!r}")
