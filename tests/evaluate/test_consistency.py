"""Consistency metrics on data built in code: exact and perturbed projections, known motion."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.evaluate.consistency import (
    consistency,
    coverage_pct,
    mean_acceleration_mm_per_frame2,
    planted_feet,
    reprojection_by_camera,
    without_absent_foot_points,
)
from pipeline.evaluate.metrics import bone_length_std
from pipeline.schema import COCO17_FEET, CameraRig, Keypoints3D, Tracks2D
from pipeline.schema.joints import RIGID_BONES
from tests.conftest import fit_stage_inputs, make_rig


def _skeleton(frames: int = 6, persons: int = 2, seed: int = 0) -> np.ndarray:
    """(frames, persons, 23, 3) a fixed random pose per person, persons 1.5 m apart, static."""
    rng = np.random.default_rng(seed)
    pose = rng.normal(0.0, 0.25, size=(persons, len(COCO17_FEET), 3)) + np.array([0.0, 0.0, 1.0])
    pose[:, :, 0] += 1.5 * np.arange(persons)[:, None] - 0.75
    return np.repeat(pose[None], frames, axis=0)


def _kp(xyz: np.ndarray, valid: np.ndarray | None = None, fps: float = 50.0) -> Keypoints3D:
    f, p, j, _ = xyz.shape
    return Keypoints3D(
        joint_names=COCO17_FEET,
        person_ids=np.arange(p),
        frame_indices=np.arange(f),
        fps=fps,
        xyz_m=xyz,
        valid=np.ones((f, p, j), bool) if valid is None else valid,
        confidence=np.ones((f, p, j)),
        n_views=np.zeros((f, p, j), np.int64),
        reproj_err_px=np.full((f, p, j), np.nan),
        source="fit",
    )


def _front_rig() -> CameraRig:
    """One camera at (0, -5, 1) looking along +y (camera x = world x, y = -world z), f = 1000 px."""
    T = np.eye(4)
    T[:3, :3] = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # columns: camera x, y, z in world
    T[:3, 3] = [0.0, -5.0, 1.0]
    return CameraRig(
        names=("front",),
        K=np.array([[[1000.0, 0, 640], [0, 1000.0, 360], [0, 0, 1]]]),
        dist=np.zeros((1, 5)),
        T_world_cam=T[None],
        image_size_wh=np.array([[1280, 720]]),
        fps=50.0,
    )


def test_exact_projections_give_zero_error() -> None:
    rig = make_rig(3)
    kp, tracks, assoc = fit_stage_inputs(rig, _skeleton())
    rep = reprojection_by_camera(kp, tracks, assoc, rig)
    assert rep.camera_names == rig.names
    np.testing.assert_allclose(rep.median_px, 0.0, atol=1e-6)
    np.testing.assert_allclose(rep.p95_px, 0.0, atol=1e-6)
    assert rep.p95_all_px == pytest.approx(0.0, abs=1e-6)
    assert rep.n_scored.tolist() == [6 * 2 * 23] * 3
    assert rep.scored_pct == pytest.approx(100.0)


def test_shifted_joints_give_focal_times_shift_over_depth() -> None:
    """Joints in the plane 5 m in front of the camera, moved 5 cm sideways: 1000 px * 0.05 / 5 = 10 px."""
    rig = _front_rig()
    n = len(COCO17_FEET)
    xyz = np.zeros((1, 1, n, 3))
    xyz[..., 0] = np.linspace(-0.4, 0.4, n)
    xyz[..., 2] = np.linspace(0.3, 1.8, n)  # world y = 0: depth 5 m for every joint
    kp, tracks, assoc = fit_stage_inputs(rig, xyz)
    moved = xyz.copy()
    moved[..., 0] += 0.05
    moved[0, 0, :4, 2] += 0.10  # and 4 joints 10 cm up on top: 20 px up, 10 px across
    rep = reprojection_by_camera(kp.replace(xyz_m=moved), tracks, assoc, rig)
    err = np.full(n, 10.0)
    err[:4] = np.hypot(10.0, 20.0)
    assert rep.median_all_px == pytest.approx(10.0, rel=1e-9)
    assert rep.p95_all_px == pytest.approx(np.hypot(10.0, 20.0), rel=1e-9)
    assert rep.median_px.tolist() == pytest.approx([10.0], rel=1e-9)


def test_per_camera_aggregation_puts_errors_in_their_camera() -> None:
    rig = make_rig(3)
    kp, tracks, assoc = fit_stage_inputs(rig, _skeleton())
    px = tracks.keypoints_px.copy()
    px[tracks.view == 1] += np.array([3.0, 4.0])  # 5 px off in the second camera only
    rep = reprojection_by_camera(kp, _with(tracks, keypoints_px=px), assoc, rig)
    np.testing.assert_allclose(rep.median_px, [0.0, 5.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(rep.p95_px, [0.0, 5.0, 0.0], atol=1e-6)
    assert rep.median_all_px == pytest.approx(0.0, abs=1e-6)  # two cameras of three are exact
    assert rep.p95_all_px == pytest.approx(5.0, abs=1e-6)


def _with(tracks: Tracks2D, **fields: np.ndarray) -> Tracks2D:
    return Tracks2D(**{**tracks.__dict__, **fields})


def test_low_confidence_keypoints_are_excluded() -> None:
    rig = make_rig(2)
    kp, tracks, assoc = fit_stage_inputs(rig, _skeleton())
    px, conf = tracks.keypoints_px.copy(), tracks.keypoint_conf.copy()
    bad = np.zeros_like(conf, dtype=bool)
    bad[::2, :5] = True  # 5 joints of every other detection: 100 px off, confidence 0.2
    px[bad] += 100.0
    conf[bad] = 0.2
    t = _with(tracks, keypoints_px=px, keypoint_conf=conf)
    strict = reprojection_by_camera(kp, t, assoc, rig, min_keypoint_conf=0.5)
    assert strict.p95_all_px == pytest.approx(0.0, abs=1e-6)
    assert strict.n_scored.sum() == (~bad).sum()
    assert strict.n_confident == (~bad).sum()
    loose = reprojection_by_camera(kp, t, assoc, rig, min_keypoint_conf=0.1)
    assert loose.n_scored.sum() == bad.size
    assert loose.p95_all_px == pytest.approx(100.0 * np.sqrt(2), rel=1e-6)


def test_unassociated_detections_and_invalid_3d_joints_are_not_scored() -> None:
    rig = make_rig(2)
    kp, tracks, assoc = fit_stage_inputs(rig, _skeleton())
    nobody = np.where(tracks.track_id == 1, -1, assoc.person_of_det)  # person 1 unassociated
    a = type(assoc)(**{**assoc.__dict__, "person_of_det": nobody})
    valid = kp.valid.copy()
    valid[:, 0, 0] = False  # person 0's nose never triangulated
    far = kp.xyz_m.copy()
    far[:, 0, 0] += 10.0  # meaningless coordinates where invalid
    rep = reprojection_by_camera(kp.replace(valid=valid, xyz_m=far), tracks, a, rig)
    assert rep.p95_all_px == pytest.approx(0.0, abs=1e-6)
    n_person0 = int((nobody >= 0).sum())
    assert rep.n_confident == n_person0 * 23
    assert rep.n_scored.sum() == n_person0 * 22
    assert rep.scored_pct == pytest.approx(100.0 * 22 / 23)


def test_bad_inputs_raise() -> None:
    rig = make_rig(2)
    kp, tracks, assoc = fit_stage_inputs(rig, _skeleton())
    with pytest.raises(ValueError, match="min_keypoint_conf"):
        reprojection_by_camera(kp, tracks, assoc, rig, min_keypoint_conf=1.5)
    with pytest.raises(ValueError, match="views"):
        reprojection_by_camera(kp, tracks, assoc, make_rig(3))


def test_constant_velocity_has_zero_acceleration_even_with_gaps() -> None:
    frames = 10
    xyz = _skeleton(frames)
    xyz = xyz + np.arange(frames)[:, None, None, None] * np.array([0.01, -0.02, 0.005])
    valid = np.ones(xyz.shape[:3], bool)
    valid[4, 0, :] = False
    xyz[4, 0, :] = 0.0  # meaningless where invalid: must not read as a jump
    kp = _kp(xyz, valid)
    assert mean_acceleration_mm_per_frame2(kp) == pytest.approx(0.0, abs=1e-9)
    jolt = xyz.copy()
    jolt[5, 1, 3, 2] += 0.002  # one joint 2 mm up for one frame: |a| = 2, 4, 2 mm/f^2
    acc = mean_acceleration_mm_per_frame2(_kp(jolt, valid))
    n_triplets = (frames - 2) * 2 * 23 - 3 * 23  # person 0 loses the triplets around frame 4
    assert acc == pytest.approx((2 + 4 + 2) / n_triplets, rel=1e-9)


def test_rigid_skeleton_has_zero_bone_std_and_known_overlap() -> None:
    frames = 8
    xyz = _skeleton(frames) + np.arange(frames)[:, None, None, None] * np.array([0.0, 0.03, 0.0])
    c = consistency(_kp(xyz), *fit_stage_inputs(make_rig(2), xyz)[1:], make_rig(2))
    assert c.bone_length_std_mm == pytest.approx(0.0, abs=1e-6)
    assert c.accel_mm_per_frame2 == pytest.approx(0.0, abs=1e-9)
    assert c.coverage_pct == pytest.approx(100.0)
    d = c.to_dict()
    assert d["reproj_cam1_median_px"] == pytest.approx(0.0, abs=1e-6)
    assert {
        "reproj_median_px",
        "reproj_p95_px",
        "bone_length_std_mm",
        "overlap_max_mm",
        "accel_m_per_s2",
    } <= set(d)
    same = np.repeat(xyz[:, :1], 2, axis=1)  # two persons in the same place overlap deeply
    assert (
        consistency(_kp(same), *fit_stage_inputs(make_rig(2), same)[1:], make_rig(2)).overlap_max_mm > 100.0
    )


def test_stretching_bone_has_known_std() -> None:
    xyz = _skeleton(2, persons=1)
    wrist = COCO17_FEET.index("left_wrist")
    elbow = COCO17_FEET.index("left_elbow")
    xyz[1, 0, wrist] = xyz[0, 0, wrist] + 0.02 * (xyz[0, 0, wrist] - xyz[0, 0, elbow]) / np.linalg.norm(
        xyz[0, 0, wrist] - xyz[0, 0, elbow]
    )  # the forearm 20 mm longer in the second frame: std 10 mm over 2 frames, other bones 0
    n_bones = sum(a in COCO17_FEET and b in COCO17_FEET for a, b in RIGID_BONES)
    assert [b for b in RIGID_BONES if "left_wrist" in b] == [("left_elbow", "left_wrist")]
    assert bone_length_std(_kp(xyz)) == pytest.approx(10.0 / n_bones, rel=1e-6)


def _feet_on_floor(frames: int, slide_m_per_frame: float) -> np.ndarray:
    """(frames, 1, 23, 3): a standing person, foot points at z = 1 cm, sliding along x."""
    xyz = _skeleton(frames, persons=1)
    feet = [i for i, n in enumerate(COCO17_FEET) if n.endswith(("heel", "toe"))]
    xyz[:, :, feet, 2] = 0.01
    xyz[:, :, :, 0] += slide_m_per_frame * np.arange(frames)[:, None, None]
    return xyz


def test_foot_skating_on_planted_feet() -> None:
    rig = make_rig(2)
    still = _feet_on_floor(6, 0.0)
    c = consistency(_kp(still), *fit_stage_inputs(rig, still)[1:], rig)
    assert c.planted_pct == pytest.approx(100.0)
    assert c.foot_skate_mm_per_frame == pytest.approx(0.0, abs=1e-9)
    sliding = _feet_on_floor(6, 0.002)
    c = consistency(_kp(sliding), *fit_stage_inputs(rig, sliding)[1:], rig)
    assert c.foot_skate_mm_per_frame == pytest.approx(2.0, rel=1e-6)
    assert c.accel_mm_per_frame2 == pytest.approx(0.0, abs=1e-9)


def test_invalid_or_absent_foot_points_are_not_planted() -> None:
    xyz = _feet_on_floor(4, 0.0)
    xyz[:, :, :, 2] += 0.5  # every joint well above the floor...
    small = [COCO17_FEET.index("left_small_toe"), COCO17_FEET.index("right_small_toe")]
    valid = np.ones(xyz.shape[:3], bool)
    valid[:, :, small] = False
    xyz[:, :, small] = 0.0  # ...but the small toes, never valid, sit at 0 (a 2D model without them)
    kp = without_absent_foot_points(_kp(xyz, valid))
    assert "left_small_toe" not in kp.joint_names and "left_heel" in kp.joint_names
    assert not planted_feet(kp).any()
    heel = COCO17_FEET.index("left_heel")
    valid2 = np.ones(xyz.shape[:3], bool)
    valid2[1, 0, heel] = False
    low = _feet_on_floor(4, 0.0)
    contact = planted_feet(_kp(low, valid2))
    assert not contact[1, 0, 0] and contact[1, 0, 1] and contact[0, 0, 0]


def test_coverage_counts_valid_entries() -> None:
    xyz = _skeleton(4)
    valid = np.ones(xyz.shape[:3], bool)
    valid[0] = False
    assert coverage_pct(_kp(xyz, valid)) == pytest.approx(75.0)
