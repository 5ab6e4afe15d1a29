"""Temporal filter: gaps (spline / Kalman), bone-length outliers, batch smoother vs recursive RTS."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.schema import COCO17, Keypoints3D
from pipeline.stages.filtering import FilterConfig, bone_outliers, ca_model, rts_smooth_batch, run


def _traj(F: int, fps: float = 50.0) -> np.ndarray:
    """(F, 1, 17, 3) smooth motion: a standing skeleton swaying and walking."""
    t = np.arange(F) / fps
    base = np.zeros((17, 3))
    base[:, 2] = np.linspace(0.1, 1.7, 17)
    base[:, 0] = np.linspace(-0.2, 0.2, 17)
    X = np.repeat(base[None, None], F, axis=0)
    X[..., 0] += (0.3 * np.sin(2.0 * t))[:, None, None]
    X[..., 1] += (0.5 * t)[:, None, None]
    return X


def _kp(xyz: np.ndarray, valid: np.ndarray) -> Keypoints3D:
    F = xyz.shape[0]
    return Keypoints3D(
        joint_names=COCO17, person_ids=np.array([0]), frame_indices=np.arange(F), fps=50.0,
        xyz_m=np.where(valid[..., None], xyz, 0.0), valid=valid, confidence=np.where(valid, 0.9, 0.0),
        n_views=np.where(valid, 4, 0), reproj_err_px=np.where(valid, 2.0, np.nan), source="raw",
    )


def test_short_gap_is_splined_long_gap_bridged_longer_stays_invalid() -> None:
    F = 200
    X = _traj(F)
    valid = np.ones(X.shape[:3], bool)
    valid[20:25, 0, 3] = False  # 5 frames: spline
    valid[60:90, 0, 4] = False  # 30 frames = 0.6 s: Kalman bridge
    valid[100:180, 0, 5] = False  # 80 frames = 1.6 s > 1 s: stays invalid
    valid[:10, 0, 6] = False  # leading: no extrapolation
    out = run(_kp(X, valid), FilterConfig(ray_iterations=0))
    assert out.source == "filtered"
    assert out.valid[20:25, 0, 3].all() and np.abs(out.xyz_m[20:25, 0, 3] - X[20:25, 0, 3]).max() < 0.005
    assert out.valid[60:90, 0, 4].all() and np.abs(out.xyz_m[60:90, 0, 4] - X[60:90, 0, 4]).max() < 0.05
    assert not out.valid[100:180, 0, 5].any() and not out.valid[:10, 0, 6].any()
    assert (out.n_views[20:25, 0, 3] == 0).all() and np.isnan(out.reproj_err_px[20:25, 0, 3]).all()
    assert out.confidence[20:25, 0, 3].max() < 0.9
    # Disabled filter: raw relabelled.
    same = run(_kp(X, valid), FilterConfig(enabled=False))
    assert same.source == "filtered" and (same.valid == valid).all()


def test_smoothing_reduces_noise_and_keeps_floor() -> None:
    F = 150
    X = _traj(F)
    rng = np.random.default_rng(0)
    noisy = X + rng.normal(0, 0.015, X.shape)
    noisy[..., 0, 2] = -0.01  # a joint at the floor, measured slightly below it
    valid = np.ones(X.shape[:3], bool)
    out = run(_kp(noisy, valid))
    err_raw = np.linalg.norm(noisy - X, axis=-1)[:, :, 1:].mean()
    err_out = np.linalg.norm(out.xyz_m - X, axis=-1)[:, :, 1:].mean()
    assert err_out < 0.6 * err_raw
    assert out.xyz_m[..., 0, 2].min() >= 0.0


def test_jump_outlier_is_rejected() -> None:
    F = 100
    X = _traj(F)
    noisy = X.copy()
    noisy[50, 0, 9] += [0.0, 0.4, 0.0]  # a 40 cm glitch in one frame
    out = run(_kp(noisy, np.ones(X.shape[:3], bool)), FilterConfig(bone_tolerance=0.0))
    assert np.linalg.norm(out.xyz_m[50, 0, 9] - X[50, 0, 9]) < 0.03


def test_bone_length_outlier_flags_the_weaker_end() -> None:
    F = 30
    X = _traj(F)
    ls, le = COCO17.index("left_shoulder"), COCO17.index("left_elbow")
    bad = X.copy()
    bad[10, 0, le, 2] -= 0.3  # upper arm 0.3 m too long in frame 10
    valid = np.ones(X.shape[:3], bool)
    conf = np.full(valid.shape, 0.9)
    conf[10, 0, le] = 0.5
    flags = bone_outliers(bad, valid, conf, COCO17, 0.25)
    assert flags[10, 0, le] and not flags[10, 0, ls] and flags.sum() == 1
    out = run(_kp(bad, valid))
    assert np.linalg.norm(out.xyz_m[10, 0, le] - X[10, 0, le]) < 0.03


def _rts_recursive(z: np.ndarray, r: np.ndarray, fps: float, jerk: float) -> np.ndarray:
    """Reference: textbook forward Kalman filter + backward RTS pass, one axis, loops."""
    A, Q = ca_model(fps, jerk)
    F = z.shape[0]
    ridge = 1e-9 * np.linalg.inv(Q)[0, 0]
    x = np.zeros(3)
    P = np.eye(3) / ridge  # the batch solver's ridge is this (very vague) prior
    xp, Pp, xf, Pf = [], [], [], []
    for t in range(F):
        if t > 0:
            x = A @ x
            P = A @ P @ A.T + Q
        xp.append(x.copy())
        Pp.append(P.copy())
        if np.isfinite(r[t]):
            K = P[:, 0] / (P[0, 0] + r[t])
            x = x + K * (z[t] - x[0])
            P = P - np.outer(K, P[0])
        xf.append(x.copy())
        Pf.append(P.copy())
    xs = xf[-1]
    out = [xs[0]]
    for t in range(F - 2, -1, -1):
        C = Pf[t] @ A.T @ np.linalg.inv(Pp[t + 1])
        xs = xf[t] + C @ (xs - xp[t + 1])
        out.append(xs[0])
    return np.array(out[::-1])


def test_batch_smoother_matches_recursive_rts() -> None:
    rng = np.random.default_rng(1)
    F, fps, jerk = 80, 50.0, 100.0
    z = np.cumsum(np.cumsum(rng.normal(0, 0.002, (F, 3)), axis=0), axis=0)
    r = np.full(F, 0.01**2)
    r[30:45] = np.inf  # a gap
    info = np.where(np.isfinite(r), 1.0 / np.where(np.isfinite(r), r, 1.0), 0.0)[:, None, None, None] * np.eye(3)
    g = np.einsum("fnij,fnj->fni", info, z[:, None])
    batch = rts_smooth_batch(info, g, fps, jerk)[:, 0]
    for ax in range(3):
        ref = _rts_recursive(z[:, ax], r, fps, jerk)
        assert np.abs(batch[:, ax] - ref).max() < 1e-6


@pytest.mark.parametrize("fps", [30.0, 50.0, 120.0])
def test_a_joint_never_measured_does_not_break_the_others(fps: float) -> None:
    """At 30 and 120 fps the smoother's system of a trajectory with no measurement at all
    is numerically singular; it used to stop the whole triangulation (LinAlgError)."""
    F = 100
    X = _traj(F, fps)
    valid = np.ones(X.shape[:3], bool)
    valid[:, 0, 15:] = False  # the ankles are never seen
    out = run(_kp(X, valid).replace(fps=fps), FilterConfig(ray_iterations=0))
    assert not out.valid[:, 0, 15:].any()
    assert out.valid[:, 0, :15].all()
    assert np.abs(out.xyz_m[:, 0, :15] - X[:, 0, :15]).max() < 0.01
    info = np.zeros((F, 2, 3, 3))
    info[:, 1] = 1e4 * np.eye(3)
    g = np.einsum("fnij,fnj->fni", info, X[:, 0, :2])
    both = rts_smooth_batch(info, g, fps, 100.0)
    assert np.isnan(both[:, 0]).all()
    assert np.allclose(both[:, 1], rts_smooth_batch(info[:, 1:], g[:, 1:], fps, 100.0)[:, 0])
    # A joint only ever seen along one fixed ray (one static camera): its depth is not
    # observed, the system is singular in rounding and is solved with a tiny ridge; the
    # observed directions keep the measurement.
    d = np.array([0.3, 0.9, 0.1]) / np.linalg.norm([0.3, 0.9, 0.1])
    across = np.eye(3) - np.outer(d, d)
    ray_info = np.repeat((1e4 * across)[None, None], F, axis=0)
    z = np.array([1.0, 2.0, 0.5])
    ray = rts_smooth_batch(ray_info, np.einsum("fnij,j->fni", ray_info, z), fps, 100.0)[:, 0]
    assert np.isfinite(ray).all()
    assert np.abs((ray - z) @ across).max() < 1e-3


@pytest.mark.parametrize(
    "kw, msg",
    [
        ({"jerk_std": 0.0}, "jerk_std must be > 0"),
        ({"jerk_std": -100.0}, "jerk_std must be > 0"),
        ({"meas_std_m": float("nan")}, "meas_std_m must be > 0"),
        ({"kalman_max_gap_s": -1.0}, "kalman_max_gap_s must be >= 0"),
        ({"smoother": "spline"}, "smoother must be 'kalman' or 'none'"),
    ],
)
def test_bad_filter_settings_are_refused(kw: dict, msg: str) -> None:
    with pytest.raises(ValueError, match=msg):
        FilterConfig(**kw)
    from pipeline.stages.triangulate import TriangulateConfig

    with pytest.raises(ValueError, match=msg):  # also when nested in the stage's config
        TriangulateConfig(filter=kw)  # type: ignore[arg-type]
