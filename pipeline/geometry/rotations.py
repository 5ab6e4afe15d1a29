"""Rotation conversions (pure numpy, batched over leading dimensions)."""

from __future__ import annotations

import numpy as np


def R_from_rodrigues(rvec: np.ndarray) -> np.ndarray:
    """(..., 3) axis-angle -> (..., 3, 3) rotation matrices (Rodrigues' formula)."""
    rvec = np.asarray(rvec, dtype=np.float64)
    theta = np.linalg.norm(rvec, axis=-1, keepdims=True)
    small = theta < 1e-12
    axis = rvec / np.where(small, 1.0, theta)
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    zero = np.zeros_like(x)
    Kx = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(rvec.shape[:-1] + (3, 3))
    th = theta[..., None]
    R = np.eye(3) + np.sin(th) * Kx + (1 - np.cos(th)) * (Kx @ Kx)
    return np.where(small[..., None], np.eye(3), R)


def rodrigues_from_R(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 3) axis-angle (robust near 0 and pi)."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=np.float64)
    flat = R.reshape(-1, 3, 3)
    out = Rotation.from_matrix(flat).as_rotvec()
    return out.reshape(R.shape[:-2] + (3,))


def look_at_T_world_cam(eye_m: np.ndarray, target_m: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """4x4 camera-to-world transform of an OpenCV camera at ``eye`` looking at ``target`` (z-up world)."""
    up = np.array([0.0, 0.0, 1.0]) if up is None else up
    z = target_m - eye_m
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: viewing direction is parallel to 'up'")
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = eye_m
    return T
