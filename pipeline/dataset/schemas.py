"""JSON Schemas (draft 2020-12) of every JSON file kind of a release (``schemas/<kind>.schema.json``).

The annotation edits' schema is generated from ``pipeline.schema.annotations``, so a new edit kind
appears here without a second definition.
"""

from __future__ import annotations

import dataclasses
import typing
from typing import Any

from pipeline.dataset.layout import FORMAT_ID, JSON_KINDS, KEYPOINT_SOURCES, SESSION_ID
from pipeline.io.events_export import EVENTS_FORMAT_ID
from pipeline.schema.analytics import EVENT_SOURCES
from pipeline.schema.annotations import ANNOTATION_TYPES

DRAFT = "https://json-schema.org/draft/2020-12/schema"
CALIBRATION_FORMAT_ID = "cornerman.calibration/v1"
VIDEOS_FORMAT_ID = "cornerman.videos/v1"
ANNOTATIONS_FORMAT_ID = "cornerman.annotations/v1"
META_FORMAT_ID = "cornerman.session/v1"

_SHA256 = {"type": "string", "pattern": "^[0-9a-f]{64}$"}
_NAT = {"type": "integer", "minimum": 0}
_NUM = {"type": "number"}
_STR = {"type": "string"}
_TIME = {"type": "string", "format": "date-time"}
_NULL_TIME = {"type": ["string", "null"], "format": "date-time"}


def _obj(
    props: dict[str, Any], required: tuple[str, ...] | None = None, extra: bool = False
) -> dict[str, Any]:
    """An object schema; every property is required unless ``required`` says otherwise."""
    return {
        "type": "object",
        "properties": props,
        "required": list(props if required is None else required),
        "additionalProperties": extra,
    }


def _vec(n: int, item: dict[str, Any] = _NUM) -> dict[str, Any]:
    return {"type": "array", "items": item, "minItems": n, "maxItems": n}


def _doc(kind: str, title: str, body: dict[str, Any]) -> dict[str, Any]:
    return {"$schema": DRAFT, "$id": f"{FORMAT_ID}/{kind}.schema.json", "title": title, **body}


def _release() -> dict[str, Any]:
    session = _obj({
        "id": {"type": "string", "pattern": SESSION_ID.pattern},
        "name": _STR,
        "path": {"type": "string", "pattern": "^sessions/[^/]+$"},
        "n_frames": _NAT,
        "n_cameras": _NAT,
        "athletes": {"type": "array", "items": _STR},
    })  # fmt: skip
    return _obj({
        "format": {"const": FORMAT_ID},
        "cornerman_version": _STR,
        "created_utc": _TIME,
        "conventions": {"type": "object", "additionalProperties": _STR},
        "sessions": {"type": "array", "items": session, "minItems": 1},
    })  # fmt: skip


def _meta() -> dict[str, Any]:
    stage = _obj({
        "stage": _STR,
        "status": {"enum": ["fresh", "stale", "missing"]},
        "code_version": _STR,
        "config_hash": _STR,
        "config": {"type": "object"},
        "created_utc": _TIME,
        "duration_s": {"type": "number", "minimum": 0},
        "metrics": {"type": "object"},
    })  # fmt: skip
    file = _obj({
        "path": {"type": "string", "pattern": "^[^/].*$"},
        "kind": _STR,
        "frames": _NAT,
        "camera": _STR,
        "source": {"enum": list(KEYPOINT_SOURCES)},
    }, required=("path", "kind"))  # fmt: skip
    return _obj({
        "format": {"const": META_FORMAT_ID},
        "id": {"type": "string", "pattern": SESSION_ID.pattern},
        "name": _STR,
        "source": {"enum": ["video", "keypoints", "tracks"]},
        "fps": {"type": "number", "exclusiveMinimum": 0},
        "n_frames": _NAT,
        "cameras": {"type": "array", "items": _STR, "minItems": 1},
        "athletes": {"type": "array", "items": _obj({"id": _NAT, "name": _STR})},
        "n_detections": _NAT,
        "n_detections_identified": _NAT,
        "stages": {"type": "array", "items": stage},
        "files": {"type": "array", "items": file},
    })  # fmt: skip


def _calibration() -> dict[str, Any]:
    camera = _obj({
        "name": _STR,
        "K": _vec(3, _vec(3)),
        "dist": _vec(5),
        "T_world_cam": _vec(4, _vec(4)),
        "image_size_wh": _vec(2, {"type": "integer", "minimum": 1}),
        "time_offset_s": _NUM,
    })  # fmt: skip
    return _obj({
        "format": {"const": CALIBRATION_FORMAT_ID},
        "origin": _STR,
        "conventions": {"type": "object", "additionalProperties": _STR},
        "fps": {"type": "number", "exclusiveMinimum": 0},
        "cameras": {"type": "array", "items": camera, "minItems": 1},
    })  # fmt: skip


def _videos() -> dict[str, Any]:
    ref = _obj({
        "camera": {"type": ["string", "null"]},
        "kind": {"enum": ["video", "keypoints", "tracks"]},
        "path": _STR,
        "status": {"enum": ["ok", "missing"]},
        "sha256": {"anyOf": [_SHA256, {"type": "null"}]},
        "size_bytes": {"type": ["integer", "null"], "minimum": 0},
    })  # fmt: skip
    ref["allOf"] = [{
        "if": {"properties": {"status": {"const": "ok"}}},
        "then": {"properties": {"sha256": _SHA256, "size_bytes": _NAT}},
        "else": {"properties": {"sha256": {"type": "null"}, "size_bytes": {"type": "null"}}},
    }]  # fmt: skip
    return _obj({
        "format": {"const": VIDEOS_FORMAT_ID},
        "source": {"enum": ["video", "keypoints", "tracks"]},
        "note": _STR,
        "videos": {"type": "array", "items": ref},
        "inputs": {"type": "array", "items": ref},
    })  # fmt: skip


def _with_source(props: dict[str, Any]) -> dict[str, Any]:
    """An event row; ``source`` (who made it, ``EVENT_SOURCES``) is optional for releases made
    before it existed."""
    return _obj({**props, "source": {"enum": list(EVENT_SOURCES)}}, required=tuple(props))


def _events() -> dict[str, Any]:
    frames = {"start_frame": _NAT, "end_frame": _NAT, "start_s": _NUM, "end_s": _NUM}
    punch = _with_source({
        "athlete_id": _NAT, "athlete": _STR, "hand": _STR, "type": _STR, **frames, "peak_frame": _NAT,
        "peak_s": _NUM, "peak_speed_mps": _NUM, "extension": _NUM, "target": _STR, "outcome": _STR,
        "confidence": {"type": "number", "minimum": 0, "maximum": 1},
    })  # fmt: skip
    evade = _with_source({
        "athlete_id": _NAT, "athlete": _STR, "kind": _STR, **frames, "peak_frame": _NAT, "peak_s": _NUM,
        "displacement_m": _NUM, "punch": {"type": "integer", "minimum": -1},
    })  # fmt: skip
    return _obj({
        "format": {"const": EVENTS_FORMAT_ID},
        "fps": {"type": "number", "exclusiveMinimum": 0},
        "source": _STR,
        "athletes": {"type": "array", "items": _obj({"id": _NAT, "name": _STR})},
        "punches": {"type": "array", "items": punch},
        "evades": {"type": "array", "items": evade},
        "clinches": {"type": "array", "items": _with_source(frames)},
    })  # fmt: skip


_JSON_TYPES: dict[Any, dict[str, Any]] = {
    str: _STR, int: {"type": "integer"}, float: _NUM,
    int | None: {"type": "integer"}, str | None: _STR,  # None is omitted from the JSON
}


def edit_schema() -> dict[str, Any]:
    """An edit: ``kind`` picks the fields (one ``if``/``then`` per kind, built from the annotation
    dataclasses, plus the server's ``undo`` marker), so an error names the field of that kind."""
    out: list[dict[str, Any]] = []
    for kind, cls in ANNOTATION_TYPES.items():
        hints = typing.get_type_hints(cls)
        props = {f.name: _JSON_TYPES[hints[f.name]] for f in dataclasses.fields(cls) if f.name != "kind"}
        required = [
            f.name for f in dataclasses.fields(cls) if f.default is dataclasses.MISSING and f.name != "kind"
        ]
        out.append({**_obj({"kind": {"const": kind}, **props}), "required": ["kind", *required]})
    out.append(_obj({"kind": {"const": "undo"}, "target": _NAT}))
    kinds = [o["properties"]["kind"]["const"] for o in out]
    return {
        "type": "object",
        "required": ["kind"],
        "properties": {"kind": {"enum": kinds}},
        "allOf": [
            {"if": {"properties": {"kind": {"const": k}}}, "then": o} for k, o in zip(kinds, out, strict=True)
        ],
    }


def _annotations() -> dict[str, Any]:
    row = _obj({
        "id": {"type": ["integer", "null"]},
        "edit": edit_schema(),
        "author": {"type": ["string", "null"]},
        "created_utc": _NULL_TIME,
        "active": {"type": "boolean"},
        "superseded_by": {"type": ["integer", "null"]},
        "undoes": {"type": ["integer", "null"]},
    })  # fmt: skip
    return _obj({
        "format": {"const": ANNOTATIONS_FORMAT_ID},
        "provenance": {"enum": ["server", "session_file"]},
        "note": _STR,
        "annotations": {"type": "array", "items": row},
    })  # fmt: skip


_BUILDERS = {
    "release": ("cornerman dataset release: release.json", _release),
    "meta": ("cornerman dataset release: sessions/<id>/meta.json", _meta),
    "calibration": ("cornerman dataset release: sessions/<id>/calibration.json", _calibration),
    "videos": ("cornerman dataset release: sessions/<id>/videos.json", _videos),
    "events": ("cornerman dataset release: sessions/<id>/events.json", _events),
    "annotations": ("cornerman dataset release: sessions/<id>/annotations.json", _annotations),
}


def json_schemas() -> dict[str, dict[str, Any]]:
    """Kind -> JSON Schema document, for every kind of ``layout.JSON_KINDS``."""
    out = {kind: _doc(kind, title, build()) for kind, (title, build) in _BUILDERS.items()}
    missing = set(JSON_KINDS) - set(out)
    if missing:
        raise ValueError(f"no JSON Schema for file kinds {sorted(missing)}")
    return out
