"""Checks of a human edit against the session it is for: the one place these rules live.

``check_annotation(a, bounds)`` raises ``ValueError`` with the reason when an edit names a
frame outside the bout, an unknown camera, a track without a detection where the edit
needs one, an unknown joint, a pixel outside the image or a person that is not one of
the session's. The server's annotation routes answer 422 with that message;
``pipeline.runner.annotation_bounds.annotation_bounds(session_dir)`` reads the
``AnnotationBounds`` of a session folder. A part of the bounds that is ``None`` is not
known yet (e.g. the tracks before the track stage has run) and is not checked.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.schema.analytics import HANDS, OUTCOMES, PUNCH_TYPES
from pipeline.schema.annotations import (
    EVENT_KINDS,
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
    annotation_to_dict,
)
from pipeline.schema.detections import Tracks2D


@dataclass(frozen=True, eq=False)
class AnnotationBounds:
    """What a session's edits may refer to; ``None`` = not known yet (that part is not checked).

    Fields:
        n_frames: frames of the bout; frame fields must lie in ``[0, n_frames)`` (a swap's
            exclusive ``frame_end`` in ``(frame, n_frames]``).
        person_ids: the session's person ids (its athletes, the association's persons and any
            person given a name); the persons an edit names must be among them.
        cameras: camera names in view order; a ``view`` field must be one of them.
        tracks: the tracks edits refer to (the track stage's output with every active track
            edit applied); its ``view`` indexes ``cameras``.
        image_size_wh: (views, 2) image width and height in pixels, by ``cameras`` order.
    """

    n_frames: int | None = None
    person_ids: tuple[int, ...] | None = None
    cameras: tuple[str, ...] | None = None
    tracks: Tracks2D | None = None
    image_size_wh: np.ndarray | None = None


_FRAME_FIELDS = ("frame", "frame_start", "frame_end")
_INT_FIELDS = (*_FRAME_FIELDS, "person", "person_a", "person_b", "track", "track_a", "track_b")


def _is_int(x: object) -> bool:
    return isinstance(x, int | np.integer) and not isinstance(x, bool)


def _check_types(a: Annotation, d: dict) -> None:
    for f in _INT_FIELDS:
        if f in d and d[f] is not None and not _is_int(d[f]):
            raise ValueError(f"{a.kind}: {f} must be an integer, got {d[f]!r}")
    for f in ("view", "joint", "part_a", "part_b", "event", "hand", "punch_type", "outcome"):
        if f in d and d[f] is not None and not isinstance(d[f], str):
            raise ValueError(f"{a.kind}: {f} must be a string, got {d[f]!r}")
    for f in ("x_px", "y_px"):
        if f in d and (isinstance(d[f], bool) or not isinstance(d[f], int | float) or not np.isfinite(d[f])):
            raise ValueError(f"{a.kind}: {f} must be a finite number of pixels, got {d[f]!r}")


def _check_frames(a: Annotation, d: dict, n_frames: int | None) -> None:
    span = f"[0, {n_frames - 1}]" if n_frames is not None else ">= 0"
    for f in _FRAME_FIELDS:
        if f not in d or d[f] is None:
            continue
        if isinstance(a, SwapIdentities) and f == "frame_end":
            # exclusive end: the swap covers [frame, frame_end)
            if d[f] <= d["frame"] or (n_frames is not None and d[f] > n_frames):
                end = f"{n_frames}" if n_frames is not None else "the bout's end"
                raise ValueError(f"{a.kind}: frame_end {d[f]} must be after frame {d['frame']} and at most {end} "
                                 "(the range [frame, frame_end) excludes frame_end)")
            continue
        if d[f] < 0 or (n_frames is not None and d[f] >= n_frames):
            raise ValueError(f"{a.kind}: {f} {d[f]} is outside the bout (frames {span})")
    if "frame_start" in d and d["frame_start"] > d["frame_end"]:
        raise ValueError(f"{a.kind}: frame_start {d['frame_start']} is after frame_end {d['frame_end']}")


def _check_persons(a: Annotation, d: dict, person_ids: tuple[int, ...] | None) -> None:
    names = ("person",) if isinstance(a, AssignIdentity | CorrectEvent | AddEvent | DeleteEvent) else ("person_a", "person_b")
    for f in names:
        if f not in d:
            continue
        if isinstance(a, AssignIdentity) and d[f] == -1:
            continue  # -1 = nobody (a bystander)
        if d[f] < 0 or (person_ids is not None and d[f] not in person_ids):
            known = f"known persons {sorted(person_ids)}" if person_ids is not None else "ids >= 0"
            hint = "; name a new person first (PUT .../identities/{id})" if isinstance(a, AssignIdentity) else ""
            raise ValueError(f"{a.kind}: {f} {d[f]} is not a person of this session ({known}{hint})")
    if isinstance(a, SwapIdentities) and a.person_a == a.person_b:
        raise ValueError(f"{a.kind}: person_a and person_b are both {a.person_a}; a swap needs two persons")


def _check_event(a: CorrectEvent | AddEvent | DeleteEvent) -> None:
    """Event edits: a known event kind, punch type, outcome and hand, and the fields each needs."""
    if a.event not in EVENT_KINDS:
        raise ValueError(f"{a.kind}: event {a.event!r} is not one of {list(EVENT_KINDS)}")
    if isinstance(a, DeleteEvent):
        return
    for f, vocab in (("punch_type", PUNCH_TYPES), ("outcome", OUTCOMES), ("hand", HANDS)):
        v = getattr(a, f, None)
        if v is not None and v not in vocab:
            raise ValueError(f"{a.kind}: {f} {v!r} is not one of {list(vocab)}")
    if isinstance(a, CorrectEvent):
        if a.event != "punch":
            raise ValueError(f"{a.kind}: only a punch's type or outcome can be corrected (event {a.event!r}); "
                             "delete the event and add the right one instead")
        if a.punch_type is None and a.outcome is None:
            raise ValueError(f"{a.kind}: give punch_type and/or outcome (both are missing)")
        return
    if a.event == "punch":
        missing = [f for f in ("punch_type", "outcome") if getattr(a, f) is None]
        if missing:
            raise ValueError(f"{a.kind}: an added punch needs {' and '.join(missing)}")
    else:
        given = [f for f in ("hand", "punch_type", "outcome") if getattr(a, f) is not None]
        if given:
            raise ValueError(f"{a.kind}: {', '.join(given)} only apply to a punch, not to a {a.event}")
    if a.frame is not None and not a.frame_start <= a.frame <= a.frame_end:
        raise ValueError(f"{a.kind}: frame {a.frame} (the peak) is outside frames {a.frame_start}–{a.frame_end}")


def _frames_of(tracks: Tracks2D, v: int, track: int) -> np.ndarray:
    return np.asarray(tracks.frame[(tracks.view == v) & (tracks.track_id == track)])


def _check_tracks(a: Annotation, v: int, view: str, tracks: Tracks2D) -> None:
    """The detections ``a`` names exist in ``tracks`` (view index ``v``)."""
    if isinstance(a, MergeTracks):
        if a.track_a == a.track_b:
            raise ValueError(f"{a.kind}: track_a and track_b are both {a.track_a}; a merge needs two tracks")
        for f, t in (("track_a", a.track_a), ("track_b", a.track_b)):
            if _frames_of(tracks, v, t).size == 0:
                raise ValueError(f"{a.kind}: {f} {t} is not a track of view {view!r}")
        return
    if not isinstance(a, SplitTrack | MarkInvalid | FixKeypoint | AssignIdentity):
        return
    frames = _frames_of(tracks, v, a.track)
    if frames.size == 0:
        raise ValueError(f"{a.kind}: track {a.track} is not a track of view {view!r}")
    if isinstance(a, SplitTrack):
        if not np.any(frames >= a.frame):
            raise ValueError(f"{a.kind}: track {a.track} of view {view!r} has no detection at or after frame {a.frame} "
                             f"(its frames: {int(frames.min())}..{int(frames.max())})")
    elif isinstance(a, AssignIdentity):
        if not np.any((frames >= a.frame_start) & (frames <= a.frame_end)):
            raise ValueError(f"{a.kind}: track {a.track} of view {view!r} has no detection in frames "
                             f"{a.frame_start}..{a.frame_end} (its frames: {int(frames.min())}..{int(frames.max())})")
    elif not np.any(frames == a.frame):
        raise ValueError(f"{a.kind}: track {a.track} of view {view!r} has no detection at frame {a.frame}")
    if isinstance(a, FixKeypoint) and a.joint not in tracks.joint_names:
        raise ValueError(f"{a.kind}: joint {a.joint!r} is not one of the keypoints {list(tracks.joint_names)}")


def check_annotation(a: Annotation, bounds: AnnotationBounds) -> None:
    """``ValueError`` with the reason when ``a`` refers outside the session ``bounds`` describes.

    Every kind: frame fields in ``[0, n_frames)``, spans in order, a swap's ``frame_end`` in
    ``(frame, n_frames]``, ``view`` a known camera (a swap's ``""`` = every view), persons
    among ``person_ids`` (``assign_identity`` also takes -1 = nobody), a swap of two persons.
    With ``tracks``: the named track has a detection at the edit's frame (``mark_invalid``,
    ``fix_keypoint``), at or after it (``split_track``), within the span (``assign_identity``);
    both merged tracks exist and differ. ``fix_keypoint``: a known joint, a pixel inside the image.
    ``label_contact``: non-empty body-part names. Event edits (``correct_event``, ``add_event``,
    ``delete_event``): a known event kind, punch type, outcome and hand; a correction changes a
    punch's type or outcome; an added punch has both, and its peak ``frame`` lies in its span.
    """
    d = annotation_to_dict(a)
    _check_types(a, d)
    _check_frames(a, d, bounds.n_frames)
    _check_persons(a, d, bounds.person_ids)
    if isinstance(a, CorrectEvent | AddEvent | DeleteEvent):
        _check_event(a)
    if isinstance(a, LabelContact):
        for f in ("part_a", "part_b"):
            if not d[f].strip():
                raise ValueError(f"{a.kind}: {f} must name a body part, got {d[f]!r}")
    view = d.get("view", "")
    if "view" in d and not view and not isinstance(a, SwapIdentities):
        raise ValueError(f"{a.kind}: view must name a camera, got ''")
    if not view or bounds.cameras is None:
        return
    if view not in bounds.cameras:
        raise ValueError(f"{a.kind}: view {view!r} is not a camera of this session {list(bounds.cameras)}")
    v = bounds.cameras.index(view)
    if bounds.tracks is not None:
        _check_tracks(a, v, view, bounds.tracks)
    if isinstance(a, FixKeypoint) and bounds.image_size_wh is not None:
        w, h = (int(x) for x in bounds.image_size_wh[v])
        if not (0 <= a.x_px < w and 0 <= a.y_px < h):
            raise ValueError(f"{a.kind}: pixel ({a.x_px}, {a.y_px}) is outside the {w}x{h} image of view {view!r}")
