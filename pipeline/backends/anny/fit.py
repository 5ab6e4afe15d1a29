"""Fit anny to every person's 2D and 3D keypoints over a whole sequence (torch, L-BFGS).

Steps, all persons batched together (their losses are independent sums):
1. Shape: 6 phenotypes per person from the triangulated limb lengths.
2. Initialisation per frame: root by Kabsch of the rest torso keypoints onto the observed
   ones, then each limb bone swung so that its child keypoint points at the observed one.
3. Pose pass 1: 3D term + priors + smoothness (cheap, gets the limbs close).
4. Pose pass 2: eq. 3 of the paper (2D Geman-McClure reprojection in every view, 3D,
   regularisation, smoothness on the pose and on the whole mesh, priors) plus our terms:
   a pseudo-Huber penalty on keypoint accelerations, soft joint limits, the ground, and
   per-person landmark offsets; the shape is refined jointly.
Both pose passes use L-BFGS (history 100, lr 1, strong Wolfe) over every frame at once, on
variables scaled by the lever arm of what they move (see ``lever_arms``): without that
scaling L-BFGS needs ~3x more iterations for the same accuracy.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import roma
import torch

from pipeline.backends.anny.fit_init import (
    PersonObservations,
    fit_shapes,
    forward_kinematics_rootmat,
    init_limbs,
    init_roots,
    joint_idx,
    rotmat_rows,
)
from pipeline.backends.anny.fit_terms import MeshMoments, lever_arms, rest_tails, sole_vertices
from pipeline.backends.anny.fk import SparseKeypoints, keypoints_from_bones
from pipeline.backends.anny.model import FIT_DTYPES, AnnyBody, anny_fit_body
from pipeline.backends.anny.priors import joint_limit_penalty, joint_limit_tables, load_pose_prior
from pipeline.backends.fitting.common import ground_term, run_pose_passes, sequence_terms
from pipeline.backends.fitting.config import FitConfig
from pipeline.backends.fitting.contacts import ProxyOverlap
from pipeline.schema.joints import COCO17_FEET, FOOT_JOINTS

logger = logging.getLogger(__name__)

__all__ = ["AnnyFitOutput", "PersonObservations", "fit_anny"]


@dataclass(frozen=True)
class AnnyFitOutput:
    """Fitted parameters and keypoints (persons in input order)."""

    bone_names: tuple[str, ...]
    shape: np.ndarray  # (persons, 6)
    pose_aa: np.ndarray  # (frames, persons, bones, 3)
    root_m: np.ndarray  # (frames, persons, 3)
    keypoints_m: np.ndarray  # (frames, persons, joints, 3)
    present: np.ndarray  # (frames, persons) bool
    loss: np.ndarray  # (persons,)
    timings_s: dict[str, float] = field(default_factory=dict)
    loss_terms: dict[str, float] = field(default_factory=dict)


def fit_anny(
    observations: list[PersonObservations], P_px: np.ndarray, cfg: FitConfig, body: AnnyBody | None = None
) -> AnnyFitOutput:
    """Fit shape and per-frame pose of every person.

    Args:
        observations: one entry per person (same frame count).
        P_px: (views, 3, 4) projection matrices to *undistorted* pixels.
        cfg: the stage config (weights, iterations, robust function).
    Raises ``ValueError`` on inconsistent inputs.
    """
    if not observations:
        raise ValueError("fit_anny: no persons to fit")
    nf = observations[0].kp3d_m.shape[0]
    nv = P_px.shape[0]
    for o in observations:
        if o.kp3d_m.shape != (nf, len(COCO17_FEET), 3) or o.uv_px.shape[:2] != (nv, nf):
            raise ValueError(f"fit_anny: inconsistent observation shapes {o.kp3d_m.shape} / {o.uv_px.shape}")
    body = anny_fit_body(cfg.rig, cfg.precision) if body is None else body.to(FIT_DTYPES[cfg.precision])
    threads = torch.get_num_threads()
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    try:
        return _fit(observations, P_px, cfg, body)
    finally:
        torch.set_num_threads(threads)


def _fit(
    observations: list[PersonObservations], P_px: np.ndarray, cfg: FitConfig, body: AnnyBody
) -> AnnyFitOutput:
    nf = observations[0].kp3d_m.shape[0]
    nv = P_px.shape[0]
    npers, nb, nj = len(observations), body.n_bones, len(COCO17_FEET)
    timings: dict[str, float] = {}

    t0, c0 = time.perf_counter(), time.process_time()
    shape = fit_shapes(body, observations, cfg)
    coeffs = body.shape_coeffs(shape)
    heads_p = body.rest_heads(coeffs)  # (P, B, 3)
    kpts_p = body.rest_kp_points(coeffs)  # (P, J, B, 3)
    timings["shape_s"] = time.perf_counter() - t0
    timings["shape_cpu_s"] = time.process_time() - c0

    t0, c0 = time.perf_counter(), time.process_time()
    dt = body.dtype
    eye = torch.eye(3, dtype=dt).expand(npers, nb, 3, 3)
    rest_kp = keypoints_from_bones(body, eye, heads_p - heads_p[:, :1], heads_p, kpts_p).double().numpy()
    R0 = np.zeros((npers, nf, 3, 3))
    T0 = np.zeros((npers, nf, 3))
    present = np.zeros((nf, npers), dtype=bool)
    for p, o in enumerate(observations):
        R0[p], T0[p], _ = init_roots(rest_kp[p], o)
        present[:, p] = (o.w3d > 0).sum(axis=1) >= cfg.min_valid_joints

    # flattened rows: person-major (row = p * nf + f)
    n = npers * nf
    row_person = torch.arange(npers).repeat_interleave(nf)
    heads = heads_p[row_person]
    R0_t = torch.as_tensor(R0.reshape(n, 3, 3), dtype=dt)
    kp3d = torch.as_tensor(np.stack([o.kp3d_m for o in observations]).reshape(n, nj, 3), dtype=dt)
    w3d = torch.as_tensor(np.stack([o.w3d for o in observations]).reshape(n, nj), dtype=dt)
    uv = torch.as_tensor(np.stack([o.uv_px for o in observations], axis=1).reshape(nv, n, nj, 2), dtype=dt)
    w2d = torch.as_tensor(np.stack([o.w2d for o in observations], axis=1).reshape(nv, n, nj), dtype=dt)
    P_t = torch.as_tensor(P_px, dtype=dt)

    heads_np = heads_p[0].double().numpy()
    rest_v = body.rest_vertices(coeffs[:1])[0].double().numpy()  # (verts, 3), first person
    tails = rest_tails(body, heads_np, rest_v)
    frames, lo, hi = (
        torch.as_tensor(a, dtype=dt) for a in joint_limit_tables(body.bone_names, heads_np, tails)
    )
    lo, hi = torch.nan_to_num(lo, neginf=-1e6), torch.nan_to_num(hi, posinf=1e6)
    prior = load_pose_prior(cfg.pose_prior_path, body.bone_names, cfg.rig) if cfg.w_prior > 0 else None
    moments = MeshMoments(body, coeffs) if cfg.w_smooth > 0 else None
    sparse_kp = SparseKeypoints(body, heads_p, kpts_p)
    foot = torch.as_tensor(joint_idx(FOOT_JOINTS))
    sole_idx = torch.as_tensor(sole_vertices(body, rest_v))
    sole_w = body.model.dense_vertex_bone_weights[sole_idx]

    def sole_points(c: torch.Tensor) -> torch.Tensor:
        v = body.model.template_vertices[sole_idx] + torch.einsum(
            "cvd,pc->pvd", body.model.blendshapes[:, sole_idx], c
        )
        return sole_w[None, :, :, None] * v[:, :, None, :]

    soles = SparseKeypoints(body, heads_p, sole_points(coeffs), weights=sole_w)

    overlap = ProxyOverlap() if cfg.w_overlap > 0 and npers > 1 else None
    present_t = torch.as_tensor(present.T.copy())
    root0 = torch.as_tensor(T0.reshape(n, 3), dtype=dt).clone()
    with torch.no_grad():
        pose0 = init_limbs(
            body,
            R0_t,
            torch.zeros(n, nb - 1, 3, dtype=dt),
            root0,
            heads,
            sparse_kp,
            row_person,
            kp3d,
            w3d,
        )
    timings["init_s"] = time.perf_counter() - t0
    # Optimised variables are scaled so that the loss has similar curvature along each
    # (L-BFGS starts from a scalar Hessian): a rotation is scaled by the lever arm of the
    # keypoints it moves, the per-person constants by the number of frames they explain
    # (the landmark offsets times ``landmark_step``).
    lever = lever_arms(body, rest_kp[0] + heads_np[0], heads_np)
    s_rot = torch.as_tensor(lever, dtype=dt)[None, :, None]
    s_root = float(np.sqrt(nj))
    s_const = float(np.sqrt(nf))
    s_offsets = s_const * cfg.landmark_step
    delta_s = torch.zeros(n, 3, dtype=dt, requires_grad=True)
    pose_s = (pose0 * s_rot[:, 1:]).requires_grad_(True)
    root_s = (root0 * s_root).requires_grad_(True)
    # per-person landmark offsets, rigid in the frame of each keypoint's dominant bone
    offsets_s = torch.zeros(npers, nj, 3, dtype=dt, requires_grad=cfg.calibrate_landmarks)
    dom = body.kp_w.argmax(dim=1)
    shape_s = (torch.logit(shape.clamp(1e-4, 1 - 1e-4)) * s_const * 0.3).requires_grad_(cfg.refine_shape)
    params = [delta_s, pose_s, root_s]
    params += ([offsets_s] if cfg.calibrate_landmarks else []) + ([shape_s] if cfg.refine_shape else [])
    rest_heads = heads

    def unscale() -> tuple[torch.Tensor, ...]:
        """(delta, pose, root, offsets, shape_u) in physical units."""
        return (
            delta_s / s_rot[:, 0],
            pose_s / s_rot[:, 1:],
            root_s / s_root,
            offsets_s / s_offsets,
            shape_s / (s_const * 0.3),
        )

    def set_shape(shape_u: torch.Tensor) -> torch.Tensor:
        """Rest heads per row for the current shape (and the folded keypoint points)."""
        if not cfg.refine_shape:
            return rest_heads
        c = body.shape_coeffs(torch.sigmoid(shape_u))
        hp = body.rest_heads(c)
        sparse_kp.set_shape(hp, body.rest_kp_points(c))
        soles.set_shape(hp, sole_points(c))
        return hp[row_person]

    def keypoints(G: torch.Tensor, x: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
        kp = sparse_kp(G, x, row_person)
        if cfg.calibrate_landmarks:
            kp = kp + (G[:, dom] @ offsets[row_person][..., None])[..., 0]
        return kp

    def evaluate(
        use_2d: bool, accel_weights: torch.Tensor | None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor], torch.Tensor]:
        delta, pose, root, offsets, shape_u = unscale()
        heads = set_shape(shape_u)
        G_root = rotmat_rows(delta) @ R0_t
        full = torch.cat([roma.rotmat_to_rotvec(G_root)[:, None], pose], dim=1)
        G, x = forward_kinematics_rootmat(body, G_root, pose, root, heads)
        kp = keypoints(G, x, offsets)
        out = sequence_terms(
            cfg, kp, kp3d, w3d, P_t, uv, w2d, use_2d, pose, G_root, G, x, heads, npers, nf, moments, accel_weights
        )
        if cfg.calibrate_landmarks:
            out["landmarks"] = cfg.w_landmarks * offsets.square().sum()
        if cfg.refine_shape:
            out["shape"] = 1e-4 * (torch.sigmoid(shape_u) - 0.5).square().sum()
        out["limits"] = cfg.w_limits * joint_limit_penalty(full, frames, lo, hi)
        if prior is not None:
            out["prior"] = cfg.w_prior * prior.pose_nll(full)
        if cfg.w_ground > 0:
            sole_z = soles(G, x, row_person)[..., 2]
            out["ground"] = cfg.w_ground * ground_term(kp, foot, sole_z)
        if overlap is not None:
            out["overlap"] = cfg.w_overlap * overlap(kp.reshape(npers, nf, nj, 3), present_t)
        return sum(out.values()), out, kp  # type: ignore[return-value]

    accel_w = run_pose_passes(params, evaluate, cfg, npers, nf)
    timings["pose_s"] = time.perf_counter() - t0
    timings["pose_cpu_s"] = time.process_time() - c0

    with torch.no_grad():
        total, parts, _ = evaluate(cfg.use_2d, accel_w)
        terms = {k: float(v) for k, v in parts.items()}
        delta, pose, root, offsets, shape_u = unscale()
        heads = set_shape(shape_u)
        shape = torch.sigmoid(shape_u) if cfg.refine_shape else shape
        G_root = rotmat_rows(delta) @ R0_t
        full = torch.cat([roma.rotmat_to_rotvec(G_root)[:, None], pose], dim=1)
        G, x = forward_kinematics_rootmat(body, G_root, pose, root, heads)
        kp = keypoints(G, x, offsets)
        per_person = _per_person_loss(kp, kp3d, w3d, npers, nf)
    logger.info("anny fit: %d persons x %d frames, loss %.4g %s, %s", npers, nf, float(total), terms, timings)
    return AnnyFitOutput(
        bone_names=body.bone_names,
        shape=shape.double().numpy(),
        pose_aa=full.reshape(npers, nf, nb, 3).permute(1, 0, 2, 3).double().numpy().copy(),
        root_m=root.reshape(npers, nf, 3).permute(1, 0, 2).double().numpy().copy(),
        keypoints_m=kp.reshape(npers, nf, nj, 3).permute(1, 0, 2, 3).double().numpy().copy(),
        present=present,
        loss=per_person,
        timings_s=timings,
        loss_terms=terms,
    )


def _per_person_loss(
    kp: torch.Tensor, kp3d: torch.Tensor, w3d: torch.Tensor, npers: int, nf: int
) -> np.ndarray:
    """Mean confidence-weighted 3D distance (m) of each person's fit, a comparable summary."""
    d = (kp - kp3d).norm(dim=-1).reshape(npers, nf, -1)
    w = w3d.reshape(npers, nf, -1)
    return ((d * w).sum(dim=(1, 2)) / w.sum(dim=(1, 2)).clamp(min=1e-9)).double().numpy()
