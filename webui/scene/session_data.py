"""Everything the viewer shows, loaded read-only from a session's artifacts.

Any stage may be missing (not run yet, failed, or being re-run): the matching field is
``None`` / absent and the viewer shows what exists. Nothing here imports torch or mujoco.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from pipeline.artifacts import ArtifactStore
from pipeline.runner.rig import rig_for
from pipeline.schema.analytics import AthleteSeries, BoutEvents
from pipeline.schema.association import Association
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit, PhysicsResult
from pipeline.schema.session import SessionConfig
from pipeline.schema.sources import RESULT_ARTIFACTS
from pipeline.stages.evaluate import ProblemFlags

log = logging.getLogger(__name__)

KeypointSource = Literal["filtered", "fit", "physics"]
KEYPOINT_SOURCES: dict[str, str] = {name: RESULT_ARTIFACTS[name][0] for name in ("filtered", "fit", "physics")}
"""Viewer source name (``pipeline.schema.sources``) -> stage whose ``keypoints3d.npz`` it shows."""

STAGES_READ: tuple[str, ...] = ("track", "associate", "triangulate", "fit", "physics", "analyze", "evaluate")


@dataclass
class SessionData:
    """Artifacts of one session, as the viewer sees them at one point in time.

    Fields:
        session_dir: the session folder.
        config: its ``session.json``.
        rig: calibration (fps overridden by ``session.fps`` when set).
        n_frames: timeline length (frames of the 2D input, else of the 3D results).
        tracks: ``track/tracks.npz`` or None.
        association: ``associate/association.npz`` (rows aligned with ``tracks``) or None.
        keypoints: source name (``filtered``/``fit``/``physics``) -> Keypoints3D.
        bodyfit: ``fit/bodyfit.npz`` or None.
        physics: ``physics/result.npz`` or None.
        physics_xml: path of ``physics/scene.xml`` or None.
        metrics: ``evaluate/metrics.json`` content (empty when absent).
        problems: ``evaluate/problems.npz`` (the per-frame problem flags) or None.
        events: ``analyze/events.npz`` (punches, defence: slips, ducks, blocks, parries; clinches) or None.
        series: ``analyze/series.npz`` (distance, stance, guard, work rate) or None.
        stamp: manifests' creation times, to notice a re-run.
    """

    session_dir: Path
    config: SessionConfig
    rig: CameraRig
    n_frames: int
    tracks: Tracks2D | None = None
    association: Association | None = None
    keypoints: dict[str, Keypoints3D] = field(default_factory=dict)
    bodyfit: BodyFit | None = None
    physics: PhysicsResult | None = None
    physics_xml: Path | None = None
    metrics: dict[str, Any] = field(default_factory=dict)
    problems: ProblemFlags | None = None
    events: BoutEvents | None = None
    series: AthleteSeries | None = None
    stamp: tuple[float, ...] = ()
    _row_keys: np.ndarray | None = None
    _row_order: np.ndarray | None = None

    @property
    def fps(self) -> float:
        return float(self.rig.fps)

    @property
    def camera_names(self) -> tuple[str, ...]:
        return self.rig.names

    @property
    def person_ids(self) -> list[int]:
        """Global person ids known to any artifact (sorted)."""
        ids: set[int] = set()
        if self.association is not None:
            ids |= {int(p) for p in self.association.person_ids}
        for kp in self.keypoints.values():
            ids |= {int(p) for p in kp.person_ids}
        return sorted(ids)

    def det_rows(self, view: int, frame: int) -> np.ndarray:
        """Row indices of ``tracks`` in ``view`` at ``frame`` (empty without tracks)."""
        if self.tracks is None:
            return np.zeros(0, dtype=np.int64)
        if self._row_keys is None:
            keys = self.tracks.frame.astype(np.int64) * self.tracks.n_views + self.tracks.view.astype(np.int64)
            self._row_order = np.argsort(keys, kind="stable")
            self._row_keys = keys[self._row_order]
        assert self._row_order is not None
        k = int(frame) * self.tracks.n_views + int(view)
        lo, hi = np.searchsorted(self._row_keys, [k, k + 1])
        return self._row_order[lo:hi]

    def person_of_rows(self, rows: np.ndarray) -> np.ndarray:
        """Global person id of each tracks row (``-1`` = nobody / not associated yet)."""
        if self.association is None:
            return np.full(len(rows), -1, dtype=np.int64)
        return self.association.person_of_det[rows].astype(np.int64)

    def confidence_of_rows(self, rows: np.ndarray) -> np.ndarray:
        if self.association is None:
            return np.zeros(len(rows))
        return self.association.confidence[rows]

    def track_person(self, view: int, track: int, frame: int) -> int:
        """Person of track ``track`` in ``view`` at ``frame`` (``-1`` if absent or unassigned)."""
        rows = self.det_rows(view, frame)
        if self.tracks is None or rows.size == 0:
            return -1
        hit = rows[self.tracks.track_id[rows] == track]
        return int(self.person_of_rows(hit)[0]) if hit.size else -1


def _stamp(store: ArtifactStore) -> tuple[float, ...]:
    out = []
    for stage in STAGES_READ:
        m = store.manifest(stage)
        out.append(m.created_unix_s if m else 0.0)
    return tuple(out)


def artifacts_stamp(session_dir: Path) -> tuple[float, ...]:
    """Cheap fingerprint of the session's artifacts (manifest times of the stages read)."""
    return _stamp(ArtifactStore(session_dir))


def _load_opt(store: ArtifactStore, stage: str, name: str, cls: type) -> Any:
    if not store.has(stage, f"{name}.npz"):
        return None
    try:
        return store.load(stage, name, cls)
    except ValueError as e:
        # A malformed artifact must not take the whole viewer down: show the rest.
        log.warning("cannot load %s/%s.npz: %s", stage, name, e)
        return None


def load_session_data(session_dir: str | Path) -> SessionData:
    """Load every artifact the viewer can show; ``ValueError`` if the session itself is unreadable."""
    session_dir = Path(session_dir)
    config = SessionConfig.load(session_dir)
    rig = rig_for("downstream", session_dir, config)  # the refined rig when calibrate adopted one
    store = ArtifactStore(session_dir)
    tracks = _load_opt(store, "track", "tracks", Tracks2D)
    association = _load_opt(store, "associate", "association", Association)
    if association is not None and (tracks is None or association.person_of_det.shape[0] != tracks.n_dets):
        log.warning("association rows do not match the tracks (stale artifact?): ignoring it until the re-run")
        association = None
    keypoints: dict[str, Keypoints3D] = {}
    for src, stage in KEYPOINT_SOURCES.items():
        kp = _load_opt(store, stage, "keypoints3d", Keypoints3D)
        if kp is not None:
            keypoints[src] = kp
    bodyfit = _load_opt(store, "fit", "bodyfit", BodyFit)
    physics = _load_opt(store, "physics", "result", PhysicsResult)
    physics_xml = store.stage_dir("physics") / "scene.xml" if store.has("physics", "scene.xml") else None
    metrics: dict[str, Any] = {}
    if store.has("evaluate", "metrics.json"):
        try:
            metrics = json.loads(store.path("evaluate", "metrics.json").read_text())
        except json.JSONDecodeError as e:
            log.warning("evaluate/metrics.json is malformed: %s", e)
    problems = _load_problems(store)
    n_frames = tracks.n_frames if tracks is not None else 0
    for kp in keypoints.values():
        if kp.n_frames:
            n_frames = max(n_frames, int(kp.frame_indices.max()) + 1)
    return SessionData(
        session_dir=session_dir,
        config=config,
        rig=rig,
        n_frames=max(n_frames, 1),
        tracks=tracks,
        association=association,
        keypoints=keypoints,
        bodyfit=bodyfit,
        physics=physics,
        physics_xml=physics_xml,
        metrics=metrics,
        problems=problems,
        events=_load_opt(store, "analyze", "events", BoutEvents),
        series=_load_opt(store, "analyze", "series", AthleteSeries),
        stamp=_stamp(store),
    )


def _load_problems(store: ArtifactStore) -> ProblemFlags | None:
    """``evaluate/problems.npz`` as ``ProblemFlags``; None when absent or unreadable (logged)."""
    if not store.has("evaluate", "problems.npz"):
        return None
    try:
        with np.load(store.path("evaluate", "problems.npz"), allow_pickle=False) as z:
            return ProblemFlags(**{k: z[k] for k in z.files})
    except (OSError, ValueError, TypeError) as e:
        log.warning("evaluate/problems.npz is unreadable (stale artifact?): %s", e)
        return None


def frame_row(kp: Keypoints3D, frame: int) -> int | None:
    """Row of ``kp`` holding video frame ``frame`` (None when that frame has no estimate)."""
    i = int(np.searchsorted(kp.frame_indices, frame))
    if i < kp.n_frames and int(kp.frame_indices[i]) == frame:
        return i
    return None
