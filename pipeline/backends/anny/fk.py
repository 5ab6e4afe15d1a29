"""Forward kinematics, folded keypoints and skinning of anny in torch (batched over frames).

Pose convention (cornerman's, not anny's ``local-ref``): each bone ``c`` has a rotation
``pose_aa[c]`` (axis-angle, radians) *relative to its parent*, expressed in the world-aligned
axes of the rest pose. Its world rotation (rest -> posed) is ``G_c = G_parent @ R(pose_aa[c])``
and its head follows the parent: ``x_c = x_p + G_p (h_c - h_p)``, ``h`` being the rest heads.
The root: ``G_0 = R(pose_aa[0])``, ``x_0 = root_translation_m`` (the world position of the
root bone's head, i.e. the pelvis centre). A vertex ``v`` is skinned by
``sum_b w_vb (G_b (v - h_b) + x_b)``. All-zero poses give the rest pose with its root head at
``root_translation_m``; rest-pose body frames are world-aligned, which maps one-to-one to a
MuJoCo body tree whose bodies have identity rest orientation.
"""

from __future__ import annotations

import roma
import torch

from pipeline.backends.anny.model import AnnyBody


def rotmat(pose_aa: torch.Tensor) -> torch.Tensor:
    """(..., 3) axis-angle -> (..., 3, 3) rotation matrices (finite gradients at zero)."""
    return roma.rotvec_to_rotmat(pose_aa)


def forward_kinematics(
    body: AnnyBody, pose_aa: torch.Tensor, root_m: torch.Tensor, heads: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """World rotations and head positions of every bone.

    Args:
        pose_aa: (n, bones, 3) parent-relative rotations (see module docstring).
        root_m: (n, 3) world position of the root head.
        heads: (n or 1, bones, 3) rest bone heads (``body.rest_heads``).
    Returns:
        G: (n, bones, 3, 3) rest->posed world rotations; x: (n, bones, 3) posed heads.
    """
    n, nb = pose_aa.shape[0], pose_aa.shape[1]
    R = rotmat(pose_aa)
    parent = torch.as_tensor(body.bone_parent)
    offs = heads - heads[:, parent.clamp(min=0)]  # (n|1, bones, 3); root's offset unused
    offs = offs.expand(n, nb, 3)
    G_levels: list[torch.Tensor] = [R[:, :1]]
    x_levels: list[torch.Tensor] = [root_m[:, None, :]]
    # slot of each bone inside the tensors of its level, to gather parents level by level
    slot = torch.zeros(nb, dtype=torch.long)
    for lev in body.levels:
        slot[lev] = torch.arange(len(lev))
    for li in range(1, len(body.levels)):
        lev = body.levels[li]
        ps = slot[parent[lev]]
        Gp = G_levels[li - 1][:, ps]
        xp = x_levels[li - 1][:, ps]
        G_levels.append(Gp @ R[:, lev])
        x_levels.append(xp + (Gp @ offs[:, lev, :, None])[..., 0])
    order = torch.cat(body.levels)
    inv = torch.argsort(order)
    G = torch.cat(G_levels, dim=1)[:, inv]
    x = torch.cat(x_levels, dim=1)[:, inv]
    return G, x


def keypoints_from_bones(
    body: AnnyBody, G: torch.Tensor, x: torch.Tensor, heads: torch.Tensor, kp_pts: torch.Tensor
) -> torch.Tensor:
    """Folded COCO(+feet) keypoints.

    Args:
        G, x: from :func:`forward_kinematics` (n, bones, ...).
        heads: (n|1, bones, 3) rest heads; kp_pts: (n|1, joints, bones, 3) from ``body.rest_kp_points``.
    Returns:
        (n, joints, 3) world keypoints, identical to regressing the skinned mesh.
    """
    rel = kp_pts - body.kp_w[None, :, :, None] * heads[:, None, :, :]  # (n|1, K, B, 3)
    rot = torch.einsum("nbij,nkbj->nki", G, rel.expand(G.shape[0], -1, -1, -1))
    return rot + torch.einsum("kb,nbd->nkd", body.kp_w, x)


class SparseKeypoints:
    """The folded keypoints restricted to the (keypoint, bone) pairs with non-zero weight.

    Each keypoint depends on a handful of bones (about 4 on average), so gathering those pairs
    is ~8x cheaper than the dense (joints x bones) contraction. Built for fixed shapes
    (one per person); ``__call__`` takes the per-row person index.
    """

    def __init__(
        self,
        body: AnnyBody,
        heads: torch.Tensor,
        kp_pts: torch.Tensor,
        eps: float = 1e-9,
        weights: torch.Tensor | None = None,
    ) -> None:
        """``weights`` (points, bones) replaces ``body.kp_w`` to fold other points (e.g. mesh
        vertices: their skinning weights, with ``kp_pts = w_vb v``)."""
        kp_w = body.kp_w if weights is None else weights
        k_idx, b_idx = torch.nonzero(kp_w > eps, as_tuple=True)
        self.k_idx, self.b_idx = k_idx, b_idx
        self.w = kp_w[k_idx, b_idx]  # (pairs,)
        self.kp_w = kp_w
        self.n_joints = kp_w.shape[0]
        self.set_shape(heads, kp_pts)

    def set_shape(self, heads: torch.Tensor, kp_pts: torch.Tensor) -> None:
        """(persons, B, 3) rest heads and (persons, K, B, 3) folded points (may carry gradients)."""
        rel = kp_pts - self.kp_w[None, :, :, None] * heads[:, None, :, :]  # (persons, K, B, 3)
        self.rel = rel[:, self.k_idx, self.b_idx]  # (persons, pairs, 3)

    def __call__(self, G: torch.Tensor, x: torch.Tensor, row_person: torch.Tensor) -> torch.Tensor:
        """G (n, bones, 3, 3), x (n, bones, 3), row_person (n,) -> (n, joints, 3)."""
        rel = self.rel[row_person]  # (n, pairs, 3)
        contrib = (G[:, self.b_idx] @ rel[..., None])[..., 0] + self.w[None, :, None] * x[:, self.b_idx]
        out = contrib.new_zeros((G.shape[0], self.n_joints, 3))
        return out.index_add(1, self.k_idx, contrib)


def skin_vertices(
    body: AnnyBody,
    G: torch.Tensor,
    x: torch.Tensor,
    heads: torch.Tensor,
    rest_verts: torch.Tensor,
    vertex_idx: torch.Tensor | None = None,
) -> torch.Tensor:
    """(n, verts, 3) skinned mesh (linear blend skinning; costly: use for display).

    ``vertex_idx`` selects a subset: ``rest_verts`` then holds only those vertices."""
    w = body.model.dense_vertex_bone_weights  # (verts, bones)
    if vertex_idx is not None:
        w = w[vertex_idx]
    t = x - (G @ heads.expand(G.shape[0], -1, -1)[..., None])[..., 0]  # (n, bones, 3)
    A = torch.einsum("vb,nbij->nvij", w, G)
    tv = torch.einsum("vb,nbi->nvi", w, t)
    return (A @ rest_verts.expand(G.shape[0], -1, -1)[..., None])[..., 0] + tv


def body_keypoints(
    body: AnnyBody, shape: torch.Tensor, pose_aa: torch.Tensor, root_m: torch.Tensor
) -> torch.Tensor:
    """Convenience: (6,) shape, (n, bones, 3) pose, (n, 3) root -> (n, joints, 3) keypoints."""
    coeffs = body.shape_coeffs(shape[None])
    heads = body.rest_heads(coeffs)
    G, x = forward_kinematics(body, pose_aa, root_m, heads)
    return keypoints_from_bones(body, G, x, heads, body.rest_kp_points(coeffs))
