"""Stage ``triangulate``: one 3D skeleton per athlete and frame (paper section 3.2).

``run(tracks, assoc, rig, cfg) -> (raw, filtered)``:

1. Gather, for every (frame, person, view), the detection the association gave that
   person (if an edit left two, the more confident one), undistort and normalise its
   keypoints: a dense (frames, persons, joints, views) batch.
2. Weighted DLT (eq. 2, ``pipeline.geometry.dlt``) for every joint of every person and
   frame in one batched solve, weights ``mu_j`` from the 2D confidences.
3. Outlier views are removed per joint by iterative worst-view removal (at most
   ``views - min_views`` batched rounds, so 16 cameras cost 14 rounds, not 2^16 subsets).
4. Per joint and frame: reprojection error (px), number of views used, a confidence.
5. ``pipeline.stages.filtering`` smooths, fills gaps and checks bone lengths.
6. ``pipeline.stages.joint_fill`` places joints still missing (a face seen from behind, a
   hidden foot) from the person's rigid neighbours, flagged ``filled``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any, Literal

import numpy as np

from pipeline.evaluate.consistency import reprojection_by_camera
from pipeline.geometry.dlt import normalized_projections, point_information, triangulate_robust
from pipeline.geometry.projection import undistort_rig_points
from pipeline.schema.association import Association
from pipeline.schema.bones import BoneLengths
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.stages.filtering import FilterConfig, RayObservations
from pipeline.stages.filtering import run_holding as run_filter
from pipeline.stages.joint_fill import FillConfig
from pipeline.stages.joint_fill import run as run_fill
from pipeline.stages.observations import athlete_rows


@dataclass(frozen=True)
class TriangulateConfig:
    """Weighted triangulation + temporal filtering."""

    min_views: int = 2
    """A joint needs at least this many views (never below 2)."""
    min_keypoint_conf: float = 0.1
    """2D joints below this confidence are not used."""
    weighting: Literal["joint_conf", "view_mean_conf", "uniform"] = "joint_conf"
    """``mu_j`` of eq. 2: the joint's 2D confidence, the mean confidence of the detection
    (the paper's "average detection confidence for camera j"), or 1."""
    method: Literal["lstsq", "svd"] = "lstsq"
    """DLT solver (``pipeline.geometry.dlt.triangulate_weighted``): ``svd`` is the paper's
    homogeneous solution, ``lstsq`` the same rows with ``X_4 = 1`` (faster, same accuracy)."""
    max_view_err_px: float = 20.0
    """A view whose reprojection error exceeds this is dropped (while more than ``min_views`` remain)."""
    max_mean_err_px: float = 30.0
    """A joint whose mean reprojection error over the kept views still exceeds this is invalid."""
    pixel_std_px: float = 4.0
    """2D keypoint noise (std, pixels) of a confidence-1 joint: with the camera geometry it
    gives each 3D point's covariance, which weights it in the temporal filter."""
    point_covariance: bool = False
    """Weight each 3D point in the temporal filter by its full triangulation covariance
    (from ``pixel_std_px`` and the view geometry) instead of an isotropic ``meas_std_m``:
    better with >= 3 well-spread cameras, worse with two nearly opposite ones; off."""
    filter: FilterConfig = field(default_factory=FilterConfig)
    """Temporal filter (a dict in ``session.json`` is accepted)."""
    fill: FillConfig = field(default_factory=FillConfig)
    """Filling of joints still missing after the filter from their rigid neighbours
    (``pipeline.stages.joint_fill``; a dict in ``session.json`` is accepted)."""
    incremental: bool = True
    """Re-use the previous run's per-person bone lengths where they barely moved
    (``filter.hold_bone_rel``), so an identity edit changes the frames near it only; False:
    estimate them afresh each run."""

    def __post_init__(self) -> None:
        for name, cls in (("filter", FilterConfig), ("fill", FillConfig)):
            value = getattr(self, name)
            if isinstance(value, dict):
                known = {f.name for f in fields(cls)}
                extra = set(value) - known
                if extra:
                    raise ValueError(f"TriangulateConfig.{name}: unknown keys {sorted(extra)}; known: {sorted(known)}")
                object.__setattr__(self, name, cls(**value))
        if self.min_views < 2:
            raise ValueError(f"TriangulateConfig.min_views must be >= 2, got {self.min_views}")


def gather(
    tracks: Tracks2D, assoc: Association, rig: CameraRig, min_conf: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dense per-person observations from the flat rows.

    Returns:
        xn: (frames, persons, joints, views, 2) normalised undistorted coordinates.
        conf: (frames, persons, joints, views) 2D confidence (0 = no observation).
        det_conf: (frames, persons, views) mean keypoint confidence of the detection used.
    """
    Fn, P, J, V = tracks.n_frames, assoc.n_persons, len(tracks.joint_names), rig.n_views
    rows, f, p, v = athlete_rows(tracks, assoc, rig.n_views)
    ok = tracks.keypoint_valid[rows] & (tracks.keypoint_conf[rows] >= min_conf)
    uv = undistort_rig_points(rig, np.where(ok[..., None], tracks.keypoints_px[rows], 0.0), v)
    Kinv = np.linalg.inv(rig.K)[v]
    xn = np.einsum("dij,dkj->dki", Kinv[:, :2, :2], uv) + Kinv[:, None, :2, 2]
    out_xn = np.zeros((Fn, P, V, J, 2))
    out_c = np.zeros((Fn, P, V, J))
    out_xn[f, p, v] = np.where(ok[..., None], xn, 0.0)
    c = np.where(ok, tracks.keypoint_conf[rows], 0.0)
    out_c[f, p, v] = c
    det_conf = np.zeros((Fn, P, V))
    det_conf[f, p, v] = c.sum(axis=1) / np.maximum(ok.sum(axis=1), 1)
    return np.moveaxis(out_xn, 2, 3), np.moveaxis(out_c, 2, 3), det_conf


def run(
    tracks: Tracks2D, assoc: Association, rig: CameraRig, cfg: TriangulateConfig = TriangulateConfig()
) -> tuple[Keypoints3D, Keypoints3D]:
    """``run_holding`` without held bone lengths: ``(raw, filtered)``."""
    raw, filtered, _ = run_holding(tracks, assoc, rig, cfg)
    return raw, filtered


def run_holding(
    tracks: Tracks2D,
    assoc: Association,
    rig: CameraRig,
    cfg: TriangulateConfig = TriangulateConfig(),
    held: BoneLengths | None = None,
) -> tuple[Keypoints3D, Keypoints3D, BoneLengths]:
    """Triangulate every athlete; returns ``(raw, filtered)`` keypoints (frames ``0..n_frames-1``)
    and the bone lengths the filter used (``held``: a previous run's, see ``filtering.run_holding``).

    ``raw`` (``source="raw"``): DLT results with ``valid``, ``n_views``,
    ``reproj_err_px`` (mean over the kept views, undistorted pixels) and ``confidence``
    (mean 2D confidence of the kept views, lowered by the reprojection error).
    ``filtered`` (``source="filtered"``): after ``pipeline.stages.filtering.run``.
    """
    xn, conf, det_conf = gather(tracks, assoc, rig, cfg.min_keypoint_conf)
    if cfg.weighting == "joint_conf":
        w = conf
    elif cfg.weighting == "view_mean_conf":
        w = np.where(conf > 0, det_conf[:, :, None, :], 0.0)
    else:
        w = (conf > 0).astype(float)
    P, offset = normalized_projections(rig)
    focal = 0.5 * (rig.K[:, 0, 0] + rig.K[:, 1, 1])
    X, ok, used, _, mean_err = triangulate_robust(P, xn, w, focal, cfg.max_view_err_px, cfg.min_views, cfg.method)
    ok &= mean_err <= cfg.max_mean_err_px
    n_used = np.where(ok, used.sum(axis=-1), 0)
    mean_conf = np.where(ok, (conf * used).sum(axis=-1) / np.maximum(n_used, 1), 0.0)
    confidence = mean_conf * np.exp(-np.nan_to_num(mean_err, nan=0.0) / (2.0 * cfg.max_view_err_px))
    raw = Keypoints3D(
        joint_names=tracks.joint_names,
        person_ids=assoc.person_ids.copy(),
        frame_indices=np.arange(tracks.n_frames, dtype=np.int64),
        fps=float(rig.fps),
        xyz_m=np.where(ok[..., None], X + offset, 0.0),
        valid=ok,
        confidence=np.where(ok, np.clip(confidence, 0.0, 1.0), 0.0),
        n_views=n_used.astype(np.int64),
        reproj_err_px=np.where(ok, mean_err, np.nan),
        source="raw",
    )
    if not cfg.filter.enabled:
        filtered, bones = run_filter(raw, cfg.filter, held=held)
        return raw, run_fill(filtered, cfg.fill), bones
    info = point_information(P, X, used, conf, focal, cfg.pixel_std_px) if cfg.point_covariance else None
    single = ~ok & ((conf > 0).sum(axis=-1) >= 1)
    best = np.argmax(conf, axis=-1)
    rays = RayObservations(
        P=P,
        offset_m=offset,
        focal_px=focal,
        mask=single,
        view=best,
        xn=np.take_along_axis(xn, best[..., None, None], axis=-2)[..., 0, :],
        conf=np.take_along_axis(conf, best[..., None], axis=-1)[..., 0],
        pixel_std_px=cfg.pixel_std_px,
    )
    filtered, bones = run_filter(raw, cfg.filter, meas_info=info, rays=rays, held=held)
    return raw, run_fill(filtered, cfg.fill), bones


FEW_FRAMES_PCT = 25.0
"""An athlete with 3D in fewer than this share of the frames (%) is named in a warning
(``sparse_persons``): most likely no two cameras saw them together (a camera subset, a narrow
rig), or their identity was lost. Shelf's actor who enters half-way has 50 %."""


def person_frames_pct(kp: Keypoints3D) -> np.ndarray:
    """(persons,) share of the frames (%, 0-100) in which the person has any valid joint."""
    if kp.valid.size == 0:
        return np.zeros(kp.valid.shape[1] if kp.valid.ndim == 3 else 0)
    return 100.0 * kp.valid.any(axis=2).mean(axis=0)


def sparse_persons(kp: Keypoints3D, names: dict[int, str]) -> list[str]:
    """One sentence per person (``names``: person id -> athlete name) with 3D in fewer than
    ``FEW_FRAMES_PCT`` % of the frames of ``kp``."""
    out = []
    n_f = kp.valid.shape[0]
    for pid, pct in zip(kp.person_ids.tolist(), person_frames_pct(kp).tolist(), strict=True):
        if pct < FEW_FRAMES_PCT:
            who = f"{names[pid]} (person {pid})" if names.get(pid) else f"person {pid}"
            out.append(
                f"{who} has 3D in {round(pct * n_f / 100)} of {n_f} frames: fewer than two cameras saw them "
                "together there, so the later stages have little or nothing of them. Check that every "
                "athlete is in at least two views (cornerman new --cameras, the camera layout)."
            )
    return out


def summary(
    raw: Keypoints3D, filtered: Keypoints3D, tracks: Tracks2D, assoc: Association, rig: CameraRig
) -> dict[str, Any]:
    """Small scalar metrics for the manifest / run table. ``reproj_*`` is the filtered
    result's error in every view (``consistency.reprojection_by_camera``, the metric the
    fit reports too); ``kept_views_*`` the raw DLT's over the views it kept."""
    e = raw.reproj_err_px[raw.valid]
    rep = reprojection_by_camera(filtered, tracks, assoc, rig)
    return {
        "reproj_median_px": round(rep.median_all_px, 2),
        "reproj_p95_px": round(rep.p95_all_px, 2),
        "kept_views_median_px": round(float(np.median(e)), 2) if e.size else None,
        "kept_views_p95_px": round(float(np.percentile(e, 95)), 2) if e.size else None,
        "valid_raw_pct": round(100.0 * float(raw.valid.mean()), 1) if raw.valid.size else 0.0,
        "valid_filtered_pct": round(100.0 * float(filtered.valid.mean()), 1) if filtered.valid.size else 0.0,
        "mean_views": round(float(raw.n_views[raw.valid].mean()), 2) if e.size else 0.0,
        "person_frames_min_pct": round(float(person_frames_pct(filtered).min()), 1) if filtered.valid.size else 0.0,
    }
