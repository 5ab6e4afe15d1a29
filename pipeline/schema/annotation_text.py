"""One line of text per edit, for edit-history lists (server API, viewer, picker)."""

from __future__ import annotations

from collections.abc import Mapping

from pipeline.schema.annotations import (
    AddEvent,
    Annotation,
    AssignIdentity,
    CorrectEvent,
    DeleteEvent,
    FixKeypoint,
    LabelContact,
    MarkInvalid,
    MergeTracks,
    SplitTrack,
    SwapIdentities,
)


def _who(pid: int, names: Mapping[int, str]) -> str:
    if pid == -1:
        return "nobody"
    return f"{names[pid]} (#{pid})" if names.get(pid) else f"person {pid}"


def _frames(first: int, last: int) -> str:
    return f"frame {first}" if first == last else f"frames {first}–{last}"


def describe_annotation(a: Annotation, names: Mapping[int, str] | None = None) -> str:
    """A short human summary of ``a``; ``names`` maps person ids to display names (frames are
    inclusive in the text: a swap over ``[10, 20)`` reads "frames 10–19")."""
    names = names or {}
    if isinstance(a, AssignIdentity):
        return f"assign {a.view} track {a.track}, {_frames(a.frame_start, a.frame_end)} → {_who(a.person, names)}"
    if isinstance(a, SwapIdentities):
        span = f"from frame {a.frame} on" if a.frame_end is None else _frames(a.frame, a.frame_end - 1)
        where = a.view if a.view else "every view"
        return f"swap {_who(a.person_a, names)} ↔ {_who(a.person_b, names)}, {span}, {where}"
    if isinstance(a, SplitTrack):
        return f"split {a.view} track {a.track} at frame {a.frame}"
    if isinstance(a, MergeTracks):
        return f"merge {a.view} track {a.track_b} into track {a.track_a}"
    if isinstance(a, MarkInvalid):
        return f"mark {a.view} track {a.track} invalid at frame {a.frame}"
    if isinstance(a, FixKeypoint):
        return f"move {a.view} track {a.track} {a.joint} to ({a.x_px:.1f}, {a.y_px:.1f}) px at frame {a.frame}"
    if isinstance(a, LabelContact):
        return (f"contact {_who(a.person_a, names)} {a.part_a} → {_who(a.person_b, names)} {a.part_b}, "
                f"{_frames(a.frame_start, a.frame_end)}")
    if isinstance(a, CorrectEvent):
        changes = [f"{k} → {v}" for k, v in (("type", a.punch_type), ("outcome", a.outcome)) if v is not None]
        return f"correct {_who(a.person, names)} {a.event} at frame {a.frame}: {', '.join(changes) or 'no change'}"
    if isinstance(a, AddEvent):
        what = " ".join(x for x in (a.hand, a.punch_type, a.event if a.punch_type is None else None) if x)
        peak = f", peak at frame {a.frame}" if a.frame is not None else ""
        result = f", {a.outcome}" if a.outcome is not None else ""
        return f"add {_who(a.person, names)} {what}, {_frames(a.frame_start, a.frame_end)}{peak}{result}"
    if isinstance(a, DeleteEvent):
        return f"delete {_who(a.person, names)} {a.event} at frame {a.frame}"
    raise ValueError(f"no description for edit kind {a.kind!r}")
