"""Apply human track edits (split, merge, mark invalid, fix keypoint) as an overlay.

Pure function over ``Tracks2D``; the stored detector/tracker output is never changed.
"""

from __future__ import annotations

import numpy as np

from pipeline.schema.annotations import Annotation, FixKeypoint, MarkInvalid, MergeTracks, SplitTrack
from pipeline.schema.detections import Tracks2D


def apply_track_edits(tracks: Tracks2D, camera_names: tuple[str, ...], edits: list[Annotation]) -> Tracks2D:
    """Return ``tracks`` with the edits applied in order.

    - ``SplitTrack``: rows of (view, track) at frames >= frame get a fresh track id.
    - ``MergeTracks``: rows of track_b get track_a's id (rows of b that collide with
      a row of a in the same frame keep b's id: a merge never creates duplicates).
    - ``MarkInvalid``: the row's track id becomes -1 and its keypoints invalid.
    - ``FixKeypoint``: the joint is set to the given pixel with confidence 1.
    Raises ``ValueError`` for an unknown camera or joint.
    """
    track_id = tracks.track_id.copy()
    kp = tracks.keypoints_px.copy()
    conf = tracks.keypoint_conf.copy()
    valid = tracks.keypoint_valid.copy()

    def view_index(name: str) -> int:
        if name not in camera_names:
            raise ValueError(f"annotation refers to camera {name!r}, not in {camera_names}")
        return camera_names.index(name)

    for e in edits:
        if isinstance(e, SplitTrack):
            v = view_index(e.view)
            sel = (tracks.view == v) & (track_id == e.track) & (tracks.frame >= e.frame)
            new_id = int(track_id[tracks.view == v].max(initial=-1)) + 1
            track_id[sel] = new_id
        elif isinstance(e, MergeTracks):
            v = view_index(e.view)
            in_v = tracks.view == v
            frames_a = set(tracks.frame[in_v & (track_id == e.track_a)].tolist())
            sel = in_v & (track_id == e.track_b) & ~np.isin(tracks.frame, list(frames_a))
            track_id[sel] = e.track_a
        elif isinstance(e, MarkInvalid):
            v = view_index(e.view)
            sel = (tracks.view == v) & (tracks.frame == e.frame) & (track_id == e.track)
            track_id[sel] = -1
            valid[sel] = False
        elif isinstance(e, FixKeypoint):
            v = view_index(e.view)
            if e.joint not in tracks.joint_names:
                raise ValueError(f"annotation fixes joint {e.joint!r}, not in {tracks.joint_names}")
            j = tracks.joint_names.index(e.joint)
            sel = (tracks.view == v) & (tracks.frame == e.frame) & (track_id == e.track)
            kp[sel, j] = (e.x_px, e.y_px)
            conf[sel, j] = 1.0
            valid[sel, j] = True
    kw = dict(tracks.__dict__)
    kw.update(track_id=track_id, keypoints_px=kp, keypoint_conf=conf, keypoint_valid=valid)
    return Tracks2D(**kw)
