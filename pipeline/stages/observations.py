"""The detections that speak for each athlete: one per (frame, person, view)."""

from __future__ import annotations

import numpy as np

from pipeline.schema.association import Association
from pipeline.schema.detections import Tracks2D


def athlete_rows(tracks: Tracks2D, assoc: Association, n_views: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rows of ``tracks`` with the detection used for each (frame, person, view): when an edit
    left two, the more confident. Returns ``(rows, frame, person, view)``, ``person`` the index
    into ``assoc.person_ids``. ``ValueError`` when the association or the rig do not match."""
    if assoc.person_of_det.shape[0] != tracks.n_dets:
        raise ValueError(f"association has {assoc.person_of_det.shape[0]} rows but tracks have {tracks.n_dets}")
    if tracks.n_views != n_views:
        raise ValueError(f"tracks have {tracks.n_views} views but the rig has {n_views}")
    P, V = assoc.n_persons, n_views
    lut = np.full(int(max(assoc.person_ids.max(initial=0), assoc.person_of_det.max(initial=0))) + 1, -1)
    lut[assoc.person_ids] = np.arange(P)
    pid = np.where(assoc.person_of_det >= 0, lut[np.maximum(assoc.person_of_det, 0)], -1)
    rows = np.flatnonzero(pid >= 0)
    # Most confident last after sorting; np.unique on the reversed keys keeps it.
    rows = rows[np.argsort(assoc.confidence[rows], kind="stable")]
    key = (tracks.frame[rows] * P + pid[rows]) * V + tracks.view[rows]
    _, last = np.unique(key[::-1], return_index=True)
    rows = rows[::-1][last]
    return rows, tracks.frame[rows], pid[rows], tracks.view[rows]
