"""Ground-truth anny motion for tests and benchmarks (known shape and pose -> keypoints).

The motion is smooth and stays inside the joint-limit ranges: every bone oscillates around
the middle of its range in its local (flexion, twist, abduction) frame; the root walks a
small circle while turning. Keypoints come from the same folded model the fit uses, so a
noise-free fit can recover them exactly.

Needs torch and anny; they are imported when a motion is made, so that importing
``pipeline.synthetic`` stays light.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from pipeline.backends.anny.model import AnnyBody


@dataclass(frozen=True)
class AnnyMotion:
    """Known parameters of one person and their keypoints.

    shape (6,); pose_aa (frames, bones, 3) (cornerman convention); root_m (frames, 3);
    keypoints_m (frames, 23, 3) in ``COCO17_FEET`` order.
    """

    shape: np.ndarray
    pose_aa: np.ndarray
    root_m: np.ndarray
    keypoints_m: np.ndarray


def make_anny_motion(
    n_frames: int,
    fps: float = 50.0,
    seed: int = 0,
    centre_m: tuple[float, float] = (0.0, 0.0),
    body: AnnyBody | None = None,
) -> AnnyMotion:
    """A smooth, plausible random motion of a random adult shape."""
    import torch

    from pipeline.backends.anny.body import bone_tails
    from pipeline.backends.anny.fk import forward_kinematics, keypoints_from_bones
    from pipeline.backends.anny.model import anny_body
    from pipeline.backends.anny.priors import joint_limit_tables

    body = body or anny_body()
    rng = np.random.default_rng(seed)
    shape = np.array(
        [
            rng.uniform(0.2, 0.9),
            rng.uniform(0.35, 0.6),
            rng.uniform(0.3, 0.8),
            rng.uniform(0.3, 0.7),
            rng.uniform(0.3, 0.8),
            rng.uniform(0.3, 0.7),
        ]
    )
    with torch.no_grad():
        coeffs = body.shape_coeffs(torch.as_tensor(shape)[None])
        heads = body.rest_heads(coeffs)
        kpts = body.rest_kp_points(coeffs)
        verts = body.rest_vertices(coeffs)[0].numpy()
    h0 = heads[0].numpy()
    frames, lo, hi = joint_limit_tables(body.bone_names, h0, bone_tails(body, h0, verts, body.vertex_bone))
    t = np.arange(n_frames) / fps
    nb = body.n_bones
    local = np.zeros((n_frames, nb, 3))
    for b in range(1, nb):
        for k in range(3):
            lo_k, hi_k = max(lo[b, k], -1.5), min(hi[b, k], 1.5)
            mid = float(np.clip((lo_k + hi_k) / 2, -0.4, 0.6))
            amp = 0.35 * min(hi_k - mid, mid - lo_k)
            w = 2 * np.pi * rng.uniform(0.3, 1.5)
            local[:, b, k] = mid + amp * np.sin(w * t + rng.uniform(0, 2 * np.pi))
    pose = np.einsum("bji,fbj->fbi", frames, local)  # local -> world-aligned rotation vectors
    yaw = rng.uniform(-np.pi, np.pi) + 0.8 * np.sin(2 * np.pi * 0.2 * t)
    pose[:, 0] = 0.0
    pose[:, 0, 2] = yaw
    ground = -verts[:, 2].min()
    root = np.stack(
        [
            centre_m[0] + 0.3 * np.sin(2 * np.pi * 0.15 * t),
            centre_m[1] + 0.3 * np.cos(2 * np.pi * 0.15 * t),
            np.full(n_frames, h0[0, 2] + ground - 0.03) + 0.02 * np.sin(2 * np.pi * 1.1 * t),
        ],
        axis=1,
    )
    with torch.no_grad():
        G, x = forward_kinematics(body, torch.as_tensor(pose), torch.as_tensor(root), heads)
        kp = keypoints_from_bones(body, G, x, heads, kpts).numpy()
    lift = max(0.0, 0.01 - float(kp[:, 15:, 2].min()))  # ankles, toes and heels stay above ground
    root[:, 2] += lift
    kp[..., 2] += lift
    return AnnyMotion(shape=shape, pose_aa=pose, root_m=root, keypoints_m=kp)
