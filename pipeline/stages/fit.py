"""Stage ``fit``: a parametric body model per athlete from 2D and 3D keypoints (paper 3.3).

Pure: ``run(keypoints3d, tracks, association, rig, cfg) -> FitResult``. The heavy work
(torch) is ``pipeline.backends.fitting.sequence.fit_sequence`` with the body model's adapter
from ``pipeline.backends.anny.fit`` (anny) or ``pipeline.backends.smpl.fit`` (SMPL/SMPL-X,
the user's model files), imported when ``run`` is called.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from pipeline.evaluate.consistency import MIN_KEYPOINT_CONF, reprojection_by_camera
from pipeline.evaluate.metrics import reprojection_error
from pipeline.geometry.projection import undistort_points
from pipeline.schema.association import Association
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D
from pipeline.schema.joints import COCO17_FEET
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit
from pipeline.stages.fit_config import FitConfig
from pipeline.stages.fit_incremental import (
    FitCheckpoints,
    FitPrevious,
    changed_frames,
    free_frames,
    layout_mismatch,
    refit_span,
)

if TYPE_CHECKING:
    from pipeline.backends.fitting.body_model import BodyModel

__all__ = ["FitConfig", "FitResult", "PersonInputs", "gather_inputs", "run"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class PersonInputs:
    """One person's observations in ``COCO17_FEET`` order (numpy; see ``gather_inputs``).

    kp3d_m (frames, 23, 3), w3d (frames, 23), uv_px (views, frames, 23, 2) undistorted,
    w2d (views, frames, 23): confidence where usable, 0 elsewhere.
    """

    kp3d_m: np.ndarray
    w3d: np.ndarray
    uv_px: np.ndarray
    w2d: np.ndarray


@dataclass(frozen=True)
class FitResult:
    """Output of the stage: the fit, its keypoints (``source="fit"``) and summary metrics."""

    bodyfit: BodyFit
    keypoints3d: Keypoints3D
    metrics: dict[str, float | str] = field(default_factory=dict)
    checkpoints: FitCheckpoints | None = None
    """What a later incremental re-fit needs (``pipeline.stages.fit_incremental``)."""


def _joint_map(names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Indices (src, dst) of the joints of ``names`` that are in ``COCO17_FEET``."""
    pairs = [(i, COCO17_FEET.index(n)) for i, n in enumerate(names) if n in COCO17_FEET]
    if not pairs:
        raise ValueError(f"fit: no joint of {names} is in COCO17_FEET")
    src, dst = zip(*pairs, strict=True)
    return np.array(src), np.array(dst)


def gather_inputs(
    keypoints3d: Keypoints3D, tracks: Tracks2D, association: Association, rig: CameraRig, cfg: FitConfig
) -> list[PersonInputs]:
    """Per-person 3D targets and undistorted 2D keypoints of every view, aligned on
    ``keypoints3d.frame_indices``. Detections of frames outside them are ignored; when a
    person has several detections in one view and frame, the highest-scoring one is used.
    A detection that disagrees with the triangulated person as a whole (``outlier_view_frac``:
    a failed 2D pose, a wrong person) is left out of the 2D term."""
    if association.person_of_det.shape[0] != tracks.n_dets:
        raise ValueError(
            f"fit: association has {association.person_of_det.shape[0]} rows but tracks have {tracks.n_dets}"
        )
    if tracks.n_views != rig.n_views:
        raise ValueError(f"fit: tracks have {tracks.n_views} views but the rig has {rig.n_views}")
    nf, nj, nv = keypoints3d.n_frames, len(COCO17_FEET), rig.n_views
    s3, d3 = _joint_map(keypoints3d.joint_names)
    s2, d2 = _joint_map(tracks.joint_names)
    rows = np.searchsorted(keypoints3d.frame_indices, tracks.frame)
    rows_ok = (rows < nf) & (keypoints3d.frame_indices[np.minimum(rows, nf - 1)] == tracks.frame)
    undist = np.zeros_like(tracks.keypoints_px, dtype=np.float64)
    for v in range(nv):
        sel = tracks.view == v
        if sel.any():
            undist[sel] = undistort_points(tracks.keypoints_px[sel], rig.K[v], rig.dist[v])
    outlier = outlier_detections(keypoints3d, tracks, association, rig, cfg.outlier_view_frac)
    out = []
    for p, pid in enumerate(keypoints3d.person_ids):
        kp3d = np.zeros((nf, nj, 3))
        w3d = np.zeros((nf, nj))
        kp3d[:, d3] = np.where(keypoints3d.valid[:, p, s3, None], keypoints3d.xyz_m[:, p][:, s3], 0.0)
        # Joints the triangulation only filled from the skeleton are not targets: the body
        # model places them itself.
        measured = keypoints3d.valid[:, p, s3] & ~keypoints3d.filled[:, p, s3]
        w3d[:, d3] = np.where(measured, np.clip(keypoints3d.confidence[:, p, s3], 0, 1), 0.0)
        uv = np.zeros((nv, nf, nj, 2))
        w2d = np.zeros((nv, nf, nj))
        dets = np.flatnonzero((association.person_of_det == pid) & rows_ok & ~outlier)
        dets = dets[np.argsort(tracks.bbox_score[dets], kind="stable")]  # best written last
        for i in dets:
            v, f = tracks.view[i], rows[i]
            conf = tracks.keypoint_conf[i, s2]
            ok = (
                tracks.keypoint_valid[i, s2]
                & (conf > cfg.min_conf_2d)
                & np.all(np.isfinite(undist[i, s2]), axis=-1)
            )
            uv[v, f, d2] = np.where(ok[:, None], undist[i, s2], 0.0)
            w2d[v, f, d2] = np.where(ok, conf, 0.0)
        out.append(PersonInputs(kp3d_m=kp3d, w3d=w3d, uv_px=uv, w2d=w2d))
    return out


def outlier_detections(
    keypoints3d: Keypoints3D, tracks: Tracks2D, association: Association, rig: CameraRig, max_frac: float
) -> np.ndarray:
    """(dets,) True for an associated detection whose confident keypoints (>= 0.5) lie, in the
    median, farther than ``max_frac`` of its box height from the projections of its person's
    triangulated joints: the whole 2D pose disagrees with the other views. 0 disables."""
    out = np.zeros(tracks.n_dets, dtype=bool)
    if max_frac <= 0:
        return out
    err = reprojection_error(keypoints3d, tracks, association, rig)
    err = np.where(tracks.keypoint_conf >= MIN_KEYPOINT_CONF, err, np.nan)
    scored = np.isfinite(err).sum(axis=1) >= 3
    med = np.full(tracks.n_dets, np.nan)
    med[scored] = np.nanmedian(err[scored], axis=1)
    height = np.maximum(tracks.bbox_xyxy_px[:, 3] - tracks.bbox_xyxy_px[:, 1], 1.0)
    out[scored] = med[scored] > max_frac * height[scored]
    return out


def _reprojection_px(kp: np.ndarray, inp: PersonInputs, P: np.ndarray) -> np.ndarray:
    """(frames, joints) mean pixel error over the views with a usable 2D keypoint (NaN if none)."""
    h = np.einsum("vij,fkj->vfki", P[:, :, :3], kp) + P[:, None, None, :, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        proj = h[..., :2] / h[..., 2:]
        err = np.linalg.norm(proj - inp.uv_px, axis=-1)
    used = inp.w2d > 0
    n = used.sum(axis=0)
    with np.errstate(invalid="ignore"):
        return np.where(n > 0, np.where(used, err, 0.0).sum(axis=0) / np.maximum(n, 1), np.nan)


def run(
    keypoints3d: Keypoints3D,
    tracks: Tracks2D,
    association: Association,
    rig: CameraRig,
    cfg: FitConfig = FitConfig(),
    progress: Callable[[float, float | None, str], None] | None = None,
    previous: FitPrevious | None = None,
) -> FitResult:
    """Fit the body model to every person of ``keypoints3d`` (one shape per person, one pose
    and root translation per frame). Raises ``ValueError`` for inconsistent inputs and, for
    SMPL/SMPL-X, when the ``smplx`` package or the model files are missing.

    ``previous``: the stage's previous run; with ``cfg.incremental`` only the frames whose
    inputs changed (and a margin) are re-optimised (``pipeline.stages.fit_incremental``).

    ``progress(done, total, message)``, when given, is called at every L-BFGS iteration
    (``total``: the iteration budget of the whole fit); it may raise to stop the fit."""
    t_start = time.perf_counter()
    cfg = cfg.at_rate(keypoints3d.fps)
    if cfg.body_model == "anny":  # anny_fit_body is cached: no copy of the model per run
        from pipeline.backends.anny.fit import anny_fit_model

        body: BodyModel = anny_fit_model(cfg)
    else:  # SMPL / SMPL-X: ValueError naming the path when files or smplx are missing
        from pipeline.backends.smpl.fit import smpl_fit_model

        body = smpl_fit_model(cfg)
    bone_names, rig_name, shape0 = body.bone_names, body.rig, body.neutral_shape

    inputs = gather_inputs(keypoints3d, tracks, association, rig, cfg)
    present = np.stack([(i.w3d > 0).sum(axis=1) >= cfg.min_valid_joints for i in inputs], axis=1)  # (F, P)
    fit_persons = [p for p in range(len(inputs)) if present[:, p].sum() >= 2]
    nf, npers, nj = keypoints3d.n_frames, keypoints3d.n_persons, len(COCO17_FEET)

    from pipeline.backends.fitting.common import PersonObservations
    from pipeline.backends.fitting.sequence import FitHold, fit_sequence

    nb = len(bone_names)
    shape = np.tile(shape0, (npers, 1))
    pose = np.zeros((nf, npers, nb, 3))
    root = np.zeros((nf, npers, 3))
    kp = np.zeros((nf, npers, nj, 3))
    loss = np.full(npers, np.nan)
    offsets = np.zeros((npers, nj, 3))
    metrics: dict[str, float | str] = {}
    ck = _checkpoints(keypoints3d, inputs, fit_persons, offsets)
    prev, free, why = _incremental_plan(previous, ck, cfg, cfg.body_model, rig_name)
    if prev is not None and free is not None:
        # Start from the previous fit; the re-fit below overwrites its free frames.
        shape, offsets = prev.bodyfit.shape.copy(), prev.checkpoints.landmark_offsets_m.copy()
        pose, root = prev.bodyfit.pose.copy(), prev.bodyfit.root_translation_m.copy()
        kp = prev.keypoints3d.xyz_m.copy()
        loss = prev.bodyfit.loss_final.copy()
        changed = changed_frames(prev.checkpoints, ck)
        metrics.update(_reuse_metrics(changed, free))
    else:
        changed = np.zeros(nf, dtype=bool)
    if fit_persons and (free is None or free.any()):
        obs = [
            PersonObservations(inputs[p].kp3d_m, inputs[p].w3d, inputs[p].uv_px, inputs[p].w2d)
            for p in fit_persons
        ]
        lo, hi, hold = 0, nf, None
        if free is not None:
            lo, hi = refit_span(free, cfg.accel_adapt_window)
            obs = [PersonObservations(o.kp3d_m[lo:hi], o.w3d[lo:hi], o.uv_px[:, lo:hi], o.w2d[:, lo:hi]) for o in obs]
            hold = FitHold(
                shape=shape[fit_persons], landmark_offsets_m=offsets[fit_persons],
                pose_aa=pose[lo:hi][:, fit_persons], root_m=root[lo:hi][:, fit_persons], free=free[lo:hi],
                fresh=changed[lo:hi],
            )
        res = fit_sequence(body, obs, rig.P, cfg, progress, hold=hold)
        rows = np.arange(lo, hi) if free is None else np.flatnonzero(free)
        for k, p in enumerate(fit_persons):
            pose[rows, p], root[rows, p], kp[rows, p] = (
                res.pose_aa[rows - lo, k], res.root_m[rows - lo, k], res.keypoints_m[rows - lo, k],
            )
            if free is None:
                shape[p], loss[p] = res.shape[k], res.loss[k]
                if res.landmark_offsets_m is not None:
                    offsets[p] = res.landmark_offsets_m[k]
            else:
                loss[p] = _mean_3d_error(kp[:, p], inputs[p])
        metrics.update({f"time_{k}": round(v, 3) for k, v in res.timings_s.items()})
        metrics.update({f"loss_{k}": round(v, 6) for k, v in res.loss_terms.items()})
    if free is None:
        metrics["incremental"] = f"full run: {why}"
    valid = present.copy()
    valid[:, [p for p in range(npers) if p not in fit_persons]] = False

    reproj = np.full((nf, npers, nj), np.nan)
    for p in fit_persons:
        reproj[:, p] = _reprojection_px(kp[:, p], inputs[p], rig.P)
    bodyfit = BodyFit(
        body_model=cfg.body_model,
        rig=rig_name,
        bone_names=bone_names,
        person_ids=keypoints3d.person_ids.copy(),
        frame_indices=keypoints3d.frame_indices.copy(),
        fps=keypoints3d.fps,
        shape=shape,
        pose=pose,
        root_translation_m=root,
        valid=valid,
        loss_final=loss,
    )
    fitted = Keypoints3D(
        joint_names=COCO17_FEET,
        person_ids=keypoints3d.person_ids.copy(),
        frame_indices=keypoints3d.frame_indices.copy(),
        fps=keypoints3d.fps,
        xyz_m=kp,
        valid=np.repeat(valid[:, :, None], nj, axis=2),
        confidence=np.repeat(valid[:, :, None], nj, axis=2).astype(np.float64),
        n_views=np.zeros((nf, npers, nj), dtype=np.int64),
        reproj_err_px=reproj,
        source="fit",
    )
    rep = reprojection_by_camera(fitted, tracks, association, rig)
    summary: dict[str, float | str] = {
        "reproj_median_px": round(rep.median_all_px, 2),
        "reproj_p95_px": round(rep.p95_all_px, 2),
        "residual_3d_mm": round(float(np.nanmean(loss) * 1000), 2) if fit_persons else float("nan"),
        "persons_fitted": len(fit_persons),
        "frames_valid_pct": round(100.0 * float(valid.mean()), 1),
        "time_total_s": round(time.perf_counter() - t_start, 3),
    }
    checkpoints = FitCheckpoints(**{**ck.__dict__, "landmark_offsets_m": offsets})
    return FitResult(bodyfit=bodyfit, keypoints3d=fitted, metrics={**summary, **metrics}, checkpoints=checkpoints)


def _checkpoints(kp3d: Keypoints3D, inputs: list[PersonInputs], fit_persons: list[int], offsets: np.ndarray) -> FitCheckpoints:
    fitted = np.zeros(len(inputs), dtype=bool)
    fitted[fit_persons] = True
    return FitCheckpoints(
        person_ids=kp3d.person_ids.astype(np.int64),
        frame_indices=kp3d.frame_indices.astype(np.int64),
        fitted=fitted,
        kp3d_m=np.stack([i.kp3d_m for i in inputs], axis=1),
        w3d=np.stack([i.w3d for i in inputs], axis=1),
        uv_px=np.stack([i.uv_px for i in inputs], axis=2),
        w2d=np.stack([i.w2d for i in inputs], axis=2),
        landmark_offsets_m=offsets,
    )


def _incremental_plan(
    previous: FitPrevious | None, ck: FitCheckpoints, cfg: FitConfig, body_model: str, rig: str
) -> tuple[FitPrevious | None, np.ndarray | None, str]:
    """(the previous fit to build on, the frames to re-optimise, "") or (None, None, why not)."""
    if previous is None:
        return None, None, "no previous run given"
    if not cfg.incremental:
        return None, None, "incremental is off"
    why = layout_mismatch(previous, ck, body_model, rig)
    if why:
        return None, None, why
    free = free_frames(changed_frames(previous.checkpoints, ck), cfg.incremental_margin_frames)
    if free.all():  # a full fit then re-estimates the shapes too
        return None, None, "every frame's inputs changed"
    return previous, free, ""


def _reuse_metrics(changed: np.ndarray, free: np.ndarray) -> dict[str, float | str]:
    """What an incremental re-fit reused (manifest metrics)."""
    first = int(np.argmax(free)) if free.any() else -1
    return {
        "incremental": f"re-fit {int(free.sum())} frames from frame {first}" if free.any() else "nothing changed",
        "reused_frames": int((~free).sum()),
        "refit_frames": int(free.sum()),
        "refit_from_frame": first,
        "first_changed_input_frame": int(np.argmax(changed)) if changed.any() else -1,
    }


def _mean_3d_error(kp: np.ndarray, inp: PersonInputs) -> float:
    """Mean confidence-weighted distance (m) between fitted ``kp`` (frames, joints, 3) and
    the 3D targets (the fit's per-person ``loss_final``)."""
    d = np.linalg.norm(kp - inp.kp3d_m, axis=-1)
    return float((d * inp.w3d).sum() / max(float(inp.w3d.sum()), 1e-9))
