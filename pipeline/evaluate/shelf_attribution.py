"""Why a Shelf limb part is wrong: the 2D detections, or what we made of them.

A part the Shelf protocol scores wrong is *attributed* by the part's worse endpoint: the
2D keypoints of that joint in the person's associated detections (every view where the
detector gave it) are compared with the projections of our output and of the ground
truth. When the detections sit much closer to our output than to the ground truth, the
error was in the detector's input (or the annotation), and no method that follows its
detections can score the part; when they sit much closer to the ground truth, the error
is ours. This splits a PCP gap into what the pipeline can still win and what it cannot
on these detections.

Only the 12 limb joints are attributed (the head and torso parts are built from several
COCO joints, so no single detection stands for them). Pure numpy.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from pipeline.evaluate.shelf import SHELF_JOINTS, SHELF_PARTS, ShelfScore
from pipeline.geometry.projection import project
from pipeline.schema.association import Association
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D
from pipeline.schema.keypoints3d import Keypoints3D

LIMB_JOINTS: tuple[str, ...] = SHELF_JOINTS[:12]
"""The Shelf joints that are COCO joints of the same name (ankles to wrists)."""

AGREE_RATIO = 0.5
"""Detections "agree" with one side when their median pixel distance to it is at most
this fraction of their distance to the other side (in (0, 1))."""

MIN_KEYPOINT_CONF = 0.1
"""Detector confidence (in [0, 1]) below which a 2D keypoint counts as not given."""


@dataclass(frozen=True)
class WrongPartAttribution:
    """Counts of wrong limb parts (arms and legs) of one output, over actors and frames.

    Fields:
        wrong_parts: limb parts scored and wrong.
        detections_agree_output: of those, parts whose worse endpoint's 2D detections lie
            near our output's projection and far from the ground truth's.
        detections_agree_gt: parts whose detections lie near the ground truth (our error).
        unobserved: parts whose worse endpoint no associated detection gives.
        ambiguous: the rest (detections between both, or split across views).
    """

    wrong_parts: int
    detections_agree_output: int
    detections_agree_gt: int
    unobserved: int
    ambiguous: int

    @property
    def detector_share(self) -> float:
        """Fraction in [0, 1] of wrong parts where the detections agree with our output (NaN: none wrong)."""
        return self.detections_agree_output / self.wrong_parts if self.wrong_parts else float("nan")


def associated_limb_keypoints(
    tracks: Tracks2D,
    association: Association,
    person_ids: np.ndarray,
    frame_indices: np.ndarray,
    min_conf: float = MIN_KEYPOINT_CONF,
) -> np.ndarray:
    """The limb joints each predicted person's associated detections give, per view.

    Returns (frames, persons, views, 12, 2) pixels, NaN where the person has no detection
    in that view and frame or the joint's confidence is below ``min_conf`` (the most
    confident detection wins when a person has several in one view). ``ValueError`` when
    the detections lack a limb joint or the association does not match the tracks.
    """
    missing = [j for j in LIMB_JOINTS if j not in tracks.joint_names]
    if missing:
        raise ValueError(f"associated_limb_keypoints: detections lack the joints {missing}")
    if association.person_of_det.shape[0] != tracks.frame.shape[0]:
        raise ValueError(
            f"associated_limb_keypoints: the association has {association.person_of_det.shape[0]} "
            f"detections, the tracks {tracks.frame.shape[0]}"
        )
    jidx = np.array([tracks.joint_names.index(j) for j in LIMB_JOINTS])
    out = np.full((len(frame_indices), len(person_ids), tracks.n_views, len(LIMB_JOINTS), 2), np.nan)
    best = np.full(out.shape[:4], -np.inf)
    f_of = {int(f): i for i, f in enumerate(frame_indices)}
    p_of = {int(p): i for i, p in enumerate(person_ids)}
    for r in np.flatnonzero(association.person_of_det >= 0):
        fi, pi = f_of.get(int(tracks.frame[r])), p_of.get(int(association.person_of_det[r]))
        if fi is None or pi is None:
            continue
        v = int(tracks.view[r])
        conf = tracks.keypoint_conf[r, jidx]
        ok = (conf >= min_conf) & tracks.keypoint_valid[r, jidx] & (conf > best[fi, pi, v])
        out[fi, pi, v, ok] = tracks.keypoints_px[r, jidx[ok]]
        best[fi, pi, v, ok] = conf[ok]
    return out


def attribute_wrong_parts(
    pred: Keypoints3D,
    gt: Keypoints3D,
    score: ShelfScore,
    observed_px: np.ndarray,
    rig: CameraRig,
    alpha: float = 0.5,
    agree_ratio: float = AGREE_RATIO,
) -> WrongPartAttribution:
    """Attribute each wrong limb part of ``pred`` (``SHELF_JOINTS``, scored as ``score``).

    ``observed_px`` is ``associated_limb_keypoints`` over ``pred``'s frames and persons;
    ``gt`` is ``load_ground_truth``'s; ``alpha`` is the PCP threshold the score used.
    """
    if pred.joint_names != SHELF_JOINTS:
        raise ValueError(f"attribute_wrong_parts: pred must have the Shelf joints, got {pred.joint_names}")
    if not 0 < agree_ratio < 1:
        raise ValueError(f"attribute_wrong_parts: agree_ratio must lie in (0, 1), got {agree_ratio}")
    limb_parts = [(a, b) for _, a, b in SHELF_PARTS if a in LIMB_JOINTS and b in LIMB_JOINTS]
    counts = dict(out=0, gt=0, unobserved=0, ambiguous=0, wrong=0)
    for g, fg, fp, pm in _matched(pred, gt, score):
        for a, b in limb_parts:
            ja, jb = SHELF_JOINTS.index(a), SHELF_JOINTS.index(b)
            if not (gt.valid[fg, g, ja] and gt.valid[fg, g, jb]):
                continue
            ga, gb = gt.xyz_m[fg, g, ja], gt.xyz_m[fg, g, jb]
            ok = pred.valid[fp, pm, ja] and pred.valid[fp, pm, jb]
            ea = np.linalg.norm(pred.xyz_m[fp, pm, ja] - ga)
            eb = np.linalg.norm(pred.xyz_m[fp, pm, jb] - gb)
            if ok and 0.5 * (ea + eb) <= alpha * np.linalg.norm(ga - gb):
                continue
            counts["wrong"] += 1
            j = ja if (not pred.valid[fp, pm, jb] or ea >= eb) else jb
            counts[
                _side(pred.xyz_m[fp, pm, j], gt.xyz_m[fg, g, j], observed_px[fp, pm, :, j], rig, agree_ratio)
            ] += 1
    return WrongPartAttribution(
        wrong_parts=counts["wrong"],
        detections_agree_output=counts["out"],
        detections_agree_gt=counts["gt"],
        unobserved=counts["unobserved"],
        ambiguous=counts["ambiguous"],
    )


def _matched(pred: Keypoints3D, gt: Keypoints3D, score: ShelfScore) -> Iterator[tuple[int, int, int, int]]:
    """(ground-truth person index, ground-truth frame, prediction frame, predicted person) of
    every actor-frame the score matched to a predicted person."""
    p_frame = {int(f): i for i, f in enumerate(pred.frame_indices)}
    for ai, actor in enumerate(score.actors):
        g = gt.person_index(actor)
        for fg, pm in enumerate(score.matched_person[:, ai]):
            fp = p_frame.get(int(gt.frame_indices[fg]))
            if pm >= 0 and fp is not None:
                yield g, fg, fp, int(pm)


def _side(ours: np.ndarray, truth: np.ndarray, obs: np.ndarray, rig: CameraRig, ratio: float) -> str:
    """``out``, ``gt``, ``unobserved`` or ``ambiguous`` for one joint seen as ``obs`` (views, 2)."""
    seen = np.isfinite(obs).all(-1)
    if not seen.any():
        return "unobserved"
    uv, _ = project(rig, np.stack([ours, truth]))  # (views, 2, 2)
    d_out = float(np.median(np.linalg.norm(obs[seen] - uv[seen, 0], axis=-1)))
    d_gt = float(np.median(np.linalg.norm(obs[seen] - uv[seen, 1], axis=-1)))
    if d_out <= ratio * d_gt:
        return "out"
    if d_gt <= ratio * d_out:
        return "gt"
    return "ambiguous"


def hip_height_offset_mm(pred: Keypoints3D, gt: Keypoints3D, score: ShelfScore) -> float:
    """Median height (mm, z up) of the output's hips above the ground truth's, over matched
    actor-frames: the part of MPJPE that comes from where COCO and Shelf put the hip."""
    hips = [SHELF_JOINTS.index("right_hip"), SHELF_JOINTS.index("left_hip")]
    dz: list[float] = []
    for g, fg, fp, pm in _matched(pred, gt, score):
        for j in hips:
            if gt.valid[fg, g, j] and pred.valid[fp, pm, j]:
                dz.append(float(pred.xyz_m[fp, pm, j, 2] - gt.xyz_m[fg, g, j, 2]))
    return 1000.0 * float(np.median(dz)) if dz else float("nan")
