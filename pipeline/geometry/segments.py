"""Closest points between 3D segments, and body points named on a skeleton (pure numpy).

Capsule body proxies (the evaluation's ``CapsuleProxy``, the fit's overlap term, the
synthetic bout's separation) are segments between points of a keypoint set plus a
radius; two capsules overlap by ``r_a + r_b - distance`` between their segments.
"""

from __future__ import annotations

import numpy as np


def point_weights(name: str, joint_names: tuple[str, ...]) -> tuple[list[int], list[float]]:
    """Joint indices and weights of a named body point: the point is the weighted sum of
    those joints.

    A point is a joint name, ``"mid:a+b"`` (the midpoint of two joints) or
    ``"frac:a,b,t"`` (``a + t (b - a)``; ``t`` may lie outside [0, 1], e.g. past the
    wrist). Raises ``ValueError`` for a malformed point or unknown joint."""
    try:
        if name.startswith("mid:"):
            a, b = name[4:].split("+")
            return [joint_names.index(a), joint_names.index(b)], [0.5, 0.5]
        if name.startswith("frac:"):
            a, b, t = name[5:].split(",")
            tf = float(t)
            return [joint_names.index(a), joint_names.index(b)], [1.0 - tf, tf]
        return [joint_names.index(name)], [1.0]
    except ValueError as e:
        raise ValueError(f"capsule point {name!r}: {e} (joints: {list(joint_names)})") from e


def segment_closest_params(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Parameters (s, t) in [0, 1] of the closest points ``p0 + s (p1 - p0)`` and
    ``q0 + t (q1 - q0)`` of two segments (broadcast over leading dims)."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.sum(d1 * d1, -1)
    e = np.sum(d2 * d2, -1)
    f = np.sum(d2 * r, -1)
    c = np.sum(d1 * r, -1)
    b = np.sum(d1 * d2, -1)
    eps = 1e-12
    a_s, e_s = np.maximum(a, eps), np.maximum(e, eps)
    denom = a * e - b * b
    # Ericson, Real-Time Collision Detection §5.1.9, vectorised.
    s = np.where(denom > eps * np.maximum(a * e, eps), np.clip((b * f - c * e) / np.maximum(denom, eps), 0.0, 1.0), 0.0)
    s = np.where(e <= eps, np.clip(-c / a_s, 0.0, 1.0), s)
    t = np.where(e > eps, (b * s + f) / e_s, 0.0)
    s = np.where(t < 0.0, np.clip(-c / a_s, 0.0, 1.0), s)
    s = np.where(t > 1.0, np.clip((b - c) / a_s, 0.0, 1.0), s)
    t_c = np.clip(t, 0.0, 1.0)
    s = np.where(a <= eps, 0.0, s)
    t_c = np.where(a <= eps, np.where(e > eps, np.clip(f / e_s, 0.0, 1.0), 0.0), t_c)
    return s, t_c


def segment_distance(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Closest distance between segments [p0, p1] and [q0, q1] (broadcast over leading dims)."""
    s, t = segment_closest_params(p0, p1, q0, q1)
    cp = p0 + (p1 - p0) * s[..., None]
    cq = q0 + (q1 - q0) * t[..., None]
    return np.linalg.norm(cp - cq, axis=-1)
