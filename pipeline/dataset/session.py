"""One session's part of a release: ``sessions/<id>/`` (see ``pipeline.dataset.layout``).

Reads the session's artifacts (never re-runs a stage) and writes calibration, video references,
per-view 2D tracks with final identities, 3D keypoints per result, body parameters, physics,
events and annotations, then ``meta.json`` listing them with the stages' provenance.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import io
import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.artifacts import ArtifactStore, sha256_file
from pipeline.dataset.annotations import AnnotationRecord, annotations_doc
from pipeline.dataset.layout import KEYPOINT_SOURCES
from pipeline.dataset.schemas import CALIBRATION_FORMAT_ID, META_FORMAT_ID, VIDEOS_FORMAT_ID
from pipeline.io.calibration import save_toml
from pipeline.io.events_export import ANALYZE_STAGE, events_to_json, load_analytics
from pipeline.schema.association import Association
from pipeline.schema.base import to_arrays
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit, PhysicsResult
from pipeline.schema.session import SessionConfig
from pipeline.schema.sources import RESULT_ARTIFACTS

Step = Callable[[str], None]
"""Called with a short description before each piece of work (progress display)."""

CONVENTIONS: dict[str, str] = {
    "world": "floor world (the calibration's, levelled and lowered: calibrate/world.json), metres, z-up, right-handed",
    "camera": "OpenCV camera frame (x right, y down, z forward); T_world_cam maps camera to world",
    "pixels": "pixels of the distorted (recorded) image, origin at the top-left pixel's corner",
    "time": "frame indices of the synchronised videos; seconds = frame / fps",
}


def utc_iso(unix_s: float) -> str:
    """``unix_s`` as an ISO 8601 UTC time (``...Z``, seconds precision)."""
    return dt.datetime.fromtimestamp(unix_s, dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def write_json(path: Path, doc: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n")


def write_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Compressed NPZ without pickle (object arrays are refused by ``to_arrays``)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)  # type: ignore[arg-type]  # numpy stub, see schema.base
    path.write_bytes(buf.getvalue())


def release_physics(res: PhysicsResult) -> PhysicsResult:
    """``res`` with ``observed`` and ``untrackable`` as (frames, persons) arrays, also for a result
    written before they were recorded ((0, 0): observed everywhere, never untrackable)."""
    shape = (res.frame_indices.shape[0], res.person_ids.shape[0])
    untrackable = res.untrackable if res.untrackable.shape == shape else np.zeros(shape, dtype=bool)
    return replace(res, observed=res.observed_mask(), untrackable=untrackable)


def calibration_doc(rig: CameraRig, origin: str) -> dict[str, Any]:
    """``calibration.json``: the rig as plain numbers (``K`` OpenCV, ``dist`` k1 k2 p1 p2 k3)."""
    cams = [
        {
            "name": name,
            "K": rig.K[i].tolist(),
            "dist": rig.dist[i].tolist(),
            "T_world_cam": rig.T_world_cam[i].tolist(),
            "image_size_wh": [int(x) for x in rig.image_size_wh[i]],
            "time_offset_s": float(rig.time_offset_s[i]),
        }
        for i, name in enumerate(rig.names)
    ]
    return {
        "format": CALIBRATION_FORMAT_ID,
        "origin": origin,
        "conventions": {k: CONVENTIONS[k] for k in ("world", "camera", "pixels")},
        "fps": float(rig.fps),
        "cameras": cams,
    }


def _hash_path(path: Path) -> tuple[str, int]:
    """(sha256, size in bytes) of a file; of a folder, a sha256 over its files' relative paths and hashes."""
    if path.is_file():
        return sha256_file(path), path.stat().st_size
    h, size = hashlib.sha256(), 0
    for p in sorted(q for q in path.rglob("*") if q.is_file()):
        h.update(str(p.relative_to(path)).encode())
        h.update(sha256_file(p).encode())
        size += p.stat().st_size
    return h.hexdigest(), size


def _reference(session_dir: Path, camera: str | None, kind: str, rel: str, step: Step) -> dict[str, Any]:
    path = Path(rel) if Path(rel).is_absolute() else session_dir / rel
    ref: dict[str, Any] = {"camera": camera, "kind": kind, "path": rel}
    if path.exists():
        step(f"hashing {path.name}")
        digest, size = _hash_path(path)
        return {**ref, "status": "ok", "sha256": digest, "size_bytes": size}
    return {**ref, "status": "missing", "sha256": None, "size_bytes": None}


def videos_doc(session_dir: Path, cfg: SessionConfig, step: Step) -> dict[str, Any]:
    """``videos.json``: the session's videos (and, for 2D-input sessions, those inputs) with sha256;
    a file that is not there is recorded with status ``missing``."""
    videos = [_reference(session_dir, cam, "video", p, step) for cam, p in sorted(cfg.videos.items())]
    inputs: list[dict[str, Any]] = []
    if cfg.source == "keypoints":
        inputs = [
            _reference(session_dir, cam, "keypoints", p, step) for cam, p in sorted(cfg.keypoints.items())
        ]
    elif cfg.source == "tracks":
        inputs = [_reference(session_dir, None, "tracks", cfg.tracks, step)]
    if cfg.source == "video":
        note = "Recorded videos, hashed when present; 'missing' = the file was not found at export time."
    else:
        note = (
            f"This session was made from {cfg.source} (2D input files, listed in 'inputs'), not from videos"
            + (": the videos below are references only." if videos else "; it has no videos.")
        )
    missing = [r["path"] for r in videos + inputs if r["status"] == "missing"]
    if missing:
        note += f" Missing at export time: {', '.join(missing)}."
    return {
        "format": VIDEOS_FORMAT_ID,
        "source": cfg.source,
        "note": note,
        "videos": videos,
        "inputs": inputs,
    }


def tracks_by_view(
    tracks: Tracks2D, assoc: Association, names: tuple[str, ...]
) -> dict[str, dict[str, np.ndarray]]:
    """Camera name -> the ``tracks2d`` NPZ arrays of that view (rows in (frame, track) order)."""
    if assoc.person_of_det.shape[0] != tracks.n_dets:
        raise ValueError(
            f"the association has {assoc.person_of_det.shape[0]} rows for {tracks.n_dets} tracked detections "
            "(stale artifacts: run the session's stages again)"
        )
    if tracks.n_views != len(names):
        raise ValueError(
            f"the tracks have {tracks.n_views} views, the calibration {len(names)} cameras {list(names)}"
        )
    out = {}
    for v, cam in enumerate(names):
        rows = np.flatnonzero(tracks.view == v)
        rows = rows[np.lexsort((tracks.track_id[rows], tracks.frame[rows]))]
        out[cam] = {
            "joint_names": np.array(tracks.joint_names, dtype=np.str_),
            "frame": tracks.frame[rows].astype(np.int64),
            "track_id": tracks.track_id[rows].astype(np.int64),
            "person_id": assoc.person_of_det[rows].astype(np.int64),
            "identity_confidence": assoc.confidence[rows].astype(np.float64),
            "bbox_xyxy_px": tracks.bbox_xyxy_px[rows],
            "bbox_score": tracks.bbox_score[rows],
            "keypoints_px": tracks.keypoints_px[rows],
            "keypoint_conf": tracks.keypoint_conf[rows],
            "keypoint_valid": tracks.keypoint_valid[rows],
        }
    return out


def _stage_rows(store: ArtifactStore, status: dict[str, str]) -> list[dict[str, Any]]:
    rows = []
    for stage, st in status.items():
        m = store.manifest(stage)
        if m is None:
            continue
        rows.append({
            "stage": stage, "status": st, "code_version": m.code_version, "config_hash": m.config_hash,
            "config": m.config, "created_utc": utc_iso(m.created_unix_s), "duration_s": round(float(m.duration_s), 3),
            "metrics": m.metrics,
        })  # fmt: skip
    return rows


def write_session(
    session_dir: Path,
    dest: Path,
    sid: str,
    status: dict[str, str],
    history: list[AnnotationRecord] | None,
    step: Step,
) -> dict[str, Any]:
    """Write ``sessions/<sid>/`` of a release into ``dest`` and return its ``meta.json`` document.

    ``status`` is the runner's per-stage status (enabled stages only: a disabled stage's leftover
    artifacts are not released). ``ValueError``/``LookupError`` name the session and what is missing.
    """
    from pipeline.runner.rig import CALIBRATE, rig_for, uses_calibrated_rig

    cfg = SessionConfig.load(session_dir)
    store = ArtifactStore(session_dir)
    for need in ("track", "associate"):
        if status.get(need) in (None, "missing"):
            raise LookupError(f"{session_dir}: the {need} stage has not run; run the session's stages first")
    files: list[dict[str, Any]] = []

    step("calibration")
    rig = rig_for("downstream", session_dir, cfg)
    m_cal = store.manifest(CALIBRATE)
    if m_cal is not None and uses_calibrated_rig("downstream", cfg):
        origin = f"calibrate stage: {m_cal.metrics.get('reason', 'its result')}"
    else:
        origin = f"input calibration {cfg.calibration} (the calibrate stage did not run)"
    save_toml(rig, dest / "calibration.toml")
    write_json(dest / "calibration.json", calibration_doc(rig, origin))
    files += [
        {"path": "calibration.toml", "kind": "calibration_toml"},
        {"path": "calibration.json", "kind": "calibration"},
    ]

    write_json(dest / "videos.json", videos_doc(session_dir, cfg, step))
    files.append({"path": "videos.json", "kind": "videos"})

    step("2D tracks")
    tracks = store.load("track", "tracks", Tracks2D)
    assoc = store.load("associate", "association", Association)
    for cam, arrays in tracks_by_view(tracks, assoc, rig.names).items():
        write_npz(dest / "tracks2d" / f"{cam}.npz", arrays)
        files.append({"path": f"tracks2d/{cam}.npz", "kind": "tracks2d", "camera": cam})

    for source in KEYPOINT_SOURCES:
        stage, name = RESULT_ARTIFACTS[source]
        if status.get(stage) in (None, "missing") or not store.has(stage, f"{name}.npz"):
            continue
        step(f"3D keypoints ({source})")
        kp = store.load(stage, name, Keypoints3D)
        write_npz(dest / "keypoints3d" / f"{source}.npz", to_arrays(kp))
        files.append(
            {
                "path": f"keypoints3d/{source}.npz",
                "kind": "keypoints3d",
                "source": source,
                "frames": kp.n_frames,
            }
        )

    if status.get("fit") not in (None, "missing") and store.has("fit", "bodyfit.npz"):
        step("body parameters")
        fit = store.load("fit", "bodyfit", BodyFit)
        write_npz(dest / "body" / "bodyfit.npz", to_arrays(fit))
        files.append(
            {"path": "body/bodyfit.npz", "kind": "bodyfit", "frames": int(fit.frame_indices.shape[0])}
        )

    if status.get("physics") not in (None, "missing") and store.has("physics", "result.npz"):
        step("physics")
        res = release_physics(store.load("physics", "result", PhysicsResult))
        write_npz(dest / "physics" / "result.npz", to_arrays(res))
        (dest / "physics" / "scene.xml").write_bytes(store.path("physics", "scene.xml").read_bytes())
        files += [
            {"path": "physics/result.npz", "kind": "physics", "frames": int(res.frame_indices.shape[0])},
            {"path": "physics/scene.xml", "kind": "mjcf"},
        ]

    names = {i: n for i, n in enumerate(cfg.athletes)}
    if status.get(ANALYZE_STAGE) not in (None, "missing"):
        step("events")
        events, _, source = load_analytics(session_dir)
        write_json(dest / "events.json", events_to_json(events, names, source))
        files.append({"path": "events.json", "kind": "events"})

    step("annotations")
    write_json(dest / "annotations.json", annotations_doc(session_dir, history))
    files.append({"path": "annotations.json", "kind": "annotations"})

    identified = int(np.sum(assoc.person_of_det >= 0))
    meta = {
        "format": META_FORMAT_ID,
        "id": sid,
        "name": cfg.name,
        "source": cfg.source,
        "fps": float(rig.fps),
        "n_frames": int(tracks.n_frames),
        "cameras": list(rig.names),
        "athletes": [
            {"id": int(p), "name": str(n) or names.get(int(p), "")}
            for p, n in zip(assoc.person_ids.tolist(), assoc.person_names, strict=True)
        ],
        "n_detections": int(tracks.n_dets),
        "n_detections_identified": identified,
        "stages": _stage_rows(store, status),
        "files": files,
    }
    write_json(dest / "meta.json", meta)
    return meta
