"""Metrics on hand-built cases (numbers checked by hand)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.evaluate.metrics import (
    acceleration_error,
    bone_length_std,
    coverage,
    identity_accuracy,
    match_persons,
    mpjpe,
    pa_mpjpe,
    pcp,
    reprojection_error,
)
from pipeline.geometry import project
from pipeline.geometry.rotations import R_from_rodrigues, look_at_T_world_cam
from pipeline.schema import COCO17, Association, CameraRig, Keypoints3D, Tracks2D


def _kp(xyz: np.ndarray, valid: np.ndarray | None = None, ids: tuple[int, ...] = (0, 1), names: tuple[str, ...] = COCO17) -> Keypoints3D:
    f, p, j, _ = xyz.shape
    return Keypoints3D(
        joint_names=names,
        person_ids=np.array(ids),
        frame_indices=np.arange(f),
        fps=50.0,
        xyz_m=xyz,
        valid=np.ones((f, p, j), bool) if valid is None else valid,
        confidence=np.ones((f, p, j)),
        n_views=np.zeros((f, p, j), np.int64),
        reproj_err_px=np.full((f, p, j), np.nan),
        source="gt",
    )


def _skeleton(rng: np.random.Generator, frames: int = 4, persons: int = 2) -> np.ndarray:
    X = rng.uniform(-0.3, 0.3, (frames, persons, 17, 3))
    X[..., 2] += np.linspace(0.1, 1.7, 17)
    X[:, 1, :, 0] += 2.0  # second person 2 m away
    return X


def test_mpjpe_and_match_persons_handle_permutation() -> None:
    rng = np.random.default_rng(0)
    gt = _skeleton(rng)
    est = gt[:, ::-1].copy()  # persons swapped in the estimate
    est[..., 0] += 0.010  # 10 mm error everywhere
    E, G = _kp(est, ids=(5, 7)), _kp(gt)
    assert match_persons(E, G) == {0: 7, 1: 5}
    assert mpjpe(E, G) == pytest.approx(10.0)
    # Missing estimates are skipped by MPJPE and reported by coverage.
    v = np.ones(est.shape[:3], bool)
    v[:, :, :5] = False
    E2 = _kp(est, v, ids=(5, 7))
    assert mpjpe(E2, G) == pytest.approx(10.0)
    assert coverage(E2, G) == pytest.approx(12 / 17)
    # A joint subset by name.
    assert mpjpe(E, G, joint_names=("nose", "left_hip")) == pytest.approx(10.0)


def test_pcp_half_limb_rule() -> None:
    # One frame, one person; left upper arm from shoulder (0,0,1.5) to elbow (0,0,1.2): length 0.3.
    gt = np.zeros((1, 1, 17, 3))
    gt[0, 0, :, 2] = np.linspace(0.1, 1.7, 17)
    ls, le = COCO17.index("left_shoulder"), COCO17.index("left_elbow")
    gt[0, 0, ls] = [0.0, 0.0, 1.5]
    gt[0, 0, le] = [0.0, 0.0, 1.2]
    limbs = (("left_shoulder", "left_elbow"),)
    G = _kp(gt, ids=(0,))
    est = gt.copy()
    est[0, 0, le, 0] += 0.29  # endpoint errors (0 + 0.29)/2 = 0.145 <= 0.15 -> correct
    assert pcp(_kp(est, ids=(0,)), G, limbs=limbs) == 1.0
    est[0, 0, le, 0] += 0.02  # (0 + 0.31)/2 = 0.155 > 0.15 -> wrong
    assert pcp(_kp(est, ids=(0,)), G, limbs=limbs) == 0.0
    # A missing endpoint is wrong; all 10 Campus limbs scored on a perfect estimate.
    v = np.ones((1, 1, 17), bool)
    v[0, 0, le] = False
    assert pcp(_kp(gt.copy(), v, ids=(0,)), G, limbs=limbs) == 0.0
    assert pcp(_kp(gt.copy(), v, ids=(0,)), G) == pytest.approx(8 / 10)


def test_pa_mpjpe_removes_similarity_transform() -> None:
    rng = np.random.default_rng(1)
    gt = _skeleton(rng)
    R = R_from_rodrigues(np.array([0.3, -0.2, 1.0]))
    est = 1.3 * gt @ R.T + np.array([1.0, -2.0, 0.5])
    G = _kp(gt)
    E = _kp(est)
    assert mpjpe(E, G, mapping={0: 0, 1: 1}) > 100.0
    assert pa_mpjpe(E, G, mapping={0: 0, 1: 1}) < 1e-6
    # Non-rigid noise survives the alignment.
    noisy = gt + rng.normal(0, 0.01, gt.shape)
    assert 5.0 < pa_mpjpe(_kp(noisy), G) < mpjpe(_kp(noisy), G) + 1e-9


def test_identity_accuracy_hand_built() -> None:
    gt = np.array([0, 0, 1, 1, -1, -1])
    assert identity_accuracy(np.array([1, 1, 0, 0, -1, -1]), gt) == 1.0  # global relabelling is free
    assert identity_accuracy(np.array([1, 1, 0, 1, -1, -1]), gt) == pytest.approx(5 / 6)
    assert identity_accuracy(np.array([1, 1, 0, 0, 0, -1]), gt) == pytest.approx(5 / 6)  # bystander stolen
    assert identity_accuracy(np.array([-1, -1, -1, -1, -1, -1]), gt) == pytest.approx(2 / 6)
    assert identity_accuracy(np.array([3, 3, 3, 3, -1, -1]), gt) == pytest.approx(4 / 6)  # merged persons
    with pytest.raises(ValueError):
        identity_accuracy(np.zeros(3), np.zeros(4))


def test_bone_length_std_and_acceleration_error() -> None:
    names = COCO17
    F = 6
    xyz = np.zeros((F, 1, 17, 3))
    xyz[..., 2] = np.linspace(0.1, 1.7, 17)
    ls, le = names.index("left_shoulder"), names.index("left_elbow")
    xyz[:, 0, ls] = [0.0, 0.0, 1.5]
    lengths = np.array([0.30, 0.32, 0.30, 0.32, 0.30, 0.32])
    xyz[:, 0, le] = np.c_[np.zeros(F), np.zeros(F), 1.5 - lengths]
    kp = _kp(xyz, ids=(0,))
    assert bone_length_std(kp, bones=(("left_shoulder", "left_elbow"),)) == pytest.approx(10.0)
    # Constant-velocity estimate vs a ground truth with a 1 mm/frame^2 acceleration.
    t = np.arange(F, dtype=float)
    gt = np.zeros((F, 1, 17, 3))
    gt[:, 0, :, 0] = (0.5e-3 * t**2)[:, None]
    est = np.zeros_like(gt)
    est[:, 0, :, 0] = (1e-3 * t)[:, None]
    assert acceleration_error(_kp(est, ids=(0,)), _kp(gt, ids=(0,))) == pytest.approx(1.0)


def test_reprojection_error_hand_built() -> None:
    T = look_at_T_world_cam(np.array([5.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0]))
    rig = CameraRig(
        names=("a",), K=np.array([[[1000.0, 0, 640], [0, 1000.0, 360], [0, 0, 1]]]), dist=np.zeros((1, 5)),
        T_world_cam=T[None], image_size_wh=np.array([[1280, 720]]), fps=50.0,
    )
    xyz = np.zeros((2, 1, 17, 3))
    xyz[..., 2] = np.linspace(0.1, 1.7, 17)
    kp = _kp(xyz, ids=(4,))
    uv, _ = project(rig, xyz[:, 0])
    kpx = uv[0].copy()
    kpx[0, 3] += [3.0, 4.0]  # 5 px off in frame 0, joint 3
    valid = np.ones((2, 17), bool)
    valid[1, 5] = False
    tracks = Tracks2D(
        joint_names=COCO17, n_views=1, n_frames=2, view=np.zeros(2, np.int64), frame=np.arange(2),
        bbox_xyxy_px=np.tile([0.0, 0.0, 10.0, 10.0], (2, 1)), bbox_score=np.ones(2), keypoints_px=kpx,
        keypoint_conf=np.ones((2, 17)), keypoint_valid=valid, track_id=np.zeros(2, np.int64),
    )
    assoc = Association(person_ids=np.array([4]), person_names=("",), person_of_det=np.array([4, 4]), confidence=np.ones(2))
    err = reprojection_error(kp, tracks, assoc, rig)
    assert err[0, 3] == pytest.approx(5.0)
    assert np.nanmax(np.delete(err[0], 3)) < 1e-9
    assert np.isnan(err[1, 5]) and np.isfinite(err[1, 4])
    # A detection of nobody has no error.
    assoc2 = Association(person_ids=np.array([4]), person_names=("",), person_of_det=np.array([-1, 4]), confidence=np.ones(2))
    assert np.isnan(reprojection_error(kp, tracks, assoc2, rig)[0]).all()
