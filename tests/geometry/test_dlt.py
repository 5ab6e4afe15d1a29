"""Weighted DLT: project -> triangulate round trips, weights, batched vs per-point reference."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.geometry import project
from pipeline.geometry.dlt import (
    inv_sym3,
    normalized_projections,
    point_information,
    triangulate_reference,
    triangulate_robust,
    triangulate_weighted,
)
from pipeline.geometry.rotations import look_at_T_world_cam
from pipeline.schema import CameraRig


def _rig(n: int) -> CameraRig:
    T, K = [], []
    for v in range(n):
        a = 2 * np.pi * v / n + 0.2
        T.append(look_at_T_world_cam(np.array([6 * np.cos(a), 6 * np.sin(a), 2.5]), np.array([0.0, 0.0, 1.0])))
        K.append([[1000.0, 0.0, 960.0], [0.0, 1000.0, 540.0], [0.0, 0.0, 1.0]])
    return CameraRig(
        names=tuple(f"c{v}" for v in range(n)),
        K=np.array(K),
        dist=np.zeros((n, 5)),
        T_world_cam=np.array(T),
        image_size_wh=np.tile([1920, 1080], (n, 1)),
        fps=50.0,
    )


def _observations(rig: CameraRig, X: np.ndarray) -> np.ndarray:
    """(..., views, 2) pixels of points (..., 3)."""
    uv, _ = project(rig, X, distort=False)
    return np.moveaxis(uv, 0, -2)


@pytest.mark.parametrize("method", ["lstsq", "svd"])
@pytest.mark.parametrize("n_views", [2, 3, 4, 8])
def test_noise_free_round_trip(method: str, n_views: int) -> None:
    rig = _rig(n_views)
    rng = np.random.default_rng(n_views)
    X = rng.uniform([-2, -2, 0], [2, 2, 2], (5, 7, 3))
    uv = _observations(rig, X)
    w = rng.uniform(0.1, 1.0, uv.shape[:-1])
    # pixels + K[R|t] ...
    Xs, ok = triangulate_weighted(rig.P, uv, w, method)
    assert ok.all() and np.abs(Xs - X).max() < 1e-6
    # ... and normalised coordinates + [R|t'] with the world offset.
    P, off = normalized_projections(rig)
    xn = (uv - rig.K[:, :2, 2]) / rig.K[:, [0, 1], [0, 1]]
    Xn, ok = triangulate_weighted(P, xn, w, method)
    assert ok.all() and np.abs(Xn + off - X).max() < 1e-9


def test_batched_matches_per_point_reference_under_noise() -> None:
    rig = _rig(5)
    rng = np.random.default_rng(7)
    X = rng.uniform([-2, -2, 0], [2, 2, 2], (200, 3))
    uv = _observations(rig, X) + rng.normal(0, 3.0, (200, 5, 2))
    w = rng.uniform(0.0, 1.0, (200, 5))
    w[rng.random((200, 5)) < 0.3] = 0.0
    Xs, ok = triangulate_weighted(rig.P, uv, w, "svd")
    Xl, okl = triangulate_weighted(rig.P, uv, w, "lstsq")
    for i in range(200):
        ref = triangulate_reference(rig.P, uv[i], w[i])
        assert (ref is not None) == ok[i] == okl[i]
        if ref is not None:
            assert np.abs(Xs[i] - ref).max() < 1e-6
            # Same rows, X_4 = 1 instead of |X| = 1: far below the ~cm noise level.
            assert np.abs(Xl[i] - ref).max() < 2e-3


def test_weights_behave() -> None:
    rig = _rig(4)
    rng = np.random.default_rng(8)
    X = rng.uniform([-1, -1, 0.5], [1, 1, 1.5], (100, 3))
    uv = _observations(rig, X)
    noisy = uv.copy()
    noisy[:, 3] += rng.normal(0, 30.0, (100, 2))  # view 3 is bad
    w = np.ones((100, 4))
    base, _ = triangulate_weighted(rig.P, noisy, w)
    # Scaling every weight by a constant changes nothing.
    scaled, _ = triangulate_weighted(rig.P, noisy, 7.5 * w)
    assert np.abs(scaled - base).max() < 1e-9
    # Down-weighting the bad view moves the solution towards the truth, monotonically.
    errs = []
    for w3 in (1.0, 0.3, 0.1, 0.0):
        ww = w.copy()
        ww[:, 3] = w3
        Xs, _ = triangulate_weighted(rig.P, noisy, ww)
        errs.append(np.linalg.norm(Xs - X, axis=1).mean())
    assert errs[0] > errs[1] > errs[2] > errs[3] and errs[3] < 1e-6
    # Weight 0 is the same as removing the view (its coordinates may even be NaN).
    nan_uv = noisy.copy()
    nan_uv[:, 3] = np.nan
    ww = w.copy()
    ww[:, 3] = 0
    a, _ = triangulate_weighted(rig.P, nan_uv, ww)
    b, _ = triangulate_weighted(rig.P[:3], uv[:, :3], w[:, :3])
    assert np.abs(a - b).max() < 1e-9


def test_fewer_than_two_views_is_invalid() -> None:
    rig = _rig(3)
    uv = _observations(rig, np.array([[0.0, 0.0, 1.0], [0.5, 0.0, 1.0]]))
    w = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    for method in ("lstsq", "svd"):
        _, ok = triangulate_weighted(rig.P, uv, w, method)  # type: ignore[arg-type]
        assert not ok.any()


def test_robust_drops_outlier_view_with_bounded_rounds() -> None:
    rig = _rig(16)
    rng = np.random.default_rng(9)
    X = rng.uniform([-1, -1, 0.5], [1, 1, 1.5], (300, 3))
    uv = _observations(rig, X) + rng.normal(0, 1.0, (300, 16, 2))
    bad_view = rng.integers(0, 16, 300)
    uv[np.arange(300), bad_view] += rng.choice([-1, 1], (300, 2)) * rng.uniform(80, 200, (300, 2))
    w = np.ones((300, 16))
    plain, _ = triangulate_weighted(rig.P, uv, w)
    Xr, ok, used, err, mean_err = triangulate_robust(rig.P, uv, w, np.ones(16), max_view_err_px=10.0)
    assert ok.all()
    assert not used[np.arange(300), bad_view].any()  # the corrupted view is always dropped
    assert used.sum(axis=1).min() >= 14  # and few good ones with it
    assert np.linalg.norm(Xr - X, axis=1).max() < 0.01 < np.linalg.norm(plain - X, axis=1).mean()
    assert np.nanmax(mean_err) < 10.0 and np.isnan(err[np.arange(300), bad_view]).all()
    # Two views cannot be voted on: both stay.
    _, ok2, used2, _, _ = triangulate_robust(rig.P[:2], uv[:, :2], w[:, :2], np.ones(2), 10.0)
    assert used2[ok2].all()


def test_point_information_is_inverse_covariance() -> None:
    rig = _rig(2)  # two cameras at 180 deg: depth along the baseline is poorly known
    P, off = normalized_projections(rig)
    X = np.array([0.3, 0.2, 1.0]) - off
    info = point_information(P, X, np.ones(2, bool), np.ones(2), np.full(2, 1000.0), 2.0)
    cov = inv_sym3(info + 1e-9 * np.eye(3))
    assert np.allclose(cov, np.linalg.inv(info + 1e-9 * np.eye(3)))
    # Monte Carlo: triangulating noisy projections has (about) that covariance.
    rng = np.random.default_rng(10)
    uv = _observations(rig, X + off)
    xn = (uv - rig.K[:, :2, 2]) / 1000.0
    samples = xn + rng.normal(0, 2.0 / 1000.0, (4000, 2, 2))
    Xs, ok = triangulate_weighted(P, samples, np.ones((4000, 2)))
    emp = np.cov(Xs[ok].T)
    assert np.allclose(np.sqrt(np.diag(emp)), np.sqrt(np.diag(cov)), rtol=0.15)
