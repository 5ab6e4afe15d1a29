"""What a session's annotations may refer to: its frame count, persons and cameras.

Read from the session's artifacts when they exist (``detect2d``'s frame count, the
``associate`` stage's person ids), else from its inputs (a tracks file's frame count),
else left unknown (``None``: not checked). The rules themselves live in
``pipeline.schema.annotations.check_annotation``.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from pipeline.artifacts import ArtifactStore
from pipeline.schema.annotations import AnnotationBounds
from pipeline.schema.base import load_npz_scalar
from pipeline.schema.session import SessionConfig

log = logging.getLogger(__name__)


def _n_frames(session_dir: Path, session: SessionConfig, store: ArtifactStore) -> int | None:
    if store.has("detect2d", "detections.npz"):
        return int(load_npz_scalar(store.path("detect2d", "detections.npz"), "n_frames"))
    if session.source == "tracks" and session.tracks:
        p = Path(session.tracks)
        path = p if p.is_absolute() else session_dir / p
        if path.is_file():
            return int(load_npz_scalar(path, "n_frames"))
    return None


def _person_ids(store: ArtifactStore) -> tuple[int, ...] | None:
    if not store.has("associate", "association.npz"):
        return None
    path = store.path("associate", "association.npz")
    try:
        with np.load(path, allow_pickle=False) as z:
            return tuple(int(i) for i in z["person_ids"])
    except (OSError, KeyError, ValueError) as e:
        raise ValueError(f"{path}: cannot read the person ids: {e}") from e


def annotation_bounds(session_dir: Path) -> AnnotationBounds:
    """The session's ``AnnotationBounds`` (best effort: a part that cannot be read yet, such as
    the camera names of a calibration that does not parse, stays ``None`` and is logged)."""
    from pipeline.io.session_rig import session_rig

    session_dir = Path(session_dir)
    session = SessionConfig.load(session_dir)
    store = ArtifactStore(session_dir)
    n_frames = person_ids = cameras = None
    try:
        n_frames = _n_frames(session_dir, session, store)
        person_ids = _person_ids(store)
        cameras = session_rig(session_dir, session).names
    except ValueError as e:
        log.warning("%s: annotation bounds partly unknown: %s", session_dir, e)
    return AnnotationBounds(n_frames=n_frames, person_ids=person_ids, cameras=cameras)
