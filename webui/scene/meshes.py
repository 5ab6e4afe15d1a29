"""Template triangle meshes of MuJoCo geom primitives (pure numpy)."""

from __future__ import annotations

import numpy as np


def _ring_strip_faces(n_rings: int, n_seg: int) -> np.ndarray:
    faces = []
    for r in range(n_rings - 1):
        for s in range(n_seg):
            a = r * n_seg + s
            b = r * n_seg + (s + 1) % n_seg
            c = (r + 1) * n_seg + s
            d = (r + 1) * n_seg + (s + 1) % n_seg
            faces += [[a, c, b], [b, c, d]]
    return np.asarray(faces, dtype=np.int64)


def capsule_mesh(radius: float, half_length: float, n_seg: int = 12, n_lat: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Capsule along local z (MuJoCo convention): (verts, 3) and (faces, 3), outward winding.

    ``half_length = 0`` gives a sphere.
    """
    rings = []
    for i in range(n_lat + 1):  # north pole -> equator, shifted up
        th = np.pi / 2 * i / n_lat
        rings.append((np.sin(th), np.cos(th) + half_length / max(radius, 1e-9)))
    for i in range(n_lat + 1):  # equator -> south pole, shifted down
        th = np.pi / 2 + np.pi / 2 * i / n_lat
        rings.append((np.sin(th), np.cos(th) - half_length / max(radius, 1e-9)))
    phi = 2 * np.pi * np.arange(n_seg) / n_seg
    verts = np.concatenate([np.stack([r * np.cos(phi), r * np.sin(phi), np.full(n_seg, z)], axis=1) for r, z in rings]) * radius
    return verts, _ring_strip_faces(len(rings), n_seg)


def cylinder_mesh(radius: float, half_length: float, n_seg: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Closed cylinder along local z."""
    rings = [(0.0, half_length), (radius, half_length), (radius, -half_length), (0.0, -half_length)]
    phi = 2 * np.pi * np.arange(n_seg) / n_seg
    verts = np.concatenate([np.stack([r * np.cos(phi), r * np.sin(phi), np.full(n_seg, z)], axis=1) for r, z in rings])
    return verts, _ring_strip_faces(len(rings), n_seg)


def box_mesh(half_extents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Box centred at the origin with the given half extents."""
    hx, hy, hz = (float(v) for v in half_extents[:3])
    verts = np.array([[x, y, z] for x in (-hx, hx) for y in (-hy, hy) for z in (-hz, hz)])
    faces = np.array(
        [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]],
        dtype=np.int64,
    )
    return verts, faces


def ellipsoid_mesh(radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    v, f = capsule_mesh(1.0, 0.0)
    return v * np.asarray(radii[:3], dtype=np.float64)[None, :], f


def merge_meshes(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate meshes, offsetting face indices."""
    if not parts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    verts, faces, off = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + off)
        off += v.shape[0]
    return np.concatenate(verts), np.concatenate(faces)
