"""Visibility of joints: rays from each camera centre to each joint tested against simple
body volumes (capsules around trunk halves, limbs and feet, a sphere for the head) of
every person, including the joint's own body (self-occlusion).

A joint never counts as hidden by a volume it lies inside (its own limb, a grip on the
opponent's back); the ray stops ``RAY_MARGIN_M`` short of the joint so surface landmarks
(face, shoulders) are hidden only by volumes in front of them.
"""

from __future__ import annotations

import numpy as np

from pipeline.synthetic.skeleton import BodyDims, J

RAY_MARGIN_M = 0.03


def capsules(joints: np.ndarray, body: BodyDims) -> tuple[np.ndarray, np.ndarray]:
    """Capsules of one person: ends (F, C, 2, 3) and radii (C,) (metres).

    Two trunk halves (hip side -> shoulder side), upper arms, forearms, thighs, shanks,
    feet and a head sphere (a capsule with equal ends) around the head centre.
    """
    j = joints
    mid_hip = 0.5 * (j[:, J["left_hip"]] + j[:, J["right_hip"]])
    neck = 0.5 * (j[:, J["left_shoulder"]] + j[:, J["right_shoulder"]])
    head = j[:, [J["left_ear"], J["right_ear"]]].mean(axis=1)
    nose_dir = j[:, J["nose"]] - head
    head_c = head + 0.04 * nose_dir  # the ear midpoint sits a little behind the sphere centre
    segs: list[tuple[np.ndarray, np.ndarray, float]] = []
    r_l = body.limb_radius_m
    for side in ("left", "right"):
        segs.append(
            (
                0.5 * (mid_hip + j[:, J[f"{side}_hip"]]),
                0.55 * neck + 0.45 * j[:, J[f"{side}_shoulder"]],
                body.torso_radius_m,
            )
        )
        segs.append((j[:, J[f"{side}_shoulder"]], j[:, J[f"{side}_elbow"]], 1.0 * r_l))
        segs.append((j[:, J[f"{side}_elbow"]], j[:, J[f"{side}_wrist"]], 0.9 * r_l))
        segs.append((j[:, J[f"{side}_hip"]], j[:, J[f"{side}_knee"]], 1.5 * r_l))
        segs.append((j[:, J[f"{side}_knee"]], j[:, J[f"{side}_ankle"]], 1.1 * r_l))
        toes = 0.5 * (j[:, J[f"{side}_big_toe"]] + j[:, J[f"{side}_small_toe"]])
        segs.append((j[:, J[f"{side}_ankle"]], 0.5 * (j[:, J[f"{side}_ankle"]] + toes), 0.8 * r_l))
    segs.append((head_c, head_c, body.head_radius_m))
    ends = np.stack([np.stack([a, b], axis=1) for a, b, _ in segs], axis=1)
    radii = np.array([r for _, _, r in segs])
    return ends, radii


def _point_segment_dist(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-12), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


def _segment_segment_dist(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Closest distance between segments [p1, q1] and [p2, q2] (broadcast over leading dims;
    Ericson, Real-Time Collision Detection 5.1.9; degenerate segments allowed)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = np.sum(d1 * d1, -1)
    e = np.sum(d2 * d2, -1)
    f = np.sum(d2 * r, -1)
    c = np.sum(d1 * r, -1)
    b = np.sum(d1 * d2, -1)
    denom = a * e - b * b
    a_safe = np.maximum(a, 1e-12)
    e_safe = np.maximum(e, 1e-12)
    s = np.where(denom > 1e-12, np.clip((b * f - c * e) / np.maximum(denom, 1e-12), 0.0, 1.0), 0.0)
    t = (b * s + f) / e_safe
    s = np.where(
        t < 0.0, np.clip(-c / a_safe, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a_safe, 0.0, 1.0), s)
    )
    t = np.clip(t, 0.0, 1.0)
    # Degenerate second segment (a sphere): closest point on the first to p2.
    s = np.where(e <= 1e-12, np.clip(-c / a_safe, 0.0, 1.0), s)
    t = np.where(e <= 1e-12, 0.0, t)
    diff = (p1 + s[..., None] * d1) - (p2 + t[..., None] * d2)
    return np.linalg.norm(diff, axis=-1)


def occluded(
    cam_centres_m: np.ndarray,
    joints_m: np.ndarray,
    caps_ends_m: np.ndarray,
    caps_radii_m: np.ndarray,
    chunk_pairs: int = 200_000,
) -> np.ndarray:
    """Which joints are hidden behind a body volume, per camera.

    Args:
        cam_centres_m: (V, 3) camera centres.
        joints_m: (F, N, 3) all joints of all persons (N = persons x joints).
        caps_ends_m: (F, C, 2, 3) capsule end points of all persons; caps_radii_m: (C,).
    Returns:
        (V, F, N) bool, True = the ray from the camera to the joint passes through a volume.
    """
    n_f, n_j = joints_m.shape[:2]
    # Volumes that contain the joint cannot hide it (per frame, all persons).
    inside = _point_segment_dist(
        joints_m[:, :, None, :], caps_ends_m[:, None, :, 0], caps_ends_m[:, None, :, 1]
    )
    excluded = inside < caps_radii_m + 0.005
    out = np.zeros((cam_centres_m.shape[0], n_f, n_j), dtype=bool)
    mid = 0.5 * (caps_ends_m[:, :, 0] + caps_ends_m[:, :, 1])  # (F, C, 3)
    bound = (
        0.5 * np.linalg.norm(caps_ends_m[:, :, 1] - caps_ends_m[:, :, 0], axis=-1) + caps_radii_m
    )  # (F, C)
    for v, c in enumerate(cam_centres_m):
        ray = joints_m - c
        dist_j = np.linalg.norm(ray, axis=-1)  # (F, N)
        end = joints_m - RAY_MARGIN_M * ray / np.maximum(dist_j, 1e-9)[..., None]
        to_mid = mid - c
        dist_c = np.linalg.norm(to_mid, axis=-1)  # (F, C)
        # Conservative cull: a capsule inside its bounding sphere can only hide joints whose
        # direction lies within the sphere's angular radius and which lie beyond its near side.
        cos_r = np.where(
            bound < dist_c, np.sqrt(np.clip(1.0 - (bound / np.maximum(dist_c, 1e-9)) ** 2, 0.0, 1.0)), -1.0
        )
        cos_a = np.einsum("fni,fci->fnc", ray, to_mid) / (dist_j[..., None] * dist_c[:, None, :])
        cand = (
            (cos_a >= cos_r[:, None, :] - 1e-9)
            & ((dist_c - bound)[:, None, :] < dist_j[..., None])
            & ~excluded
        )
        f_i, n_i, c_i = np.nonzero(cand)
        for k0 in range(0, f_i.size, chunk_pairs):
            sl = slice(k0, k0 + chunk_pairs)
            fi, ni, ci = f_i[sl], n_i[sl], c_i[sl]
            d = _segment_segment_dist(c[None, :], end[fi, ni], caps_ends_m[fi, ci, 0], caps_ends_m[fi, ci, 1])
            hit = d < caps_radii_m[ci]
            out[v, fi[hit], ni[hit]] = True
    return out
