"""evaluate: accuracy metrics against ground truth and per-frame problem flags.

Pure: gets the 3D results of every stage that ran, the 2D tracks and association,
the physics stage's effort when it ran, and (optionally) ground truth; returns a metrics
dict and the per-frame flags the viewer's timeline marks (``FLAG_KINDS``).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from pipeline.evaluate import metrics as M
from pipeline.evaluate.consistency import MIN_KEYPOINT_CONF
from pipeline.evaluate.effort import residual_per_frame, torque_ratio_per_frame
from pipeline.evaluate.physics_metrics import CapsuleProxy, inter_person_penetration_mm, physics_metrics
from pipeline.schema.association import Association
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D
from pipeline.schema.joints import BODY_LIMBS, COCO17
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import PhysicsResult


class FlagKind(NamedTuple):
    """One kind of per-frame problem: ``key`` names it in metrics, files and benches,
    ``label`` is what the viewer shows, ``group`` is ``tracking`` (the 3D result disagrees with
    the cameras or itself) or ``physics`` (how the physics humanoids achieve it)."""

    key: str
    label: str
    group: str = "tracking"


FLAG_KINDS: tuple[FlagKind, ...] = (
    FlagKind("identity_low", "identity confidence low"),
    FlagKind("reprojection_high", "reprojection error high"),
    FlagKind("penetration_high", "penetration high"),
    FlagKind("residual_high", "residual root force high", "physics"),
    FlagKind("torque_high", "joint torque over human limit", "physics"),
    FlagKind("untrackable", "not trackable without a residual root force", "physics"),
)
"""The columns of ``ProblemFlags.flags``, in order: the one list every reader uses (the
benches, the viewer). A new kind is appended here and computed in ``problem_flags``."""

LEGACY_FLAG_KINDS: tuple[str, ...] = ("identity_low", "reprojection_high", "penetration_high")
"""The columns of a ``problems.npz`` written before it named its columns (``flag_kinds``)."""


@dataclass(frozen=True)
class EvaluateConfig:
    """Thresholds of the per-frame problem flags (the viewer's timeline marks)."""

    identity_conf_low: float = 0.5
    """A frame is flagged when, for some athlete, the median association confidence of its
    detections (one per view) is below this, in [0, 1]: most views are in doubt."""
    reproj_high_frac: float = 0.03
    """A frame is flagged when, for some athlete, the median over its views of each
    detection's median keypoint error (confident keypoints, against the shown result)
    exceeds this fraction of the detection's box height, in (0, 1): the result disagrees
    with most cameras (3 % is 15 px for a person 500 px tall). One bad view is not a flag."""
    penetration_high_mm: float = 20.0
    """A frame is flagged when the inter-person penetration exceeds this (millimetres)."""
    body_radius_m: float = 0.06
    """Radius of the capsule proxy around bones used to estimate penetration from keypoints."""
    residual_high_frac_bw: float = 0.05
    """A frame is flagged when, for some athlete, the physics stage's residual root force
    exceeds this, in body weights, >= 0 (0.05: the cap of the opt-in residual)."""
    torque_high_ratio: float = 1.0
    """A frame is flagged when some joint torque of the physics result exceeds its human peak
    (``pipeline.evaluate.effort.HUMAN_PEAK_TORQUE_NM_PER_KG``) times this, > 0."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.identity_conf_low <= 1.0 or not 0.0 < self.reproj_high_frac < 1.0:
            raise ValueError(
                "EvaluateConfig: identity_conf_low must be in [0, 1] and reproj_high_frac in (0, 1), got "
                f"{self.identity_conf_low}, {self.reproj_high_frac}"
            )
        if not self.penetration_high_mm >= 0 or not self.body_radius_m > 0:
            raise ValueError(
                f"EvaluateConfig: penetration_high_mm must be >= 0 and body_radius_m > 0, got "
                f"{self.penetration_high_mm}, {self.body_radius_m}"
            )
        if not self.residual_high_frac_bw >= 0 or not self.torque_high_ratio > 0:
            raise ValueError(
                f"EvaluateConfig: residual_high_frac_bw must be >= 0 and torque_high_ratio > 0, got "
                f"{self.residual_high_frac_bw}, {self.torque_high_ratio}"
            )


@dataclass(frozen=True)
class PhysicsEffortInputs:
    """The physics stage's result and what its scene says about it, for the effort flags."""

    result: PhysicsResult
    actuator_names: tuple[str, ...]
    """(actuators,) MuJoCo name of each column of ``result.joint_torque_nm`` (``p{pid}_…``)."""
    mass_kg: np.ndarray
    """(persons,) body mass of each athlete of ``result.person_ids``, kg (> 0)."""

    def __post_init__(self) -> None:
        nu, P = self.result.joint_torque_nm.shape[1], self.result.person_ids.shape[0]
        if len(self.actuator_names) != nu or np.shape(self.mass_kg) != (P,) or np.any(np.asarray(self.mass_kg) <= 0):
            raise ValueError(
                f"PhysicsEffortInputs: need {nu} actuator names and {P} positive masses, got "
                f"{len(self.actuator_names)} names and masses {np.asarray(self.mass_kg).tolist()}"
            )


@dataclass(frozen=True)
class EvaluateInputs:
    rig: CameraRig
    tracks: Tracks2D
    association: Association
    sources: dict[str, Keypoints3D]
    """3D results by name (``raw``, ``filtered``, ``fit``, ``physics``), in pipeline order."""
    gt: Keypoints3D | None = None
    gt_person_of_det: np.ndarray | None = None
    physics: PhysicsEffortInputs | None = None
    """The physics result with its actuator names and masses; None when physics did not run."""


@dataclass(frozen=True)
class ProblemFlags:
    """Per-frame signals for the viewer (arrays of shape (frames,), worst athlete).

    Fields: identity_conf_min, the lowest per-athlete median association confidence in
    [0, 1]; reproj_err_px, the largest per-athlete median (over views) keypoint error in
    pixels; reproj_rel, the same relative to the box height; penetration_mm, the capsule
    overlap between persons in mm; residual_frac_bw and torque_ratio_max, the physics
    effort; flags, the thresholds applied. Files written before a field existed load with
    it empty.
    """

    frame_indices: np.ndarray
    identity_conf_min: np.ndarray
    reproj_err_px: np.ndarray
    penetration_mm: np.ndarray
    reproj_rel: np.ndarray = field(default_factory=lambda: np.zeros(0))
    flags: np.ndarray = field(default_factory=lambda: np.zeros((0, len(LEGACY_FLAG_KINDS)), bool))
    """(frames, kinds) bool, one column per entry of ``flag_kinds``."""
    flag_kinds: np.ndarray = field(default_factory=lambda: np.array(LEGACY_FLAG_KINDS))
    """(kinds,) str: the ``FlagKind.key`` of each column of ``flags``."""
    residual_frac_bw: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """(frames,) physics residual root force of the worst athlete, body weights (0 without physics)."""
    torque_ratio_max: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """(frames,) largest physics joint torque over its human limit, worst athlete and joint
    (> 1 = over; 0 without physics)."""

    def __post_init__(self) -> None:
        F = np.shape(self.frame_indices)[0] if np.ndim(self.frame_indices) == 1 else -1
        kinds = np.asarray(self.flag_kinds)
        if F < 0 or kinds.ndim != 1 or np.shape(self.flags) != (F, kinds.shape[0]):
            raise ValueError(
                f"ProblemFlags: flags of shape {np.shape(self.flags)} for {np.shape(self.frame_indices)} frames "
                f"and kinds {kinds.tolist()}"
            )

    def column(self, key: str) -> np.ndarray | None:
        """(frames,) bool flags of kind ``key``; None when this result has no such column."""
        hits = np.flatnonzero(np.asarray(self.flag_kinds) == key)
        return np.asarray(self.flags[:, hits[0]], dtype=bool) if hits.size else None

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


def physics_effort_per_frame(ph: PhysicsEffortInputs | None, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(frames,) residual root force (body weights) and largest joint torque over its human
    limit, worst athlete, on video frames ``frames`` (sorted); 0 where physics has no frame."""
    F = frames.shape[0]
    res, tau = np.zeros(F), np.zeros(F)
    if ph is None or F == 0:
        return res, tau
    r = ph.result
    row = np.searchsorted(frames, r.frame_indices)
    ok = (row < F) & (frames[np.minimum(row, F - 1)] == r.frame_indices)
    pids = [int(p) for p in r.person_ids]
    seen = r.observed_mask()
    res[row[ok]] = residual_per_frame(r.residual_root_force, ph.mass_kg, seen)[ok]
    tau[row[ok]] = torque_ratio_per_frame(r.joint_torque_nm, ph.actuator_names, pids, ph.mass_kg, seen)[ok]
    return res, tau


def untrackable_per_frame(ph: PhysicsEffortInputs | None, frames: np.ndarray) -> np.ndarray:
    """(frames,) bool: some athlete seen in the frame had a physics window that could not be
    tracked without a residual root force (``PhysicsResult.untrackable``) at video frames
    ``frames`` (sorted); False
    where physics has no frame or its result did not record it."""
    F = frames.shape[0]
    out = np.zeros(F, dtype=bool)
    if ph is None or F == 0 or ph.result.untrackable.shape[0] != ph.result.frame_indices.shape[0]:
        return out
    r = ph.result
    row = np.searchsorted(frames, r.frame_indices)
    ok = (row < F) & (frames[np.minimum(row, F - 1)] == r.frame_indices)
    out[row[ok]] = np.asarray((r.untrackable & r.observed_mask()).any(axis=1))[ok]
    return out


def problem_flags(inp: EvaluateInputs, cfg: EvaluateConfig) -> ProblemFlags:
    """Per-frame identity doubt, disagreement with the cameras and penetration of the shown
    (last) result, each per athlete and robust to a single bad view, and the physics
    effort (residual, joint torques) and its windows not trackable without a residual when
    physics ran (``EvaluateConfig``)."""
    best = next(iter(reversed(inp.sources.values())))
    frames = best.frame_indices
    F = frames.size
    tracks, assoc = inp.tracks, inp.association
    row = np.searchsorted(frames, tracks.frame)
    row_ok = (row < F) & (frames[np.minimum(row, max(F - 1, 0))] == tracks.frame) if F else np.zeros(tracks.n_dets, bool)
    err = M.reprojection_error(best, tracks, assoc, inp.rig)  # (dets, joints), NaN = n/a
    err = np.where(tracks.keypoint_conf >= MIN_KEYPOINT_CONF, err, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # detections with no scored keypoint
        det_px = np.nanmedian(err, axis=1) if err.size else np.full(tracks.n_dets, np.nan)
    height = np.maximum(tracks.bbox_xyxy_px[:, 3] - tracks.bbox_xyxy_px[:, 1], 1.0)
    id_min, rep_px, rep_rel = np.ones(F), np.zeros(F), np.zeros(F)
    for pid in assoc.person_ids:
        sel = np.flatnonzero((assoc.person_of_det == pid) & row_ok)
        for r, dets in _group(row[sel], sel):
            id_min[r] = min(id_min[r], float(np.median(assoc.confidence[dets])))
            scored = dets[np.isfinite(det_px[dets])]
            if scored.size:
                rep_px[r] = max(rep_px[r], float(np.median(det_px[scored])))
                rep_rel[r] = max(rep_rel[r], float(np.median(det_px[scored] / height[scored])))
    pen = capsule_penetration_mm(best, cfg.body_radius_m)
    res, tau = physics_effort_per_frame(inp.physics, frames)
    by_kind = {
        "identity_low": id_min < cfg.identity_conf_low,
        "reprojection_high": rep_rel > cfg.reproj_high_frac,
        "penetration_high": pen > cfg.penetration_high_mm,
        "residual_high": res > cfg.residual_high_frac_bw,
        "torque_high": tau > cfg.torque_high_ratio,
        "untrackable": untrackable_per_frame(inp.physics, frames),
    }
    flags = np.stack([by_kind[k.key] for k in FLAG_KINDS], axis=1).reshape(F, len(FLAG_KINDS))
    kinds = np.array([k.key for k in FLAG_KINDS])
    return ProblemFlags(frames, id_min, rep_px, pen, rep_rel, flags, kinds, res, tau)


def _group(keys: np.ndarray, values: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """``values`` grouped by equal ``keys``: [(key, values with that key)]."""
    order = np.argsort(keys, kind="stable")
    k, v = keys[order], values[order]
    cuts = np.flatnonzero(np.diff(k)) + 1
    return [(int(kk[0]), vv) for kk, vv in zip(np.split(k, cuts), np.split(v, cuts), strict=True) if kk.size]


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
    out["problem_frames"] = {k.key: int(flags.flags[:, i].sum()) for i, k in enumerate(FLAG_KINDS)}
    out["penetration_proxy_max_mm"] = _clean(float(flags.penetration_mm.max(initial=0.0)))
    if inp.physics is not None:
        out["physics_residual_max_frac_bw"] = _clean(float(flags.residual_frac_bw.max(initial=0.0)))
        out["physics_torque_ratio_max"] = _clean(float(flags.torque_ratio_max.max(initial=0.0)))
        out["physics_residual_high_frac_bw"] = cfg.residual_high_frac_bw
    return out, flags
