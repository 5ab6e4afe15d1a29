"""Epipolar geometry: fundamental matrices from the calibration, point-line distances."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.geometry import project, undistort_points
from pipeline.geometry.epipolar import (
    fundamental_matrices,
    point_line_distance,
    pose_epipolar_distance,
    symmetric_epipolar_distance,
)
from pipeline.geometry.rotations import look_at_T_world_cam
from pipeline.schema import CameraRig


def _rig(n: int = 4, k1: float = 0.0) -> CameraRig:
    T, K = [], []
    for v in range(n):
        a = 2 * np.pi * v / n + 0.4
        T.append(look_at_T_world_cam(np.array([6 * np.cos(a), 6 * np.sin(a), 2.0 + 0.4 * v]), np.array([0.0, 0.0, 1.0])))
        K.append([[900.0 + 40 * v, 0.0, 640.0], [0.0, 910.0 + 40 * v, 360.0], [0.0, 0.0, 1.0]])
    return CameraRig(
        names=tuple(f"c{v}" for v in range(n)),
        K=np.array(K),
        dist=np.tile([k1, 0.0, 0.0, 0.0, 0.0], (n, 1)),
        T_world_cam=np.array(T),
        image_size_wh=np.tile([1280, 720], (n, 1)),
        fps=50.0,
    )


def test_point_line_distance_hand_built() -> None:
    # Line x = 2 (1*u + 0*v - 2 = 0), point (5, 7): distance 3. Scaling the line changes nothing.
    assert point_line_distance(np.array([5.0, 7.0]), np.array([1.0, 0.0, -2.0])) == pytest.approx(3.0)
    assert point_line_distance(np.array([5.0, 7.0]), np.array([-4.0, 0.0, 8.0])) == pytest.approx(3.0)
    # Line u + v = 0, point (1, 1): sqrt(2).
    assert point_line_distance(np.array([1.0, 1.0]), np.array([1.0, 1.0, 0.0])) == pytest.approx(np.sqrt(2))
    assert np.isinf(point_line_distance(np.array([1.0, 1.0]), np.array([0.0, 0.0, 1.0])))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_true_correspondences_satisfy_epipolar_constraint(seed: int) -> None:
    rig = _rig()
    rng = np.random.default_rng(seed)
    X = rng.uniform([-2, -2, 0], [2, 2, 2], (50, 3))
    uv, _ = project(rig, X, distort=False)
    F = fundamental_matrices(rig)
    for i in range(rig.n_views):
        for j in range(rig.n_views):
            if i == j:
                assert np.allclose(F[i, j], 0)
                continue
            xi = np.c_[uv[i], np.ones(50)]
            xj = np.c_[uv[j], np.ones(50)]
            alg = np.einsum("ni,ij,nj->n", xj, F[i, j], xi)
            assert np.abs(alg).max() < 1e-9
            d = symmetric_epipolar_distance(uv[i], uv[j], F[i, j])
            assert d.max() < 1e-6
            # F[j, i] is F[i, j] transposed (up to sign after normalisation).
            assert min(np.abs(F[j, i] - F[i, j].T).max(), np.abs(F[j, i] + F[i, j].T).max()) < 1e-9


def test_wrong_correspondences_are_far_and_distance_is_symmetric() -> None:
    rig = _rig()
    rng = np.random.default_rng(3)
    X = rng.uniform([-2, -2, 0], [2, 2, 2], (40, 3))
    uv, _ = project(rig, X, distort=False)
    F = fundamental_matrices(rig)
    d_wrong = symmetric_epipolar_distance(uv[0], uv[1][::-1], F[0, 1])
    assert np.median(d_wrong) > 20.0
    # d_e(p1, p2; F12) == d_e(p2, p1; F21)
    assert np.allclose(d_wrong, symmetric_epipolar_distance(uv[1][::-1], uv[0], F[1, 0]))
    # A point moved by 5 px perpendicular to its epipolar line is ~5 px away (one side).
    line = F[0, 1] @ np.r_[uv[0, 0], 1.0]
    n = line[:2] / np.linalg.norm(line[:2])
    moved = uv[1, 0] + 5.0 * n
    one_side = point_line_distance(moved, line)
    assert one_side == pytest.approx(5.0, abs=1e-6)


def test_distorted_points_need_undistortion() -> None:
    rig = _rig(k1=-0.2)
    rng = np.random.default_rng(4)
    X = rng.uniform([-2, -2, 0], [2, 2, 2], (30, 3))
    uv, _ = project(rig, X, distort=True)
    F = fundamental_matrices(rig)
    raw = symmetric_epipolar_distance(uv[0], uv[2], F[0, 2])
    und = symmetric_epipolar_distance(
        undistort_points(uv[0], rig.K[0], rig.dist[0]), undistort_points(uv[2], rig.K[2], rig.dist[2]), F[0, 2]
    )
    assert und.max() < 1e-3 < raw.max()


def test_pose_distance_averages_shared_joints_and_falls_back_to_centroids() -> None:
    rig = _rig()
    rng = np.random.default_rng(5)
    X = rng.uniform([-0.3, -0.3, 0], [0.3, 0.3, 1.8], (17, 3))
    uv, _ = project(rig, X, distort=False)
    F = fundamental_matrices(rig)
    w = np.ones(17)
    d, n = pose_epipolar_distance(uv[0], uv[1], w, w, F[0, 1])
    assert n == 17 and d < 1e-6
    # Corrupt one joint by 100 px in view 1 but give it a tiny weight: the mean barely moves.
    bad = uv[1].copy()
    bad[3] += [100.0, 0.0]
    w_low = w.copy()
    w_low[3] = 1e-3
    d_low, _ = pose_epipolar_distance(uv[0], bad, w, w_low, F[0, 1])
    d_full, _ = pose_epipolar_distance(uv[0], bad, w, w, F[0, 1])
    assert d_low < 0.1 * d_full
    # Only two joints shared -> centroid fallback (centroids of all confident joints).
    w1 = np.zeros(17)
    w1[:2] = 1
    w2 = np.zeros(17)
    w2[1:10] = 1
    d_c, n_c = pose_epipolar_distance(uv[0], uv[1], w1, w2, F[0, 1], min_joints=3)
    assert n_c == 1
    c1 = uv[0][:2].mean(0)
    c2 = uv[1][1:10].mean(0)
    assert d_c == pytest.approx(symmetric_epipolar_distance(c1, c2, F[0, 1]))
    # Batched over leading dims equals one by one.
    d_b, _ = pose_epipolar_distance(np.stack([uv[0], uv[0]]), np.stack([uv[1], bad]), np.ones((2, 17)), np.ones((2, 17)), F[0, 1])
    assert d_b[0] == pytest.approx(d) and d_b[1] == pytest.approx(d_full)
