"""Epipolar geometry from a calibrated rig (pure numpy).

Conventions: ``F[i, j]`` maps an *undistorted* pixel ``x_i`` of view ``i`` (homogeneous)
to its epipolar line ``l_j = F[i, j] @ x_i`` in view ``j``, so ``x_j^T F[i, j] x_i = 0``
for a true correspondence; ``F[j, i] = F[i, j]^T``. Distances are in undistorted pixels:
undistort detections first (``pipeline.geometry.undistort_points``).

Failure modes: ``F[i, i]`` is all zeros (no epipolar constraint within a view), and the
fundamental matrix of two cameras with the same centre is zero as well; points at the
epipoles give zero-length lines whose distance is reported as ``inf``.
"""

from __future__ import annotations

import numpy as np

from pipeline.schema.camera import CameraRig


def skew(t: np.ndarray) -> np.ndarray:
    """(..., 3) vectors -> (..., 3, 3) cross-product matrices ``[t]_x``."""
    t = np.asarray(t, dtype=np.float64)
    z = np.zeros(t.shape[:-1])
    return np.stack(
        [z, -t[..., 2], t[..., 1], t[..., 2], z, -t[..., 0], -t[..., 1], t[..., 0], z], axis=-1
    ).reshape(t.shape[:-1] + (3, 3))


def fundamental_matrices(rig: CameraRig) -> np.ndarray:
    """(views, views, 3, 3) fundamental matrices ``F[i, j]`` (view i pixels -> view j lines).

    Derived from the calibration: with world-to-camera ``(R_i, t_i)``, the relative pose
    is ``R_ji = R_j R_i^T``, ``t_ji = t_j - R_ji t_i``, ``E_ji = [t_ji]_x R_ji`` and
    ``F[i, j] = K_j^-T E_ji K_i^-1``. Each matrix is scaled to unit Frobenius norm
    (distances to lines do not depend on the scale).
    """
    T = rig.T_cam_world
    R, t = T[:, :3, :3], T[:, :3, 3]
    R_ji = np.einsum("jab,icb->ijac", R, R)  # R_j R_i^T, indexed [i, j]
    t_ji = t[None, :, :] - np.einsum("ijab,ib->ija", R_ji, t)
    E = np.einsum("ijab,ijbc->ijac", skew(t_ji), R_ji)
    Kinv = np.linalg.inv(rig.K)
    F = np.einsum("jba,ijbc,icd->ijad", Kinv, E, Kinv)
    norm = np.linalg.norm(F, axis=(2, 3), keepdims=True)
    return np.where(norm > 1e-12, F / np.where(norm > 1e-12, norm, 1.0), 0.0)


def point_line_distance(uv_px: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Perpendicular distance (pixels) of points (..., 2) to lines (..., 3) ``a u + b v + c = 0``.

    Degenerate lines (``a = b = 0``) give ``inf``.
    """
    ab = np.hypot(line[..., 0], line[..., 1])
    num = np.abs(line[..., 0] * uv_px[..., 0] + line[..., 1] * uv_px[..., 1] + line[..., 2])
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(ab > 1e-15, num / np.where(ab > 1e-15, ab, 1.0), np.inf)


def epipolar_lines(uv_px: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Lines ``F @ [u, v, 1]`` for points (..., 2) and matrices broadcastable to (..., 3, 3)."""
    return (
        F[..., :, 0] * uv_px[..., None, 0] + F[..., :, 1] * uv_px[..., None, 1] + F[..., :, 2]
    )


def symmetric_epipolar_distance(uv1_px: np.ndarray, uv2_px: np.ndarray, F12: np.ndarray) -> np.ndarray:
    """The paper's ``d_e(p1, p2) = d(p2, F12 p1) + d(p1, F12^T p2)`` in pixels.

    Args:
        uv1_px: (..., 2) undistorted pixels in view 1.
        uv2_px: (..., 2) undistorted pixels in view 2 (broadcast against ``uv1_px``).
        F12: (..., 3, 3) fundamental matrix from view 1 to view 2 (``F[1, 2]`` above).
    Returns:
        (...) the sum of the two point-to-epipolar-line distances; 0 for a perfect match.
    """
    l2 = epipolar_lines(uv1_px, F12)
    l1 = epipolar_lines(uv2_px, np.swapaxes(F12, -1, -2))
    return point_line_distance(uv2_px, l2) + point_line_distance(uv1_px, l1)


def pose_epipolar_distance(
    kp1_px: np.ndarray,
    kp2_px: np.ndarray,
    w1: np.ndarray,
    w2: np.ndarray,
    F12: np.ndarray,
    min_joints: int = 3,
) -> tuple[np.ndarray, np.ndarray]:
    """Epipolar distance of two whole poses, averaged over joints confident in both views.

    Args:
        kp1_px, kp2_px: (..., joints, 2) undistorted keypoints of the two detections.
        w1, w2: (..., joints) confidences (0 where a joint is missing).
        F12: (..., 3, 3) fundamental matrix view 1 -> view 2 (broadcast over the leading dims).
        min_joints: fewer shared joints than this falls back to the confidence-weighted
            body centroids of the two detections.
    Returns:
        dist_px: (...) weighted mean of ``d_e`` over shared joints (centroid ``d_e`` on fallback;
            ``inf`` if either detection has no joint at all).
        n_shared: (...) number of joints confident in both views.
    """
    w = w1 * w2
    shared = w > 0
    n_shared = shared.sum(axis=-1)
    d = symmetric_epipolar_distance(kp1_px, kp2_px, F12[..., None, :, :])
    d = np.where(shared, d, 0.0)
    wsum = np.where(shared, w, 0.0).sum(axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        joint_mean = (np.where(shared, w, 0.0) * d).sum(axis=-1) / wsum
    c1, ok1 = weighted_centroid(kp1_px, w1)
    c2, ok2 = weighted_centroid(kp2_px, w2)
    cen = symmetric_epipolar_distance(c1, c2, F12)
    cen = np.where(ok1 & ok2, cen, np.inf)
    return np.where(n_shared >= min_joints, joint_mean, cen), n_shared


def weighted_centroid(kp_px: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(..., joints, 2), (..., joints) -> confidence-weighted centroid (..., 2) and a has-joints mask."""
    s = w.sum(axis=-1)
    ok = s > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        c = (np.where(w[..., None] > 0, kp_px, 0.0) * w[..., None]).sum(axis=-2) / np.where(ok, s, 1.0)[..., None]
    return c, ok
