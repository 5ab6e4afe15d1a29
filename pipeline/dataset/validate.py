"""``cornerman dataset validate``: check a release against its checksums, schemas and layout.

Checks, each problem reported with the file (release-relative path) it concerns:

- ``checksums.sha256``: every listed file exists with that sha256, and every file is listed;
- every file belongs to the layout (``pipeline.dataset.layout.file_kind``);
- JSON files against the format's JSON Schemas (the ones in this code, which the release's
  ``schemas/`` must equal), naming the offending field;
- NPZ files against ``layout.NPZ_LAYOUTS`` (names, dtypes, shapes; no pickled objects) and, for
  cornerman schema types, their own validation (value ranges, masks);
- cross-references: every session ``release.json`` lists exists and no other, each session's files
  are the ones ``meta.json`` lists, and cameras, frame counts, frame ranges and person ids agree.
"""

from __future__ import annotations

import json
import re
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from jsonschema import Draft202012Validator
from jsonschema.exceptions import ValidationError, best_match

from pipeline.artifacts import sha256_file
from pipeline.dataset.layout import (
    CHECKSUMS,
    DATASHEET,
    FORMAT_ID,
    NPZ_KINDS,
    NPZ_LAYOUTS,
    NPZ_LAYOUTS_JSON,
    RELEASE_JSON,
    SESSIONS_DIR,
    file_kind,
    npz_layouts_doc,
)
from pipeline.dataset.schemas import json_schemas
from pipeline.schema.base import from_arrays
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit, PhysicsResult

MAX_ERRORS_PER_FILE = 20
"""Schema errors listed per JSON file before the rest are summarised."""

_SCHEMA_TYPES: dict[str, type] = {"keypoints3d": Keypoints3D, "bodyfit": BodyFit, "physics": PhysicsResult}
_LINE = re.compile(r"^([0-9a-f]{64}) [ *](.+)$")


@dataclass(frozen=True)
class Problem:
    """One reason a release is invalid: ``file`` (path relative to the release, ``.`` = the folder) and
    what is wrong with it."""

    file: str
    message: str


@dataclass(frozen=True)
class ValidationReport:
    """The outcome of :func:`validate_release`.

    Fields:
        root: the release folder.
        problems: every problem found (empty = valid).
        n_files: files found in the release.
        kinds: file kind -> files of that kind checked.
        sessions: the session ids ``release.json`` lists.
    """

    root: Path
    problems: tuple[Problem, ...]
    n_files: int
    kinds: dict[str, int]
    sessions: tuple[str, ...]

    @property
    def ok(self) -> bool:
        return not self.problems


class _Checker:
    def __init__(self, root: Path) -> None:
        self.root = root
        self.problems: list[Problem] = []
        self.schemas = json_schemas()
        self.validators = {
            k: Draft202012Validator(s, format_checker=Draft202012Validator.FORMAT_CHECKER)
            for k, s in self.schemas.items()
        }

    def bad(self, file: str, message: str) -> None:
        self.problems.append(Problem(file, message))

    # -- files -------------------------------------------------------------------------------
    def checksums(self, files: list[str]) -> None:
        path = self.root / CHECKSUMS
        if not path.is_file():
            self.bad(CHECKSUMS, "missing: the release has no checksums")
            return
        listed: dict[str, str] = {}
        for n, line in enumerate(path.read_text().splitlines(), 1):
            m = _LINE.match(line)
            if m is None:
                self.bad(CHECKSUMS, f"line {n}: not '<sha256>  <path>' (sha256sum format): {line[:80]!r}")
                continue
            digest, rel = m.groups()
            if rel.startswith("/") or ".." in rel.split("/"):
                self.bad(CHECKSUMS, f"line {n}: path {rel!r} leaves the release folder")
                continue
            listed[rel] = digest
        for rel, digest in listed.items():
            f = self.root / rel
            if not f.is_file():
                self.bad(rel, f"listed in {CHECKSUMS} but missing")
            elif sha256_file(f) != digest:
                self.bad(rel, f"sha256 differs from {CHECKSUMS} (the file was changed or is corrupt)")
        for rel in files:
            if rel != CHECKSUMS and rel not in listed:
                self.bad(rel, f"not listed in {CHECKSUMS}")

    def json(self, rel: str, kind: str) -> Any:
        """The parsed document when it is valid JSON (schema errors are recorded, the document returned)."""
        try:
            doc = json.loads((self.root / rel).read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            self.bad(rel, f"not readable JSON: {e}")
            return None
        errors = sorted(
            self.validators[kind].iter_errors(doc), key=lambda err: list(map(str, err.absolute_path))
        )
        for err in errors[:MAX_ERRORS_PER_FILE]:
            self.bad(rel, _describe(err))
        if len(errors) > MAX_ERRORS_PER_FILE:
            self.bad(rel, f"... and {len(errors) - MAX_ERRORS_PER_FILE} more schema errors")
        return doc

    def npz(self, rel: str, kind: str) -> tuple[dict[str, np.ndarray], dict[str, int]] | None:
        """Arrays and named sizes of an NPZ that matches its layout; ``None`` (problems recorded) otherwise."""
        try:
            with np.load(self.root / rel, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as e:
            self.bad(rel, f"not a readable NPZ without pickled objects: {e}")
            return None
        specs = {a.name: a for a in NPZ_LAYOUTS[kind]}
        ok = True
        for name in sorted(set(specs) - set(arrays)):
            self.bad(rel, f"array {name!r} missing ({kind} layout)")
            ok = False
        for name in sorted(set(arrays) - set(specs)):
            self.bad(rel, f"array {name!r} is not part of the {kind} layout")
            ok = False
        sizes: dict[str, int] = {}
        first: dict[str, str] = {}
        for name, spec in specs.items():
            if name not in arrays:
                continue
            a = arrays[name]
            if a.dtype.kind not in spec.kinds:
                self.bad(rel, f"array {name!r}: dtype {a.dtype} (expected kind {spec.kinds!r})")
                ok = False
            if a.ndim != len(spec.shape):
                self.bad(
                    rel, f"array {name!r}: shape {a.shape}, expected {len(spec.shape)} axes {spec.shape}"
                )
                ok = False
                continue
            for axis, (want, got) in enumerate(zip(spec.shape, a.shape, strict=True)):
                if isinstance(want, int) and got != want:
                    self.bad(rel, f"array {name!r}: axis {axis} is {got}, expected {want}")
                    ok = False
                elif isinstance(want, str) and sizes.setdefault(want, got) != got:
                    self.bad(
                        rel,
                        f"array {name!r}: axis {axis} ({want}) is {got}, but {first[want]!r} has {sizes[want]}",
                    )
                    ok = False
                first.setdefault(str(want), name)
        if ok and kind in _SCHEMA_TYPES:
            try:
                from_arrays(_SCHEMA_TYPES[kind], arrays)
            except (TypeError, ValueError) as e:
                self.bad(rel, f"invalid {_SCHEMA_TYPES[kind].__name__}: {e}")
                ok = False
        return (arrays, sizes) if ok else None

    # -- sessions ------------------------------------------------------------------------------
    def valid_json(self, rel: str, kind: str) -> Any:
        """The document when it is readable and matches its schema, else ``None`` (problems recorded)."""
        before = len(self.problems)
        doc = self.json(rel, kind)
        return doc if len(self.problems) == before else None

    def session(self, entry: dict[str, Any], files: list[str]) -> None:
        """Check one session listed in a schema-valid ``release.json``."""
        sid = entry["id"]
        base = f"{SESSIONS_DIR}/{sid}"
        if entry["path"] != base:
            self.bad(RELEASE_JSON, f"session {sid!r}: path {entry['path']!r}, expected {base!r}")
        if not (self.root / base).is_dir():
            self.bad(base, "listed in release.json but missing")
            return
        present = {rel[len(base) + 1 :] for rel in files if rel.startswith(base + "/")} - {"meta.json"}
        if not (self.root / base / "meta.json").is_file():
            self.bad(f"{base}/meta.json", "missing")
            meta = None
        else:
            meta = self.valid_json(f"{base}/meta.json", "meta")
        if meta is None:  # each file on its own: cross-references need a valid meta.json
            self.standalone(base, sorted(present))
            return
        athletes = [a["name"] for a in meta["athletes"]]
        for key, got, want in (
            ("id", meta["id"], sid),
            ("name", meta["name"], entry["name"]),
            ("n_frames", meta["n_frames"], entry["n_frames"]),
            ("athletes", athletes, entry["athletes"]),
            ("number of cameras", len(meta["cameras"]), entry["n_cameras"]),
        ):
            if got != want:
                self.bad(f"{base}/meta.json", f"{key} {got!r} disagrees with release.json's {want!r}")
        listed = {f["path"]: f for f in meta["files"]}
        for p in sorted(set(listed) - present):
            self.bad(f"{base}/{p}", "listed in meta.json but missing")
        for p in sorted(present - set(listed)):
            self.bad(f"{base}/{p}", "not listed in meta.json's files")
        for p in sorted(set(listed) & present):
            kind = file_kind(f"{base}/{p}")
            if listed[p]["kind"] != kind:
                self.bad(
                    f"{base}/meta.json", f"files: {p} has kind {listed[p]['kind']!r}, its path says {kind!r}"
                )
            else:
                self.session_file(base, p, listed[p], meta)
        cams = {f.get("camera") for f in meta["files"] if f["kind"] == "tracks2d"}
        if cams != set(meta["cameras"]):
            self.bad(
                f"{base}/meta.json",
                f"tracks2d files for cameras {sorted(map(str, cams))}, cameras are {meta['cameras']}",
            )

    def standalone(self, base: str, paths: list[str]) -> None:
        """Check the files of a session folder by their own schema or layout only."""
        for p in paths:
            kind = file_kind(f"{base}/{p}")
            if kind == "meta":
                self.json(f"{base}/{p}", "meta")
            elif kind is not None:
                self.session_file(base, p, {"kind": kind}, None)

    def session_file(self, base: str, p: str, entry: dict[str, Any], meta: dict[str, Any] | None) -> None:
        """Check one session file; with ``meta`` (a schema-valid ``meta.json``), its cross-references too."""
        rel, kind = f"{base}/{p}", entry["kind"]
        if kind in ("calibration", "events", "annotations", "videos"):
            doc = self.valid_json(rel, kind)
            if doc is None or meta is None:
                return
            if kind == "calibration" and [c["name"] for c in doc["cameras"]] != meta["cameras"]:
                self.bad(
                    rel,
                    f"cameras {[c['name'] for c in doc['cameras']]} differ from meta.json's {meta['cameras']}",
                )
            if kind == "events":
                rows = [*doc["punches"], *doc["evades"], *doc["clinches"]]
                late = [r["end_frame"] for r in rows if r["end_frame"] >= meta["n_frames"]]
                if late:
                    self.bad(
                        rel,
                        f"events end at frames {late[:5]} outside the session's {meta['n_frames']} frames",
                    )
        elif kind == "calibration_toml":
            self.toml(rel, meta)
        elif kind in NPZ_KINDS:
            got = self.npz(rel, kind)
            if got is not None and meta is not None:
                ids = {int(a["id"]) for a in meta["athletes"]}
                self.npz_refs(rel, kind, entry, got[0], got[1], int(meta["n_frames"]), ids)

    def toml(self, rel: str, meta: dict[str, Any] | None) -> None:
        from pipeline.io.calibration_toml import load_toml

        try:
            rig = load_toml(self.root / rel)
        except (ValueError, OSError) as e:
            self.bad(rel, f"not a readable calibration: {e}")
            return
        if meta is not None and list(rig.names) != meta["cameras"]:
            self.bad(rel, f"cameras {list(rig.names)} differ from meta.json's {meta['cameras']}")

    def npz_refs(self, rel: str, kind: str, entry: dict[str, Any], arrays: dict[str, np.ndarray],
                 sizes: dict[str, int], n_frames: int, ids: set[int]) -> None:  # fmt: skip
        frames = arrays["frame"] if kind == "tracks2d" else arrays["frame_indices"]
        if frames.size and (frames.min() < 0 or frames.max() >= n_frames):
            self.bad(
                rel,
                f"frames {int(frames.min())}..{int(frames.max())} outside the session's {n_frames} frames",
            )
        persons = arrays["person_id"] if kind == "tracks2d" else arrays["person_ids"]
        unknown = sorted(set(persons.tolist()) - ids - ({-1} if kind == "tracks2d" else set()))
        if unknown:
            self.bad(rel, f"person ids {unknown[:5]} are not athletes of meta.json ({sorted(ids)})")
        if "frames" in entry and sizes.get("frames") != entry["frames"]:
            self.bad(rel, f"{sizes.get('frames')} frames, meta.json says {entry['frames']}")
        if kind == "keypoints3d" and str(arrays["__scalar__source"]) != entry.get("source"):
            self.bad(
                rel, f"source {str(arrays['__scalar__source'])!r}, meta.json says {entry.get('source')!r}"
            )


def _describe(e: ValidationError) -> str:
    """``field <path>: message`` of a schema error; for ``anyOf``/``oneOf`` failures, the closest alternative's error."""
    if e.context:
        e = best_match(e.context)
    where = "/".join(str(p) for p in e.absolute_path) or "(top level)"
    return f"field {where}: {e.message}"


def _files(root: Path) -> list[str]:
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())


def validate_release(root: Path) -> ValidationReport:
    """Check the release folder ``root``; never raises for a bad release (problems are reported)."""
    root = Path(root)
    c = _Checker(root)
    if not root.is_dir():
        c.bad(".", f"{root} is not a folder")
        return ValidationReport(root, tuple(c.problems), 0, {}, ())
    files = _files(root)
    kinds: dict[str, int] = {}
    for rel in files:
        kind = file_kind(rel)
        if kind is None:
            c.bad(rel, f"not part of the {FORMAT_ID} layout")
        kinds[str(kind)] = kinds.get(str(kind), 0) + 1
    c.checksums(files)
    if not (root / RELEASE_JSON).is_file():
        c.bad(RELEASE_JSON, "missing: not a cornerman dataset release")
        return ValidationReport(root, tuple(c.problems), len(files), kinds, ())
    release = c.valid_json(RELEASE_JSON, "release")
    raw = _load_json(root / RELEASE_JSON)
    if isinstance(raw, dict) and raw.get("format") != FORMAT_ID:
        c.bad(RELEASE_JSON, f"format {raw.get('format')!r}: this cornerman reads {FORMAT_ID}")
        return ValidationReport(root, tuple(c.problems), len(files), kinds, ())
    for kind, schema in c.schemas.items():
        _same_json(c, f"schemas/{kind}.schema.json", schema)
    _same_json(c, NPZ_LAYOUTS_JSON, npz_layouts_doc())
    if not (root / DATASHEET).is_file():
        c.bad(DATASHEET, "missing")
    on_disk = sorted(
        {rel.split("/")[1] for rel in files if rel.startswith(f"{SESSIONS_DIR}/") and rel.count("/") >= 2}
    )
    if release is None:  # without a valid session list, check each session folder's files on their own
        for sid in on_disk:
            base = f"{SESSIONS_DIR}/{sid}"
            c.standalone(base, [rel[len(base) + 1 :] for rel in files if rel.startswith(base + "/")])
        return ValidationReport(root, tuple(c.problems), len(files), kinds, ())
    entries = release["sessions"]
    for e in entries:
        c.session(e, files)
    for sid in sorted(set(on_disk) - {e["id"] for e in entries}):
        c.bad(f"{SESSIONS_DIR}/{sid}", "session folder not listed in release.json")
    return ValidationReport(root, tuple(c.problems), len(files), kinds, tuple(e["id"] for e in entries))


def _load_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None


def _same_json(c: _Checker, rel: str, want: Any) -> None:
    path = c.root / rel
    if not path.is_file():
        c.bad(rel, "missing")
        return
    try:
        got = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        c.bad(rel, f"not readable JSON: {e}")
        return
    if got != want:
        c.bad(rel, f"differs from the {FORMAT_ID} definition this cornerman validates with")
