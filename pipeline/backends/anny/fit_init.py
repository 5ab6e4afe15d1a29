"""Initialisation of the anny fit: shape from limb lengths, roots by Kabsch, limbs by swing IK.

The body-model-independent pieces (observations, L-BFGS driver, limb lengths, Kabsch root
initialisation) live in ``fitting.common`` and are re-exported here under their old names.
"""

from __future__ import annotations

import numpy as np
import roma
import torch

from pipeline.backends.anny.fk import SparseKeypoints, forward_kinematics, keypoints_from_bones
from pipeline.backends.anny.model import PHENOTYPE_LABELS, AnnyBody
from pipeline.backends.fitting.common import (
    SHAPE_LIMBS,
    TORSO,
    PersonObservations,
    init_roots,
    joint_idx,
    run_lbfgs,
)
from pipeline.backends.fitting.common import min_rotation as _min_rotation
from pipeline.backends.fitting.common import observed_lengths as _observed_lengths
from pipeline.backends.fitting.config import FitConfig
from pipeline.schema.joints import COCO17_FEET

__all__ = [
    "IK_DRIVERS",
    "SHAPE_LIMBS",
    "TORSO",
    "PersonObservations",
    "fit_shapes",
    "forward_kinematics_rootmat",
    "init_limbs",
    "init_roots",
    "joint_idx",
    "rotmat_rows",
    "run_lbfgs",
]

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


def fit_shapes(body: AnnyBody, observations: list[PersonObservations], cfg: FitConfig) -> torch.Tensor:
    """(persons, 6) phenotypes minimising the limb-length differences to the observations.

    Bone lengths say little about girth, so ``muscle`` and ``weight`` are held near
    ``cfg.girth_prior`` (weight ``cfg.girth_prior_weight``); the other phenotypes have a
    weak pull (1e-4) towards anny's average."""
    lengths, weights = zip(*(_observed_lengths(o) for o in observations), strict=True)
    L = torch.as_tensor(np.stack(lengths), dtype=body.dtype)
    W = torch.as_tensor(np.stack(weights), dtype=body.dtype)
    ia = torch.as_tensor(joint_idx(tuple(a for a, _ in SHAPE_LIMBS)))
    ib = torch.as_tensor(joint_idx(tuple(b for _, b in SHAPE_LIMBS)))
    u = torch.zeros(len(observations), 6, dtype=body.dtype, requires_grad=True)
    eye = torch.eye(3, dtype=body.dtype)
    centre = torch.full((6,), 0.5, dtype=body.dtype)
    prior_w = torch.full((6,), 1e-4, dtype=body.dtype)
    for label, value in zip(("muscle", "weight"), cfg.girth_prior, strict=True):
        centre[PHENOTYPE_LABELS.index(label)] = value
        prior_w[PHENOTYPE_LABELS.index(label)] = cfg.girth_prior_weight

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
        return (W * (model_len - L).square()).sum() + (prior_w * (shape - centre).square()).sum()

    run_lbfgs([u], closure, cfg.shape_iters, cfg)
    return torch.sigmoid(u).detach()


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
