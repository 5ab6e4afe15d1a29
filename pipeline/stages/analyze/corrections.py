"""Annotators' event edits on the detector's events (pure): ``apply_corrections``.

The edits (``correct_event``, ``add_event``, ``delete_event``; ``pipeline.schema.annotations``)
are applied in order after detection, on every run, so they survive re-runs. An edit names an
event by athlete, kind and the frame of its peak (strike); it takes the nearest such event within
``CorrectionConfig.match_frames`` (a clinch: ``frame`` within its span, either athlete). An edit
whose event is not there (any more) is skipped and reported, never raised. An added event's
measurements come from the 3D bodies over the annotated frames (``EVENT_SOURCES``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pipeline.evaluate.glove_contact import glove_gaps
from pipeline.schema.analytics import EVADE_KINDS, BoutEvents
from pipeline.schema.annotation_checks import AnnotationBounds, check_annotation
from pipeline.schema.annotation_text import describe_annotation
from pipeline.schema.annotations import AddEvent, Annotation, CorrectEvent, DeleteEvent
from pipeline.stages.analyze import blocks, outcome
from pipeline.stages.analyze.body import Body
from pipeline.stages.analyze.config import AnalyzeConfig

EVENT_EDITS: tuple[type, ...] = (CorrectEvent, AddEvent, DeleteEvent)
"""The annotation types this module applies (others are ignored)."""


@dataclass(frozen=True)
class CorrectionReport:
    """applied: edits that found (or made) their event; unmatched: one line per edit that did
    not, with the reason."""

    applied: int = 0
    unmatched: tuple[str, ...] = field(default_factory=tuple)


@dataclass(frozen=True)
class Athlete:
    """An athlete's 3D body on the analysed frames and the opponent it is analysed against."""

    body: Body
    opponent: Body | None


def _rows(ev: BoutEvents) -> tuple[list[dict[str, Any]], list[dict[str, Any]], list[dict[str, Any]]]:
    punches = [
        {"person": int(ev.punch_person[i]), "hand": str(ev.punch_hand[i]), "type": str(ev.punch_type[i]),
         "start": int(ev.punch_start_frame[i]), "peak": int(ev.punch_peak_frame[i]), "end": int(ev.punch_end_frame[i]),
         "speed": float(ev.punch_peak_speed_mps[i]), "extension": float(ev.punch_extension[i]),
         "target": str(ev.punch_target[i]), "outcome": str(ev.punch_outcome[i]),
         "confidence": float(ev.punch_confidence[i]), "source": str(ev.punch_source[i])}
        for i in range(ev.n_punches)
    ]  # fmt: skip
    evades = [
        {"person": int(ev.evade_person[i]), "kind": str(ev.evade_kind[i]), "start": int(ev.evade_start_frame[i]),
         "peak": int(ev.evade_peak_frame[i]), "end": int(ev.evade_end_frame[i]),
         "displacement": float(ev.evade_displacement_m[i]), "punch": punches[int(ev.evade_punch[i])],
         "source": str(ev.evade_source[i])}
        for i in range(ev.n_evades)
    ]  # fmt: skip
    clinches = [
        {"start": int(s), "end": int(e), "source": str(src)}
        for s, e, src in zip(ev.clinch_start_frame, ev.clinch_end_frame, ev.clinch_source, strict=True)
    ]
    return punches, evades, clinches


def _events(ev: BoutEvents, punches: list[dict[str, Any]], evades: list[dict[str, Any]],
            clinches: list[dict[str, Any]]) -> BoutEvents:  # fmt: skip
    punches = sorted(punches, key=lambda p: (p["peak"], p["person"]))
    index = {id(p): k for k, p in enumerate(punches)}
    evades = sorted(evades, key=lambda e: (e["peak"], e["person"]))
    clinches = sorted(clinches, key=lambda c: c["start"])

    def col(rows: list[dict[str, Any]], key: str, dtype: Any) -> np.ndarray:
        if not rows:
            return np.zeros(0, dtype="<U1" if dtype is np.str_ else dtype)
        return np.array([r[key] for r in rows], dtype=dtype)

    return BoutEvents(
        fps=ev.fps, person_ids=ev.person_ids,
        punch_person=col(punches, "person", np.int64), punch_hand=col(punches, "hand", np.str_),
        punch_type=col(punches, "type", np.str_), punch_start_frame=col(punches, "start", np.int64),
        punch_peak_frame=col(punches, "peak", np.int64), punch_end_frame=col(punches, "end", np.int64),
        punch_peak_speed_mps=col(punches, "speed", np.float64), punch_extension=col(punches, "extension", np.float64),
        punch_target=col(punches, "target", np.str_), punch_outcome=col(punches, "outcome", np.str_),
        punch_confidence=col(punches, "confidence", np.float64), punch_source=col(punches, "source", np.str_),
        evade_person=col(evades, "person", np.int64), evade_kind=col(evades, "kind", np.str_),
        evade_start_frame=col(evades, "start", np.int64), evade_peak_frame=col(evades, "peak", np.int64),
        evade_end_frame=col(evades, "end", np.int64), evade_displacement_m=col(evades, "displacement", np.float64),
        evade_punch=np.array([index[id(e["punch"])] for e in evades], dtype=np.int64) if evades else np.zeros(0, np.int64),
        evade_source=col(evades, "source", np.str_),
        clinch_start_frame=col(clinches, "start", np.int64), clinch_end_frame=col(clinches, "end", np.int64),
        clinch_source=col(clinches, "source", np.str_),
    )  # fmt: skip


def _nearest(rows: list[dict[str, Any]], frame: int, tol: int, clinch: bool = False) -> dict[str, Any] | None:
    """The row nearest ``frame`` (its peak; a clinch's span) within ``tol`` frames, first on ties."""

    def gap(r: dict[str, Any]) -> int:
        if clinch:
            return (
                0 if r["start"] <= frame <= r["end"] else min(abs(frame - r["start"]), abs(frame - r["end"]))
            )
        return abs(frame - r["peak"])

    near = [r for r in rows if gap(r) <= tol]
    return min(near, key=gap) if near else None


def _candidates(a: CorrectEvent | DeleteEvent, punches: list[dict[str, Any]], evades: list[dict[str, Any]],
                clinches: list[dict[str, Any]]) -> list[dict[str, Any]]:  # fmt: skip
    if a.event == "punch":
        return [p for p in punches if p["person"] == a.person]
    if a.event in EVADE_KINDS:
        return [e for e in evades if e["person"] == a.person and e["kind"] == a.event]
    return clinches if a.event == "clinch" else []


def _span_rows(frames: np.ndarray, first: int, last: int) -> np.ndarray:
    """Rows of the analysed ``frames`` (video frame indices) in ``[first, last]``."""
    return np.arange(int(np.searchsorted(frames, first, "left")), int(np.searchsorted(frames, last, "right")))


def _speeds(x: np.ndarray, ok: np.ndarray, frames: np.ndarray, fps: float) -> np.ndarray:
    """(rows,) speed (m/s) reaching each row from the previous valid row (0 where unknown)."""
    v = np.zeros(x.shape[0])
    good = np.flatnonzero(ok)
    if good.size >= 2:
        dt = np.diff(frames[good]) / fps
        v[good[1:]] = np.linalg.norm(np.diff(x[good], axis=0), axis=1) / dt
    return v


def _punch_of(a: AddEvent, me: Athlete, frames: np.ndarray, cfg: AnalyzeConfig) -> dict[str, Any] | str:
    """The added punch measured on the 3D, or the reason it cannot be placed."""
    b = me.body
    rows = _span_rows(frames, a.frame_start, a.frame_end)
    tracks = {}
    for side in ("left", "right"):
        wr, wok = b.point(f"{side}_wrist")
        sh, sok = b.point(f"{side}_shoulder")
        el, eok = b.point(f"{side}_elbow")
        ok = (wok & sok)[rows]
        reach = np.where(ok, np.linalg.norm(wr[rows] - sh[rows], axis=1), 0.0)
        arm_ok = wok & sok & eok
        arm = np.linalg.norm(sh - el, axis=1) + np.linalg.norm(el - wr, axis=1)
        length = float(np.median(arm[arm_ok])) if arm_ok.any() else 0.0
        tracks[side] = (
            rows[ok] if ok.any() else rows[:0],
            reach,
            _speeds(wr[rows], wok[rows], frames[rows], b.fps),
            length,
        )
    hand = a.hand
    if hand is None:
        if not any(t[0].size for t in tracks.values()):
            return (
                f"no hand given and no 3D wrist of person {a.person} in frames {a.frame_start}–{a.frame_end}"
            )
        hand = max(("left", "right"), key=lambda h: float(tracks[h][2].max(initial=0.0)))
    valid_rows, reach, speed, length = tracks[hand]
    if a.frame is not None:
        peak = a.frame
    elif valid_rows.size:
        peak = int(frames[rows[int(np.argmax(reach))]])
    else:
        peak = (a.frame_start + a.frame_end) // 2
    out_rows = frames[rows] <= peak
    at_peak = np.flatnonzero(frames[rows] == peak)
    extension = float(reach[at_peak[0]] / length) if at_peak.size and length > 0 else 0.0
    target = "none"
    opp = me.opponent
    if opp is not None and at_peak.size:
        r = rows[at_peak[0]]
        lo, hi = max(0, r - cfg.outcome.window_frames), min(b.n_frames, r + cfg.outcome.window_frames + 1)
        near = np.arange(lo, hi)
        ok = b.ok[near].all(axis=1) & opp.ok[near].all(axis=1)
        if ok.any():
            gaps = glove_gaps(b.xyz[near[ok]], hand, opp.xyz[near[ok]], b.names)
            target, _ = outcome.from_gaps({k: float(v.min()) for k, v in gaps.items()}, cfg.outcome)
    return {
        "person": a.person, "hand": hand, "type": a.punch_type, "start": a.frame_start, "peak": peak,
        "end": a.frame_end, "speed": float(speed[out_rows].max(initial=0.0)), "extension": extension,
        "target": target, "outcome": a.outcome, "confidence": 1.0, "source": "annotator",
    }  # fmt: skip


def _evade_of(
    a: AddEvent, me: Athlete, frames: np.ndarray, punches: list[dict[str, Any]], tol: int
) -> dict[str, Any] | str:
    """The added slip or duck with its head displacement on the 3D, tied to the opponent's
    punch whose strike is nearest its peak; or the reason it cannot be placed."""
    rows = _span_rows(frames, a.frame_start, a.frame_end)
    head, hok = me.body.point("mid:left_ear+right_ear")
    ok_rows = rows[hok[rows]]
    if a.frame is not None:
        peak = a.frame
    elif ok_rows.size:
        h0 = head[ok_rows[0]]
        score = (
            h0[2] - head[ok_rows, 2]
            if a.event == "duck"
            else np.linalg.norm(head[ok_rows, :2] - h0[:2], axis=1)
        )
        peak = int(frames[ok_rows[int(np.argmax(score))]])
    else:
        peak = (a.frame_start + a.frame_end) // 2
    displacement = 0.0
    at_peak = ok_rows[frames[ok_rows] == peak]
    if ok_rows.size and at_peak.size:
        d = head[at_peak[0]] - head[ok_rows[0]]
        displacement = float(-d[2] if a.event == "duck" else np.linalg.norm(d[:2]))
    theirs = [
        p
        for p in punches
        if p["person"] != a.person and a.frame_start - tol <= p["peak"] <= a.frame_end + tol
    ]
    if not theirs:
        return f"no punch of the opponent with its strike in frames {a.frame_start - tol}–{a.frame_end + tol} to {a.event}"
    punch = min(theirs, key=lambda p: abs(p["peak"] - peak))
    return {"person": a.person, "kind": a.event, "start": a.frame_start, "peak": peak, "end": a.frame_end,
            "displacement": displacement, "punch": punch, "source": "annotator"}  # fmt: skip


def _guard_of(
    a: AddEvent, me: Athlete, frames: np.ndarray, punches: list[dict[str, Any]], cfg: AnalyzeConfig
) -> dict[str, Any] | str:
    """An added block or parry: tied to the opponent's punch whose strike is nearest its peak
    (``frame``, else that strike clipped to the span), its displacement the punching glove's
    deflection after the peak on the 3D (``blocks.deflection_at``; 0 without it)."""
    tol = cfg.corrections.match_frames
    theirs = [
        p
        for p in punches
        if p["person"] != a.person and a.frame_start - tol <= p["peak"] <= a.frame_end + tol
    ]
    if not theirs:
        return f"no punch of the opponent with its strike in frames {a.frame_start - tol}–{a.frame_end + tol} to {a.event}"
    ref = a.frame if a.frame is not None else (a.frame_start + a.frame_end) // 2
    punch = min(theirs, key=lambda p: abs(p["peak"] - ref))
    peak = a.frame if a.frame is not None else int(np.clip(punch["peak"], a.frame_start, a.frame_end))
    displacement = 0.0
    rows = np.searchsorted(frames, [punch["start"], peak])
    if me.opponent is not None and rows[1] < frames.size and frames[rows[1]] == peak and rows[0] < frames.size:
        displacement = blocks.deflection_at(
            me.opponent, punch["hand"], me.body, int(rows[0]), int(rows[1]), cfg
        )
    return {"person": a.person, "kind": a.event, "start": a.frame_start, "peak": peak, "end": a.frame_end,
            "displacement": displacement, "punch": punch, "source": "annotator"}  # fmt: skip


def _add_clinch(clinches: list[dict[str, Any]], first: int, last: int) -> None:
    """Add ``[first, last]``, merged with the clinches it overlaps or touches."""
    touching = [c for c in clinches if c["start"] <= last + 1 and first <= c["end"] + 1]
    for c in touching:
        clinches.remove(c)
        first, last = min(first, c["start"]), max(last, c["end"])
    clinches.append({"start": first, "end": last, "source": "annotator" if not touching else "corrected"})


def _apply(a: Annotation, punches: list[dict[str, Any]], evades: list[dict[str, Any]], clinches: list[dict[str, Any]],
           athletes: dict[int, Athlete], frames: np.ndarray, cfg: AnalyzeConfig) -> str:  # fmt: skip
    """Apply one edit to the rows in place; "" when done, else why not."""
    tol = cfg.corrections.match_frames
    try:  # the server checked it; an annotations.json written by hand may not have been
        check_annotation(a, AnnotationBounds())
    except ValueError as err:
        return str(err)
    if isinstance(a, CorrectEvent | DeleteEvent):
        row = _nearest(_candidates(a, punches, evades, clinches), a.frame, tol, clinch=a.event == "clinch")
        if row is None:
            who = "" if a.event == "clinch" else f" of person {a.person}"
            return f"no {a.event}{who} within ±{tol} frames of frame {a.frame}"
        if isinstance(a, DeleteEvent):
            for rows in (punches, evades, clinches):
                if any(r is row for r in rows):
                    rows.remove(row)
            evades[:] = [e for e in evades if e["punch"] is not row]
        else:  # a punch (check_annotation)
            row["type"] = a.punch_type or row["type"]
            row["outcome"] = a.outcome or row["outcome"]
            row["source"] = "annotator" if row["source"] == "annotator" else "corrected"
        return ""
    if not isinstance(a, AddEvent):
        return f"{a.kind} is not an event edit"
    me = athletes.get(a.person)
    if me is None:
        return f"person {a.person} is not an analysed athlete {sorted(athletes)}"
    if a.event == "clinch":
        _add_clinch(clinches, a.frame_start, a.frame_end)
        return ""
    if a.event == "punch":
        new = _punch_of(a, me, frames, cfg)
    elif a.event in ("block", "parry"):
        new = _guard_of(a, me, frames, punches, cfg)
    else:
        new = _evade_of(a, me, frames, punches, tol)
    if isinstance(new, str):
        return new
    (punches if a.event == "punch" else evades).append(new)
    return ""


def apply_corrections(events: BoutEvents, edits: Sequence[Annotation], athletes: dict[int, Athlete],
                      frames: np.ndarray, cfg: AnalyzeConfig = AnalyzeConfig()) -> tuple[BoutEvents, CorrectionReport]:  # fmt: skip
    """``events`` with the event ``edits`` applied in order (other kinds ignored).

    ``athletes``: person id -> 3D body on the analysed ``frames`` (video frame indices, strictly
    increasing), used to measure added events. Corrected punches get source ``"corrected"``, added
    events ``"annotator"``; deleting a punch deletes the defence against it. Never raises on an edit
    that is invalid or whose event is missing: it is listed in the report's ``unmatched`` with
    the reason.
    """
    mine = [a for a in edits if isinstance(a, EVENT_EDITS)]
    if not mine:
        return events, CorrectionReport()
    punches, evades, clinches = _rows(events)
    unmatched = []
    for a in mine:
        why = _apply(a, punches, evades, clinches, athletes, frames, cfg)
        if why:
            unmatched.append(f"{describe_annotation(a)}: {why}")
    report = CorrectionReport(len(mine) - len(unmatched), tuple(unmatched))
    return _events(events, punches, evades, clinches), report
