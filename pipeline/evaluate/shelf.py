"""The Shelf benchmark's scoring: PCP per actor and per part, and MPJPE (pure numpy).

Protocol (``<shared data>/shelf/README.md``; VoxelPose's and 4D Association's):

- actors 0-2 are scored on every frame where they have ground truth;
- per frame, each actor is matched to the predicted person with the smallest mean
  distance over the Shelf joints valid in both (several actors may share one person);
- 10 parts (``SHELF_PARTS``) per actor and frame; a part is correct when the mean of its
  two endpoint errors is at most ``alpha`` (0.5) times its true length; a part with an
  endpoint the prediction lacks, and every part of an actor with no predicted person in
  that frame, is wrong;
- MPJPE over the matched persons and the 14 Shelf joints valid in both.

Our COCO joints become Shelf joints with ``coco_to_shelf``. Positions are metres in the
world frame (z up), errors are reported in millimetres, PCP as fractions in [0, 1].
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.schema.keypoints3d import Keypoints3D

log = logging.getLogger(__name__)

SHELF_JOINTS: tuple[str, ...] = (
    "right_ankle",
    "right_knee",
    "right_hip",
    "left_hip",
    "left_knee",
    "left_ankle",
    "right_wrist",
    "right_elbow",
    "right_shoulder",
    "left_shoulder",
    "left_elbow",
    "left_wrist",
    "head_bottom",
    "head_top",
)
"""The 14 Shelf joints in the dataset's order (``gt.npz``'s first 14); the first 12 are
COCO joints of the same name, ``head_bottom`` is the neck, ``head_top`` the crown."""

SHELF_PARTS: tuple[tuple[str, str, str], ...] = (
    ("right_lower_leg", "right_ankle", "right_knee"),
    ("right_upper_leg", "right_knee", "right_hip"),
    ("left_upper_leg", "left_hip", "left_knee"),
    ("left_lower_leg", "left_knee", "left_ankle"),
    ("right_lower_arm", "right_wrist", "right_elbow"),
    ("right_upper_arm", "right_elbow", "right_shoulder"),
    ("left_upper_arm", "left_shoulder", "left_elbow"),
    ("left_lower_arm", "left_elbow", "left_wrist"),
    ("head", "head_bottom", "head_top"),
    ("torso", "hips_mid", "head_bottom"),
)
"""(part, joint, joint): the 10 scored parts, in VoxelPose's order; ``hips_mid`` is the
midpoint of both hips (valid when both are)."""

PART_NAMES: tuple[str, ...] = tuple(p[0] for p in SHELF_PARTS)

SHELF_ACTORS: tuple[int, ...] = (0, 1, 2)
"""The scored actors (the fourth appears in 33 frames and is not scored)."""

_HEAD_INPUTS: tuple[str, ...] = ("nose", "left_ear", "right_ear", "left_shoulder", "right_shoulder")


@dataclass(frozen=True)
class ShelfScore:
    """PCP and MPJPE of one prediction against the Shelf ground truth.

    Fields:
        actors: (actors,) the scored ground-truth person ids.
        part_names: the 10 parts (``PART_NAMES``).
        pcp_per_actor: (actors,) fraction of correct parts in [0, 1]; NaN for an actor
            without ground truth.
        pcp_per_part: (actors, parts) fraction of correct parts in [0, 1]; NaN as above.
        pcp: mean of ``pcp_per_actor`` over the actors with ground truth, in [0, 1].
        mpjpe_mm: mean joint error (mm) over matched persons and joints valid in both.
        matched_person: (frames, actors) index into the prediction's persons matched in
            each ground-truth frame, -1 when the actor is absent or no person was predicted.
        n_frames_gt: (actors,) frames in which the actor has ground truth.
        n_frames_matched: (actors,) of those, frames with a matched predicted person.
        joints_valid_frac: fraction, in [0, 1], of the matched persons' Shelf joints that
            were estimated (NaN when nothing matched).
    """

    actors: tuple[int, ...]
    part_names: tuple[str, ...]
    pcp_per_actor: np.ndarray
    pcp_per_part: np.ndarray
    pcp: float
    mpjpe_mm: float
    matched_person: np.ndarray
    n_frames_gt: np.ndarray
    n_frames_matched: np.ndarray
    joints_valid_frac: float

    def __post_init__(self) -> None:
        a, p = len(self.actors), len(self.part_names)
        shapes = {
            "pcp_per_actor": (self.pcp_per_actor.shape, (a,)),
            "pcp_per_part": (self.pcp_per_part.shape, (a, p)),
            "n_frames_gt": (self.n_frames_gt.shape, (a,)),
            "n_frames_matched": (self.n_frames_matched.shape, (a,)),
        }
        bad = {k: v for k, v in shapes.items() if v[0] != v[1]}
        if bad or self.matched_person.ndim != 2 or self.matched_person.shape[1] != a:
            raise ValueError(
                f"ShelfScore: shapes (got, expected) {bad}, matched_person {self.matched_person.shape}"
            )

    @property
    def coverage(self) -> float:
        """Fraction, in [0, 1], of ground-truth actor-frames with a matched predicted person."""
        n = int(self.n_frames_gt.sum())
        return float(self.n_frames_matched.sum() / n) if n else float("nan")


def load_ground_truth(path: str | Path, fps: float = 25.0) -> Keypoints3D:
    """The Shelf ``gt.npz`` (``gt[frame, actor, 15, 3]`` metres, NaN where absent) as
    ``Keypoints3D`` with ``SHELF_JOINTS`` (the 15th joint, the hip midpoint, is dropped),
    ``person_ids`` 0..actors-1, ``frame_indices`` 0..frames-1 (the index of the keypoint
    files; ``first_frame`` of the original sequence is only logged) and a validity mask.

    ``ValueError`` naming the file when the array is missing or of another shape.
    """
    try:
        with np.load(path, allow_pickle=False) as z:
            if "gt" not in z.files:
                raise ValueError(f"{path}: no array 'gt' (has {z.files})")
            gt = np.asarray(z["gt"], dtype=np.float64)
            first = int(z["first_frame"]) if "first_frame" in z.files else 0
    except OSError as e:
        raise ValueError(f"{path}: cannot read npz: {e}") from e
    if gt.ndim != 4 or gt.shape[2] < len(SHELF_JOINTS) or gt.shape[3] != 3:
        raise ValueError(f"{path}: gt must be (frames, actors, >=14, 3), got {gt.shape}")
    xyz = gt[:, :, : len(SHELF_JOINTS)]
    valid: np.ndarray = np.all(np.isfinite(xyz), axis=-1)
    log.debug(
        "%s: %d frames from original frame %d, actors present %s",
        path,
        xyz.shape[0],
        first,
        valid.any(2).sum(0),
    )
    f, p, j = valid.shape
    return Keypoints3D(
        joint_names=SHELF_JOINTS,
        person_ids=np.arange(p, dtype=np.int64),
        frame_indices=np.arange(f, dtype=np.int64),
        fps=float(fps),
        xyz_m=np.where(valid[..., None], xyz, 0.0),
        valid=valid,
        confidence=valid.astype(np.float64),
        n_views=np.zeros((f, p, j), dtype=np.int64),
        reproj_err_px=np.full((f, p, j), np.nan),
        source="gt",
    )


def shelf_head(
    nose: np.ndarray,
    left_ear: np.ndarray,
    right_ear: np.ndarray,
    left_shoulder: np.ndarray,
    right_shoulder: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Shelf's bottom and top of head from COCO points (each (..., 3), metres, z up).

    VoxelPose's ``coco2shelf3D`` (microsoft/voxelpose-pytorch, lib/dataset/shelf.py), which
    Shelf PCP numbers of COCO-joint methods use: a nose-based guess (bottom halfway from
    the shoulder midpoint to the nose, top at 0.75 / 0.75 / 1.5 of that vector in x / y / z)
    blended 3:1 with an ear-based one (bottom halfway from the shoulder midpoint to the ear
    midpoint, top as far again above the ear midpoint). The 1.5 on z assumes z is up.
    """
    mid_shoulder = 0.5 * (left_shoulder + right_shoulder)
    ear_mid = 0.5 * (left_ear + right_ear)
    to_nose = nose - mid_shoulder
    ear_bottom = 0.5 * (mid_shoulder + ear_mid)
    ear_top = 2.0 * ear_mid - ear_bottom
    nose_bottom = mid_shoulder + 0.5 * to_nose
    nose_top = mid_shoulder + to_nose * np.array([0.75, 0.75, 1.5])
    return 0.75 * nose_bottom + 0.25 * ear_bottom, 0.75 * nose_top + 0.25 * ear_top


def coco_to_shelf(kp: Keypoints3D) -> Keypoints3D:
    """Our COCO-named keypoints as the 14 Shelf joints (same persons and frames).

    The 12 limb joints are copied by name; the two head joints come from ``shelf_head``
    and are valid where all five of its inputs are (confidence and view count: the
    smallest of the inputs'). ``ValueError`` listing the missing names when ``kp`` lacks
    one of the joints needed.
    """
    needed = SHELF_JOINTS[:12] + _HEAD_INPUTS
    missing = [n for n in needed if n not in kp.joint_names]
    if missing:
        raise ValueError(f"coco_to_shelf: joints {missing} are not in {kp.joint_names}")
    idx = [kp.joint_names.index(n) for n in SHELF_JOINTS[:12]]
    h = [kp.joint_names.index(n) for n in _HEAD_INPUTS]
    bottom, top = shelf_head(*(kp.xyz_m[:, :, i] for i in h))
    head_ok = kp.valid[:, :, h].all(axis=-1)
    head_conf = kp.confidence[:, :, h].min(axis=-1)
    head_views = kp.n_views[:, :, h].min(axis=-1)
    both = np.stack([head_ok, head_ok], axis=-1)
    xyz = np.concatenate([kp.xyz_m[:, :, idx], np.stack([bottom, top], axis=2)], axis=2)
    return kp.replace(
        joint_names=SHELF_JOINTS,
        xyz_m=np.where(np.concatenate([kp.valid[:, :, idx], both], axis=2)[..., None], xyz, 0.0),
        valid=np.concatenate([kp.valid[:, :, idx], both], axis=2),
        confidence=np.concatenate([kp.confidence[:, :, idx], np.stack([head_conf, head_conf], -1)], axis=2),
        n_views=np.concatenate([kp.n_views[:, :, idx], np.stack([head_views, head_views], -1)], axis=2),
        reproj_err_px=np.concatenate([kp.reproj_err_px[:, :, idx], np.full(both.shape, np.nan)], axis=2),
    )


def _with_hips_mid(xyz: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Append the hips' midpoint as joint 14: (..., 14, 3), (..., 14) -> (..., 15, 3), (..., 15)."""
    r, left = SHELF_JOINTS.index("right_hip"), SHELF_JOINTS.index("left_hip")
    mid = 0.5 * (xyz[..., r, :] + xyz[..., left, :])
    ok = valid[..., r] & valid[..., left]
    return np.concatenate([xyz, mid[..., None, :]], axis=-2), np.concatenate([valid, ok[..., None]], axis=-1)


def _part_index() -> np.ndarray:
    names = SHELF_JOINTS + ("hips_mid",)
    return np.array([[names.index(a), names.index(b)] for _, a, b in SHELF_PARTS])


def score_shelf(
    pred: Keypoints3D, gt: Keypoints3D, actors: tuple[int, ...] = SHELF_ACTORS, alpha: float = 0.5
) -> ShelfScore:
    """PCP per actor and part, and MPJPE, of ``pred`` against ``gt`` (see the module doc).

    Args:
        pred: predicted persons, with COCO joint names (converted by ``coco_to_shelf``) or
            already ``SHELF_JOINTS``.
        gt: ground truth with ``SHELF_JOINTS`` (``load_ground_truth``).
        actors: ground-truth person ids to score.
        alpha: a part is correct when its mean endpoint error is <= alpha × its true length.

    Frames are paired by ``frame_indices``; a ground-truth frame the prediction lacks
    counts as a frame with no predicted person. ``ValueError`` on a ground truth without
    Shelf joints, an unknown actor, or ``alpha <= 0``.
    """
    if gt.joint_names != SHELF_JOINTS:
        raise ValueError(f"score_shelf: gt must have the Shelf joints {SHELF_JOINTS}, got {gt.joint_names}")
    if not alpha > 0:
        raise ValueError(f"score_shelf: alpha must be > 0, got {alpha}")
    unknown = [a for a in actors if a not in gt.person_ids]
    if unknown:
        raise ValueError(f"score_shelf: actors {unknown} not in the ground truth's {gt.person_ids.tolist()}")
    if pred.joint_names != SHELF_JOINTS:
        pred = coco_to_shelf(pred)
    gi = np.array([gt.person_index(a) for a in actors], dtype=np.int64)
    # Invalid entries may hold anything (NaN too): zeroed, so that masked sums stay finite.
    g_ok = gt.valid[:, gi]  # (F, A, 14)
    g_xyz = np.where(g_ok[..., None], gt.xyz_m[:, gi], 0.0)
    n_f, n_a, n_j = g_ok.shape
    # The prediction on the ground truth's frames; frames it lacks stay invalid (and one
    # all-invalid person stands in for an empty prediction, so that nothing matches).
    n_p = max(pred.n_persons, 1)
    p_xyz = np.zeros((n_f, n_p, n_j, 3))
    p_ok = np.zeros((n_f, n_p, n_j), dtype=bool)
    _, fg, fp = np.intersect1d(gt.frame_indices, pred.frame_indices, return_indices=True)
    if pred.n_persons:
        p_ok[fg] = pred.valid[fp]
        p_xyz[fg] = np.where(p_ok[fg][..., None], pred.xyz_m[fp], 0.0)

    # Matching: mean distance over the joints valid in both, per (frame, actor, person).
    dist = np.linalg.norm(p_xyz[:, None] - g_xyz[:, :, None], axis=-1)  # (F, A, P, J)
    both = p_ok[:, None] & g_ok[:, :, None]
    n_both = both.sum(-1)
    mean_d = np.where(n_both > 0, (dist * both).sum(-1) / np.maximum(n_both, 1), np.inf)
    present: np.ndarray = np.any(g_ok, axis=-1)  # (F, A)
    best = np.argmin(mean_d, axis=-1)  # (F, A)
    has = present & np.isfinite(mean_d.min(-1))
    matched = np.where(has, best, -1)

    # The matched person's joints per (frame, actor); all invalid where nothing matched.
    frames = np.arange(n_f)[:, None]
    m_xyz = p_xyz[frames, best]  # (F, A, J, 3)
    m_ok = p_ok[frames, best] & has[..., None]

    gx, gv = _with_hips_mid(g_xyz, g_ok)
    mx, mv = _with_hips_mid(m_xyz, m_ok)
    ends = _part_index()
    err = np.linalg.norm(mx - gx, axis=-1)  # (F, A, 15)
    part_err = 0.5 * (err[..., ends[:, 0]] + err[..., ends[:, 1]])  # (F, A, parts)
    length = np.linalg.norm(gx[..., ends[:, 0], :] - gx[..., ends[:, 1], :], axis=-1)
    scored = present[..., None] & gv[..., ends[:, 0]] & gv[..., ends[:, 1]]
    correct = scored & mv[..., ends[:, 0]] & mv[..., ends[:, 1]] & (part_err <= alpha * length)

    n_scored_part = scored.sum(0)  # (A, parts)
    with np.errstate(invalid="ignore", divide="ignore"):
        pcp_part = np.where(n_scored_part > 0, correct.sum(0) / n_scored_part, np.nan)
        n_scored = n_scored_part.sum(-1)
        pcp_actor = np.where(n_scored > 0, correct.sum((0, 2)) / np.maximum(n_scored, 1), np.nan)
    joint_both = m_ok & g_ok
    n_jb = int(joint_both.sum())
    mpjpe_mm = float(err[..., :n_j][joint_both].mean() * 1000.0) if n_jb else float("nan")
    n_matched_joints = int(g_ok[has].sum())
    return ShelfScore(
        actors=tuple(int(a) for a in actors),
        part_names=PART_NAMES,
        pcp_per_actor=pcp_actor,
        pcp_per_part=pcp_part,
        pcp=float(np.nanmean(pcp_actor)) if np.isfinite(pcp_actor).any() else float("nan"),
        mpjpe_mm=mpjpe_mm,
        matched_person=matched.astype(np.int64),
        n_frames_gt=present.sum(0).astype(np.int64),
        n_frames_matched=has.sum(0).astype(np.int64),
        joints_valid_frac=float(n_jb / n_matched_joints) if n_matched_joints else float("nan"),
    )
