"""Helpers shared by the calibration importers: checked arrays, rotations, rig building.

Every importer reads its format into per-camera ``K``, distortion, ``R_cam_world`` /
``t_cam_world_m`` (OpenCV camera frame, world -> camera, metres) and an image size,
then calls :func:`rig_from_extrinsics`. Errors are ``ValueError`` naming the file,
the camera and the offending value.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Mapping, Sequence

import numpy as np

from pipeline.schema.camera import CameraRig

log = logging.getLogger(__name__)

# A rotation read from a file may carry float32 rounding (Shelf: ~1e-6); beyond this
# orthogonality error the matrix is not a rotation and the file is rejected.
_MAX_ROTATION_ERROR = 1e-3


def as_float_array(where: str, key: str, value: object, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a finite float64 array reshaped to ``shape`` (same number of elements)."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: {key} is not numeric: {e}") from e
    if arr.size != int(np.prod(shape)):
        raise ValueError(
            f"{where}: {key} must have {int(np.prod(shape))} numbers (shape {shape}), got shape {arr.shape}"
        )
    arr = arr.reshape(shape)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{where}: {key} contains NaN/inf: {arr.tolist()}")
    return arr


def dist5(where: str, value: object) -> np.ndarray:
    """OpenCV distortion ``k1 k2 p1 p2 [k3 ...]`` -> 5-vector.

    4 or 5 coefficients are accepted; longer vectors (OpenCV's rational/thin-prism
    models) only if the extra coefficients are zero, since ``CameraRig`` keeps 5.
    """
    try:
        d = np.asarray(value, dtype=np.float64).ravel()
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: distortion is not numeric: {e}") from e
    if not np.all(np.isfinite(d)):
        raise ValueError(f"{where}: distortion contains NaN/inf: {d.tolist()}")
    if d.size < 4 or (d.size > 5 and np.any(d[5:] != 0)):
        raise ValueError(
            f"{where}: distortion must be 4 or 5 OpenCV coefficients (k1 k2 p1 p2 [k3]), got {d.tolist()}"
        )
    out = np.zeros(5)
    out[: min(5, d.size)] = d[:5]
    return out


def nearest_rotation(where: str, R: np.ndarray) -> np.ndarray:
    """Project a nearly orthonormal 3x3 matrix onto SO(3) (SVD).

    Files store rotations with a few digits (float32 in Shelf's JSON); the projection
    makes the rig exact so that Rodrigues round trips (TOML export) are lossless.
    Raises if the matrix is a reflection or far from a rotation.
    """
    err = float(np.abs(R @ R.T - np.eye(3)).max())
    if err > _MAX_ROTATION_ERROR or np.linalg.det(R) <= 0:
        raise ValueError(
            f"{where}: rotation is not a proper rotation matrix "
            f"(orthogonality error {err:.2e}, det {np.linalg.det(R):.4f}): {R.tolist()}"
        )
    U, _, Vt = np.linalg.svd(R)
    out = U @ Vt
    if np.linalg.det(out) < 0:  # pragma: no cover - excluded by the det check above
        U[:, -1] *= -1
        out = U @ Vt
    return out


def check_intrinsics(where: str, K: np.ndarray) -> np.ndarray:
    """K must be upper triangular with positive focal lengths and K[2] = [0, 0, 1]."""
    if not np.allclose(K[2], [0.0, 0.0, 1.0]) or abs(K[1, 0]) > 1e-9 or abs(K[2, 0]) > 1e-9:
        raise ValueError(f"{where}: K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"{where}: focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
    return K


def image_size(where: str, value: object) -> np.ndarray:
    """(w, h) -> int64 array; sizes must be positive and (nearly) integral."""
    wh = as_float_array(where, "image size", value, (2,))
    if np.any(wh <= 0) or np.any(np.abs(wh - np.round(wh)) > 1e-6):
        raise ValueError(f"{where}: image size must be two positive integers (w, h), got {wh.tolist()}")
    return np.round(wh).astype(np.int64)


def T_world_cam_from(R_cam_world: np.ndarray, t_cam_world_m: np.ndarray) -> np.ndarray:
    """4x4 camera-to-world transform from the world-to-camera rotation and translation."""
    T = np.eye(4)
    T[:3, :3] = R_cam_world.T
    T[:3, 3] = -R_cam_world.T @ t_cam_world_m
    return T


def rig_from_extrinsics(
    where: str,
    names: Sequence[str],
    K: Sequence[np.ndarray],
    dist: Sequence[np.ndarray],
    R_cam_world: Sequence[np.ndarray],
    t_cam_world_m: Sequence[np.ndarray],
    image_size_wh: Sequence[np.ndarray],
    fps: float,
) -> CameraRig:
    """Build a validated ``CameraRig``; rotations are projected onto SO(3) first."""
    if not names:
        raise ValueError(f"{where}: no cameras found")
    Ts = [
        T_world_cam_from(
            nearest_rotation(f"{where} [camera {n}]", np.asarray(R, dtype=np.float64)), np.asarray(t)
        )
        for n, R, t in zip(names, R_cam_world, t_cam_world_m, strict=True)
    ]
    try:
        return CameraRig(
            names=tuple(names),
            K=np.stack(K).astype(np.float64),
            dist=np.stack(dist).astype(np.float64),
            T_world_cam=np.stack(Ts),
            image_size_wh=np.stack(image_size_wh).astype(np.int64),
            fps=float(fps),
        )
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from e


def natural_key(s: str) -> list[int | str]:
    """Sort key putting ``cam2`` before ``cam10``."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", s)]


def with_fps(rig: CameraRig, fps: float) -> CameraRig:
    """The same rig with another frame rate."""
    return CameraRig(
        names=rig.names,
        K=rig.K,
        dist=rig.dist,
        T_world_cam=rig.T_world_cam,
        image_size_wh=rig.image_size_wh,
        fps=float(fps),
        time_offset_s=rig.time_offset_s,
    )


def _quarter_turn_cw(K: np.ndarray, dist: np.ndarray, T_world_cam: np.ndarray, wh: np.ndarray) -> tuple:
    """One 90-degree clockwise rotation of the image of one camera.

    A pixel (u, v) of the old image of width w and height h lands at (h - 1 - v, u).
    The new camera axes are x' = -y, y' = x (z unchanged), so fx' = fy, fy' = fx,
    cx' = h - 1 - cy, cy' = cx; radial distortion is unchanged and the tangential
    terms become p1' = p2, p2' = -p1 (derived from OpenCV's model).
    """
    if abs(K[0, 1]) > 1e-12:
        raise ValueError(f"cannot rotate a camera with skew {K[0, 1]}")
    w, h = int(wh[0]), int(wh[1])
    K2 = np.array([[K[1, 1], 0.0, h - 1 - K[1, 2]], [0.0, K[0, 0], K[0, 2]], [0.0, 0.0, 1.0]])
    d2 = dist.copy()
    d2[2], d2[3] = dist[3], -dist[2]
    # Columns: the new camera axes in the old camera frame.
    R_old_new = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    T2 = T_world_cam.copy()
    T2[:3, :3] = T_world_cam[:3, :3] @ R_old_new
    return K2, d2, T2, np.array([h, w], dtype=np.int64)


def rotate_images_cw(rig: CameraRig, quarter_turns: Mapping[str, int]) -> CameraRig:
    """The rig whose camera ``name`` sees its image rotated clockwise by ``90 * k`` degrees.

    Use it when the video frames are the sensor image rotated (portrait recordings of
    a landscape sensor). ``quarter_turns`` maps camera names to ``k`` (any integer;
    taken modulo 4). Raises ``ValueError`` for unknown cameras.
    """
    K, dist, T, wh = rig.K.copy(), rig.dist.copy(), rig.T_world_cam.copy(), rig.image_size_wh.copy()
    for name, k in quarter_turns.items():
        v = rig.index(name)
        for _ in range(int(k) % 4):
            K[v], dist[v], T[v], wh[v] = _quarter_turn_cw(K[v], dist[v], T[v], wh[v])
    return CameraRig(
        names=rig.names,
        K=K,
        dist=dist,
        T_world_cam=T,
        image_size_wh=wh,
        fps=rig.fps,
        time_offset_s=rig.time_offset_s.copy(),
    )
