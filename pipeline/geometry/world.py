"""The downstream world against the calibration's: rigid transforms of a rig's world, and
the angles that describe them (``pipeline.geometry.level`` turns the world, ``floor`` lowers
it; ``calibrate/world.json`` stores the result)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pipeline.schema.camera import CameraRig


def rigid(R: np.ndarray | None = None, t: Sequence[float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """The 4x4 rigid transform ``x -> R x + t`` (R: 3x3 rotation, identity when None; t in m)."""
    W = np.eye(4)
    if R is not None:
        W[:3, :3] = R
    W[:3, 3] = t
    return W


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (deg, 0-180) between two 3-vectors."""
    c = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _turns_deg(R: np.ndarray) -> np.ndarray:
    """Angle (deg, 0-180) of each rotation of a stack (..., 3, 3)."""
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def turn_deg(R: np.ndarray) -> float:
    """Angle (deg, 0-180) of the rotation ``R`` (3, 3)."""
    return float(_turns_deg(R))


def turns_between_deg(R0: np.ndarray, R1: np.ndarray) -> np.ndarray:
    """Angle (deg, 0-180) of the rotation from each of ``R0`` to the matching one of ``R1``,
    both (n, 3, 3)."""
    return _turns_deg(np.swapaxes(R0, -1, -2) @ R1)


def rotation_to_z(n: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) taking the unit vector ``n`` to +z (a half turn about x
    when ``n`` points down)."""
    n = np.asarray(n, float) / np.linalg.norm(n)
    axis = np.cross(n, [0.0, 0.0, 1.0])
    s, c = float(np.linalg.norm(axis)), float(n[2])
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = axis / s
    Kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + s * Kx + (1.0 - c) * (Kx @ Kx)


def transform_world(rig: CameraRig, world_from_input: np.ndarray) -> CameraRig:
    """``rig`` in a new world: a point ``x`` of the old world is at ``world_from_input @ x``
    (4x4 rigid) in the new one; the pixels do not change."""
    W = np.asarray(world_from_input, float)
    if np.array_equal(W, np.eye(4)):
        return rig
    T = np.einsum("ij,vjk->vik", W, rig.T_world_cam)
    return CameraRig(rig.names, rig.K, rig.dist, T, rig.image_size_wh, rig.fps, rig.time_offset_s)


def lower_world(rig: CameraRig, shift_m: float) -> CameraRig:
    """``rig`` in a world lowered by ``shift_m`` (m): a point at height ``z`` is at ``z - shift_m``."""
    return transform_world(rig, rigid(t=(0.0, 0.0, -shift_m)))
