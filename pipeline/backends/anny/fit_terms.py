"""Precomputed pieces of the anny fit's loss: mesh-moment factors, sole vertices, variable
scales and bone tails for the joint limits (used by ``anny.fit_body``)."""

from __future__ import annotations

import numpy as np
import torch

from pipeline.backends.anny.model import AnnyBody
from pipeline.backends.fitting.common import lbs_moment_factors


def mesh_moment_factors(body: AnnyBody, coeffs: torch.Tensor) -> torch.Tensor:
    """(persons, bones * 4, rank) factors of the skinning moments of each person's whole rest
    mesh at blendshape coefficients ``coeffs`` (persons, coeffs), for the smoothness term's
    vertex velocity (``fitting.common.lbs_moment_factors``; in ``body``'s dtype)."""
    w = body.model.dense_vertex_bone_weights
    return lbs_moment_factors([body.rest_vertices(c[None])[0] for c in coeffs], w)


def sole_vertices(body: AnnyBody, rest_verts: np.ndarray, per_foot: int = 24) -> np.ndarray:
    """Indices of up to ``per_foot`` vertices spread over each sole (the lowest 1.5 cm of the
    vertices whose dominant bone is a foot)."""
    out = []
    for name in ("foot.L", "foot.R"):
        cand = np.flatnonzero(body.vertex_bone == body.bone_names.index(name))
        z = rest_verts[cand, 2]
        sole = cand[z <= z.min() + 0.015]
        sole = sole[np.argsort(rest_verts[sole, 1])]  # heel to toe
        out.append(sole[np.linspace(0, len(sole) - 1, min(per_foot, len(sole))).astype(int)])
    return np.concatenate(out)


def lever_arms(body: AnnyBody, rest_kp: np.ndarray, heads: np.ndarray) -> np.ndarray:
    """(bones,) RMS distance from each bone's head to the keypoints it moves (>= 5 cm)."""
    nb = body.n_bones
    anc = np.eye(nb, dtype=bool)  # anc[c, b]: b is c or an ancestor of c
    for c in range(1, nb):
        anc[c] |= anc[body.bone_parent[c]]
    moved = (body.kp_w.numpy() > 1e-9).astype(float) @ anc.astype(float) > 0  # (joints, bones)
    out = np.full(nb, 0.05)
    for b in range(nb):
        k = np.flatnonzero(moved[:, b])
        if k.size:
            out[b] = max(0.05, float(np.sqrt((np.linalg.norm(rest_kp[k] - heads[b], axis=1) ** 2).sum())))
    return out


def rest_tails(body: AnnyBody, heads: np.ndarray, verts: np.ndarray) -> np.ndarray:
    """Bone tails for the joint-limit frames (same rule as ``RestMesh.bone_tail_m``)."""
    from pipeline.backends.anny.body import bone_tails

    return bone_tails(body, heads, verts, body.vertex_bone)
