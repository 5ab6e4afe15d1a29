"""evaluate: accuracy metrics against ground truth and per-frame problem flags.

Pure: gets the 3D results of every stage that ran, the 2D tracks and association,
and (optionally) ground truth; returns a metrics dict and the per-frame flags the
viewer's timeline marks ("identity confidence low", "reprojection error high",
"penetration high").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pipeline.evaluate import metrics as M
from pipeline.evaluate.physics_metrics import CapsuleProxy, inter_person_penetration_mm, physics_metrics
from pipeline.schema.association import Association
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D
from pipeline.schema.joints import BODY_LIMBS, COCO17
from pipeline.schema.keypoints3d import Keypoints3D


@dataclass(frozen=True)
class EvaluateConfig:
    identity_conf_low: float = 0.5
    """A frame is flagged when an athlete's lowest association confidence is below this."""
    reproj_high_px: float = 15.0
    """A frame is flagged when the median reprojection error of an athlete exceeds this (pixels)."""
    penetration_high_mm: float = 20.0
    """A frame is flagged when the inter-person penetration exceeds this (millimetres)."""
    body_radius_m: float = 0.06
    """Radius of the capsule proxy around bones used to estimate penetration from keypoints."""


@dataclass(frozen=True)
class EvaluateInputs:
    rig: CameraRig
    tracks: Tracks2D
    association: Association
    sources: dict[str, Keypoints3D]
    """3D results by name (``raw``, ``filtered``, ``fit``, ``physics``), in pipeline order."""
    gt: Keypoints3D | None = None
    gt_person_of_det: np.ndarray | None = None


@dataclass(frozen=True)
class ProblemFlags:
    """Per-frame signals for the viewer (arrays of shape (frames,))."""

    frame_indices: np.ndarray
    identity_conf_min: np.ndarray
    reproj_err_px: np.ndarray
    penetration_mm: np.ndarray
    flags: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), bool))
    """(frames, 3) bool: identity low, reprojection high, penetration high."""

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {k: np.asarray(v) for k, v in self.__dict__.items()}


def _clean(x: float) -> float | None:
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else round(float(x), 4)


def capsule_penetration_mm(kp: Keypoints3D, radius_m: float) -> np.ndarray:
    """(frames,) max overlap between bone capsules of different persons, in mm (0 = apart).

    A keypoint-only proxy used for the timeline flags: every limb of ``BODY_LIMBS`` is a
    capsule of ``radius_m`` (the physics metrics use anatomical radii instead).
    """
    proxy = CapsuleProxy(segments=tuple((a, b, radius_m) for a, b in BODY_LIMBS))
    return inter_person_penetration_mm(kp, proxy)


PLAUSIBILITY_SOURCES = ("filtered", "fit", "physics")
"""Sources with gap-free joints, scored for physical plausibility (raw triangulation has
holes that would read as foot skating)."""


def _plausibility_metrics(kp: Keypoints3D) -> dict[str, Any]:
    """Inter-person and ground penetration, foot skating (contact = foot below 3 cm) and
    smoothness, as in ``cornerman bench physics`` (anatomical capsule proxies)."""
    pm = physics_metrics(kp)
    keys = (
        "inter_penetration_max_mm",
        "inter_penetration_mean_mm",
        "ground_penetration_max_mm",
        "foot_skate_mm_per_frame",
        "accel_mm_per_frame2",
    )
    return {k: _clean(pm[k]) for k in keys}


def _source_metrics(est: Keypoints3D, gt: Keypoints3D) -> dict[str, Any]:
    mapping = M.match_persons(est, gt)
    coco = tuple(n for n in COCO17 if n in est.joint_names)
    return {
        "pcp_pct": _clean(100 * M.pcp(est, gt, mapping=mapping)),
        "mpjpe_mm": _clean(M.mpjpe(est, gt, joint_names=coco, mapping=mapping)),
        "mpjpe_all_joints_mm": _clean(M.mpjpe(est, gt, mapping=mapping)),
        "pa_mpjpe_mm": _clean(M.pa_mpjpe(est, gt, joint_names=coco, mapping=mapping)),
        "accel_error_mm_per_frame2": _clean(M.acceleration_error(est, gt, mapping=mapping)),
        "coverage_pct": _clean(100 * M.coverage(est, gt, mapping=mapping)),
    }


def problem_flags(inp: EvaluateInputs, cfg: EvaluateConfig) -> ProblemFlags:
    """Per-frame identity confidence, reprojection error and penetration, with thresholds applied."""
    best = next(iter(reversed(inp.sources.values())))
    frames = best.frame_indices
    F = frames.size
    row_of = {int(f): i for i, f in enumerate(frames)}
    assigned = inp.association.person_of_det >= 0
    id_min = np.ones(F)
    if assigned.any():
        rows = np.array([row_of.get(int(f), -1) for f in inp.tracks.frame[assigned]])
        keep = rows >= 0
        np.minimum.at(id_min, rows[keep], inp.association.confidence[assigned][keep])
    reproj = np.zeros(F)
    tri = inp.sources.get("filtered") or inp.sources.get("raw")
    if tri is not None:
        err = M.reprojection_error(tri, inp.tracks, inp.association, inp.rig)  # (dets, joints), NaN = n/a
        has = np.isfinite(err).any(axis=1) if err.size else np.zeros(0, bool)
        if has.any():
            med = np.nanmedian(err[has], axis=1)  # rows with at least one finite error only
            rows = np.array([row_of.get(int(f), -1) for f in inp.tracks.frame[has]])
            ok = rows >= 0
            np.maximum.at(reproj, rows[ok], med[ok])
    pen = capsule_penetration_mm(best, cfg.body_radius_m)
    flags = np.stack([id_min < cfg.identity_conf_low, reproj > cfg.reproj_high_px, pen > cfg.penetration_high_mm], axis=1)
    return ProblemFlags(frames, id_min, reproj, pen, flags)


def run(inp: EvaluateInputs, cfg: EvaluateConfig) -> tuple[dict[str, Any], ProblemFlags]:
    """Metrics per 3D source (vs ground truth when present) and per-frame problem flags."""
    if not inp.sources:
        raise ValueError("evaluate: no 3D result to evaluate (run triangulate first)")
    out: dict[str, Any] = {"sources": {}}
    for name, kp in inp.sources.items():
        m: dict[str, Any] = {"bone_length_std_mm": _clean(M.bone_length_std(kp))}
        if name in PLAUSIBILITY_SOURCES:
            m.update(_plausibility_metrics(kp))
        if inp.gt is not None:
            m.update(_source_metrics(kp, inp.gt))
        out["sources"][name] = m
    if inp.gt_person_of_det is not None:
        if inp.gt_person_of_det.shape != inp.association.person_of_det.shape:
            raise ValueError(
                f"evaluate: ground-truth labels cover {inp.gt_person_of_det.shape[0]} detections, "
                f"the association {inp.association.person_of_det.shape[0]}"
            )
        out["identity_accuracy_pct"] = _clean(100 * M.identity_accuracy(inp.association.person_of_det, inp.gt_person_of_det))
    flags = problem_flags(inp, cfg)
    out["problem_frames"] = {
        "identity_low": int(flags.flags[:, 0].sum()),
        "reprojection_high": int(flags.flags[:, 1].sum()),
        "penetration_high": int(flags.flags[:, 2].sum()),
    }
    out["penetration_proxy_max_mm"] = _clean(float(flags.penetration_mm.max(initial=0.0)))
    return out, flags
