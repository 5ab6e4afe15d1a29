"""Annotation actions of the viewer: build typed edits from the selection, send them to the API.

Nothing here touches session files: the server stores the edit, rewrites
``annotations.json`` and queues the re-run; the viewer follows that job.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from pipeline.schema.annotations import (
    Annotation,
    AssignIdentity,
    MarkInvalid,
    SplitTrack,
    SwapIdentities,
    annotation_to_dict,
)
from webui.api_client import ApiClient
from webui.scene.session_data import SessionData

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Selection:
    """What the analyst picked: a view, a track in it (or none) and the current frame."""

    view: str
    track: int | None
    frame: int


def track_span(data: SessionData, view: int, track: int) -> tuple[int, int]:
    """First and last frame of ``track`` in ``view``; ``ValueError`` when the track does not exist."""
    t = data.tracks
    if t is None:
        raise ValueError("no tracks loaded: run the track stage first")
    frames = t.frame[(t.view == view) & (t.track_id == track)]
    if frames.size == 0:
        raise ValueError(f"track {track} does not exist in view {data.rig.names[view]!r}")
    return int(frames.min()), int(frames.max())


def assign_edit(data: SessionData, sel: Selection, person: int, from_here: bool) -> AssignIdentity:
    if sel.track is None:
        raise ValueError("select a detection first")
    lo, hi = track_span(data, data.rig.index(sel.view), sel.track)
    start = max(lo, sel.frame) if from_here else lo
    return AssignIdentity(view=sel.view, track=sel.track, frame_start=start, frame_end=hi, person=person)


def swap_edit(sel: Selection, person_a: int, person_b: int, all_views: bool, until: int = 0) -> SwapIdentities:
    """Swap from the selection's frame; ``until`` > 0 ends it before that frame (0: to the end);
    ``ValueError`` when ``until`` does not come after the frame."""
    if until < 0:
        raise ValueError(f"swap until frame must be >= 0 (0: to the end), got {until}")
    if until and until <= sel.frame:
        raise ValueError(f"swap until frame {until} must come after the current frame {sel.frame} (or be 0: to the end)")
    return SwapIdentities(frame=sel.frame, person_a=person_a, person_b=person_b, view="" if all_views else sel.view,
                          frame_end=until or None)


def split_edit(sel: Selection) -> SplitTrack:
    if sel.track is None:
        raise ValueError("select a detection first")
    return SplitTrack(view=sel.view, track=sel.track, frame=sel.frame)


def invalid_edit(sel: Selection) -> MarkInvalid:
    if sel.track is None:
        raise ValueError("select a detection first")
    return MarkInvalid(view=sel.view, frame=sel.frame, track=sel.track)


@dataclass
class EditHistory:
    """Undo/redo through the API: undo reverts the newest active edit, redo re-applies
    the edits this viewer undid (most recent first)."""

    api: ApiClient
    session_id: str
    redo_stack: list[int] = field(default_factory=list)

    def submit(self, edit: Annotation) -> dict:
        """POST the edit with ``rerun``; returns the API's ``{annotation, job, stale_from}``."""
        res = self.api.add_annotation(self.session_id, annotation_to_dict(edit), rerun=True)
        self.redo_stack.clear()
        return res

    def undo(self) -> dict | None:
        active = self.api.annotations(self.session_id)
        if not active:
            return None
        last = active[-1]
        res = self.api.undo(last["id"], rerun=True)
        self.redo_stack.append(int(last["id"]))
        return res

    def undo_entry(self, annotation_id: int) -> dict:
        """Revert edit ``annotation_id`` (any active one); it can then be redone."""
        res = self.api.undo(annotation_id, rerun=True)
        self.redo_stack.append(int(annotation_id))
        return res

    def entries(self) -> list[dict]:
        """The session's edit history, newest first (``GET .../annotations/history``)."""
        return self.api.history(self.session_id)

    def redo(self) -> dict | None:
        if not self.redo_stack:
            return None
        aid = self.redo_stack.pop()
        return self.api.redo(aid, rerun=True)

    def count(self) -> int:
        return len(self.api.annotations(self.session_id))


def describe_selection(data: SessionData, sel: Selection, names: dict[int, str]) -> str:
    """One line for the panel: which track, and who it is at this frame after the last run."""
    if sel.track is None:
        return f"{sel.view} @ frame {sel.frame}: no detection selected"
    v = data.rig.index(sel.view)
    pid = data.track_person(v, sel.track, sel.frame)
    rows = data.det_rows(v, sel.frame)
    conf = float("nan")
    if data.tracks is not None and rows.size:
        hit = rows[data.tracks.track_id[rows] == sel.track]
        if hit.size:
            conf = float(data.confidence_of_rows(hit)[0])
    who = names.get(pid, "unassigned") if pid >= 0 else "unassigned"
    conf_txt = f"{conf:.2f}" if np.isfinite(conf) else "n/a"
    return f"{sel.view} track #{sel.track} @ frame {sel.frame} is **{who}** (confidence {conf_txt})"
