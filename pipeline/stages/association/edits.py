"""The human identity edits overlay (``AssignIdentity``, ``SwapIdentities``), applied in order."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pipeline.schema.annotations import Annotation, AssignIdentity, SwapIdentities
from pipeline.schema.detections import Tracks2D


def apply_identity_edits(
    tracks: Tracks2D,
    camera_names: tuple[str, ...],
    person_of_det: np.ndarray,
    confidence: np.ndarray,
    edits: Sequence[Annotation],
) -> tuple[np.ndarray, np.ndarray, set[int]]:
    """Override the automatic association with the edits; returns new arrays + ids the edits use.

    - ``AssignIdentity(view, track, frame_start, frame_end, person)``: those detections get
      ``person`` (confidence 1); another detection of that view and frame that had
      ``person`` loses it (-1), so one person never has two detections in one image.
    - ``SwapIdentities(frame, a, b, view, frame_end)``: over frames ``[frame, frame_end)``
      (``frame_end=None``: to the end), ``a`` and ``b`` trade their detections in ``view``
      (``""`` = every view).
    Other annotation kinds are not consumed by association and are ignored.
    Raises ``ValueError`` for unknown camera names and malformed edits.
    """
    pod = person_of_det.copy()
    conf = confidence.copy()
    used: set[int] = set()
    for e in edits:
        if isinstance(e, AssignIdentity):
            v = _view_index(camera_names, e.view, e)
            if e.frame_start > e.frame_end or e.person < -1:
                raise ValueError(f"invalid edit {e}: needs frame_start <= frame_end and person >= -1")
            sel = (tracks.view == v) & (tracks.track_id == e.track) & (tracks.frame >= e.frame_start)
            sel &= tracks.frame <= e.frame_end
            if e.person >= 0:
                frames = np.unique(tracks.frame[sel])
                clash = (tracks.view == v) & np.isin(tracks.frame, frames) & (pod == e.person) & ~sel
                pod[clash] = -1
                used.add(e.person)
            pod[sel] = e.person
            conf[sel] = 1.0
        elif isinstance(e, SwapIdentities):
            if e.person_a < 0 or e.person_b < 0:
                raise ValueError(f"invalid edit {e}: persons must be >= 0")
            if e.frame_end is not None and e.frame_end <= e.frame:
                raise ValueError(f"invalid edit {e}: frame_end must be after frame")
            sel = tracks.frame >= e.frame
            if e.frame_end is not None:
                sel &= tracks.frame < e.frame_end
            if e.view:
                sel &= tracks.view == _view_index(camera_names, e.view, e)
            a = sel & (pod == e.person_a)
            b = sel & (pod == e.person_b)
            pod[a] = e.person_b
            pod[b] = e.person_a
            conf[a | b] = 1.0
            used.update((e.person_a, e.person_b))
    return pod, conf, used


def _view_index(names: tuple[str, ...], view: str, edit: Annotation) -> int:
    if view not in names:
        raise ValueError(f"edit {edit}: camera {view!r} is not in the rig {names}")
    return names.index(view)
