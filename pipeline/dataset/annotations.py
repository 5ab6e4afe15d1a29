"""The annotations of a release: every human edit with its author and time.

A session folder holds only the edits in force (``annotations.json``, what the stages used), without
authors or times; the server's database holds the full history (author, creation time, undo and
replace chains). The caller passes that history when it has it (``cornerman dataset export`` reads
the server home); otherwise the release says the authors and times are unknown.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipeline.dataset.schemas import ANNOTATIONS_FORMAT_ID
from pipeline.schema.annotations import annotation_to_dict, load_annotations


@dataclass(frozen=True)
class AnnotationRecord:
    """One row of a session's annotation history.

    Fields:
        edit: the edit as JSON (``{"kind": ..., **fields}``, ``pipeline.schema.annotations``), or
            the server's undo marker ``{"kind": "undo", "target": id}``.
        id: the server's annotation id (``None`` when read from ``annotations.json``).
        author: user name of whoever made the edit (``None`` = not recorded).
        created_utc: ISO 8601 UTC time the edit was made (``None`` = not recorded).
        active: whether the edit is in force (not undone or replaced).
        superseded_by: id of the row that undid or replaced this one.
        undoes: for an undo marker, the id of the edit it reverts.
    """

    edit: dict[str, Any]
    id: int | None = None
    author: str | None = None
    created_utc: str | None = None
    active: bool = True
    superseded_by: int | None = None
    undoes: int | None = None


def annotations_doc(session_dir: Path, history: list[AnnotationRecord] | None) -> dict[str, Any]:
    """``annotations.json`` of a release: ``history`` when given (the server's), else the session's
    active edits. ``ValueError`` when the history's active edits are not the ones the stages used."""
    active_file = [annotation_to_dict(a) for a in load_annotations(session_dir / "annotations.json")]
    if history is None:
        rows = [AnnotationRecord(edit=e) for e in active_file]
        provenance = "session_file"
        note = (
            "The edits in force, from the session's annotations.json; authors and times were not available "
            "(export with the server home that holds the session to include them)."
        )
    else:
        rows = list(history)
        provenance = "server"
        note = "The full history from the server database: undone and replaced edits have active = false."
        in_force = [r.edit for r in rows if r.active and r.edit.get("kind") != "undo"]
        if in_force != active_file:
            raise ValueError(
                f"{session_dir / 'annotations.json'}: its {len(active_file)} edits differ from the {len(in_force)} active "
                "edits of the server's history (was the folder edited outside the server?); re-run the session from "
                "the server, or export with --no-server"
            )
    return {
        "format": ANNOTATIONS_FORMAT_ID,
        "provenance": provenance,
        "note": note,
        "annotations": [
            {
                "id": r.id,
                "edit": r.edit,
                "author": r.author,
                "created_utc": r.created_utc,
                "active": r.active,
                "superseded_by": r.superseded_by,
                "undoes": r.undoes,
            }
            for r in rows
        ],
    }


def annotation_counts(doc: dict[str, Any]) -> Counter[tuple[str, str]]:
    """(kind, author) -> number of active edits in an ``annotations.json`` document (author
    ``"unknown"`` when not recorded)."""
    out: Counter[tuple[str, str]] = Counter()
    for row in doc["annotations"]:
        if row["active"] and row["edit"]["kind"] != "undo":
            out[(row["edit"]["kind"], row["author"] or "unknown")] += 1
    return out
