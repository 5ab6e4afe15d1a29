"""Pinhole projection with OpenCV's 5-parameter lens distortion (pure numpy).

Failure modes: points behind a camera get ``depth <= 0`` (their pixels are
meaningless; callers mask them). Undistortion is iterative and converges for the
moderate distortion of real sport cameras (|k1| < ~0.5).
"""

from __future__ import annotations

import numpy as np

from pipeline.schema.camera import CameraRig


def world_to_cam(X_world_m: np.ndarray, T_cam_world: np.ndarray) -> np.ndarray:
    """(..., 3) world points -> (views, ..., 3) camera-frame points for (views, 4, 4) transforms."""
    R = T_cam_world[:, :3, :3]
    t = T_cam_world[:, :3, 3]
    flat = X_world_m.reshape(-1, 3)
    out = np.einsum("vij,nj->vni", R, flat) + t[:, None, :]
    return out.reshape((T_cam_world.shape[0],) + X_world_m.shape)


def distort_normalized(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Apply OpenCV distortion to normalised coords. xy: (views, ..., 2); dist: (views, 5)."""
    shape = xy.shape
    xy = xy.reshape(shape[0], -1, 2)
    k1, k2, p1, p2, k3 = (dist[:, i][:, None] for i in range(5))
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], axis=-1).reshape(shape)


def project(rig: CameraRig, X_world_m: np.ndarray, distort: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Project world points into every view.

    Args:
        X_world_m: (..., 3) points in the world frame.
        distort: apply lens distortion (True gives pixels of the real image).
    Returns:
        uv_px: (views, ..., 2) pixel coordinates.
        depth_m: (views, ...) z in the camera frame (<= 0: behind the camera).
    """
    Xc = world_to_cam(X_world_m, rig.T_cam_world)
    depth = Xc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = Xc[..., :2] / np.where(np.abs(depth) < 1e-9, 1e-9, depth)[..., None]
    if distort and np.any(rig.dist != 0):
        xy = distort_normalized(xy, rig.dist)
    fx = rig.K[:, 0, 0].reshape((-1,) + (1,) * (xy.ndim - 2))
    fy = rig.K[:, 1, 1].reshape(fx.shape)
    cx = rig.K[:, 0, 2].reshape(fx.shape)
    cy = rig.K[:, 1, 2].reshape(fx.shape)
    s = rig.K[:, 0, 1].reshape(fx.shape)
    u = fx * xy[..., 0] + s * xy[..., 1] + cx
    v = fy * xy[..., 1] + cy
    return np.stack([u, v], axis=-1), depth


def undistort_points(uv_px: np.ndarray, K: np.ndarray, dist: np.ndarray, iterations: int = 20) -> np.ndarray:
    """Remove lens distortion from pixels of one camera, returning *undistorted pixels*.

    uv_px: (..., 2); K: (3, 3); dist: (5,). Vectorised fixed-point iteration (the
    same scheme as ``cv2.undistortPoints``).
    """
    if not np.any(dist != 0):
        return uv_px.astype(np.float64, copy=True)
    shape = uv_px.shape
    uv = uv_px.reshape(-1, 2).astype(np.float64)
    fx, fy, cx, cy, s = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
    yd = (uv[:, 1] - cy) / fy
    xd = (uv[:, 0] - cx - s * yd) / fx
    k1, k2, p1, p2, k3 = dist
    x, y = xd.copy(), yd.copy()
    for _ in range(iterations):
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x = (xd - dx) / radial
        y = (yd - dy) / radial
    out = np.stack([fx * x + s * y + cx, fy * y + cy], axis=-1)
    return out.reshape(shape)


def undistort_rig_points(rig: CameraRig, uv_px: np.ndarray, view: np.ndarray) -> np.ndarray:
    """Undistort flat rows of pixels, each from the view given in ``view``.

    uv_px: (dets, joints, 2) or (dets, 2); view: (dets,) view indices.
    """
    out = np.empty_like(uv_px, dtype=np.float64)
    for v in np.unique(view):
        sel = view == v
        out[sel] = undistort_points(uv_px[sel], rig.K[v], rig.dist[v])
    return out
