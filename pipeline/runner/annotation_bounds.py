"""What a session's annotations may refer to: its frames, persons, cameras and tracks.

Read from the session's artifacts when they exist (``detect2d``'s frame count, the
``associate`` stage's person ids, the ``track`` stage's tracks), else from its inputs (a
tracks file's frame count, the athletes of ``session.json``, the calibration's cameras and
image sizes), else left unknown (``None``: not checked). The rules themselves live in
``pipeline.schema.annotation_checks.check_annotation``.

The tracks edits name are the track stage's output with every active track edit applied.
The stored output already holds the edits it was run with (its manifest hashes them); when
the active edits are those plus newer ones, the newer ones are applied on top. When an edit
the output holds has since been undone, the tracks are not known until the stage re-runs.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from pipeline.artifacts import ArtifactStore
from pipeline.schema.annotation_checks import AnnotationBounds
from pipeline.schema.annotations import annotations_for, annotations_hash, load_annotations
from pipeline.schema.base import load_npz_scalar
from pipeline.schema.detections import Tracks2D
from pipeline.schema.session import SessionConfig
from pipeline.stages.track_edits import apply_track_edits

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


def _person_ids(store: ArtifactStore, session: SessionConfig, extra: Iterable[int]) -> tuple[int, ...]:
    ids = set(range(len(session.athletes))) | {int(i) for i in extra}
    if store.has("associate", "association.npz"):
        path = store.path("associate", "association.npz")
        try:
            with np.load(path, allow_pickle=False) as z:
                ids |= {int(i) for i in z["person_ids"]}
        except (OSError, KeyError, ValueError) as e:
            raise ValueError(f"{path}: cannot read the person ids: {e}") from e
    return tuple(sorted(ids))


def _tracks(session_dir: Path, store: ArtifactStore, cameras: tuple[str, ...]) -> Tracks2D | None:
    """The track stage's output with the active track edits it does not hold yet applied; None
    before the stage has run or when an edit it holds has been undone since."""
    manifest = store.manifest("track")
    if manifest is None or not store.has("track", "tracks.npz"):
        return None
    edits = annotations_for(load_annotations(session_dir / "annotations.json"), "track")
    held = manifest.inputs.get("annotations")
    for k in range(len(edits), -1, -1):
        if annotations_hash(edits[:k]) == held:
            tracks = store.load("track", "tracks", Tracks2D)
            return apply_track_edits(tracks, cameras, edits[k:]) if k < len(edits) else tracks
    log.info("%s: the track edits changed since the track stage ran; tracks not checked", session_dir)
    return None


def annotation_bounds(session_dir: Path, extra_person_ids: Iterable[int] = ()) -> AnnotationBounds:
    """The session's ``AnnotationBounds``; ``extra_person_ids`` are persons the caller knows of
    besides the athletes and the association's (the server's named identities).

    Best effort: a part that cannot be read yet (a calibration that does not parse, a
    missing artifact) stays ``None`` and is logged."""
    from pipeline.io.session_rig import session_rig

    session_dir = Path(session_dir)
    session = SessionConfig.load(session_dir)
    store = ArtifactStore(session_dir)
    n_frames = person_ids = cameras = tracks = image_size_wh = None
    try:
        n_frames = _n_frames(session_dir, session, store)
        person_ids = _person_ids(store, session, extra_person_ids)
        rig = session_rig(session_dir, session)
        cameras, image_size_wh = rig.names, rig.image_size_wh
        tracks = _tracks(session_dir, store, cameras)
    except ValueError as e:
        log.warning("%s: annotation bounds partly unknown: %s", session_dir, e)
    return AnnotationBounds(n_frames=n_frames, person_ids=person_ids, cameras=cameras, tracks=tracks,
                            image_size_wh=image_size_wh)
