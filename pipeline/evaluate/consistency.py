"""Consistency of one 3D result with the session's own 2D evidence, without ground truth (pure numpy).

A ``Keypoints3D`` (raw or filtered triangulation, fit, physics) is scored against the 2D
keypoints it came from and against what a human body can do:

- reprojection error in **every** view, per camera and pooled: each confident 2D keypoint
  of a detection associated with a person, against the projection (with lens distortion)
  of that person's 3D joint. Unlike the triangulation's own metric, views the
  triangulation dropped as outliers are scored too, so a wrong view shows up;
- bone-length standard deviation over time (rigid bones);
- inter-person overlap of keypoint capsule proxies (``physics_metrics.CapsuleProxy``);
- foot skating while a foot is planted (every foot point valid and the lowest below 3 cm,
  as ``foot_contact_from_height``; heel/toe joints valid nowhere are left out);
- mean joint acceleration;
- coverage: the share of (frame, person, joint) entries that are valid, since a metric
  over fewer joints is not comparable with one over all of them.

Every metric uses valid entries only (invalid coordinates are meaningless, often 0), and
treats consecutive rows as consecutive video frames where it differentiates in time,
except the acceleration, which also requires consecutive ``frame_indices``.

Units: pixels of the original (distorted) image, mm, mm / frame, mm / frame², m / s², %.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.evaluate.metrics import bone_length_std, reprojection_error
from pipeline.evaluate.physics_metrics import (
    _foot_points,  # the foot points physics_metrics skates on: validity must use the same ones
    foot_contact_from_height,
    physics_metrics,
)
from pipeline.schema.association import Association
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D
from pipeline.schema.keypoints3d import Keypoints3D

MIN_KEYPOINT_CONF = 0.5
"""Default lowest 2D keypoint confidence scored for reprojection, in [0, 1]. Below it a
keypoint is mostly a guess for an occluded joint, and its error measures the 2D model,
not the 3D result (the triangulation uses joints from 0.1; on the Pose2Sim sample with
the default models about 7 % of the valid keypoints fall below 0.5)."""

CONTACT_HEIGHT_M = 0.03
"""Default height of the lowest foot point below which a foot counts as planted (m)."""


@dataclass(frozen=True)
class ReprojectionSummary:
    """Reprojection error of one 3D result in every view.

    Fields:
        camera_names: (views,) the rig's camera names.
        median_px: (views,) median error per camera, pixels (NaN when nothing scored).
        p95_px: (views,) 95th percentile per camera, pixels (NaN when nothing scored).
        n_scored: (views,) int keypoints scored per camera.
        median_all_px: median over every camera's scored keypoints, pixels (NaN if none).
        p95_all_px: 95th percentile over every camera's scored keypoints, pixels.
        n_confident: confident, valid 2D keypoints of associated detections (scored or
            not: a keypoint whose 3D joint is invalid is not scored).
        min_keypoint_conf: the confidence threshold used, in [0, 1].
    """

    camera_names: tuple[str, ...]
    median_px: np.ndarray
    p95_px: np.ndarray
    n_scored: np.ndarray
    median_all_px: float
    p95_all_px: float
    n_confident: int
    min_keypoint_conf: float

    @property
    def scored_pct(self) -> float:
        """Share of the confident associated 2D keypoints that were scored, % (NaN if none)."""
        return 100.0 * float(self.n_scored.sum()) / self.n_confident if self.n_confident else float("nan")


def _stats(err: np.ndarray) -> tuple[float, float]:
    """(median, p95) of a 1-D error sample, NaN for an empty one."""
    if err.size == 0:
        return float("nan"), float("nan")
    return float(np.median(err)), float(np.percentile(err, 95))


def reprojection_by_camera(
    kp3d: Keypoints3D,
    tracks: Tracks2D,
    assoc: Association,
    rig: CameraRig,
    min_keypoint_conf: float = MIN_KEYPOINT_CONF,
) -> ReprojectionSummary:
    """Per-camera and pooled reprojection error of ``kp3d`` against every associated 2D keypoint
    whose confidence is at least ``min_keypoint_conf`` (``metrics.reprojection_error`` for the
    distances). Raises ``ValueError`` when the threshold lies outside [0, 1] or the tracks,
    association and rig do not belong together."""
    if not 0.0 <= min_keypoint_conf <= 1.0:
        raise ValueError(f"min_keypoint_conf must lie in [0, 1], got {min_keypoint_conf}")
    if tracks.n_views != rig.n_views:
        raise ValueError(f"tracks have {tracks.n_views} views, the rig {rig.n_views} ({list(rig.names)})")
    if assoc.person_of_det.shape[0] != tracks.n_dets:
        raise ValueError(
            f"association covers {assoc.person_of_det.shape[0]} detections, the tracks {tracks.n_dets}"
        )
    err = reprojection_error(kp3d, tracks, assoc, rig)  # (dets, joints), NaN = not applicable
    confident = tracks.keypoint_valid & (tracks.keypoint_conf >= min_keypoint_conf)
    confident &= (assoc.person_of_det >= 0)[:, None]
    # Only joints the 3D result has can be scored; the rest are not "confident and missed".
    confident &= np.isin(np.array(tracks.joint_names), kp3d.joint_names)[None, :]
    scored = confident & np.isfinite(err)
    med, p95, n = np.full(rig.n_views, np.nan), np.full(rig.n_views, np.nan), np.zeros(rig.n_views, np.int64)
    for v in range(rig.n_views):
        e = err[(tracks.view == v)[:, None] & scored]
        med[v], p95[v] = _stats(e)
        n[v] = e.size
    med_all, p95_all = _stats(err[scored])
    return ReprojectionSummary(
        camera_names=tuple(rig.names),
        median_px=med,
        p95_px=p95,
        n_scored=n,
        median_all_px=med_all,
        p95_all_px=p95_all,
        n_confident=int(confident.sum()),
        min_keypoint_conf=float(min_keypoint_conf),
    )


def coverage_pct(kp: Keypoints3D) -> float:
    """Share of (frame, person, joint) entries that are valid, % (NaN for an empty result)."""
    return 100.0 * float(kp.valid.mean()) if kp.valid.size else float("nan")


def mean_acceleration_mm_per_frame2(kp: Keypoints3D) -> float:
    """Mean norm of the second finite difference of every joint, mm / frame².

    Only triplets of consecutive frames (by ``frame_indices``) with the joint valid in all
    three count (NaN when there is none); constant-velocity motion gives 0.
    """
    if kp.n_frames < 3:
        return float("nan")
    x, ok = kp.xyz_m, kp.valid
    consecutive = (kp.frame_indices[2:] - kp.frame_indices[:-2]) == 2
    ok3 = ok[:-2] & ok[1:-1] & ok[2:] & consecutive[:, None, None]
    if not ok3.any():
        return float("nan")
    acc = np.linalg.norm(x[:-2] - 2.0 * x[1:-1] + x[2:], axis=-1)
    return float(acc[ok3].mean() * 1000.0)


def without_absent_foot_points(kp: Keypoints3D) -> Keypoints3D:
    """``kp`` without the heel and toe joints that are valid nowhere (e.g. small toes, which
    some 2D models lack): ``physics_metrics`` would read their meaningless coordinates as a
    foot on the ground. ``physics_metrics`` falls back to the ankle when no heel/toe is left."""
    absent = {
        i
        for i, n in enumerate(kp.joint_names)
        if n.endswith(("_heel", "_big_toe", "_small_toe")) and not kp.valid[:, :, i].any()
    }
    if not absent:
        return kp
    keep = [i for i in range(len(kp.joint_names)) if i not in absent]
    return kp.replace(
        joint_names=tuple(kp.joint_names[i] for i in keep),
        xyz_m=kp.xyz_m[:, :, keep],
        valid=kp.valid[:, :, keep],
        confidence=kp.confidence[:, :, keep],
        n_views=kp.n_views[:, :, keep],
        reproj_err_px=kp.reproj_err_px[:, :, keep],
    )


def planted_feet(kp: Keypoints3D, contact_height_m: float = CONTACT_HEIGHT_M) -> np.ndarray:
    """(frames, persons, 2) bool, left/right foot planted: every foot point valid and the lowest
    below ``contact_height_m`` (``foot_contact_from_height``, restricted to valid feet; call it
    on ``without_absent_foot_points(kp)`` unless every foot point can be valid)."""
    contact = foot_contact_from_height(kp, contact_height_m)
    points = _foot_points(kp)
    for k, side in enumerate(("left", "right")):
        contact[..., k] &= kp.valid[:, :, points[side]].all(axis=-1)
    return contact


@dataclass(frozen=True)
class Consistency:
    """Consistency metrics of one 3D result (see the module docstring).

    Fields:
        reprojection: per-camera and pooled reprojection error.
        coverage_pct: valid (frame, person, joint) entries, %.
        bone_length_std_mm: mean over (person, rigid bone) of the length's std over time, mm.
        overlap_max_mm / overlap_mean_mm: deepest inter-person capsule overlap, max and mean
            over frames, mm (0 = apart; ``CapsuleProxy`` radii: an adult in boxing gloves).
        foot_skate_mm_per_frame: mean horizontal foot displacement per frame while planted, mm.
        planted_pct: share of (frame, person, foot) entries planted, % (the skating's sample).
        ground_penetration_max_mm: deepest valid joint below z = 0, mm.
        accel_mm_per_frame2: mean joint acceleration magnitude, mm / frame².
        accel_m_per_s2: the same in m / s² (at ``Keypoints3D.fps``).
    """

    reprojection: ReprojectionSummary
    coverage_pct: float
    bone_length_std_mm: float
    overlap_max_mm: float
    overlap_mean_mm: float
    foot_skate_mm_per_frame: float
    planted_pct: float
    ground_penetration_max_mm: float
    accel_mm_per_frame2: float
    accel_m_per_s2: float

    def to_dict(self) -> dict[str, float]:
        """Flat, unit-suffixed keys: ``reproj_median_px``, ``reproj_cam01_p95_px``, ``coverage_pct``…"""
        r = self.reprojection
        out: dict[str, float] = {
            "reproj_median_px": r.median_all_px,
            "reproj_p95_px": r.p95_all_px,
            "reproj_scored_pct": r.scored_pct,
        }
        for name, med, p95, n in zip(r.camera_names, r.median_px, r.p95_px, r.n_scored, strict=True):
            out[f"reproj_{name}_median_px"] = float(med)
            out[f"reproj_{name}_p95_px"] = float(p95)
            out[f"reproj_{name}_n"] = int(n)
        out.update({k: v for k, v in self.__dict__.items() if k != "reprojection"})
        return out


def consistency(
    kp3d: Keypoints3D,
    tracks: Tracks2D,
    assoc: Association,
    rig: CameraRig,
    min_keypoint_conf: float = MIN_KEYPOINT_CONF,
    contact_height_m: float = CONTACT_HEIGHT_M,
) -> Consistency:
    """Every consistency metric of ``kp3d`` against the session's tracks, association and rig.

    ``ValueError`` as ``reprojection_by_camera``, or when ``contact_height_m`` is not positive.
    """
    if not contact_height_m > 0:
        raise ValueError(f"contact_height_m must be positive, got {contact_height_m}")
    feet = without_absent_foot_points(kp3d)
    contact = planted_feet(feet, contact_height_m)
    pm = physics_metrics(feet, foot_contact=contact)
    acc = mean_acceleration_mm_per_frame2(kp3d)
    return Consistency(
        reprojection=reprojection_by_camera(kp3d, tracks, assoc, rig, min_keypoint_conf),
        coverage_pct=coverage_pct(kp3d),
        bone_length_std_mm=bone_length_std(kp3d),
        overlap_max_mm=pm["inter_penetration_max_mm"],
        overlap_mean_mm=pm["inter_penetration_mean_mm"],
        # physics_metrics reports 0 when nothing is planted: NaN says "not measured".
        foot_skate_mm_per_frame=pm["foot_skate_mm_per_frame"]
        if (contact[1:] & contact[:-1]).any()
        else float("nan"),
        planted_pct=100.0 * float(contact.mean()) if contact.size else float("nan"),
        ground_penetration_max_mm=pm["ground_penetration_max_mm"],
        accel_mm_per_frame2=acc,
        accel_m_per_s2=acc / 1000.0 * kp3d.fps**2,
    )
