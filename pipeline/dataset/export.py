"""``cornerman dataset export``: write a release folder from finished sessions, atomically.

Everything is written to a temporary folder next to ``out`` and renamed into place at the end, so
a failure (or Ctrl-C) leaves no half-written release and keeps a previous one intact.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import re
import shutil
import uuid
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipeline import __version__
from pipeline.artifacts import sha256_file
from pipeline.dataset.annotations import AnnotationRecord
from pipeline.dataset.datasheet import datasheet
from pipeline.dataset.layout import (
    CHECKSUMS,
    DATASHEET,
    FORMAT_ID,
    NPZ_LAYOUTS_JSON,
    RELEASE_JSON,
    SCHEMAS_DIR,
    SESSIONS_DIR,
    npz_layouts_doc,
)
from pipeline.dataset.schemas import json_schemas
from pipeline.dataset.session import CONVENTIONS, write_json, write_session
from pipeline.schema.session import SessionConfig

Progress = Callable[[int, int, str], None]
"""``progress(done, total, message)``: ``done`` of ``total`` sessions finished; ``message`` says
what is being written."""


@dataclass(frozen=True)
class ReleaseSummary:
    """What ``export_release`` wrote.

    Fields:
        out: the release folder.
        session_ids: the sessions' folder names under ``sessions/``, in export order.
        n_files: files listed in ``checksums.sha256``.
        size_bytes: total size of those files.
    """

    out: Path
    session_ids: tuple[str, ...]
    n_files: int
    size_bytes: int


def check_out_dir(out: Path, force: bool) -> None:
    """``ValueError`` when ``out`` cannot receive a release: a file, a missing parent folder, or a
    non-empty folder (with ``force``, only a previous release may be replaced: a folder holding
    ``release.json``, never any other data)."""
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: is a file; give a folder for the release")
    if not out.parent.is_dir():
        raise ValueError(f"--out {out}: folder {out.parent} does not exist")
    if out.is_dir() and any(out.iterdir()):
        if not force:
            raise ValueError(
                f"--out {out}: folder is not empty; give a new or empty folder, or --force to replace a previous release"
            )
        if not (out / RELEASE_JSON).is_file():
            raise ValueError(
                f"--out {out}: folder is not empty and holds no {RELEASE_JSON}; --force only replaces a previous "
                "release, never other data"
            )


def session_ids(sessions: Sequence[Path]) -> list[str]:
    """Folder names under ``sessions/``: each session folder's name made safe, made unique with ``-2``, ``-3``."""
    out: list[str] = []
    for s in sessions:
        base = re.sub(r"[^A-Za-z0-9._-]", "_", Path(s).resolve().name).lstrip("._-")[:100] or "session"
        sid, n = base, 1
        while sid in out:
            n += 1
            sid = f"{base}-{n}"
        out.append(sid)
    return out


def write_checksums(root: Path) -> tuple[int, int]:
    """Write ``checksums.sha256`` (``sha256sum`` format, POSIX paths) over every other file under
    ``root``; returns (files, total bytes)."""
    files = sorted(p for p in root.rglob("*") if p.is_file() and p.relative_to(root).as_posix() != CHECKSUMS)
    lines = [f"{sha256_file(p)}  {p.relative_to(root).as_posix()}\n" for p in files]
    (root / CHECKSUMS).write_text("".join(lines))
    return len(files), sum(p.stat().st_size for p in files)


def _preflight(sessions: Sequence[Path], allow_stale: bool) -> list[dict[str, str]]:
    """Per session, the runner's stage status; ``ValueError`` for a bad folder, a session given twice
    or stale stages (unless ``allow_stale``)."""
    from pipeline.runner import stage_status

    if not sessions:
        raise ValueError("give at least one session folder")
    seen: dict[Path, Path] = {}
    out = []
    for s in sessions:
        real = Path(s).resolve()
        if real in seen:
            raise ValueError(f"session {s} is given twice (also as {seen[real]})")
        seen[real] = Path(s)
        SessionConfig.load(Path(s))
        status = stage_status(Path(s))
        stale = [k for k, v in status.items() if v == "stale"]
        if stale and not allow_stale:
            raise ValueError(
                f"{s}: stages {', '.join(stale)} are stale (inputs, annotations, config or code changed since they "
                f"ran); run `cornerman run {s}` first, or pass --allow-stale to release them as they are"
            )
        out.append({k: str(v) for k, v in status.items()})
    return out


def export_release(
    sessions: Sequence[Path],
    out: Path,
    *,
    force: bool = False,
    allow_stale: bool = False,
    histories: Mapping[Path, list[AnnotationRecord]] | None = None,
    licence: str = "",
    progress: Progress | None = None,
) -> ReleaseSummary:
    """Write a release of ``sessions`` to the folder ``out`` (see ``pipeline.dataset.layout``).

    ``histories`` maps a session folder (resolved) to its annotation history with authors and
    times (the server's); sessions without one get their ``annotations.json`` edits, author unknown.
    ``licence`` goes into ``datasheet.md`` ("" leaves a placeholder to fill).
    Raises ``ValueError``/``LookupError`` naming the session or ``--out`` before anything is written,
    or when a session lacks the track/associate artifacts; on any failure ``out`` is unchanged.
    """
    out = Path(out)
    check_out_dir(out, force)
    statuses = _preflight(sessions, allow_stale)
    report = progress or (lambda done, total, msg: None)
    ids = session_ids(sessions)
    histories = {Path(k).resolve(): v for k, v in (histories or {}).items()}
    tmp = out.parent / f".{out.name}.tmp-{uuid.uuid4().hex[:8]}"
    tmp.mkdir()
    try:
        metas, events, annotations = [], {}, {}
        for i, (s, sid, status) in enumerate(zip(sessions, ids, statuses, strict=True)):
            dest = tmp / SESSIONS_DIR / sid
            dest.mkdir(parents=True)
            meta = write_session(
                Path(s), dest, sid, status, histories.get(Path(s).resolve()),
                lambda msg, i=i, sid=sid: report(i, len(ids), f"{sid}: {msg}"),  # type: ignore[misc]
            )  # fmt: skip
            metas.append(meta)
            annotations[sid] = _read_json(dest / "annotations.json")
            if (dest / "events.json").exists():
                events[sid] = _read_json(dest / "events.json")
            report(i + 1, len(ids), f"{sid}: done")
        release = {
            "format": FORMAT_ID,
            "cornerman_version": __version__,
            "created_utc": dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "conventions": CONVENTIONS,
            "sessions": [
                {"id": m["id"], "name": m["name"], "path": f"{SESSIONS_DIR}/{m['id']}", "n_frames": m["n_frames"],
                 "n_cameras": len(m["cameras"]), "athletes": [a["name"] for a in m["athletes"]]}
                for m in metas
            ],
        }  # fmt: skip
        write_json(tmp / RELEASE_JSON, release)
        for kind, schema in json_schemas().items():
            write_json(tmp / SCHEMAS_DIR / f"{kind}.schema.json", schema)
        write_json(tmp / NPZ_LAYOUTS_JSON, npz_layouts_doc())
        (tmp / DATASHEET).write_text(datasheet(release, metas, events, annotations, licence) + "\n")
        report(len(ids), len(ids), "checksums")
        n_files, size = write_checksums(tmp)
        _swap_into_place(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return ReleaseSummary(out=out, session_ids=tuple(ids), n_files=n_files, size_bytes=size)


def _read_json(path: Path) -> Any:
    return json.loads(path.read_text())


def _swap_into_place(tmp: Path, out: Path) -> None:
    """Rename ``tmp`` to ``out``; a previous ``out`` (empty, or a release ``--force`` replaces) is moved
    aside first and restored if the rename fails."""
    old = None
    if out.exists():
        old = out.parent / f".{out.name}.old-{uuid.uuid4().hex[:8]}"
        os.rename(out, old)
    try:
        os.rename(tmp, out)
    except BaseException:
        if old is not None:
            os.rename(old, out)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
