"""Session folders on disk: safe names, allowed roots, session.json, annotations.json.

Only the server writes under ``<home>/sessions``. A session made from a server-side
folder gets its own folder there (``session.json`` with absolute input paths,
``annotations.json``, ``artifacts/``); the source folder is only read.
"""

from __future__ import annotations

import fcntl
import json
import logging
import re
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

from server.core.config import Settings
from server.models import Bout

log = logging.getLogger(__name__)

SAFE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")
CALIB_SUFFIXES = (".toml", ".txt", ".json")


class PathNotAllowed(ValueError):
    """A server-side path outside every allowed root (the API answers 403)."""


def safe_filename(name: str | None, what: str = "file name") -> str:
    """An uploaded file's name, accepted only as a plain, short, dot-free-prefix basename."""
    if not name:
        raise ValueError(f"{what}: missing")
    if "/" in name or "\\" in name or name in (".", "..") or not SAFE_NAME.match(name):
        raise ValueError(f"{what} {name!r} is not allowed (use letters, digits, '.', '_', '-'; no paths)")
    return name


def resolve_allowed(path: str | Path, settings: Settings) -> Path:
    """Resolve ``path`` (symlinks followed) and require it under an allowed root."""
    p = Path(path).expanduser()
    if not p.is_absolute():
        raise PathNotAllowed(f"server-side path must be absolute, got {str(path)!r}")
    real = p.resolve()
    for root in settings.resolved_roots():
        if real == root or real.is_relative_to(root):
            return real
    raise PathNotAllowed(f"{str(path)!r} is outside the allowed roots {[str(r) for r in settings.resolved_roots()]}")


def new_session_dir(settings: Settings) -> Path:
    d = settings.sessions_dir / f"s-{uuid.uuid4().hex[:12]}"
    d.mkdir(parents=True)
    return d


def _absolutize(value: str, base: Path, settings: Settings) -> str:
    if not value:
        return value
    p = Path(value)
    return str(resolve_allowed(p if p.is_absolute() else base / p, settings))


def _inputs_config(src: Path, name: str | None) -> Any:
    """The ``SessionConfig`` of inputs folder ``src`` (see ``session_from_folder``); ``ValueError``
    saying what is missing or which entry matches no calibrated camera."""
    from pipeline.io.calibration import calibration_files, load_calibration
    from pipeline.io.input_folders import KEYPOINT_SUBFOLDERS, EntryKind, entries, match_cameras
    from pipeline.schema.session import SessionConfig

    calib_dir = src if calibration_files(src) or not (src / "calibration").is_dir() else src / "calibration"
    calibs = calibration_files(calib_dir)
    if len(calibs) != 1:
        raise ValueError(f"{src}: no session.json, and not an inputs folder: needs exactly one calibration "
                         f"*.toml/*.qca.txt/*.qca in it or in its calibration/ subfolder, found {len(calibs)} in {calib_dir}")  # fmt: skip
    candidates: list[tuple[Path, EntryKind]] = [(src, "video"), (src / "videos", "video")]
    candidates += [(src / k, "openpose") for k in KEYPOINT_SUBFOLDERS]
    for folder, kind in candidates:
        found = entries(folder, kind) if folder.is_dir() else {}
        if found:
            inputs = match_cameras(found, load_calibration(calibs[0]).names, str(folder))
            videos, keypoints = (inputs, {}) if kind == "video" else ({}, inputs)
            return SessionConfig(name=name or src.name, source="video" if videos else "keypoints",
                                 calibration=str(calibs[0]), videos=videos, keypoints=keypoints)  # fmt: skip
    raise ValueError(f"{src}: no session.json, and no inputs: no video in it or in its videos/ subfolder, and no "
                     f"OpenPose camera folders in {', '.join(k + '/' for k in KEYPOINT_SUBFOLDERS)}")  # fmt: skip


def session_from_folder(src: Path, dest: Path, settings: Settings, name: str | None, fps: float | None = None) -> Any:
    """Write ``dest/session.json`` describing the inputs of server-side folder ``src``.

    ``src`` holds a ``session.json`` (its relative paths are made absolute and must stay
    under an allowed root), or inputs: one calibration file (``*.toml``, ``*.qca.txt``, ``*.qca``)
    in ``src`` or ``src/calibration``, and either videos (``<camera>.mp4|avi|mov|mkv|webm``) in
    ``src`` or ``src/videos``, or one OpenPose folder per camera in ``src/keypoints2d``,
    ``src/keypoints`` or ``src/pose`` (named after the cameras: ``pipeline.io.input_folders``).
    ``name`` and ``fps`` (Hz, > 0), when given, override the bout name and frame rate.
    Returns the ``SessionConfig``.
    """
    from pipeline.runner.core import check_stage_configs
    from pipeline.schema.session import SessionConfig

    if not src.is_dir():
        raise ValueError(f"{src}: not a folder")
    if (src / "session.json").exists():
        cfg = SessionConfig.load(src)
        if (src / "annotations.json").exists() and not (dest / "annotations.json").exists():
            (dest / "annotations.json").write_bytes((src / "annotations.json").read_bytes())
    else:
        cfg = _inputs_config(src, name)
    cfg = replace(  # every input path absolute, and (symbolic links followed) under an allowed root
        cfg,
        calibration=_absolutize(cfg.calibration, src, settings),
        videos={k: _absolutize(v, src, settings) for k, v in cfg.videos.items()},
        keypoints={k: _absolutize(v, src, settings) for k, v in cfg.keypoints.items()},
        tracks=_absolutize(cfg.tracks, src, settings),
        ground_truth=_absolutize(cfg.ground_truth, src, settings),
        ground_truth_labels=_absolutize(cfg.ground_truth_labels, src, settings),
    )
    if name:
        cfg = replace(cfg, name=name)
    if fps is not None:
        cfg = replace(cfg, fps=float(fps))
    try:  # a bad stage_config value is refused here, not when a queued job reaches its stage
        check_stage_configs(cfg)
    except ValueError as e:
        raise ValueError(f"{src}/{e}") from e
    cfg.save(dest)
    return cfg


def rig_meta(session_dir: Path, cfg: Any) -> dict[str, Any] | None:
    """The ``Bout`` columns that come from the session folder's calibration (``cfg``: its
    ``SessionConfig``): ``n_cameras, cameras, fps, layout_advice``; None when the calibration
    cannot be read yet (a job that reads it reports why)."""
    from pipeline.geometry.layout import layout_advice
    from pipeline.io.session_rig import session_rig

    try:
        rig = session_rig(session_dir, cfg)
    except (ValueError, OSError, KeyError, TypeError) as e:
        log.warning("%s: calibration not readable yet: %s", session_dir, e)
        return None
    return {"n_cameras": len(rig.names), "cameras": list(rig.names), "fps": float(rig.fps),
            "layout_advice": layout_advice(rig) or ""}


def session_meta(session_dir: Path) -> dict[str, Any]:
    """``name, n_cameras, cameras, fps, athletes, auto_rerun, layout_advice`` of a session folder (best
    effort on the calibration: a malformed one is reported by the job that reads it, not here)."""
    from pipeline.schema.session import SessionConfig

    cfg = SessionConfig.load(session_dir)
    cams = list(cfg.cameras) or list(cfg.camera_inputs())
    rig = rig_meta(session_dir, cfg) or {"n_cameras": len(cams), "cameras": cams, "fps": float(cfg.fps),
                                          "layout_advice": ""}
    return {"name": cfg.name, "athletes": list(cfg.athletes), "auto_rerun": bool(cfg.auto_rerun)} | rig


def rig_changes(bout: Bout) -> dict[str, Any]:
    """The ``rig_meta`` columns of ``bout`` that its folder's calibration now gives otherwise (a calibration
    replaced after the session was created); {} when none differ or it cannot be read."""
    from pipeline.schema.session import SessionConfig

    try:
        meta = rig_meta(Path(bout.folder), SessionConfig.load(Path(bout.folder)))
    except (ValueError, OSError) as e:
        log.warning("%s: session.json not readable: %s", bout.folder, e)
        return {}
    return {k: v for k, v in (meta or {}).items() if getattr(bout, k) != v}


def bout_from_meta(session_dir: Path, created_by: str, **fields: Any) -> Bout:
    """The ``Bout`` row of the session folder ``session_dir`` (``session_meta``); ``fields``
    (``name``, ``date``, ``auto_rerun``) override what the folder says."""
    meta = session_meta(session_dir)
    keep = ("name", "n_cameras", "cameras", "fps", "athletes", "auto_rerun", "layout_advice")
    return Bout(**{k: meta[k] for k in keep} | fields, folder=str(session_dir), created_by=created_by)


@contextmanager
def session_lock(session_dir: Path) -> Iterator[None]:
    """Exclusive lock on a session's overlay files across processes."""
    with open(session_dir / ".server.lock", "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def write_annotations_file(session_dir: Path, payloads: list[dict[str, Any]]) -> None:
    """Rewrite ``annotations.json`` with the active edits (validated by the pipeline schema)."""
    from pipeline.schema.annotations import annotation_from_dict, save_annotations

    save_annotations(session_dir / "annotations.json", [annotation_from_dict(p) for p in payloads])


def enabled_stage_names(session_dir: Path) -> list[str]:
    """The session's stages in pipeline order (``pipeline.runner.core.enabled_stages``)."""
    from pipeline.runner.core import enabled_stages
    from pipeline.schema.session import SessionConfig

    return enabled_stages(SessionConfig.load(session_dir))


def stale_from(session_dir: Path, kind: str) -> str | None:
    """First enabled stage an edit of ``kind`` makes stale (None: no enabled stage consumes it)."""
    from pipeline.runner.registry import STAGE_ORDER
    from pipeline.schema.annotations import CONSUMED_BY

    consumer = CONSUMED_BY[kind]
    first = STAGE_ORDER.index(consumer)
    for s in enabled_stage_names(session_dir):
        if STAGE_ORDER.index(s) >= first:
            return s
    return None


def read_json(path: Path) -> Any:
    return json.loads(path.read_text())
