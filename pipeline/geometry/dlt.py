"""Weighted linear (DLT) triangulation, batched over any leading dimensions (pure numpy).

The paper's eq. 2: for each view ``j`` with weight ``mu_j`` and observation ``(u_j, v_j)``,
two rows ``mu_j (P_1j - u_j P_3j)`` and ``mu_j (P_2j - v_j P_3j)`` of a homogeneous
system ``A X = 0``; the solution is the right singular vector of ``A`` with the smallest
singular value. With ``method="svd"`` we compute it as the eigenvector of the 4x4 normal matrix ``A^T A``
with the smallest eigenvalue (the same vector, found with one batched ``eigh`` on 4x4
matrices instead of an SVD per point); the default ``method="lstsq"`` fixes ``X_4 = 1``
and solves the same weighted rows in the least-squares sense with closed-form 3x3 solves. For good conditioning pass *normalised* image coordinates
with ``P = [R | t]`` (see ``normalized_projections``); pixel coordinates work too.

Failure modes: points seen by fewer than two weighted views are returned with
``valid = False`` (their coordinates are meaningless); points whose solution lies at
infinity (``|X_4| ~ 0``) or behind a used camera are invalid as well.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Literal

import numpy as np

from pipeline.schema.camera import CameraRig


def normalized_projections(rig: CameraRig) -> tuple[np.ndarray, np.ndarray]:
    """(views, 3, 4) projections ``[R | t']`` for normalised coordinates, and the world offset.

    The world is shifted by ``offset_m`` (the mean camera centre), so that the solved
    coordinates are small: ``X_world = X_solved + offset_m``.
    """
    offset = rig.centers_world_m.mean(axis=0)
    T = rig.T_cam_world
    P = T[:, :3, :].copy()
    P[:, :, 3] = P[:, :, 3] + np.einsum("vij,j->vi", T[:, :3, :3], offset)
    return P, offset


def normal_matrices(P: np.ndarray, uv: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``A^T A`` of eq. 2: P (views, 3, 4) or (..., views, 3, 4); uv (..., views, 2); w (..., views) -> (..., 4, 4)."""
    if P.ndim == 3:
        # Shared cameras: sum_j mu_j^2 [(P1 P1^T + P2 P2^T) + (u^2 + v^2) P3 P3^T - u S13 - v S23]
        # with S_k3 = P_k P3^T + P3 P_k^T: one (points, 4 views) x (4 views, 16) matrix product.
        basis = _basis(P.tobytes(), P.shape[0])
        w2 = w * w
        u, v = uv[..., 0], uv[..., 1]
        coef = np.stack([w2, w2 * (u * u + v * v), -w2 * u, -w2 * v], axis=-2)  # (..., 4, views)
        return (coef.reshape(-1, basis.shape[0]) @ basis).reshape(coef.shape[:-2] + (4, 4))
    lead = uv.shape[:-2]
    n_views = uv.shape[-2]
    A = np.empty(lead + (n_views, 2, 4))
    A[..., 0, :] = uv[..., 0, None] * P[..., 2, :] - P[..., 0, :]
    A[..., 1, :] = uv[..., 1, None] * P[..., 2, :] - P[..., 1, :]
    A *= w[..., None, None]
    A = A.reshape(lead + (2 * n_views, 4))
    return np.swapaxes(A, -1, -2) @ A


@lru_cache(maxsize=64)
def _basis(P_bytes: bytes, n_views: int) -> np.ndarray:
    """(4 * views, 16) outer-product basis of ``normal_matrices`` for a fixed set of cameras."""
    P = np.frombuffer(P_bytes, dtype=np.float64).reshape(n_views, 3, 4)
    P1, P2, P3 = P[:, 0], P[:, 1], P[:, 2]

    def o(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return a[:, :, None] * b[:, None, :]

    basis = np.stack([o(P1, P1) + o(P2, P2), o(P3, P3), o(P1, P3) + o(P3, P1), o(P2, P3) + o(P3, P2)], axis=0)
    return basis.reshape(4 * n_views, 16)


def triangulate_weighted(
    P: np.ndarray, uv: np.ndarray, w: np.ndarray, method: Literal["lstsq", "svd"] = "lstsq"
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted DLT (eq. 2) for a batch of points.

    Args:
        P: (views, 3, 4) projection matrices (or (..., views, 3, 4) per point).
        uv: (..., views, 2) observations in the coordinates ``P`` maps to (entries with
            ``w == 0`` may hold anything finite or not).
        w: (..., views) non-negative weights ``mu_j``; 0 = view not used.
        method: ``"svd"`` = the right singular vector of ``A`` with the smallest singular
            value (``||X|| = 1``; batched ``eigh`` of ``A^T A``); ``"lstsq"`` = the weighted
            least-squares solution of the same rows with ``X_4 = 1`` (a closed-form 3x3
            solve, ~10x faster, invariant to the choice of world origin). Both are exact
            on noise-free data and agree to well below the noise otherwise.
    Returns:
        X: (..., 3) solutions (zeros where invalid).
        valid: (...) at least two views with ``w > 0`` and a finite, non-degenerate solution.
    """
    used = w > 0
    uv = np.where(used[..., None], uv, 0.0)
    M = normal_matrices(P, uv, np.where(used, w, 0.0))
    enough = used.sum(axis=-1) >= 2
    if method == "svd":
        # Scale-normalise so that eigh's tolerances behave over any weight range.
        tr = np.trace(M, axis1=-2, axis2=-1)[..., None, None]
        _, vecs = np.linalg.eigh(M / np.where(tr > 0, tr, 1.0))
        Xh = vecs[..., :, 0]
        w4 = Xh[..., 3]
        ok = enough & (np.abs(w4) > 1e-12)
        X = Xh[..., :3] / np.where(ok, w4, 1.0)[..., None]
    elif method == "lstsq":
        X, det = _solve_sym3(M[..., :3, :3], -M[..., :3, 3])
        tr = M[..., 0, 0] + M[..., 1, 1] + M[..., 2, 2]
        ok = enough & (np.abs(det) > 1e-14 * tr**3)  # scale-free conditioning test
    else:
        raise ValueError(f"triangulate_weighted: unknown method {method!r} (lstsq or svd)")
    ok &= np.isfinite(X).all(axis=-1)
    return np.where(ok[..., None], X, 0.0), ok


def _cofactors_sym3(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Adjugate (..., 3, 3) and determinant (...) of symmetric 3x3 matrices."""
    a, bb, c = M[..., 0, 0], M[..., 0, 1], M[..., 0, 2]
    d, e, f = M[..., 1, 1], M[..., 1, 2], M[..., 2, 2]
    c00 = d * f - e * e
    c01 = c * e - bb * f
    c02 = bb * e - c * d
    c11 = a * f - c * c
    c12 = bb * c - a * e
    c22 = a * d - bb * bb
    det = a * c00 + bb * c01 + c * c02
    adj = np.stack([c00, c01, c02, c01, c11, c12, c02, c12, c22], axis=-1).reshape(M.shape)
    return adj, det


def _solve_sym3(M: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solve symmetric 3x3 systems (..., 3, 3) x = (..., 3) by cofactors; returns x and det."""
    a, bb, c = M[..., 0, 0], M[..., 0, 1], M[..., 0, 2]
    d, e, f = M[..., 1, 1], M[..., 1, 2], M[..., 2, 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    c00 = d * f - e * e
    c01 = c * e - bb * f
    c02 = bb * e - c * d
    det = a * c00 + bb * c01 + c * c02
    x = np.empty(b.shape)
    inv = 1.0 / np.where(det != 0, det, 1.0)
    x[..., 0] = (c00 * b0 + c01 * b1 + c02 * b2) * inv
    x[..., 1] = (c01 * b0 + (a * f - c * c) * b1 + (bb * c - a * e) * b2) * inv
    x[..., 2] = (c02 * b0 + (bb * c - a * e) * b1 + (a * d - bb * bb) * b2) * inv
    return x, det


def inv_sym3(M: np.ndarray) -> np.ndarray:
    """Inverse of symmetric positive-definite 3x3 matrices (...,3,3), closed form (batched)."""
    adj, det = _cofactors_sym3(M)
    return adj / np.where(det != 0, det, 1.0)[..., None, None]


def point_information(
    P: np.ndarray, X: np.ndarray, used: np.ndarray, conf: np.ndarray, focal_px: np.ndarray, pixel_std_px: float
) -> np.ndarray:
    """Fisher information (..., 3, 3) of triangulated points, in 1/m^2.

    ``sum_v (conf_v / pixel_std_px)^2 J_v^T J_v`` over the used views, with ``J_v`` the
    2x3 Jacobian of the pixel projection at ``X`` (pixel noise ``pixel_std_px / conf``).
    Its inverse is the point's covariance: elongated along the viewing rays when the
    cameras are nearly opposite or nearly aligned (poorly conditioned depth).

    P: (views, 3, 4) normalised projections; X: (..., 3) in the frame of ``P``;
    used, conf: (..., views); focal_px: (views,).
    """
    R = P[:, :, :3]
    Xc = np.einsum("vij,...j->...vi", R, X) + P[:, :, 3]
    z = np.where(Xc[..., 2] > 1e-6, Xc[..., 2], 1e-6)
    x = Xc[..., 0] / z
    y = Xc[..., 1] / z
    # d(u, v)/dX = f/z [[1, 0, -x], [0, 1, -y]] R
    J0 = R[:, 0, :] - x[..., None] * R[:, 2, :]
    J1 = R[:, 1, :] - y[..., None] * R[:, 2, :]
    s = np.where(used, (focal_px * conf / (z * pixel_std_px)) ** 2, 0.0)
    return np.einsum("...v,...vi,...vj->...ij", s, J0, J0) + np.einsum("...v,...vi,...vj->...ij", s, J1, J1)


def project_points(P: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project points (..., 3) with (views, 3, 4) -> uv (..., views, 2), depth (..., views)."""
    V = P.shape[0]
    h = (X.reshape(-1, 3) @ P[:, :, :3].reshape(3 * V, 3).T).reshape(X.shape[:-1] + (V, 3)) + P[:, :, 3]
    depth = h[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = h[..., :2] / np.where(np.abs(depth) > 1e-12, depth, 1e-12)[..., None]
    return uv, depth


def triangulate_robust(
    P: np.ndarray,
    uv: np.ndarray,
    w: np.ndarray,
    px_per_unit: np.ndarray,
    max_view_err_px: float,
    min_views: int = 2,
    method: Literal["lstsq", "svd"] = "lstsq",
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Weighted DLT with iterative worst-view removal (bounded: at most ``views - min_views`` rounds).

    Each round looks at the points that still use more than ``min_views`` views and whose
    largest reprojection error exceeds ``max_view_err_px``; for those, every used view is
    left out in turn (one batched solve), and the view the others predict worst is dropped.
    The effort is at most ``views`` rounds of ``views`` batched solves on the flagged points,
    whatever the number of cameras (no enumeration of view subsets, no RANSAC sampling).

    Args:
        P: (views, 3, 4) projections (shared by all points).
        uv: (..., views, 2) observations in the coordinates of ``P``.
        w: (..., views) weights (0 = missing).
        px_per_unit: (views,) pixels per unit of ``uv`` (focal length for normalised
            coordinates, 1 for pixels), to express errors in pixels.
        max_view_err_px: a view whose reprojection error exceeds this is an outlier.
        min_views: never drop below this many views.
        method: solver of ``triangulate_weighted``.
    Returns:
        X: (..., 3); valid: (...); used: (..., views) bool views kept;
        err_px: (..., views) reprojection error per view in pixels (NaN where unused);
        mean_err_px: (...) mean error over the kept views (NaN where invalid).
    """
    used = w > 0
    n_views = P.shape[0]
    X, ok = triangulate_weighted(P, uv, np.where(used, w, 0.0), method)
    eye = np.eye(n_views, dtype=bool)
    for _ in range(max(0, n_views - min_views)):
        err = _view_errors(P, X, uv, px_per_unit)
        worst_err = np.where(used, err, -np.inf).max(axis=-1)
        cand = ok & (used.sum(axis=-1) > min_views) & (worst_err > max_view_err_px)
        if not cand.any():
            break
        idx = np.nonzero(cand)
        # Leave-one-out: the view that the others predict worst is the outlier (the worst
        # residual of the full solution can be a good view when the outlier has leverage).
        u, wv, uvv = used[idx], w[idx], uv[idx]
        W = np.where(eye[None], 0.0, np.where(u, wv, 0.0)[:, None, :])  # (n, left out, views)
        uv_rep = np.broadcast_to(uvv[:, None], W.shape + (2,))
        X_loo, ok_loo = triangulate_weighted(P, uv_rep, W, method)  # (n, views, 3)
        e_loo = _view_errors(P, X_loo, uv_rep, px_per_unit)  # (n, left out, views)
        own = np.where(u & ok_loo, np.diagonal(e_loo, axis1=1, axis2=2), -np.inf)
        drop = np.argmax(own, axis=-1)
        rows = np.arange(drop.size)
        used[idx + (drop,)] = False
        X[idx] = X_loo[rows, drop]
        ok[idx] = ok_loo[rows, drop]
    err = _view_errors(P, X, uv, px_per_unit)
    # A solution behind a used camera is no solution.
    _, depth = project_points(P, X)
    ok &= ~np.any(used & (depth <= 0), axis=-1)
    err = np.where(used & ok[..., None], err, np.nan)
    n_used = np.where(ok, used.sum(axis=-1), 0)
    with np.errstate(invalid="ignore"):
        mean_err = np.where(ok, np.nansum(err, axis=-1) / np.maximum(n_used, 1), np.nan)
    return X, ok, used & ok[..., None], err, mean_err


def _view_errors(P: np.ndarray, X: np.ndarray, uv: np.ndarray, px_per_unit: np.ndarray) -> np.ndarray:
    proj, depth = project_points(P, X)
    err = np.linalg.norm(proj - np.where(np.isfinite(uv), uv, 0.0), axis=-1) * px_per_unit
    return np.where(depth > 0, err, np.inf)


def triangulate_reference(P: np.ndarray, uv: np.ndarray, w: np.ndarray) -> np.ndarray | None:
    """Per-point reference: build eq. 2 row by row and solve it with a full SVD.

    P: (views, 3, 4); uv: (views, 2); w: (views,). Returns (3,) or None with < 2 views.
    Slow on purpose (tests compare the batched solver against it).
    """
    rows = []
    for j in range(P.shape[0]):
        if w[j] <= 0:
            continue
        rows.append(w[j] * (P[j, 0] - uv[j, 0] * P[j, 2]))
        rows.append(w[j] * (P[j, 1] - uv[j, 1] * P[j, 2]))
    if len(rows) < 4:
        return None
    _, _, vt = np.linalg.svd(np.asarray(rows))
    Xh = vt[-1]
    return Xh[:3] / Xh[3]
