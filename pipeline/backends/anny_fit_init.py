"""Initialisation of the anny fit: shape from limb lengths, roots by Kabsch, limbs by swing IK.

Also the shared pieces of the fit: the per-person observations and the L-BFGS driver.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import roma
import torch

from pipeline.backends.anny_fk import SparseKeypoints, forward_kinematics, keypoints_from_bones
from pipeline.backends.anny_model import AnnyBody
from pipeline.schema.joints import BODY_LIMBS, COCO17_FEET
from pipeline.stages.fit_config import FitConfig

# (driver bone, child keypoint): the bone is swung so that the keypoint points at its target.
IK_DRIVERS: tuple[tuple[str, str], ...] = (
    ("upperleg01.L", "left_knee"),
    ("upperleg01.R", "right_knee"),
    ("lowerleg01.L", "left_ankle"),
    ("lowerleg01.R", "right_ankle"),
    ("foot.L", "left_big_toe"),
    ("foot.R", "right_big_toe"),
    ("upperarm01.L", "left_elbow"),
    ("upperarm01.R", "right_elbow"),
    ("lowerarm01.L", "left_wrist"),
    ("lowerarm01.R", "right_wrist"),
)


# Limbs whose length is (nearly) pose independent, used for the shape initialisation.
SHAPE_LIMBS: tuple[tuple[str, str], ...] = BODY_LIMBS + (
    ("left_ankle", "left_heel"),
    ("right_ankle", "right_heel"),
    ("left_heel", "left_big_toe"),
    ("right_heel", "right_big_toe"),
)
_EVALS_PER_ITER = 1.25
TORSO: tuple[str, ...] = ("left_shoulder", "right_shoulder", "left_hip", "right_hip")


@dataclass(frozen=True)
class PersonObservations:
    """One person's inputs, in ``COCO17_FEET`` order.

    Fields:
        kp3d_m: (frames, joints, 3) triangulated joints (anything where ``w3d == 0``).
        w3d: (frames, joints) confidence weights, 0 where invalid.
        uv_px: (views, frames, joints, 2) *undistorted* 2D keypoints.
        w2d: (views, frames, joints) confidence weights, 0 where invalid or below threshold.
    """

    kp3d_m: np.ndarray
    w3d: np.ndarray
    uv_px: np.ndarray
    w2d: np.ndarray


def joint_idx(names: tuple[str, ...]) -> list[int]:
    return [COCO17_FEET.index(n) for n in names]


def run_lbfgs(params: list[torch.Tensor], closure, iters: int, cfg: FitConfig) -> None:  # noqa: ANN001
    if iters <= 0:
        return
    opt = torch.optim.LBFGS(
        params,
        lr=cfg.lbfgs_lr,
        max_iter=iters,
        max_eval=int(iters * _EVALS_PER_ITER) + 5,
        history_size=cfg.lbfgs_history,
        line_search_fn="strong_wolfe",
        tolerance_grad=1e-10,
        tolerance_change=1e-14,
    )

    def _closure() -> torch.Tensor:
        opt.zero_grad()
        loss = closure()
        loss.backward()
        return loss

    opt.step(_closure)


def _observed_lengths(obs: PersonObservations) -> tuple[np.ndarray, np.ndarray]:
    """Median length (m) and a weight per ``SHAPE_LIMBS`` limb (0 when never observed)."""
    lengths, weights = [], []
    for a, b in SHAPE_LIMBS:
        ia, ib = COCO17_FEET.index(a), COCO17_FEET.index(b)
        ok = (obs.w3d[:, ia] > 0) & (obs.w3d[:, ib] > 0)
        if ok.sum() < 3:
            lengths.append(0.0)
            weights.append(0.0)
            continue
        d = np.linalg.norm(obs.kp3d_m[ok, ia] - obs.kp3d_m[ok, ib], axis=-1)
        lengths.append(float(np.median(d)))
        weights.append(float(np.sqrt(obs.w3d[ok, ia] * obs.w3d[ok, ib]).mean()))
    return np.array(lengths), np.array(weights)


def fit_shapes(body: AnnyBody, observations: list[PersonObservations], cfg: FitConfig) -> torch.Tensor:
    """(persons, 6) phenotypes minimising the limb-length differences to the observations."""
    lengths, weights = zip(*(_observed_lengths(o) for o in observations), strict=True)
    L = torch.as_tensor(np.stack(lengths))
    W = torch.as_tensor(np.stack(weights))
    ia = torch.as_tensor(joint_idx(tuple(a for a, _ in SHAPE_LIMBS)))
    ib = torch.as_tensor(joint_idx(tuple(b for _, b in SHAPE_LIMBS)))
    u = torch.zeros(len(observations), 6, dtype=torch.float64, requires_grad=True)
    eye = torch.eye(3, dtype=torch.float64)

    def rest_keypoints(shape: torch.Tensor) -> torch.Tensor:
        coeffs = body.shape_coeffs(shape)
        heads = body.rest_heads(coeffs)
        n = shape.shape[0]
        G = eye.expand(n, body.n_bones, 3, 3)
        return keypoints_from_bones(body, G, heads, heads, body.rest_kp_points(coeffs))

    def closure() -> torch.Tensor:
        shape = torch.sigmoid(u)
        kp = rest_keypoints(shape)
        model_len = (kp[:, ia] - kp[:, ib]).norm(dim=-1)
        return (W * (model_len - L).square()).sum() + 1e-4 * (shape - 0.5).square().sum()

    run_lbfgs([u], closure, cfg.shape_iters, cfg)
    return torch.sigmoid(u).detach()


def _kabsch(X: np.ndarray, Y: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R, t minimising sum w |R X + t - Y|^2 (X, Y: (n, 3))."""
    wn = w / w.sum()
    mx, my = wn @ X, wn @ Y
    H = ((X - mx) * wn[:, None]).T @ (Y - my)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, my - R @ mx


def init_roots(rest_kp: np.ndarray, obs: PersonObservations) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-frame root rotation (frames, 3, 3) and position (frames, 3) from the torso; and the
    frames where the torso (3+ of shoulders/hips) was seen. ``rest_kp``: zero-pose keypoints
    with the root head at the origin."""
    nf = obs.kp3d_m.shape[0]
    t_idx = joint_idx(TORSO) + joint_idx(("nose", "left_ear", "right_ear"))
    R = np.tile(np.eye(3), (nf, 1, 1))
    t = np.zeros((nf, 3))
    ok = np.zeros(nf, dtype=bool)
    for f in range(nf):
        w = obs.w3d[f, t_idx].copy()
        w[4:] *= 0.3
        if (w[:4] > 0).sum() >= 3:
            R[f], t[f] = _kabsch(rest_kp[t_idx], obs.kp3d_m[f, t_idx], w)
            ok[f] = True
    if not ok.any():
        return R, t, ok
    good = np.flatnonzero(ok)
    for f in np.flatnonzero(~ok).tolist():  # nearest seen frame
        g = int(good[np.argmin(np.abs(good - f))])
        R[f], t[f] = R[g], t[g]
    return R, t, ok


def _min_rotation(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(n, 3, 3) smallest rotations taking directions ``a`` to ``b`` (n, 3)."""
    a = a / a.norm(dim=-1, keepdim=True).clamp(min=1e-9)
    b = b / b.norm(dim=-1, keepdim=True).clamp(min=1e-9)
    axis = torch.linalg.cross(a, b)
    s = axis.norm(dim=-1, keepdim=True)
    c = (a * b).sum(-1, keepdim=True)
    angle = torch.atan2(s, c)
    return roma.rotvec_to_rotmat(axis / s.clamp(min=1e-9) * angle)


def init_limbs(
    body: AnnyBody,
    G_root: torch.Tensor,
    pose: torch.Tensor,
    root: torch.Tensor,
    heads: torch.Tensor,
    sparse_kp: SparseKeypoints,
    row_person: torch.Tensor,
    kp3d: torch.Tensor,
    w3d: torch.Tensor,
) -> torch.Tensor:
    """Swing each limb bone (``IK_DRIVERS``, in FK order) so its child keypoint points at the
    triangulated one; returns the updated (n, bones-1, 3) non-root pose. Rows without both the
    bone's parent keypoint side and the child keypoint keep their pose."""
    pose = pose.clone()
    parent = body.bone_parent
    for bone, child in IK_DRIVERS:
        b = body.bone_names.index(bone)
        k = COCO17_FEET.index(child)
        G, x = forward_kinematics_rootmat(body, G_root, pose, root, heads)
        kp = sparse_kp(G, x, row_person)
        ok = w3d[:, k] > 0
        R = _min_rotation(kp[:, k] - x[:, b], kp3d[:, k] - x[:, b])
        Gp = G[:, parent[b]]
        local = Gp.transpose(-1, -2) @ R @ G[:, b]
        new = roma.rotmat_to_rotvec(local)
        pose[:, b - 1] = torch.where(ok[:, None], new, pose[:, b - 1])
    return pose


def rotmat_rows(aa: torch.Tensor) -> torch.Tensor:
    return roma.rotvec_to_rotmat(aa)


def forward_kinematics_rootmat(
    body: AnnyBody, G_root: torch.Tensor, pose: torch.Tensor, root: torch.Tensor, heads: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """FK with the root's world rotation given as a matrix (non-root bones as axis-angle)."""
    zero = torch.zeros_like(pose[:, :1])
    G, x = forward_kinematics(body, torch.cat([zero, pose], dim=1), root, heads)
    # forward_kinematics composes every rotation on the root's; left-multiplying by G_root
    # and rotating the offsets about the root head gives the same result as using it directly.
    G = G_root[:, None] @ G
    x = root[:, None] + (G_root[:, None] @ (x - root[:, None])[..., None])[..., 0]
    return G, x
