"""Human edits as typed, append-only overlays.

Annotations never modify an artifact. A stage that consumes a kind of edit applies
the active edits to its inputs and records their hash in its manifest, so that
adding or undoing an edit makes that stage (and every later one) stale.

The server stores annotations in SQLite and writes the active ones (not
superseded) to ``<session>/annotations.json`` before it queues a job; the runner
reads that file. The JSON form of each edit is ``{"kind": ..., **fields}``.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import MISSING, asdict, dataclass, fields
from pathlib import Path
from typing import Literal

AnnotationKind = Literal[
    "assign_identity", "swap_identities", "split_track", "merge_tracks", "mark_invalid", "fix_keypoint", "label_contact",
    "correct_event", "add_event", "delete_event",
]

EVENT_KINDS: tuple[str, ...] = ("punch", "slip", "duck", "block", "parry", "clinch")
"""Events of the analyze stage an annotator can correct, add or delete (``BoutEvents`` rows;
slip, duck, block and parry are the defender's, tied to the opponent's punch)."""


@dataclass(frozen=True)
class AssignIdentity:
    """Detections of ``track`` in ``view`` over ``[frame_start, frame_end]`` belong to ``person``
    (``person = -1`` means "nobody": a bystander)."""

    view: str
    track: int
    frame_start: int
    frame_end: int
    person: int
    kind: str = "assign_identity"


@dataclass(frozen=True)
class SwapIdentities:
    """Over frames ``[frame, frame_end)`` persons ``person_a`` and ``person_b`` swap identities in
    ``view`` (``view = ""`` = in every view; ``frame_end = None`` = to the end of the bout)."""

    frame: int
    person_a: int
    person_b: int
    view: str = ""
    kind: str = "swap_identities"
    frame_end: int | None = None


@dataclass(frozen=True)
class SplitTrack:
    """Track ``track`` in ``view`` is a different person from ``frame`` on: the tail gets a new id."""

    view: str
    track: int
    frame: int
    kind: str = "split_track"


@dataclass(frozen=True)
class MergeTracks:
    """Track ``track_b`` in ``view`` is the same person as ``track_a``."""

    view: str
    track_a: int
    track_b: int
    kind: str = "merge_tracks"


@dataclass(frozen=True)
class MarkInvalid:
    """The detection of ``track`` in ``view`` at ``frame`` is wrong and must be ignored."""

    view: str
    frame: int
    track: int
    kind: str = "mark_invalid"


@dataclass(frozen=True)
class FixKeypoint:
    """Joint ``joint`` of the detection of ``track`` in ``view`` at ``frame`` is at ``(x_px, y_px)``."""

    view: str
    frame: int
    track: int
    joint: str
    x_px: float
    y_px: float
    kind: str = "fix_keypoint"


@dataclass(frozen=True)
class LabelContact:
    """A labelled contact between two persons' body parts over a frame span (dataset label)."""

    frame_start: int
    frame_end: int
    person_a: int
    part_a: str
    person_b: int
    part_b: str
    kind: str = "label_contact"


@dataclass(frozen=True)
class CorrectEvent:
    """The punch of ``person`` whose strike (peak frame) lies within the analyze stage's match
    tolerance (``CorrectionConfig.match_frames``, ±2 frames) of ``frame`` gets ``punch_type``
    and/or ``outcome`` (``None`` = keep the detector's). ``event`` must be ``"punch"``."""

    person: int
    event: str
    frame: int
    kind: str = "correct_event"
    punch_type: str | None = None
    outcome: str | None = None


@dataclass(frozen=True)
class AddEvent:
    """An event the detector missed: ``event`` (``EVENT_KINDS``) of ``person`` over the inclusive
    frames ``[frame_start, frame_end]``, its peak/strike at ``frame`` (``None`` = found on the
    3D). Punches need ``punch_type`` and ``outcome``; ``hand`` ``None`` = the faster wrist. A
    clinch is shared: ``person`` is either athlete."""

    person: int
    event: str
    frame_start: int
    frame_end: int
    kind: str = "add_event"
    frame: int | None = None
    hand: str | None = None
    punch_type: str | None = None
    outcome: str | None = None


@dataclass(frozen=True)
class DeleteEvent:
    """The detector's ``event`` of ``person`` at ``frame`` is not one: it is removed (matched as
    for ``CorrectEvent``; a clinch by ``frame`` within its span, either athlete). Deleting a
    punch also deletes the defence (slips, ducks, blocks, parries) against it."""

    person: int
    event: str
    frame: int
    kind: str = "delete_event"


Annotation = (
    AssignIdentity | SwapIdentities | SplitTrack | MergeTracks | MarkInvalid | FixKeypoint | LabelContact
    | CorrectEvent | AddEvent | DeleteEvent
)

ANNOTATION_TYPES: dict[str, type] = {
    "assign_identity": AssignIdentity,
    "swap_identities": SwapIdentities,
    "split_track": SplitTrack,
    "merge_tracks": MergeTracks,
    "mark_invalid": MarkInvalid,
    "fix_keypoint": FixKeypoint,
    "label_contact": LabelContact,
    "correct_event": CorrectEvent,
    "add_event": AddEvent,
    "delete_event": DeleteEvent,
}

# Which stage consumes which edit kinds (the first stage an edit makes stale).
CONSUMED_BY: dict[str, str] = {
    "split_track": "track",
    "merge_tracks": "track",
    "mark_invalid": "track",
    "fix_keypoint": "track",
    "assign_identity": "associate",
    "swap_identities": "associate",
    "label_contact": "evaluate",
    "correct_event": "analyze",
    "add_event": "analyze",
    "delete_event": "analyze",
}


def annotation_from_dict(d: dict) -> Annotation:
    """Build a typed annotation from its JSON dict; ``ValueError`` on unknown kind or fields."""
    if not isinstance(d, dict) or "kind" not in d:
        raise ValueError(f"annotation must be an object with a 'kind', got {d!r}")
    cls = ANNOTATION_TYPES.get(d["kind"])
    if cls is None:
        raise ValueError(f"unknown annotation kind {d['kind']!r}; known: {sorted(ANNOTATION_TYPES)}")
    names = {f.name for f in fields(cls)}
    extra = set(d) - names
    missing = {f.name for f in fields(cls) if f.default is MISSING and f.default_factory is MISSING and f.name not in d}
    if extra:
        raise ValueError(f"annotation {d['kind']}: unknown fields {sorted(extra)}")
    if missing:
        raise ValueError(f"annotation {d['kind']}: missing fields {sorted(missing)}")
    return cls(**d)  # type: ignore[no-any-return]


def annotation_to_dict(a: Annotation) -> dict:
    """The JSON form ``{"kind": ..., **fields}``; an optional field left at ``None`` is omitted, so
    edits written before that field existed keep their JSON (and their hash)."""
    optional = {f.name for f in fields(a) if f.default is None}
    return {k: v for k, v in asdict(a).items() if not (k in optional and v is None)}


def annotations_for(annotations: list[Annotation], stage: str) -> list[Annotation]:
    """The edits consumed by ``stage``, in order."""
    return [a for a in annotations if CONSUMED_BY[a.kind] == stage]


def annotations_hash(annotations: list[Annotation]) -> str:
    """Stable hash of an ordered list of edits (empty list -> hash of ``[]``)."""
    blob = json.dumps([annotation_to_dict(a) for a in annotations], sort_keys=True).encode()
    return hashlib.sha256(blob).hexdigest()


def load_annotations(path: Path) -> list[Annotation]:
    """Read ``annotations.json`` (a list of edit dicts); a missing file means no edits."""
    if not path.exists():
        return []
    try:
        raw = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: malformed JSON: {e}") from e
    if not isinstance(raw, list):
        raise ValueError(f"{path}: expected a JSON list of annotations, got {type(raw).__name__}")
    out = []
    for i, d in enumerate(raw):
        try:
            out.append(annotation_from_dict(d))
        except (TypeError, ValueError) as e:
            raise ValueError(f"{path}: annotation #{i}: {e}") from e
    return out


def save_annotations(path: Path, annotations: list[Annotation]) -> None:
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps([annotation_to_dict(a) for a in annotations], indent=1))
    tmp.replace(path)
