"""Fit SMPL / SMPL-X (the user's model files, ``smpl.body``) to every person's 2D and 3D
keypoints over a whole sequence: the same method and loss as the anny fit (``anny.fit``).

Steps, all persons batched together:
1. Shape: 10 betas per person from the triangulated limb lengths (shared over the sequence).
2. Initialisation per frame: pelvis by Kabsch of the rest torso keypoints onto the observed
   ones, then hips/knees/ankles/shoulders/elbows swung so their child keypoint points at the
   observed one.
3. Pose pass 1: 3D term + priors + smoothness.
4. Pose pass 2: eq. 3 of the paper (confidence-weighted Geman-McClure reprojection in every
   view, 3D, ``Lreg``, ``Lsmooth`` = pose differences + whole-mesh vertex velocity, pose
   prior) plus our terms: keypoint acceleration, soft joint limits, the ground (foot
   keypoints and sole vertices), per-person landmark offsets; betas refined jointly.
L-BFGS (history 100, lr 1, strong Wolfe) over every frame at once, variables scaled by the
lever arm of what they move, as for anny.

Pose prior: without user files, the soft joint limits below plus ``Lreg``. With files: a GMM
(``FitConfig.pose_prior_path``: our npz layout, or SMPLify's ``gmm_08.pkl``) over the body
pose, and/or VPoser v2 (``FitConfig.vposer_path``, see ``smpl.vposer``), both weighted by ``w_prior``.
The shipped anny prior (``pose_prior_path="builtin"``) is for anny's rig and is skipped here.
"""

from __future__ import annotations

import logging
import pickle
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import roma
import torch

from pipeline.backends.anny.priors import GMMPrior, joint_limit_penalty
from pipeline.backends.fitting.common import (
    SHAPE_LIMBS,
    PersonObservations,
    ground_term,
    init_roots,
    joint_idx,
    lbs_moment_factors,
    min_rotation,
    observed_lengths,
    run_lbfgs,
    run_pose_passes,
    sequence_terms,
)
from pipeline.backends.fitting.config import FitConfig
from pipeline.backends.fitting.contacts import ProxyOverlap
from pipeline.backends.smpl.body import N_BETAS, SmplBody, forward, keypoints, skin, smpl_body
from pipeline.schema.joints import COCO17_FEET, FOOT_JOINTS

logger = logging.getLogger(__name__)

__all__ = ["SMPL_LIMITS", "SmplFitOutput", "fit_smpl", "load_gmm_prior"]

# Soft joint limits (radians) on SMPL's parent-local axis-angle, in SMPL's canonical axes
# (x: subject's left, y: up, z: forward). Legs and spine flex about x (knee: +x bends the
# shin back; hip: -x lifts the thigh forward; spine: +x bends forward); arms (along +-x in
# the T-pose) twist about x, swing forward/back about y and up/down about z; the elbow
# flexes about y (left: negative, right: positive). Generous ranges (cf. ``anny.priors``):
# they forbid hyper-extended knees/elbows, twisted limbs and a folded spine.
SMPL_LIMITS: dict[str, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]] = {
    "left_hip": ((-2.3, 0.6), (-0.8, 0.8), (-0.6, 1.0)),
    "right_hip": ((-2.3, 0.6), (-0.8, 0.8), (-1.0, 0.6)),
    "spine1": ((-0.3, 0.45), (-0.35, 0.35), (-0.3, 0.3)),
    "left_knee": ((-0.05, 2.6), (-0.5, 0.5), (-0.12, 0.12)),
    "right_knee": ((-0.05, 2.6), (-0.5, 0.5), (-0.12, 0.12)),
    "spine2": ((-0.3, 0.45), (-0.35, 0.35), (-0.3, 0.3)),
    "left_ankle": ((-0.8, 0.9), (-0.5, 0.5), (-0.5, 0.5)),
    "right_ankle": ((-0.8, 0.9), (-0.5, 0.5), (-0.5, 0.5)),
    "spine3": ((-0.3, 0.45), (-0.35, 0.35), (-0.3, 0.3)),
    "left_foot": ((-0.6, 0.6), (-0.2, 0.2), (-0.2, 0.2)),
    "right_foot": ((-0.6, 0.6), (-0.2, 0.2), (-0.2, 0.2)),
    "neck": ((-0.5, 0.5), (-0.5, 0.5), (-0.35, 0.35)),
    "left_collar": ((-0.4, 0.4), (-0.5, 0.5), (-0.4, 0.5)),
    "right_collar": ((-0.4, 0.4), (-0.5, 0.5), (-0.5, 0.4)),
    "head": ((-0.6, 0.6), (-0.7, 0.7), (-0.5, 0.5)),
    "left_shoulder": ((-1.6, 1.6), (-2.6, 2.6), (-2.6, 2.6)),
    "right_shoulder": ((-1.6, 1.6), (-2.6, 2.6), (-2.6, 2.6)),
    "left_elbow": ((-1.3, 1.3), (-2.6, 0.05), (-0.15, 0.15)),
    "right_elbow": ((-1.3, 1.3), (-0.05, 2.6), (-0.15, 0.15)),
    "left_wrist": ((-1.0, 1.0), (-0.6, 0.6), (-1.2, 1.2)),
    "right_wrist": ((-1.0, 1.0), (-0.6, 0.6), (-1.2, 1.2)),
    "left_hand": ((-0.5, 0.5), (-0.5, 0.5), (-0.5, 0.5)),
    "right_hand": ((-0.5, 0.5), (-0.5, 0.5), (-0.5, 0.5)),
}

# (driver joint, child keypoint) for the swing initialisation, in FK order.
IK_DRIVERS: tuple[tuple[str, str], ...] = (
    ("left_hip", "left_knee"),
    ("right_hip", "right_knee"),
    ("left_knee", "left_ankle"),
    ("right_knee", "right_ankle"),
    ("left_ankle", "left_big_toe"),
    ("right_ankle", "right_big_toe"),
    ("left_shoulder", "left_elbow"),
    ("right_shoulder", "right_elbow"),
    ("left_elbow", "left_wrist"),
    ("right_elbow", "right_wrist"),
)


@dataclass(frozen=True)
class SmplFitOutput:
    """Fitted parameters and keypoints (persons in input order); see ``smpl_body`` for frames."""

    joint_names: tuple[str, ...]
    rig: str
    shape: np.ndarray  # (persons, 10) betas
    pose_aa: np.ndarray  # (frames, persons, joints, 3): world pelvis orientation, then body_pose
    root_m: np.ndarray  # (frames, persons, 3) world pelvis position
    keypoints_m: np.ndarray  # (frames, persons, 23, 3)
    present: np.ndarray  # (frames, persons) bool
    loss: np.ndarray  # (persons,)
    timings_s: dict[str, float] = field(default_factory=dict)
    loss_terms: dict[str, float] = field(default_factory=dict)


class _ArrayUnpickler(pickle.Unpickler):
    """Unpickles only numpy arrays and plain containers (SMPLify's ``gmm_08.pkl``)."""

    _ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"),
        ("_codecs", "encode"),  # bytes in protocol-2 pickles written by Python 3
        ("numpy", "dtype"),
        ("numpy.core.multiarray", "scalar"),
        ("numpy._core.multiarray", "scalar"),
    }

    def find_class(self, module: str, name: str) -> type:
        if (module, name) in self._ALLOWED:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"refusing to unpickle {module}.{name}")


def load_gmm_prior(path: str | Path, n_body_joints: int) -> tuple[GMMPrior, int]:
    """A GMM over the flattened body pose and how many joints (after the pelvis) it covers.

    ``path``: our npz (``means``, ``precisions``, ``weights``) or SMPLify's ``gmm_08.pkl``
    (``means``, ``covars``, ``weights``; 69 dims = SMPL joints 1..23). A 69-dim GMM on a
    21-joint SMPL-X body is marginalised to its first 63 dims (exact for Gaussians).
    ``ValueError`` naming the path when unreadable or of the wrong dimension."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{p}: GMM pose prior file not found (FitConfig.pose_prior_path)")
    if p.suffix == ".pkl":
        try:
            with open(p, "rb") as fh:
                raw = _ArrayUnpickler(fh, encoding="latin1").load()
            means, covars, weights = (
                np.asarray(raw[k], dtype=np.float64) for k in ("means", "covars", "weights")
            )
        except (pickle.UnpicklingError, KeyError, TypeError, EOFError, OSError) as e:
            raise ValueError(f"{p}: not an SMPLify GMM pickle (means, covars, weights): {e}") from e
    else:
        try:
            with np.load(p, allow_pickle=False) as z:
                means, precisions, weights = (
                    np.asarray(z[k], dtype=np.float64) for k in ("means", "precisions", "weights")
                )
                rig = str(z["rig"]) if "rig" in z.files else ""
        except (OSError, KeyError, ValueError) as e:
            raise ValueError(
                f"{p}: cannot read a GMM pose prior (needs means, precisions, weights): {e}"
            ) from e
        if rig and not rig.startswith("smpl"):
            raise ValueError(f"{p}: this GMM pose prior was fitted for rig {rig!r}, not SMPL/SMPL-X")
        covars = np.asarray(np.linalg.inv(precisions), dtype=np.float64)
    d = means.shape[1]
    if d % 3 or d // 3 > n_body_joints:
        if d // 3 == 23 and n_body_joints == 21:
            means, covars, d = means[:, :63], covars[:, :63, :63], 63
        else:
            raise ValueError(f"{p}: GMM of dimension {d} does not fit a body of {n_body_joints} joints")
    return GMMPrior(means, np.linalg.inv(covars), weights / weights.sum()), d // 3


def _lever_arms(body: SmplBody, rest_kp: np.ndarray, rest_joints: np.ndarray) -> np.ndarray:
    """(joints,) RMS distance from each joint to the keypoints its rotation moves (>= 5 cm)."""
    nj = body.n_joints
    anc = np.eye(nj, dtype=bool)  # anc[c, b]: b is c or an ancestor of c
    for c in range(1, nj):
        anc[c] |= anc[body.parents[c]]
    w = body.keypoint_vertices.weights.numpy() > 1e-9
    moved = np.zeros((len(COCO17_FEET), nj), dtype=bool)
    for k in range(len(COCO17_FEET)):
        j = body.kp_joint[k]
        if j >= 0:  # a joint is moved by its strict ancestors
            moved[k] = anc[j] & (np.arange(nj) != j)
        else:
            moved[k] = (w[body.kp_vertex[k]].astype(float) @ anc.astype(float)) > 0
    out = np.full(nj, 0.05)
    for b in range(nj):
        sel = np.flatnonzero(moved[:, b])
        if sel.size:
            out[b] = max(
                0.05, float(np.sqrt((np.linalg.norm(rest_kp[sel] - rest_joints[b], axis=1) ** 2).sum()))
            )
    return out


def _sole_vertices(body: SmplBody, per_foot: int = 24) -> np.ndarray:
    """Up to ``per_foot`` vertices spread over each sole: the lowest 1.5 cm (rest pose, SMPL
    y-up) of the vertices dominated by an ankle or foot joint, heel to toe."""
    v = body.v_template_all
    out = []
    for side in ("left", "right"):
        js = [body.joint_names.index(f"{side}_ankle"), body.joint_names.index(f"{side}_foot")]
        cand = np.flatnonzero(np.isin(body.lbs_weights.argmax(dim=1).numpy(), js))
        sole = cand[v[cand, 1] <= v[cand, 1].min() + 0.015]
        sole = sole[np.argsort(v[sole, 2])]
        out.append(sole[np.linspace(0, len(sole) - 1, min(per_foot, len(sole))).astype(int)])
    return np.concatenate(out)


def _mesh_moments(body: SmplBody, betas: torch.Tensor) -> torch.Tensor:
    """Factor ``L`` (persons, joints * 4, rank) with ``sum_v |dv|^2 = |Z L|^2`` for LBS
    transform differences (as ``anny.fit_terms.MeshMoments``; pose blend shapes ignored)."""
    m = body.module
    rest = [
        m.v_template.detach().double() + torch.einsum("vdb,b->vd", m.shapedirs.detach().double(), b) for b in betas
    ]
    return lbs_moment_factors(rest, body.lbs_weights)


def fit_smpl(
    observations: list[PersonObservations], P_px: np.ndarray, cfg: FitConfig, body: SmplBody | None = None
) -> SmplFitOutput:
    """Fit betas and per-frame pose of every person (see the module docstring).

    Args:
        observations: one entry per person (same frame count), ``COCO17_FEET`` order.
        P_px: (views, 3, 4) projection matrices to *undistorted* pixels.
        cfg: the stage config; ``body_model``, ``body_model_path`` and ``smpl_gender`` pick the
            model unless ``body`` is given.
    Raises ``ValueError`` on inconsistent inputs or missing/unreadable model or prior files.
    """
    if not observations:
        raise ValueError("fit_smpl: no persons to fit")
    nf, nv = observations[0].kp3d_m.shape[0], P_px.shape[0]
    for o in observations:
        if o.kp3d_m.shape != (nf, len(COCO17_FEET), 3) or o.uv_px.shape[:2] != (nv, nf):
            raise ValueError(f"fit_smpl: inconsistent observation shapes {o.kp3d_m.shape} / {o.uv_px.shape}")
    body = body or smpl_body(cfg.body_model, cfg.body_model_path, cfg.smpl_gender)
    threads = torch.get_num_threads()
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    try:
        return _fit(observations, P_px, cfg, body)
    finally:
        torch.set_num_threads(threads)


def _fit_betas(body: SmplBody, observations: list[PersonObservations], cfg: FitConfig) -> torch.Tensor:
    """(persons, 10) betas minimising the limb-length differences to the observations."""
    lengths, weights = zip(*(observed_lengths(o) for o in observations), strict=True)
    L, W = torch.as_tensor(np.stack(lengths)), torch.as_tensor(np.stack(weights))
    ia = torch.as_tensor(joint_idx(tuple(a for a, _ in SHAPE_LIMBS)))
    ib = torch.as_tensor(joint_idx(tuple(b for _, b in SHAPE_LIMBS)))
    betas = torch.zeros(len(observations), N_BETAS, dtype=torch.float64, requires_grad=True)

    def closure() -> torch.Tensor:
        kp = _rest_keypoints(body, betas)
        model_len = (kp[:, ia] - kp[:, ib]).norm(dim=-1)
        return (W * (model_len - L).square()).sum() + 1e-4 * betas.square().sum()

    run_lbfgs([betas], closure, cfg.shape_iters, cfg)
    return betas.detach()


def _rest_keypoints(body: SmplBody, betas: torch.Tensor) -> torch.Tensor:
    """(persons, 23, 3) zero-pose keypoints, SMPL frame, pelvis at the origin."""
    n = betas.shape[0]
    J = body.rest_joints(betas)
    eye = torch.eye(3, dtype=torch.float64).expand(n, 3, 3)
    G, x, R = forward(
        body,
        J,
        eye,
        torch.zeros(n, body.n_joints - 1, 3, dtype=torch.float64),
        torch.zeros(n, 3, dtype=torch.float64),
    )
    return keypoints(body, betas, J, G, x, R)


def _fit(
    observations: list[PersonObservations], P_px: np.ndarray, cfg: FitConfig, body: SmplBody
) -> SmplFitOutput:
    nf, nv = observations[0].kp3d_m.shape[0], P_px.shape[0]
    npers, nb, nj = len(observations), body.n_joints, len(COCO17_FEET)
    timings: dict[str, float] = {}

    t0, c0 = time.perf_counter(), time.process_time()
    betas0 = _fit_betas(body, observations, cfg)
    timings["shape_s"] = time.perf_counter() - t0
    timings["shape_cpu_s"] = time.process_time() - c0

    t0, c0 = time.perf_counter(), time.process_time()
    with torch.no_grad():
        rest_kp = _rest_keypoints(body, betas0).numpy()
        rest_J = body.rest_joints(betas0).numpy()
    R0 = np.zeros((npers, nf, 3, 3))
    T0 = np.zeros((npers, nf, 3))
    present = np.zeros((nf, npers), dtype=bool)
    for p, o in enumerate(observations):
        R0[p], T0[p], _ = init_roots(rest_kp[p], o)
        present[:, p] = (o.w3d > 0).sum(axis=1) >= cfg.min_valid_joints

    n = npers * nf  # rows: person-major (row = p * nf + f)
    row_person = torch.arange(npers).repeat_interleave(nf)
    R0_t = torch.as_tensor(R0.reshape(n, 3, 3))
    kp3d = torch.as_tensor(np.stack([o.kp3d_m for o in observations]).reshape(n, nj, 3))
    w3d = torch.as_tensor(np.stack([o.w3d for o in observations]).reshape(n, nj))
    uv = torch.as_tensor(np.stack([o.uv_px for o in observations], axis=1).reshape(nv, n, nj, 2))
    w2d = torch.as_tensor(np.stack([o.w2d for o in observations], axis=1).reshape(nv, n, nj))
    P_t = torch.as_tensor(P_px, dtype=torch.float64)

    lo = torch.full((nb - 1, 3), -1e6, dtype=torch.float64)
    hi = torch.full((nb - 1, 3), 1e6, dtype=torch.float64)
    for j, name in enumerate(body.joint_names[1:]):
        if name in SMPL_LIMITS:
            lo[j] = torch.as_tensor([r[0] for r in SMPL_LIMITS[name]])
            hi[j] = torch.as_tensor([r[1] for r in SMPL_LIMITS[name]])
    axes = torch.eye(3, dtype=torch.float64).expand(nb - 1, 3, 3)
    gmm, gmm_joints = None, 0
    if cfg.pose_prior_path == "builtin":
        logger.info(
            "smpl fit: the shipped GMM pose prior is for anny's rig; not used for %s", body.body_model
        )
    elif cfg.pose_prior_path:
        gmm, gmm_joints = load_gmm_prior(cfg.pose_prior_path, nb - 1)
    vposer = None
    if cfg.vposer_path:
        from pipeline.backends.smpl.vposer import load_vposer

        vposer = load_vposer(cfg.vposer_path)
    moments = _mesh_moments(body, betas0) if cfg.w_smooth > 0 else None
    soles = body.vertex_set(_sole_vertices(body))
    foot = torch.as_tensor(joint_idx(FOOT_JOINTS))
    dom = torch.as_tensor(
        np.where(
            body.kp_joint >= 0,
            body.kp_joint,
            body.keypoint_vertices.weights.numpy().argmax(1)[np.maximum(body.kp_vertex, 0)],
        )
    )

    root0 = torch.as_tensor(T0.reshape(n, 3)).clone()
    J_rows0 = torch.as_tensor(rest_J)[row_person]
    b_rows0 = betas0[row_person]
    with torch.no_grad():
        pose0 = _init_limbs(
            body, R0_t, torch.zeros(n, nb - 1, 3, dtype=torch.float64), root0, J_rows0, b_rows0, kp3d, w3d
        )
    timings["init_s"] = time.perf_counter() - t0

    lever = _lever_arms(body, rest_kp[0], rest_J[0] - rest_J[0, 0])
    s_rot = torch.as_tensor(lever)[None, :, None]
    s_root = float(np.sqrt(nj))
    s_const = float(np.sqrt(nf))
    s_beta = 0.15 * s_const
    delta_s = torch.zeros(n, 3, dtype=torch.float64, requires_grad=True)
    pose_s = (pose0 * s_rot[:, 1:]).requires_grad_(True)
    root_s = (root0 * s_root).requires_grad_(True)
    offsets_s = torch.zeros(npers, nj, 3, dtype=torch.float64, requires_grad=cfg.calibrate_landmarks)
    betas_s = (betas0 * s_beta).requires_grad_(cfg.refine_shape)
    params = [delta_s, pose_s, root_s]
    params += ([offsets_s] if cfg.calibrate_landmarks else []) + ([betas_s] if cfg.refine_shape else [])

    def state() -> tuple[torch.Tensor, ...]:
        """Physical-unit variables and the posed skeleton."""
        delta, pose, root = delta_s / s_rot[:, 0], pose_s / s_rot[:, 1:], root_s / s_root
        offsets, betas = offsets_s / s_const, betas_s / s_beta
        b_rows = betas[row_person]
        J = body.rest_joints(betas)[row_person]
        G_root = roma.rotvec_to_rotmat(delta) @ R0_t
        G, x, R_local = forward(body, J, G_root, pose, root)
        kp = keypoints(body, b_rows, J, G, x, R_local)
        if cfg.calibrate_landmarks:
            kp = kp + (G[:, dom] @ offsets[row_person][..., None])[..., 0]
        return pose, offsets, betas, b_rows, J, G_root, G, x, R_local, kp

    overlap = ProxyOverlap() if cfg.w_overlap > 0 and npers > 1 else None
    present_t = torch.as_tensor(present.T.copy())
    mesh_velocity = None
    if moments is not None:
        m_ = moments

        def mesh_velocity(dA: torch.Tensor) -> torch.Tensor:
            flat = dA.permute(0, 1, 3, 2, 4).reshape(npers, (nf - 1) * 3, nb * 4)
            return (flat @ m_).square().sum()

    def evaluate(
        use_2d: bool, accel_weights: torch.Tensor | None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor], torch.Tensor]:
        pose, offsets, betas, b_rows, J, G_root, G, x, R_local, kp = state()
        out = sequence_terms(
            cfg, kp, kp3d, w3d, P_t, uv, w2d, use_2d, pose, G_root, G, x, J, npers, nf, mesh_velocity, accel_weights
        )
        if cfg.calibrate_landmarks:
            out["landmarks"] = cfg.w_landmarks * offsets.square().sum()
        if cfg.refine_shape:
            out["shape"] = 1e-4 * betas.square().sum()
        out["limits"] = cfg.w_limits * joint_limit_penalty(pose, axes, lo, hi)
        if cfg.w_prior > 0 and gmm is not None:
            out["prior"] = cfg.w_prior * gmm(pose[:, :gmm_joints].reshape(n, -1))
        if cfg.w_prior > 0 and vposer is not None:
            out["vposer"] = cfg.w_prior * vposer(pose[:, :21])
        if cfg.w_ground > 0:
            sole_z = skin(soles, b_rows, J, G, x, R_local)[..., 2]
            out["ground"] = cfg.w_ground * ground_term(kp, foot, sole_z)
        if overlap is not None:
            out["overlap"] = cfg.w_overlap * overlap(kp.reshape(npers, nf, -1, 3), present_t)
        return sum(out.values()), out, kp  # type: ignore[return-value]

    accel_w = run_pose_passes(params, evaluate, cfg, npers, nf)
    timings["pose_s"] = time.perf_counter() - t0
    timings["pose_cpu_s"] = time.process_time() - c0

    with torch.no_grad():
        total, parts, _ = evaluate(cfg.use_2d, accel_w)
        pose, _, betas, _, _, G_root, _, _, _, kp = state()
        full = torch.cat([roma.rotmat_to_rotvec(G_root)[:, None], pose], dim=1)
        root = root_s / s_root
        d = (kp - kp3d).norm(dim=-1).reshape(npers, nf, -1)
        w = w3d.reshape(npers, nf, -1)
        per_person = ((d * w).sum(dim=(1, 2)) / w.sum(dim=(1, 2)).clamp(min=1e-9)).numpy()
    terms = {k: float(v) for k, v in parts.items()}
    logger.info(
        "%s fit: %d persons x %d frames, loss %.4g %s, %s", body.rig, npers, nf, float(total), terms, timings
    )
    return SmplFitOutput(
        joint_names=body.joint_names,
        rig=body.rig,
        shape=betas.numpy().copy(),
        pose_aa=full.reshape(npers, nf, nb, 3).permute(1, 0, 2, 3).numpy().copy(),
        root_m=root.reshape(npers, nf, 3).permute(1, 0, 2).numpy().copy(),
        keypoints_m=kp.reshape(npers, nf, nj, 3).permute(1, 0, 2, 3).numpy().copy(),
        present=present,
        loss=per_person,
        timings_s=timings,
        loss_terms=terms,
    )


def _init_limbs(
    body: SmplBody,
    G_root: torch.Tensor,
    pose: torch.Tensor,
    root: torch.Tensor,
    J: torch.Tensor,
    b_rows: torch.Tensor,
    kp3d: torch.Tensor,
    w3d: torch.Tensor,
) -> torch.Tensor:
    """Swing each ``IK_DRIVERS`` joint so its child keypoint points at the triangulated one;
    rows where that keypoint is unobserved keep their pose. Returns (n, joints - 1, 3)."""
    pose = pose.clone()
    for joint, child in IK_DRIVERS:
        b = body.joint_names.index(joint)
        k = COCO17_FEET.index(child)
        G, x, R_local = forward(body, J, G_root, pose, root)
        kp = keypoints(body, b_rows, J, G, x, R_local)
        R = min_rotation(kp[:, k] - x[:, b], kp3d[:, k] - x[:, b])
        local = G[:, body.parents[b]].transpose(-1, -2) @ R @ G[:, b]
        pose[:, b - 1] = torch.where((w3d[:, k] > 0)[:, None], roma.rotmat_to_rotvec(local), pose[:, b - 1])
    return pose
