"""Stage ``associate``: who is who across cameras (paper section 3.1).

Every detection of a ``Tracks2D`` gets a global person id (``0 .. n_persons-1`` for the
athletes, ``-1`` for everybody else) and a confidence. The method:

1. ``association.prep``: undistort and normalise every detection once.
2. ``association.tracker``: frame-by-frame multi-view 3D tracking of *every* person:
   detections are attached to predicted 3D persons by a global assignment over all views
   (reprojection cost + a per-view track prior), and new persons are born from
   cross-view pairs with a small pose epipolar distance (the paper's ``d_e`` averaged
   over the joints confident in both views, falling back to body centroids) verified in
   every other view. Identity follows geometry, so a per-view id swap changes the
   identity inside that track from the frame of the swap.
3. ``association.identities``: fragments are stitched over gaps, and the ``n_persons``
   identities with the most multi-view support over the whole sequence are the athletes
   (a referee or bystanders, even when visible in every view, get ``-1``).
4. ``association.edits``: the human ``AssignIdentity`` / ``SwapIdentities`` edits
   override the automatic result.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pipeline.schema.annotations import Annotation
from pipeline.schema.association import Association
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D
from pipeline.stages.association.config import AssociateConfig
from pipeline.stages.association.edits import apply_identity_edits
from pipeline.stages.association.identities import select_athletes, stitch_fragments
from pipeline.stages.association.prep import prepare
from pipeline.stages.association.tracker import track_fragments

__all__ = ["AssociateConfig", "person_count", "run"]


def run(
    tracks: Tracks2D,
    rig: CameraRig,
    cfg: AssociateConfig = AssociateConfig(),
    edits: Sequence[Annotation] = (),
    person_names: tuple[str, ...] = (),
) -> Association:
    """Associate detections across views into persons (how many: ``cfg.n_persons``).

    Args:
        tracks: per-view tracked 2D detections (``tracks.n_views == rig.n_views``).
        rig: the calibration.
        cfg: stage config.
        edits: identity edits (``AssignIdentity``, ``SwapIdentities``), applied in order.
        person_names: display names by person id (missing names are ""); with
            ``n_persons="athletes"`` their number is the number of persons.
    Returns:
        ``Association`` with ``person_ids = 0..n-1`` (plus any id an edit uses).
    Raises:
        ValueError: rig/tracks mismatch, bad config, no athlete names in "athletes" mode,
        or an edit naming an unknown camera.
    """
    n_wanted = person_count(cfg, person_names)
    if rig.n_views < 2:
        raise ValueError(
            f"associate: the calibration has {rig.n_views} camera ({', '.join(rig.names)}); matching persons "
            "across views needs at least 2"
        )
    prep = prepare(tracks, rig, cfg.min_keypoint_conf)
    frags = track_fragments(prep, rig, tracks.n_frames, cfg)
    ident = stitch_fragments(frags, prep.tracklet, rig.fps, cfg)
    choice = select_athletes(frags, ident, n_wanted, rig, tracks.n_frames, cfg)
    lab = frags.label
    pod = np.where(lab >= 0, choice.athlete[np.maximum(lab, 0)], -1)
    conf = _confidence(frags.cost, frags.cost_other, lab >= 0, cfg.gate)
    ids = set(range(n_wanted if n_wanted is not None else choice.n_persons))
    if edits:
        pod, conf, used = apply_identity_edits(tracks, rig.names, pod, conf, edits)
        ids |= used
    person_ids = np.array(sorted(ids), np.int64)
    names = tuple(person_names[i] if i < len(person_names) else "" for i in person_ids)
    return Association(person_ids=person_ids, person_names=names, person_of_det=pod, confidence=conf)


def person_count(cfg: AssociateConfig, person_names: Sequence[str]) -> int | None:
    """The number of persons ``cfg.n_persons`` asks for; ``None`` in "auto" mode.

    Raises ``ValueError`` in "athletes" mode when no names are given."""
    if cfg.n_persons == "auto":
        return None
    if cfg.n_persons == "athletes":
        if not person_names:
            raise ValueError(
                'associate: n_persons is "athletes" but the session lists no athletes; add names to '
                'session.json "athletes" (or `cornerman new --athlete NAME`), or set '
                'stage_config.associate.n_persons to a number or "auto"'
            )
        return len(person_names)
    return int(cfg.n_persons)


def _confidence(cost: np.ndarray, cost_other: np.ndarray, assigned: np.ndarray, gate: float) -> np.ndarray:
    """Assigned: how well the detection fits (1 - cost/gate) and how clearly it beats the
    runner-up (margin/gate). Unassigned: how far it is from every person."""
    with np.errstate(invalid="ignore"):
        fit = np.clip(1.0 - np.nan_to_num(cost, nan=gate) / gate, 0.0, 1.0)
        margin = np.clip((cost_other - np.nan_to_num(cost, nan=0.0)) / gate, 0.0, 1.0)
        conf_a = np.sqrt(fit * margin)
        conf_u = np.clip(cost_other / (2.0 * gate), 0.0, 1.0)
    return np.where(assigned, conf_a, conf_u).astype(np.float64)
