"""Bundle adjustment: recovery of a perturbed rig, gauge, outliers, two cameras, errors.

Fixtures: the synthetic bout (``pipeline.synthetic``), true identities, fixed seeds. Pixel
noise is 0.5 px: camera poses from two boxers in the middle of the ring are only as
precise as the noise allows (at 3 px the "orbit" of a camera around the compact scene
is uncertain by ~1-3 cm), and the tests check recovery to a few mm.

A perturbation is applied "gauge-free": the world frame of a refined rig can only come
from the input rig, so a perturbation with a net similarity (all cameras shifted the
same way) is indistinguishable from moving the world. ``perturb`` therefore removes that
part with ``align_similarity`` (tested on its own against a known similarity), and the
refined rig is compared with the TRUE rig, not up to a similarity.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.optimize._numdiff import approx_derivative

from pipeline.geometry.bundle import (
    BundleConfig,
    _Problem,
    _undistort,
    align_rig,
    align_similarity,
    apply_similarity,
    bundle_adjust,
    triangulate_px,
)
from pipeline.geometry.rotations import R_from_rodrigues
from pipeline.schema import Association, CameraRig, Tracks2D
from pipeline.schema.joints import flip_pairs
from pipeline.stages.calibrate import gather_pixels
from pipeline.synthetic.bout import SyntheticBout, make_bout
from pipeline.synthetic.config import SyntheticConfig


def perturb(
    rig: CameraRig, seed: int, rot_deg: float = 1.0, shift_m: float = 0.03, focal: float = 0.0
) -> CameraRig:
    """Each camera rotated by ``rot_deg`` about a random axis, its centre moved ``shift_m``
    in a random direction, focal scaled by ``1 +- focal``; then the net similarity removed."""
    rng = np.random.default_rng(seed)
    V = rig.n_views
    T = rig.T_world_cam.copy()
    axis = rng.normal(size=(V, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    T[:, :3, :3] = R_from_rodrigues(axis * np.radians(rot_deg)) @ T[:, :3, :3]
    d = rng.normal(size=(V, 3))
    T[:, :3, 3] += shift_m * d / np.linalg.norm(d, axis=1, keepdims=True)
    K = rig.K.copy()
    K[:, :2, :2] *= (1.0 + focal * rng.choice([-1.0, 1.0], V))[:, None, None]
    return align_rig(dataclasses.replace(rig, T_world_cam=T, K=K), rig)


def pose_errors(true: CameraRig, est: CameraRig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per camera: centre error (mm), rotation error (deg), relative focal error (%)."""
    dc = 1000.0 * np.linalg.norm(true.centers_world_m - est.centers_world_m, axis=1)
    cos = (np.einsum("vij,vij->v", true.T_world_cam[:, :3, :3], est.T_world_cam[:, :3, :3]) - 1.0) / 2.0
    df = 100.0 * np.abs(est.K[:, 0, 0] / true.K[:, 0, 0] - 1.0)
    return dc, np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))), df


def corrupt(
    tracks: Tracks2D, assoc: Association, frac_flip: float, frac_wrong: float, seed: int
) -> tuple[Tracks2D, Association]:
    """Left/right-swap the joints of ``frac_flip`` of the detections and give ``frac_wrong``
    of the athletes' detections to the other athlete."""
    rng = np.random.default_rng(seed)
    idx = np.arange(len(tracks.joint_names))
    for i, j in flip_pairs(tracks.joint_names):
        idx[i], idx[j] = j, i
    flip = rng.random(tracks.n_dets) < frac_flip
    kp, kc, kv = tracks.keypoints_px.copy(), tracks.keypoint_conf.copy(), tracks.keypoint_valid.copy()
    kp[flip], kc[flip], kv[flip] = kp[flip][:, idx], kc[flip][:, idx], kv[flip][:, idx]
    pod = assoc.person_of_det.copy()
    wrong = (rng.random(tracks.n_dets) < frac_wrong) & (pod >= 0)
    pod[wrong] = 1 - pod[wrong]
    return (
        dataclasses.replace(tracks, keypoints_px=kp, keypoint_conf=kc, keypoint_valid=kv),
        dataclasses.replace(assoc, person_of_det=pod),
    )


def _obs(b: SyntheticBout) -> tuple[np.ndarray, np.ndarray]:
    uv, conf, _ = gather_pixels(b.tracks, b.gt_association(), b.rig.n_views)
    return uv, conf


@pytest.fixture(scope="module")
def bout4() -> SyntheticBout:
    return make_bout(SyntheticConfig(n_cameras=4, n_frames=100, seed=0, noise_px=0.5))


@pytest.fixture(scope="module")
def bout2() -> SyntheticBout:
    return make_bout(SyntheticConfig(n_cameras=2, n_frames=100, seed=0, noise_px=0.5))


# --- gauge -------------------------------------------------------------------------------


@pytest.mark.parametrize("n_views", [2, 4])
def test_align_similarity_recovers_a_known_similarity(bout4: SyntheticBout, n_views: int) -> None:
    rig = bout4.rig.subset(list(range(n_views)))
    c = rig.centers_world_m
    baseline = (c[1] - c[0]) / np.linalg.norm(c[1] - c[0])
    # With two cameras the rotation about the baseline moves no centre: only orientations fix it.
    Q = R_from_rodrigues(np.radians(25.0) * baseline) @ R_from_rodrigues(np.array([0.1, -0.2, 0.3]))
    moved = apply_similarity(rig, 1.3, Q, np.array([0.5, -1.0, 0.2]))
    back = align_rig(moved, rig)
    assert np.abs(back.T_world_cam - rig.T_world_cam).max() < 1e-9
    s, Q2, _ = align_similarity(moved, rig)
    assert s == pytest.approx(1 / 1.3, rel=1e-9) and np.abs(Q2 @ Q - np.eye(3)).max() < 1e-9


def test_exact_rig_stays_where_it_was(bout4: SyntheticBout) -> None:
    """No drift of world frame, scale or floor when the rig is already right."""
    rig = bout4.rig
    uv, conf = _obs(bout4)
    res = bundle_adjust(rig, uv, conf)
    dc, dr, _ = pose_errors(rig, res.rig)
    assert dc.max() < 8.0 and dr.max() < 0.06  # per camera: the estimation noise only (0.5 px)
    c0, c1 = rig.centers_world_m, res.rig.centers_world_m
    assert np.linalg.norm(c1.mean(axis=0) - c0.mean(axis=0)) < 1e-3  # origin
    spread = lambda c: np.sqrt(((c - c.mean(axis=0)) ** 2).sum(axis=1).mean())  # noqa: E731
    assert spread(c1) / spread(c0) == pytest.approx(1.0, abs=2e-4)  # scale
    # Floor: the athletes' ankles triangulate at the same height with either rig.
    w = np.where(conf >= 0.3, conf, 0.0)
    names = bout4.tracks.joint_names
    ankles = np.zeros(uv.shape[0], dtype=bool).reshape(-1, len(names))  # rows: (frame, person, joint)
    ankles[:, [names.index("left_ankle"), names.index("right_ankle")]] = True
    sel = ankles.ravel() & ((w > 0).sum(axis=1) >= 2)
    X0, _, _ = triangulate_px(rig, uv[sel], w[sel], 20.0)
    X1, _, _ = triangulate_px(res.rig, uv[sel], w[sel], 20.0)
    assert abs(np.median(X1[:, 2] - X0[:, 2])) < 3e-3


def test_noise_free_exact_rig_is_a_fixed_point(bout4: SyntheticBout) -> None:
    b = make_bout(SyntheticConfig(n_cameras=3, n_frames=30, seed=1, noise_px=0.0))
    res = bundle_adjust(b.rig, *_obs(b))
    dc, dr, _ = pose_errors(b.rig, res.rig)
    assert dc.max() < 0.05 and dr.max() < 1e-3
    assert res.after.all_median_px < 1e-3


# --- recovery ----------------------------------------------------------------------------


def test_recovers_perturbed_rig(bout4: SyntheticBout) -> None:
    uv, conf = _obs(bout4)
    start = perturb(bout4.rig, seed=0)
    dc0, dr0, _ = pose_errors(bout4.rig, start)
    assert dc0.mean() > 20.0 and dr0.mean() > 0.8  # really perturbed
    res = bundle_adjust(start, uv, conf)
    dc, dr, _ = pose_errors(bout4.rig, res.rig)
    assert dc.max() < 8.0 and dr.max() < 0.08, (dc, dr)
    truth = bundle_adjust(bout4.rig, uv, conf).before  # the true rig's error: the noise floor
    assert res.after.all_median_px < 1.05 * truth.all_median_px
    assert np.all(res.after.median_px < res.before.median_px / 5)
    assert res.converged and np.all(res.n_obs > 500) and res.n_points <= BundleConfig().max_points


def test_outliers_do_not_spoil_recovery(bout4: SyntheticBout) -> None:
    """10 % left/right-flipped detections and 5 % given to the wrong athlete."""
    tracks, assoc = corrupt(bout4.tracks, bout4.gt_association(), 0.10, 0.05, seed=0)
    uv, conf, _ = gather_pixels(tracks, assoc, 4)
    start = perturb(bout4.rig, seed=0)
    dc, dr, _ = pose_errors(bout4.rig, bundle_adjust(start, uv, conf).rig)
    assert dc.max() < 10.0 and dr.max() < 0.1, (dc, dr)
    # Without the outer loop and the robust loss the same data pull the cameras far away.
    naive = BundleConfig(loss="linear", n_rounds=1, start_threshold_px=1e4, end_threshold_px=1e4)
    dc_n, dr_n, _ = pose_errors(bout4.rig, bundle_adjust(start, uv, conf, naive).rig)
    assert dc_n.max() > 100.0 and dr_n.max() > 1.0


def test_two_cameras(bout2: SyntheticBout) -> None:
    tracks, assoc = corrupt(bout2.tracks, bout2.gt_association(), 0.05, 0.02, seed=1)
    uv, conf, _ = gather_pixels(tracks, assoc, 2)
    start = perturb(bout2.rig, seed=0)
    dr0 = pose_errors(bout2.rig, start)[1]
    res = bundle_adjust(start, uv, conf)
    dc, dr, _ = pose_errors(bout2.rig, res.rig)
    assert dr0.mean() > 0.3 and dc.max() < 3.0 and dr.max() < 0.12, (dc, dr)
    assert res.after.all_median_px < res.before.all_median_px / 5


def test_refine_focal_on_athletes_crossing_the_ring(bout4: SyntheticBout) -> None:
    """Focal lengths are observable when the athletes cover the ring (depth varies along
    each camera's axis); two boxers standing in the centre leave a focal/distance trade-off
    of ~0.5 % at 0.5 px noise, so this scene moves them on a 2 m circle."""
    from pipeline.geometry import project

    X = bout4.gt.xyz_m.copy()
    F = X.shape[0]
    a = np.linspace(0.0, 2 * np.pi, F, endpoint=False)
    X[..., :2] += 2.0 * np.stack([np.cos(a), np.sin(a)], -1)[:, None, None] - X[..., :2].mean(
        axis=(1, 2), keepdims=True
    )
    uv, depth = project(bout4.rig, X)
    uv = uv + np.random.default_rng(0).normal(0.0, 0.5, uv.shape)
    W, H = bout4.rig.image_size_wh[0]
    inside = (depth > 0) & (uv[..., 0] >= 0) & (uv[..., 0] < W) & (uv[..., 1] >= 0) & (uv[..., 1] < H)
    uv = np.moveaxis(uv.reshape(4, -1, 2), 0, 1)
    conf = np.moveaxis(np.where(inside, 0.9, 0.0).reshape(4, -1), 0, 1)
    start = perturb(bout4.rig, seed=0, focal=0.01)
    assert pose_errors(bout4.rig, start)[2].mean() > 0.9
    res = bundle_adjust(start, uv, conf, BundleConfig(refine_focal=True))
    dc, dr, df = pose_errors(bout4.rig, res.rig)
    assert df.max() < 0.15 and dc.max() < 5.0 and dr.max() < 0.03, (dc, dr, df)
    assert res.after.all_median_px < 0.6  # ~ the noise (0.5 px; re-triangulation fits some of it)


def test_analytic_jacobian_matches_finite_differences() -> None:
    b = make_bout(SyntheticConfig(n_cameras=3, n_frames=4, seed=2, distortion=True))
    uv, conf = _obs(b)
    w = np.where(conf >= 0.3, conf, 0.0)
    keep = (w > 0).sum(axis=1) >= 2
    X, _, _ = triangulate_px(b.rig, uv[keep], w[keep], 40.0)
    prob = _Problem(b.rig, _undistort(b.rig, uv[keep]), w[keep], refine_focal=True)
    x = prob.x0(X)
    x[:21] += np.random.default_rng(0).normal(0.0, 0.02, 21)  # away from d_aa = 0
    J = prob.jacobian(x)
    J_fd = approx_derivative(prob.residuals, x, method="3-point")
    assert np.abs(J.toarray() - J_fd).max() < 1e-5 * np.abs(J_fd).max()
    assert set(zip(*J.nonzero(), strict=True)) <= set(zip(*prob.sparsity().nonzero(), strict=True))


def test_deterministic(bout4: SyntheticBout) -> None:
    uv, conf = _obs(bout4)
    cfg = BundleConfig(max_points=200, n_rounds=2)
    a, b = (bundle_adjust(perturb(bout4.rig, 1), uv, conf, cfg) for _ in range(2))
    assert np.array_equal(a.rig.T_world_cam, b.rig.T_world_cam)


# --- errors ------------------------------------------------------------------------------


def test_one_camera_is_refused(bout4: SyntheticBout) -> None:
    uv, conf = _obs(bout4)
    with pytest.raises(ValueError, match=r"needs >= 2 cameras, got 1 \(cam01\)"):
        bundle_adjust(bout4.rig.subset([0]), uv[:, :1], conf[:, :1])


def test_too_few_correspondences_names_camera_and_counts(bout4: SyntheticBout) -> None:
    uv, conf = _obs(bout4)
    conf = conf.copy()
    seen = np.flatnonzero((conf >= 0.3).sum(axis=1) >= 2)
    conf[seen[12:], 2] = 0.0  # cam03 keeps 12 shared points at most
    with pytest.raises(
        ValueError, match=r"too few correspondences.*cam03: \d+;.*minimum is 30 per camera"
    ) as e:
        bundle_adjust(bout4.rig, uv, conf)
    assert "cam01" not in str(e.value)


def test_nan_inputs_are_refused(bout4: SyntheticBout) -> None:
    uv, conf = _obs(bout4)
    uv, conf = uv.copy(), conf.copy()
    p = int(np.flatnonzero(conf[:, 1] >= 0.3)[0])
    uv[p, 1, 0] = np.nan
    with pytest.raises(ValueError, match=r"NaN/inf pixels \(first: point \d+, camera cam02\)"):
        bundle_adjust(bout4.rig, uv, conf)
    uv[p, 1, 0] = 100.0
    conf[p, 1] = np.nan
    with pytest.raises(ValueError, match=r"conf has 1 NaN/inf or out-of-\[0, 1\] entries \(e.g. \[nan\]\)"):
        bundle_adjust(bout4.rig, uv, conf)
    with pytest.raises(ValueError, match=r"expected uv_px \(points, 4, 2\)"):
        bundle_adjust(bout4.rig, uv[:, :3], conf[:, :3])


def test_config_validation() -> None:
    with pytest.raises(ValueError, match="end_threshold_px <= start_threshold_px"):
        BundleConfig(start_threshold_px=5.0, end_threshold_px=10.0)
    with pytest.raises(ValueError, match="min_conf"):
        BundleConfig(min_conf=1.5)
