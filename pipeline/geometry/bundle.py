"""Bundle adjustment of a camera rig on multi-view 2D correspondences (pure numpy/scipy).

The athletes' joints are the calibration target: every (frame, person, joint) seen in at
least two views is one 3D point. ``bundle_adjust`` refines each camera's rotation and
translation (and optionally one focal-length scale per camera) together with the points,
minimising confidence-weighted reprojection errors in undistorted pixels with a robust
loss (``scipy.optimize.least_squares``, ``x_scale="jac"``, ``tr_solver="lsmr"``). The
Jacobian is analytic and sparse: the two rows of an observation touch only its camera's
parameters and its point's xyz (the pattern of aniposelib's ``_jac_sparsity_bundle``),
which makes a run 2-3x faster than finite differences on that pattern. An outer loop
re-triangulates the points and drops observations above a shrinking pixel threshold (as
aniposelib's ``bundle_adjust_iter``), so that wrong associations and left/right flips do
not pull the cameras.

Gauge: reprojection errors do not change under a similarity transform of the whole
scene, so a bundle adjustment alone fixes neither the world frame nor its scale nor the
floor. After each round the refined rig is mapped back onto the input rig by the
least-squares similarity over the camera centres (relative to the rig's spread) and the
camera orientations (in radians), ``align_similarity`` (the points are re-triangulated
in the next round). Orientations make it well posed for two cameras too (centres alone
leave the rotation about the baseline free). The world frame of the result is the
input's, up to the similarity that best explains the input's own errors.

Distortion stays fixed; observations are undistorted with the current intrinsics.

Failure modes (``ValueError``): fewer than two cameras; NaN/inf observations; fewer than
``min_points_per_camera`` points seen by a camera and another one (names and counts given).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix
from threadpoolctl import threadpool_limits

from pipeline.geometry.dlt import normalized_projections, triangulate_robust
from pipeline.geometry.projection import undistort_points
from pipeline.geometry.rotations import R_from_rodrigues
from pipeline.schema.base import check_array
from pipeline.schema.camera import CameraRig

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BundleConfig:
    """Settings of ``bundle_adjust``."""

    refine_focal: bool = False
    """Also refine one focal-length scale per camera (fx, fy and skew together; the
    principal point and distortion stay fixed). Only observable when the athletes cover
    depth along each camera's axis: athletes near the centre leave a focal/distance
    trade-off that fits the noise, so leave it off unless the whole volume is covered."""
    min_conf: float = 0.3
    """2D keypoints below this confidence (0..1) are not used."""
    max_points: int = 2000
    """Bound on the number of 3D points (a seeded subsample of the candidates), >= 10."""
    loss: Literal["soft_l1", "huber", "cauchy", "linear"] = "soft_l1"
    """Robust loss of ``least_squares`` on the confidence-weighted pixel residuals. scipy's
    ``huber``/``cauchy`` give residuals beyond ``f_scale`` no curvature, so from a clearly
    miscalibrated start their steps stall; ``soft_l1`` does not."""
    f_scale_px: float = 1.0
    """Floor (pixels, > 0) of the robust loss's scale; each round uses the larger of this and
    the round's median view error, i.e. quadratic for typical inliers, linear beyond."""
    start_threshold_px: float = 40.0
    """Outlier threshold (pixels) of the first round: views farther than this from the
    re-triangulated point are dropped (> 0)."""
    end_threshold_px: float = 8.0
    """Outlier threshold (pixels) of the last round, <= ``start_threshold_px``; the
    thresholds shrink geometrically in between."""
    inlier_factor: float = 3.0
    """A round's threshold never drops below this times the median view error (>= 1), so
    that noisier keypoints than ``end_threshold_px`` assumes are not all rejected."""
    n_rounds: int = 4
    """Outer rounds (re-triangulate, reject, adjust), >= 1."""
    max_nfev: int = 50
    """Function evaluations per round of ``least_squares`` (>= 1)."""
    min_points_per_camera: int = 30
    """A camera needs at least this many points shared with another camera (>= 1)."""
    seed: int = 0
    """Seed of the point subsample (same seed and data -> same result)."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.min_conf <= 1.0:
            raise ValueError(f"BundleConfig.min_conf must be in [0, 1], got {self.min_conf}")
        if self.max_points < 10:
            raise ValueError(f"BundleConfig.max_points must be >= 10, got {self.max_points}")
        if not self.f_scale_px > 0:
            raise ValueError(f"BundleConfig.f_scale_px must be > 0, got {self.f_scale_px}")
        if not 0 < self.end_threshold_px <= self.start_threshold_px:
            raise ValueError(
                "BundleConfig: need 0 < end_threshold_px <= start_threshold_px, got "
                f"{self.end_threshold_px} and {self.start_threshold_px}"
            )
        if self.inlier_factor < 1:
            raise ValueError(f"BundleConfig.inlier_factor must be >= 1, got {self.inlier_factor}")
        if self.n_rounds < 1 or self.max_nfev < 1 or self.min_points_per_camera < 1:
            raise ValueError(
                f"BundleConfig: n_rounds ({self.n_rounds}), max_nfev ({self.max_nfev}) and "
                f"min_points_per_camera ({self.min_points_per_camera}) must be >= 1"
            )


@dataclass(frozen=True)
class ReprojectionStats:
    """Per-camera reprojection errors (undistorted pixels) of re-triangulated points.

    Fields: median_px, p95_px (views,) float (NaN for a camera without observations);
    n_obs (views,) int observations counted; all_median_px, the median over all views.
    """

    median_px: np.ndarray
    p95_px: np.ndarray
    n_obs: np.ndarray
    all_median_px: float

    def __post_init__(self) -> None:
        V = self.median_px.shape[0] if self.median_px.ndim == 1 else -1
        check_array("ReprojectionStats.median_px", self.median_px, (V,), "f")
        check_array("ReprojectionStats.p95_px", self.p95_px, (V,), "f")
        check_array("ReprojectionStats.n_obs", self.n_obs, (V,), "iu")


@dataclass(frozen=True)
class BundleResult:
    """Outcome of ``bundle_adjust``.

    Fields:
        rig: the refined rig, in the input rig's world frame (see the module docstring).
        before, after: reprojection statistics of the input and the refined rig, each
            re-triangulating the same candidate points (all of them, not the subsample).
        n_points: 3D points in the last round's adjustment.
        n_obs: (views,) observations of each camera in the last round's adjustment.
        converged: the last round's ``least_squares`` stopped on a tolerance, not on
            ``max_nfev``.
    """

    rig: CameraRig
    before: ReprojectionStats
    after: ReprojectionStats
    n_points: int
    n_obs: np.ndarray
    converged: bool

    def __post_init__(self) -> None:
        check_array("BundleResult.n_obs", self.n_obs, (self.rig.n_views,), "iu")


def bundle_adjust(
    rig: CameraRig, uv_px: np.ndarray, conf: np.ndarray, cfg: BundleConfig = BundleConfig()
) -> BundleResult:
    """Refine ``rig`` on correspondences; see the module docstring for the method.

    Args:
        rig: the input calibration (its world frame, scale and floor are kept).
        uv_px: (points, views, 2) *distorted* pixels, one candidate 3D point per row
            (e.g. one joint of one person in one frame); entries with ``conf`` below
            ``cfg.min_conf`` may hold anything (also NaN).
        conf: (points, views) 2D confidence in [0, 1] (0 = not seen).
        cfg: settings.
    Raises:
        ValueError: one camera, mismatched shapes, NaN where ``conf >= cfg.min_conf``,
        or too few correspondences for some camera.
    """
    # Small BLAS calls (lsmr's vector products) only lose from threading: pin BLAS to one thread.
    with threadpool_limits(limits=1, user_api="blas"):
        return _bundle_adjust(rig, uv_px, conf, cfg)


def _bundle_adjust(rig: CameraRig, uv_px: np.ndarray, conf: np.ndarray, cfg: BundleConfig) -> BundleResult:
    obs_uv, obs_w = _check_inputs(rig, uv_px, conf, cfg)
    cand = np.flatnonzero((obs_w > 0).sum(axis=1) >= 2)
    _check_counts(rig, obs_w[cand], cfg.min_points_per_camera, "")
    rng = np.random.default_rng(cfg.seed)
    sub = np.sort(rng.choice(cand, cfg.max_points, replace=False)) if cand.size > cfg.max_points else cand
    uv_s, w_s = obs_uv[sub], obs_w[sub]

    mus = np.geomspace(cfg.start_threshold_px, cfg.end_threshold_px, cfg.n_rounds)
    cur = rig
    converged = False
    n_points, n_obs = 0, np.zeros(rig.n_views, dtype=np.int64)
    for k, mu_sched in enumerate(mus):
        _, used, err = triangulate_px(cur, uv_s, w_s, cfg.start_threshold_px)
        med = float(np.median(err[used])) if used.any() else np.nan
        mu = max(float(mu_sched), cfg.inlier_factor * med) if np.isfinite(med) else float(mu_sched)
        # Re-triangulate so that views beyond this round's threshold do not pull the points.
        X, used, err = triangulate_px(cur, uv_s, w_s, mu)
        inl = used & (err <= mu)
        keep = inl.sum(axis=1) >= 2
        _check_counts(
            cur, np.where(inl[keep], w_s[keep], 0.0), cfg.min_points_per_camera, f" within {mu:.1f} px"
        )
        und = _undistort(cur, uv_s[keep])
        f_scale = max(cfg.f_scale_px, med) if np.isfinite(med) else cfg.f_scale_px
        new, status = _adjust(cur, X[keep], und, np.where(inl[keep], w_s[keep], 0.0), cfg, f_scale)
        cur = align_rig(new, rig)
        converged = status > 0
        n_points, n_obs = int(keep.sum()), inl[keep].sum(axis=0).astype(np.int64)
        log.debug(
            "bundle round %d: threshold %.1f px, %d points, median %.2f px, status %d",
            k,
            mu,
            n_points,
            med,
            status,
        )

    before, after = reprojection_stats(rig, obs_uv[cand], obs_w[cand], cur, cfg.start_threshold_px)
    return BundleResult(
        rig=cur, before=before, after=after, n_points=n_points, n_obs=n_obs, converged=converged
    )


def reprojection_errors(
    rig: CameraRig, uv_px: np.ndarray, w: np.ndarray, max_view_err_px: float
) -> np.ndarray:
    """(points, views) error (undistorted px) of every observation (``w > 0``) against its
    point triangulated by ``triangulate_robust`` (views beyond ``max_view_err_px`` left out
    of the point, but still scored); NaN where not observed or the point is invalid."""
    X, used, _ = triangulate_px(rig, uv_px, w, max_view_err_px)
    ok: np.ndarray = np.any(used, axis=1)
    und = _undistort(rig, uv_px)
    proj = _project_px(rig, X)
    err = np.linalg.norm(proj - np.where(np.isfinite(und), und, 0.0), axis=-1)
    return np.where((w > 0) & ok[:, None], err, np.nan)


def reprojection_stats(
    rig_a: CameraRig, uv_px: np.ndarray, w: np.ndarray, rig_b: CameraRig, max_view_err_px: float
) -> tuple[ReprojectionStats, ReprojectionStats]:
    """Per-camera statistics of two rigs over the same observations (those both score)."""
    ea = reprojection_errors(rig_a, uv_px, w, max_view_err_px)
    eb = reprojection_errors(rig_b, uv_px, w, max_view_err_px)
    both = np.isfinite(ea) & np.isfinite(eb)
    return _stats(np.where(both, ea, np.nan)), _stats(np.where(both, eb, np.nan))


def _stats(err: np.ndarray) -> ReprojectionStats:
    V = err.shape[1]
    med, p95 = np.full(V, np.nan), np.full(V, np.nan)
    n = np.isfinite(err).sum(axis=0).astype(np.int64)
    for v in range(V):
        e = err[:, v][np.isfinite(err[:, v])]
        if e.size:
            med[v], p95[v] = np.median(e), np.percentile(e, 95)
    allv = err[np.isfinite(err)]
    return ReprojectionStats(med, p95, n, float(np.median(allv)) if allv.size else float("nan"))


# --- gauge -------------------------------------------------------------------------------


def align_similarity(src: CameraRig, dst: CameraRig) -> tuple[float, np.ndarray, np.ndarray]:
    """Similarity ``x -> s Q x + t`` that best maps ``src``'s world onto ``dst``'s.

    Least squares over the camera centres, divided by the RMS spread of ``dst``'s centres,
    and the camera orientations (``||Q R_src - R_dst||_F^2 / 2``, ~ the squared angle in
    rad^2), so a rotation of the world by a small angle costs about the same in both terms.
    Closed-form start (Procrustes on both terms), then a 7-parameter Levenberg-Marquardt polish.
    Returns ``(s, Q (3, 3), t (3,))``.
    """
    if src.n_views != dst.n_views:
        raise ValueError(f"align_similarity: {src.n_views} cameras vs {dst.n_views}")
    a, b = src.centers_world_m, dst.centers_world_m
    Ra, Rb = src.T_world_cam[:, :3, :3], dst.T_world_cam[:, :3, :3]
    ac, bc = a - a.mean(axis=0), b - b.mean(axis=0)
    L = max(float(np.sqrt((bc**2).sum(axis=1).mean())), 1e-6)
    La = max(float(np.sqrt((ac**2).sum(axis=1).mean())), 1e-9)
    H = np.einsum("vi,vj->ij", bc, ac) / (L * La) + np.einsum("vik,vjk->ij", Rb, Ra)
    U, _, Vt = np.linalg.svd(H)
    Q0 = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    s0 = float(np.sum(bc * (ac @ Q0.T)) / max(np.sum(ac**2), 1e-12))
    t0 = b.mean(axis=0) - s0 * Q0 @ a.mean(axis=0)

    def resid(p: np.ndarray) -> np.ndarray:
        Q = R_from_rodrigues(p[:3]) @ Q0
        s = s0 * np.exp(p[3])
        rc = (s * a @ Q.T + t0 + p[4:] * L - b) / L
        ro = (np.einsum("ij,vjk->vik", Q, Ra) - Rb) / np.sqrt(2.0)
        return np.concatenate([rc.ravel(), ro.ravel()])

    p = least_squares(resid, np.zeros(7), method="lm", xtol=1e-14, ftol=1e-14).x
    Q = R_from_rodrigues(p[:3]) @ Q0
    return float(s0 * np.exp(p[3])), Q, t0 + p[4:] * L


def apply_similarity(rig: CameraRig, s: float, Q: np.ndarray, t: np.ndarray) -> CameraRig:
    """``rig`` with its world mapped by ``x -> s Q x + t`` (intrinsics unchanged)."""
    T = rig.T_world_cam.copy()
    T[:, :3, :3] = np.einsum("ij,vjk->vik", Q, T[:, :3, :3])
    T[:, :3, 3] = s * T[:, :3, 3] @ Q.T + t
    return replace(rig, T_world_cam=T)


def align_rig(rig: CameraRig, onto: CameraRig) -> CameraRig:
    """``rig`` moved by ``align_similarity(rig, onto)`` into ``onto``'s world frame."""
    return apply_similarity(rig, *align_similarity(rig, onto))


# --- internals ---------------------------------------------------------------------------


def _check_inputs(
    rig: CameraRig, uv_px: np.ndarray, conf: np.ndarray, cfg: BundleConfig
) -> tuple[np.ndarray, np.ndarray]:
    V = rig.n_views
    if V < 2:
        raise ValueError(f"a bundle adjustment needs >= 2 cameras, got {V} ({', '.join(rig.names)})")
    if uv_px.ndim != 3 or uv_px.shape[1:] != (V, 2) or conf.shape != uv_px.shape[:2]:
        raise ValueError(
            f"bundle_adjust: expected uv_px (points, {V}, 2) and conf (points, {V}), got {uv_px.shape} and {conf.shape}"
        )
    bad_conf = ~np.isfinite(conf) | (conf < 0) | (conf > 1)
    if bad_conf.any():
        raise ValueError(
            f"bundle_adjust: conf has {int(bad_conf.sum())} NaN/inf or out-of-[0, 1] entries "
            f"(e.g. {conf[bad_conf][:3].tolist()})"
        )
    w = np.where(conf >= max(cfg.min_conf, 1e-9), conf, 0.0)
    bad = (w > 0) & ~np.isfinite(uv_px).all(axis=-1)
    if bad.any():
        p, v = np.argwhere(bad)[0]
        raise ValueError(
            f"bundle_adjust: {int(bad.sum())} observations with conf >= {cfg.min_conf} have NaN/inf pixels "
            f"(first: point {p}, camera {rig.names[v]})"
        )
    return np.where(w[..., None] > 0, uv_px, 0.0), w


def _check_counts(rig: CameraRig, w: np.ndarray, minimum: int, where: str) -> None:
    """Each camera needs ``minimum`` points it shares with another camera."""
    shared = (w > 0) & ((w > 0).sum(axis=1) >= 2)[:, None]
    counts = shared.sum(axis=0)
    low = np.flatnonzero(counts < minimum)
    if low.size:
        detail = ", ".join(f"{rig.names[v]}: {int(counts[v])}" for v in low)
        raise ValueError(
            f"bundle_adjust: too few correspondences{where} (points seen by the camera and at least "
            f"one other): {detail}; the minimum is {minimum} per camera"
        )


def _undistort(rig: CameraRig, uv_px: np.ndarray) -> np.ndarray:
    """(points, views, 2) distorted -> undistorted pixels, per view with that view's K."""
    out = np.empty_like(uv_px, dtype=np.float64)
    for v in range(rig.n_views):
        out[:, v] = undistort_points(uv_px[:, v], rig.K[v], rig.dist[v])
    return out


def _project_px(rig: CameraRig, X: np.ndarray) -> np.ndarray:
    """(points, 3) world -> (points, views, 2) undistorted pixels."""
    P = rig.P
    h = np.einsum("vij,nj->nvi", P[:, :, :3], X) + P[:, :, 3]
    return h[..., :2] / np.where(np.abs(h[..., 2:]) > 1e-12, h[..., 2:], 1e-12)


def triangulate_px(
    rig: CameraRig, uv_px: np.ndarray, w: np.ndarray, max_view_err_px: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robust DLT in normalised coordinates: X (points, 3) world, used (points, views) and
    err (points, views) px (NaN where unused)."""
    und = _undistort(rig, uv_px)
    Kinv = np.linalg.inv(rig.K)
    xn = np.einsum("vij,nvj->nvi", Kinv[:, :2, :2], und) + Kinv[:, :2, 2]
    P, offset = normalized_projections(rig)
    focal = 0.5 * (rig.K[:, 0, 0] + rig.K[:, 1, 1])
    X, ok, used, err, _ = triangulate_robust(P, xn, w, focal, max_view_err_px, 2)
    used &= ok[:, None]
    return X + offset, used, err


class _Problem:
    """Reprojection residuals of one round, their analytic Jacobian and its sparsity pattern.

    Parameters ``x``: per camera ``[d_aa (3), t_cam_world_m (3), log_focal_scale (1, with
    refine_focal)]`` with the rotation ``R_cam_world = exp(d_aa) R0`` (``R0`` = this round's
    start, so ``d_aa = 0`` there), then the points' world xyz (m). Residual rows: ``(u, v)``
    of each observation, ``conf * (projection - observation)`` in undistorted pixels.
    """

    def __init__(self, rig: CameraRig, und_px: np.ndarray, w: np.ndarray, refine_focal: bool) -> None:
        self.V, self.N = rig.n_views, und_px.shape[0]
        self.nc = 7 if refine_focal else 6
        self.R0 = rig.T_cam_world[:, :3, :3]
        self.t0 = rig.T_cam_world[:, :3, 3]
        pt, vw = np.nonzero(w > 0)
        order = np.argsort(vw, kind="stable")
        self.pt, self.vw = pt[order], vw[order]
        self.bounds = np.searchsorted(self.vw, np.arange(self.V + 1))
        self.obs = und_px[self.pt, self.vw]
        self.w = w[self.pt, self.vw]
        self.K = rig.K

    def x0(self, X_world_m: np.ndarray) -> np.ndarray:
        cam = np.zeros((self.V, self.nc))
        cam[:, 3:6] = self.t0
        return np.concatenate([cam.ravel(), X_world_m.ravel()])

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """R_cam_world (V, 3, 3), t_cam_world (V, 3), focal scale (V,), X_world (N, 3)."""
        cam = x[: self.V * self.nc].reshape(self.V, self.nc)
        R = R_from_rodrigues(cam[:, :3]) @ self.R0
        g = np.exp(cam[:, 6]) if self.nc == 7 else np.ones(self.V)
        return R, cam[:, 3:6], g, x[self.V * self.nc :].reshape(self.N, 3)

    def _project(self, x: np.ndarray, v: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        R, t, g, X = self.unpack(x)
        a, b = self.bounds[v], self.bounds[v + 1]
        Xc = X[self.pt[a:b]] @ R[v].T + t[v]
        z = np.where(np.abs(Xc[:, 2]) > 1e-9, Xc[:, 2], 1e-9)
        xy = Xc[:, :2] / z[:, None]
        K = self.K[v]
        uv = np.stack(
            [g[v] * (K[0, 0] * xy[:, 0] + K[0, 1] * xy[:, 1]) + K[0, 2], g[v] * K[1, 1] * xy[:, 1] + K[1, 2]],
            1,
        )
        return uv, Xc, R[v], float(g[v])

    def residuals(self, x: np.ndarray) -> np.ndarray:
        out = np.empty((self.pt.size, 2))
        for v in range(self.V):
            a, b = self.bounds[v], self.bounds[v + 1]
            out[a:b] = self._project(x, v)[0]
        return ((out - self.obs) * self.w[:, None]).ravel()

    def jacobian(self, x: np.ndarray) -> csr_matrix:
        nc = self.nc
        data = np.empty((self.pt.size, 2, nc + 3))
        d_aa = x[: self.V * nc].reshape(self.V, nc)[:, :3]
        for v in range(self.V):
            a, b = self.bounds[v], self.bounds[v + 1]
            uv, Xc, R, g = self._project(x, v)
            K = self.K[v]
            z = Xc[:, 2]
            # d(u, v)/d(Xc) = g [[fx, s], [0, fy]] @ [[1, 0, -x], [0, 1, -y]] / z
            x_, y_ = Xc[:, 0] / z, Xc[:, 1] / z
            A = np.zeros((b - a, 2, 3))
            A[:, 0, 0] = A[:, 1, 1] = 1.0 / z
            A[:, 0, 2], A[:, 1, 2] = -x_ / z, -y_ / z
            D = g * np.einsum("ij,njk->nik", K[:2, :2], A)
            RX = Xc - x[v * nc + 3 : v * nc + 6]
            # d(exp(d) R0 X)/d(d) = -[R X]_x J_l(d)
            dR = -np.einsum("nik,kj->nij", _skew(RX), _left_jacobian(d_aa[v]))
            data[a:b, :, 0:3] = D @ dR
            data[a:b, :, 3:6] = D
            if nc == 7:
                data[a:b, :, 6] = uv - K[:2, 2]
            data[a:b, :, nc:] = D @ R
        data *= self.w[:, None, None]
        rows, cols = self.pattern()
        return csr_matrix((data.ravel(), (rows, cols)), shape=(2 * self.pt.size, self.V * nc + 3 * self.N))

    def pattern(self) -> tuple[np.ndarray, np.ndarray]:
        """Row and column of each Jacobian entry: (u, v) rows of an observation touch its
        camera's ``nc`` parameters and its point's xyz, nothing else."""
        n, nc = self.pt.size, self.nc
        rows = np.repeat(np.arange(2 * n), nc + 3)
        cols = np.concatenate(
            [self.vw[:, None] * nc + np.arange(nc), self.V * nc + self.pt[:, None] * 3 + np.arange(3)], 1
        )
        return rows, np.broadcast_to(cols[:, None, :], (n, 2, nc + 3)).ravel()

    def sparsity(self) -> csr_matrix:
        rows, cols = self.pattern()
        return csr_matrix(
            (np.ones(rows.size, dtype=np.int8), (rows, cols)),
            shape=(2 * self.pt.size, self.V * self.nc + 3 * self.N),
        )


def _skew(a: np.ndarray) -> np.ndarray:
    z = np.zeros(a.shape[:-1])
    return np.stack(
        [z, -a[..., 2], a[..., 1], a[..., 2], z, -a[..., 0], -a[..., 1], a[..., 0], z], -1
    ).reshape(a.shape + (3,))


def _left_jacobian(aa: np.ndarray) -> np.ndarray:
    """(3, 3) left Jacobian of SO(3) at the axis-angle ``aa``: exp(aa + e) ~ exp(J_l e) exp(aa)."""
    th = float(np.linalg.norm(aa))
    S = _skew(aa)
    if th < 1e-8:
        return np.eye(3) + 0.5 * S
    return np.eye(3) + (1 - np.cos(th)) / th**2 * S + (th - np.sin(th)) / th**3 * (S @ S)


def _adjust(
    rig: CameraRig, X0: np.ndarray, und_px: np.ndarray, w: np.ndarray, cfg: BundleConfig, f_scale_px: float
) -> tuple[CameraRig, int]:
    """One ``least_squares`` run; returns the adjusted rig (not yet re-aligned) and its status."""
    prob = _Problem(rig, und_px, w, cfg.refine_focal)
    sol = least_squares(
        prob.residuals, prob.x0(X0), jac=prob.jacobian, x_scale="jac", loss=cfg.loss, f_scale=f_scale_px,
        method="trf", tr_solver="lsmr", max_nfev=cfg.max_nfev, ftol=1e-6, xtol=1e-8,
    )  # fmt: skip
    R, t, g, _ = prob.unpack(sol.x)
    T_cw = np.tile(np.eye(4), (rig.n_views, 1, 1))
    T_cw[:, :3, :3], T_cw[:, :3, 3] = R, t
    K = rig.K.copy()
    K[:, :2, :2] *= g[:, None, None]
    return replace(rig, K=K, T_world_cam=np.linalg.inv(T_cw)), int(sol.status)
