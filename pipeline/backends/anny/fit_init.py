"""Initialisation of the anny fit: shape from limb lengths, the limbs' swing drivers, and FK
with the root's rotation as a matrix (used by ``fit_body.AnnyFitBody``).

The body-model-independent pieces (limb lengths, Kabsch root initialisation, the swing
initialisation itself: ``fitting.sequence.init_limbs``) live in ``fitting``.
"""

from __future__ import annotations

import numpy as np
import torch

from pipeline.backends.anny.fk import forward_kinematics, keypoints_from_bones
from pipeline.backends.anny.model import PHENOTYPE_LABELS, AnnyBody
from pipeline.backends.fitting.common import (
    SHAPE_LIMBS,
    PersonObservations,
    joint_idx,
    observed_lengths,
    run_lbfgs,
)
from pipeline.backends.fitting.config import FitConfig

__all__ = ["IK_DRIVERS", "fit_shapes", "forward_kinematics_rootmat"]

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
    lengths, weights = zip(*(observed_lengths(o) for o in observations), strict=True)
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
