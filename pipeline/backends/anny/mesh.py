"""anny's rest mesh with its skinning weights, for exporters that skin it themselves (glTF).

The mesh is in the rest frame of ``skeleton.AnnySkeleton`` (anny's A-pose of the shape,
z-up metres, soles at z = 0). anny poses it by pure linear blend skinning of these vertices
with the per-bone maps of ``skeleton.BonePoses`` (no pose-dependent correctives): a vertex
``v`` lands at ``sum_b w_vb (R_world_bone[b] @ (v - rest_head_m[b]) + head_world_m[b])``.

anny gives up to 9 bones per vertex (about 11 % of the vertices have more than 4), so keeping
only the top 4 weights moves some vertices by up to ~25 mm; 8 influences reproduce anny's
posed mesh to well under 0.1 mm.

The decimated mesh is anny's shipped ``notoes_collapse10pc`` topology (1,229 vertices,
~2,450 triangles) with each vertex snapped to the nearest vertex of the full mesh (within
~5 mm on average, 20 mm at most), so every decimated vertex *is* a full-mesh vertex: same
rest position, same weights, same posed position.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from pipeline.backends.anny.body import decimation_map, rest_mesh
from pipeline.backends.anny.model import DEFAULT_RIG, DEFAULT_TOPOLOGY, anny_body

MAX_INFLUENCES = 9
"""Most bones any vertex of anny's default rig is skinned to."""


@dataclass(frozen=True)
class SkinnedRestMesh:
    """One shape's rest mesh with sparse skinning weights.

    Fields:
        verts_m: (verts, 3) rest vertices, rest frame (z-up metres, soles at z = 0).
        faces: (faces, 3) int64 triangles, counter-clockwise seen from outside.
        source_vertex: (verts,) index of each vertex in anny's full mesh (identity for the full mesh).
        joints: (verts, influences) int64 bone indices, by decreasing weight.
        weights: (verts, influences) float64 weights, each row summing to 1 (zeros pad).
        dropped_weight: largest weight mass a vertex lost to the influence limit, in [0, 1)
            (0 when every weight is kept); the rest are renormalised.
    """

    verts_m: np.ndarray
    faces: np.ndarray
    source_vertex: np.ndarray
    joints: np.ndarray
    weights: np.ndarray
    dropped_weight: float


@lru_cache(maxsize=2)
def decimated_vertices(rig: str = DEFAULT_RIG) -> tuple[np.ndarray, np.ndarray]:
    """anny's 10 % decimated topology on full-mesh vertices.

    Returns ``faces`` (faces, 3) int64 triangles indexing ``source_vertex``, and
    ``source_vertex`` (verts,) int64 full-mesh index each decimated vertex snapped to."""
    faces, tri, bary = decimation_map(rig)
    tv = anny_body(rig, DEFAULT_TOPOLOGY).model.template_vertices.numpy()
    q = np.einsum("vkd,vk->vd", tv[tri], bary)
    nearest = np.linalg.norm(tv[tri] - q[:, None], axis=2).argmin(axis=1)
    return faces.copy(), tri[np.arange(len(tri)), nearest].astype(np.int64)


def skinned_rest_mesh(
    shape: np.ndarray | None, rig: str = DEFAULT_RIG, decimate: bool = True, influences: int = 8
) -> SkinnedRestMesh:
    """The rest mesh of ``shape`` (6 anny phenotypes in [0, 1]; None = average) with its
    ``influences`` (1..9) largest skinning weights per vertex, renormalised.

    ``decimate`` picks the 1,229-vertex mesh (module docstring) or the full 13,718-vertex one.
    ``ValueError`` for an out-of-range shape, an unknown rig or ``influences`` outside 1..9."""
    if not 1 <= influences <= MAX_INFLUENCES:
        raise ValueError(f"skinned_rest_mesh: influences must be in 1..{MAX_INFLUENCES}, got {influences}")
    rest = rest_mesh(shape, rig=rig)
    w_all = anny_body(rig, DEFAULT_TOPOLOGY).model.dense_vertex_bone_weights.numpy()
    if decimate:
        faces, src = decimated_vertices(rig)
    else:
        faces, src = rest.faces, np.arange(len(rest.verts_m), dtype=np.int64)
    w = w_all[src]
    joints = np.argsort(-w, axis=1, kind="stable")[:, :influences]
    kept = np.take_along_axis(w, joints, axis=1)
    total = kept.sum(axis=1, keepdims=True)
    return SkinnedRestMesh(
        verts_m=rest.verts_m[src],
        faces=faces.astype(np.int64),
        source_vertex=src,
        joints=joints.astype(np.int64),
        weights=kept / total,
        dropped_weight=float(np.max(1.0 - total[:, 0] / w.sum(axis=1))),
    )
