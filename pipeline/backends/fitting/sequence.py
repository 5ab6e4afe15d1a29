"""Fit a body model to every person's 2D and 3D keypoints over a whole sequence (torch, L-BFGS).

One driver for every body model (``BodyModel``: anny, SMPL/SMPL-X). Steps, all persons
batched together (their losses are independent sums):

1. Shape: per person from the triangulated limb lengths (``BodyModel.init_shape``).
2. Initialisation per frame: root by Kabsch of the rest torso keypoints onto the observed
   ones (``common.init_roots``), then each limb bone swung so that its child keypoint points
   at the observed one (``init_limbs``).
3. Pose pass 1: 3D term + priors + smoothness (cheap, gets the limbs close).
4. Pose pass 2: eq. 3 of the paper (2D Geman-McClure reprojection in every view, 3D,
   regularisation, smoothness on the pose and on the whole mesh, priors) plus our terms:
   keypoint acceleration (re-weighted late in the pass) and jerk, soft joint limits, the
   ground, the overlap between athletes and per-person landmark offsets; the shape is
   refined jointly (``common.run_pose_passes``; the terms: ``terms.DEFAULT_TERMS``).

Both pose passes use L-BFGS (history 100, lr 1, strong Wolfe) over every frame at once, on
variables scaled by the lever arm of what they move (``BodyModel.lever_arms``): without that
scaling L-BFGS needs ~3x more iterations for the same accuracy.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field

import numpy as np
import roma
import torch

from pipeline.backends.fitting.body_model import BodyModel, FitState
from pipeline.backends.fitting.common import (
    PersonObservations,
    ProgressFn,
    init_roots,
    min_rotation,
    report_lbfgs_progress,
    run_pose_passes,
)
from pipeline.backends.fitting.config import FitConfig
from pipeline.backends.fitting.terms import DEFAULT_TERMS, Targets, TermContext, build_terms, evaluate_terms
from pipeline.schema.joints import COCO17_FEET

logger = logging.getLogger(__name__)

__all__ = ["FitHold", "FitOutput", "fit_sequence", "init_limbs"]


@dataclass(frozen=True)
class FitHold:
    """What an incremental re-fit keeps from a previous fit (frames and persons as in the
    observations): the per-person constants, and every frame outside ``free``.

    shape: (persons, shape) the body shapes (not refined); landmark_offsets_m: (persons,
    joints, 3) the landmark offsets (not re-calibrated); pose_aa: (frames, persons, bones, 3)
    and root_m: (frames, persons, 3): the previous pose, as ``FitOutput``; free: (frames,)
    bool, the frames to re-optimise; the other frames stay at the previous pose and take
    part in the loss (the temporal terms see them); fresh: (frames,) bool, the free frames
    initialised as a fresh fit would (those whose observations changed), the other free
    frames start from the previous pose."""

    shape: np.ndarray
    landmark_offsets_m: np.ndarray
    pose_aa: np.ndarray
    root_m: np.ndarray
    free: np.ndarray
    fresh: np.ndarray


@dataclass(frozen=True)
class FitOutput:
    """Fitted parameters and keypoints (persons in input order; see the body model for frames).

    bone_names: (bones,) the model's posed bones; rig: its rig name; shape: (persons, shape);
    pose_aa: (frames, persons, bones, 3) the root's world axis-angle, then the parent-local
    ones (rad); root_m: (frames, persons, 3) world root joint; keypoints_m: (frames, persons,
    joints, 3) fitted ``COCO17_FEET`` keypoints (landmark offsets included); present:
    (frames, persons) bool; loss: (persons,) mean confidence-weighted 3D distance (m);
    timings_s: wall and CPU seconds of the steps; loss_terms: the final loss by term;
    landmark_offsets_m: (persons, joints, 3) per-person landmark offsets in their landmark
    bones' frames (m; zeros without ``calibrate_landmarks``).
    """

    bone_names: tuple[str, ...]
    rig: str
    shape: np.ndarray
    pose_aa: np.ndarray
    root_m: np.ndarray
    keypoints_m: np.ndarray
    present: np.ndarray
    loss: np.ndarray
    timings_s: dict[str, float] = field(default_factory=dict)
    loss_terms: dict[str, float] = field(default_factory=dict)
    landmark_offsets_m: np.ndarray | None = None


def fit_sequence(
    body: BodyModel,
    observations: list[PersonObservations],
    P_px: np.ndarray,
    cfg: FitConfig,
    progress: ProgressFn | None = None,
    terms: tuple[str, ...] = DEFAULT_TERMS,
    hold: FitHold | None = None,
) -> FitOutput:
    """Fit shape and per-frame pose of every person (see the module docstring).

    Args:
        body: the body model (an adapter of anny or SMPL; bound to these persons here).
        observations: one entry per person (same frame count), ``COCO17_FEET`` order.
        P_px: (views, 3, 4) projection matrices to *undistorted* pixels.
        cfg: the stage config (weights, iterations, robust function, threads).
        progress: ``progress(done, total, message)`` at every L-BFGS iteration
            (``common.report_lbfgs_progress``); may raise to stop the fit.
        terms: the loss terms by name (``terms.LOSS_TERMS``), summed in this order.
        hold: keep the shapes, landmark offsets and the frames outside ``hold.free`` of a
            previous fit (an incremental re-fit); None: fit everything.
    Raises ``ValueError`` on inconsistent inputs, unknown terms or unreadable prior files.
    """
    if not observations:
        raise ValueError(f"fit ({body.name}): no persons to fit")
    nf, nv = observations[0].kp3d_m.shape[0], P_px.shape[0]
    for o in observations:
        if o.kp3d_m.shape != (nf, len(COCO17_FEET), 3) or o.uv_px.shape[:2] != (nv, nf):
            raise ValueError(
                f"fit ({body.name}): inconsistent observation shapes {o.kp3d_m.shape} / {o.uv_px.shape}"
            )
    if hold is not None and (hold.free.shape != (nf,) or hold.root_m.shape != (nf, len(observations), 3)):
        raise ValueError(
            f"fit ({body.name}): hold covers {hold.free.shape} frames and root {hold.root_m.shape}, "
            f"the observations {nf} frames of {len(observations)} persons"
        )
    threads = torch.get_num_threads()
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    try:
        with report_lbfgs_progress(progress, cfg):
            return _fit(body, observations, P_px, cfg, terms, hold)
    finally:
        torch.set_num_threads(threads)


def init_limbs(
    body: BodyModel, G_root: torch.Tensor, pose: torch.Tensor, root: torch.Tensor, kp3d: torch.Tensor, w3d: torch.Tensor
) -> torch.Tensor:
    """Swing each ``body.ik_drivers`` bone (in FK order) so its child keypoint points at the
    triangulated one, at the initial shape; returns the updated (rows, bones - 1, 3)
    non-root pose. Rows where that keypoint is unobserved keep their pose."""
    pose = pose.clone()
    rest = body.rest(None)
    for b, k in body.ik_drivers:
        sk = body.forward(rest, G_root, pose, root)
        G, x = sk.G, sk.x
        R = min_rotation(sk.kp[:, k] - x[:, b], kp3d[:, k] - x[:, b])
        local = G[:, body.bone_parents[b]].transpose(-1, -2) @ R @ G[:, b]
        pose[:, b - 1] = torch.where((w3d[:, k] > 0)[:, None], roma.rotmat_to_rotvec(local), pose[:, b - 1])
    return pose


def _fit(
    body: BodyModel,
    observations: list[PersonObservations],
    P_px: np.ndarray,
    cfg: FitConfig,
    names: tuple[str, ...],
    hold: FitHold | None = None,
) -> FitOutput:
    nf, nv = observations[0].kp3d_m.shape[0], P_px.shape[0]
    npers, nb, nj = len(observations), len(body.bone_names), len(COCO17_FEET)
    dt = body.dtype
    timings: dict[str, float] = {}

    t0, c0 = time.perf_counter(), time.process_time()
    if hold is not None:
        shape = torch.as_tensor(hold.shape, dtype=dt)
        cfg = dataclasses.replace(cfg, refine_shape=False)
    else:
        shape = body.init_shape(observations, cfg)
    timings["shape_s"] = time.perf_counter() - t0
    timings["shape_cpu_s"] = time.process_time() - c0

    t0, c0 = time.perf_counter(), time.process_time()
    n = npers * nf  # rows: person-major (row = p * nf + f)
    row_person = torch.arange(npers).repeat_interleave(nf)
    body.bind(shape, row_person, cfg)
    rest_kp = body.rest_keypoints()
    R0 = np.zeros((npers, nf, 3, 3))
    T0 = np.zeros((npers, nf, 3))
    present = np.zeros((nf, npers), dtype=bool)
    for p, o in enumerate(observations):
        R0[p], T0[p], _ = init_roots(rest_kp[p], o)
        present[:, p] = (o.w3d > 0).sum(axis=1) >= cfg.min_valid_joints
    if hold is not None:  # held frames start (and stay) at the previous pose
        kept = ~(hold.free & hold.fresh)
        R0[:, kept] = roma.rotvec_to_rotmat(torch.as_tensor(hold.pose_aa[kept, :, 0].transpose(1, 0, 2).copy())).numpy()
        T0[:, kept] = hold.root_m[kept].transpose(1, 0, 2)
    R0_t = torch.as_tensor(R0.reshape(n, 3, 3), dtype=dt)
    targets = Targets(
        kp3d_m=torch.as_tensor(np.stack([o.kp3d_m for o in observations]).reshape(n, nj, 3), dtype=dt),
        w3d=torch.as_tensor(np.stack([o.w3d for o in observations]).reshape(n, nj), dtype=dt),
        uv_px=torch.as_tensor(np.stack([o.uv_px for o in observations], axis=1).reshape(nv, n, nj, 2), dtype=dt),
        w2d=torch.as_tensor(np.stack([o.w2d for o in observations], axis=1).reshape(nv, n, nj), dtype=dt),
        P_px=torch.as_tensor(P_px, dtype=dt),
        present=torch.as_tensor(present.T.copy()),
        n_persons=npers,
        n_frames=nf,
    )
    terms = build_terms(names, TermContext(cfg, body, targets))
    root0 = torch.as_tensor(T0.reshape(n, 3), dtype=dt).clone()
    with torch.no_grad():
        pose0 = init_limbs(body, R0_t, torch.zeros(n, nb - 1, 3, dtype=dt), root0, targets.kp3d_m, targets.w3d)
    row_free = None
    if hold is not None:
        row_free = torch.as_tensor(np.tile(hold.free, npers))  # rows are person-major
        row_fresh = torch.as_tensor(np.tile(hold.free & hold.fresh, npers))
        prev_pose = torch.as_tensor(hold.pose_aa[:, :, 1:].transpose(1, 0, 2, 3).reshape(n, nb - 1, 3).copy(), dtype=dt)
        pose0 = torch.where(row_fresh[:, None, None], pose0, prev_pose)
    timings["init_s"] = time.perf_counter() - t0

    # Optimised variables are scaled so that the loss has similar curvature along each
    # (L-BFGS starts from a scalar Hessian): a rotation is scaled by the lever arm of the
    # keypoints it moves, the per-person constants by the number of frames they explain
    # (the landmark offsets times the model's ``landmark_scale``).
    s_rot = torch.as_tensor(body.lever_arms(), dtype=dt)[None, :, None]
    s_root = float(np.sqrt(nj))
    s_const = float(np.sqrt(nf))
    s_offsets = s_const * body.landmark_scale(cfg)
    delta_s = torch.zeros(n, 3, dtype=dt, requires_grad=True)
    pose_s = (pose0 * s_rot[:, 1:]).requires_grad_(True)
    root_s = (root0 * s_root).requires_grad_(True)
    # per-person landmark offsets, rigid in the frame of each keypoint's landmark bone
    offsets_s = torch.zeros(npers, nj, 3, dtype=dt, requires_grad=cfg.calibrate_landmarks and hold is None)
    if hold is not None:
        with torch.no_grad():
            offsets_s += torch.as_tensor(hold.landmark_offsets_m, dtype=dt) * s_offsets
    shape_s = body.encode_shape(shape, s_const).requires_grad_(cfg.refine_shape)
    params = [delta_s, pose_s, root_s]
    params += ([offsets_s] if cfg.calibrate_landmarks and hold is None else []) + ([shape_s] if cfg.refine_shape else [])
    if row_free is not None:
        # Held rows get no gradient, so L-BFGS never moves them (its steps are combinations
        # of gradients): they stay at the previous pose exactly.
        mask = row_free.to(dt)
        for v in (delta_s, pose_s, root_s):
            v.register_hook(lambda g, m=mask.reshape(-1, *([1] * (v.dim() - 1))): g * m)

    def state(use_2d: bool, accel_weights: torch.Tensor | None) -> FitState:
        """The variables in physical units and the body posed by them."""
        delta, pose, root = delta_s / s_rot[:, 0], pose_s / s_rot[:, 1:], root_s / s_root
        offsets, shape_u = offsets_s / s_offsets, body.decode_shape(shape_s, s_const)
        rest = body.rest(shape_u)
        G_root = roma.rotvec_to_rotmat(delta) @ R0_t
        pose_full = torch.cat([roma.rotmat_to_rotvec(G_root)[:, None], pose], dim=1)
        sk = body.forward(rest, G_root, pose, root)
        kp = sk.kp
        if cfg.calibrate_landmarks:
            kp = kp + (sk.G[:, body.landmark_bones] @ offsets[row_person][..., None])[..., 0]
        return FitState(pose, G_root, pose_full, root, rest, sk, kp, offsets, shape_u, use_2d, accel_weights)

    def evaluate(
        use_2d: bool, accel_weights: torch.Tensor | None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor], torch.Tensor]:
        s = state(use_2d, accel_weights)
        out = evaluate_terms(terms, s)
        return sum(out.values()), out, s.kp  # type: ignore[return-value]

    accel_w = run_pose_passes(params, evaluate, cfg, npers, nf)
    timings["pose_s"] = time.perf_counter() - t0
    timings["pose_cpu_s"] = time.process_time() - c0

    with torch.no_grad():
        total, parts, _ = evaluate(cfg.use_2d, accel_w)
        loss_terms = {k: float(v) for k, v in parts.items()}
        s = state(cfg.use_2d, accel_w)
        shape = body.shape_of(s.shape_u) if cfg.refine_shape else shape
        d = (s.kp - targets.kp3d_m).norm(dim=-1).reshape(npers, nf, -1)
        w = targets.w3d.reshape(npers, nf, -1)
        per_person = ((d * w).sum(dim=(1, 2)) / w.sum(dim=(1, 2)).clamp(min=1e-9)).double().numpy()
    logger.info(
        "%s fit: %d persons x %d frames, loss %.4g %s, %s", body.name, npers, nf, float(total), loss_terms, timings
    )
    return FitOutput(
        bone_names=body.bone_names,
        rig=body.rig,
        shape=shape.double().numpy().copy(),
        pose_aa=s.pose_full.reshape(npers, nf, nb, 3).permute(1, 0, 2, 3).double().numpy().copy(),
        root_m=s.root.reshape(npers, nf, 3).permute(1, 0, 2).double().numpy().copy(),
        keypoints_m=s.kp.reshape(npers, nf, nj, 3).permute(1, 0, 2, 3).double().numpy().copy(),
        present=present,
        loss=per_person,
        timings_s=timings,
        loss_terms=loss_terms,
        landmark_offsets_m=hold.landmark_offsets_m.copy() if hold is not None else s.offsets.double().numpy().copy(),
    )
