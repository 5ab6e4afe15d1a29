"""Shelf scoring (``pipeline.evaluate.shelf``) on hand-built skeletons (numbers checked by hand)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.evaluate.shelf import (
    PART_NAMES,
    SHELF_JOINTS,
    coco_to_shelf,
    load_ground_truth,
    score_shelf,
    shelf_head,
)
from pipeline.schema import COCO17, Keypoints3D

# A standing person in Shelf order (metres, z up, facing +y).
STANDING = np.array(
    [
        [-0.10, 0.0, 0.05],  # right_ankle
        [-0.10, 0.0, 0.50],  # right_knee
        [-0.10, 0.0, 0.95],  # right_hip
        [0.10, 0.0, 0.95],  # left_hip
        [0.10, 0.0, 0.50],  # left_knee
        [0.10, 0.0, 0.05],  # left_ankle
        [-0.20, 0.0, 0.90],  # right_wrist
        [-0.20, 0.0, 1.15],  # right_elbow
        [-0.20, 0.0, 1.45],  # right_shoulder
        [0.20, 0.0, 1.45],  # left_shoulder
        [0.20, 0.0, 1.15],  # left_elbow
        [0.20, 0.0, 0.90],  # left_wrist
        [0.00, 0.0, 1.55],  # head_bottom
        [0.00, 0.0, 1.75],  # head_top
    ]
)
J = {n: i for i, n in enumerate(SHELF_JOINTS)}
P = {n: i for i, n in enumerate(PART_NAMES)}


def _kp(
    xyz: np.ndarray, valid: np.ndarray | None = None, names: tuple[str, ...] = SHELF_JOINTS
) -> Keypoints3D:
    f, p, j, _ = xyz.shape
    return Keypoints3D(
        joint_names=names,
        person_ids=np.arange(p),
        frame_indices=np.arange(f),
        fps=25.0,
        xyz_m=xyz,
        valid=np.ones((f, p, j), bool) if valid is None else valid,
        confidence=np.ones((f, p, j)),
        n_views=np.zeros((f, p, j), np.int64),
        reproj_err_px=np.full((f, p, j), np.nan),
        source="gt",
    )


def _gt(frames: int = 2) -> Keypoints3D:
    """Three actors side by side, 2 m apart, for ``frames`` frames."""
    xyz = np.stack([STANDING + [2.0 * a, 0.0, 0.0] for a in range(3)])
    return _kp(np.repeat(xyz[None], frames, axis=0))


def test_gt_against_itself_is_perfect() -> None:
    gt = _gt()
    s = score_shelf(gt, gt)
    assert s.pcp == 1.0
    np.testing.assert_array_equal(s.pcp_per_actor, [1.0, 1.0, 1.0])
    np.testing.assert_array_equal(s.pcp_per_part, np.ones((3, 10)))
    assert s.mpjpe_mm == 0.0
    assert s.coverage == 1.0
    np.testing.assert_array_equal(s.matched_person, [[0, 1, 2], [0, 1, 2]])


@pytest.mark.parametrize(("shift_frac", "correct"), [(0.9, True), (1.1, False)])
def test_lower_leg_displaced_by_half_its_length(shift_frac: float, correct: bool) -> None:
    # The right ankle moves sideways by shift_frac × the lower leg's length (0.45 m): the
    # mean endpoint error is half that (the knee stays), against the 0.5 × length limit.
    gt = _gt(frames=1)
    xyz = gt.xyz_m.copy()
    xyz[0, 0, J["right_ankle"], 0] += shift_frac * 0.45
    s = score_shelf(gt.replace(xyz_m=xyz), gt)
    assert s.pcp_per_part[0, P["right_lower_leg"]] == (1.0 if correct else 0.0)
    assert s.pcp_per_actor[0] == pytest.approx(1.0 if correct else 0.9)
    np.testing.assert_array_equal(s.pcp_per_actor[1:], [1.0, 1.0])


def test_missing_predicted_person_scores_zero() -> None:
    gt = _gt(frames=2)
    # Only actor 1 is predicted; in frame 1 nobody is.
    pred = _kp(gt.xyz_m[:, 1:2].copy(), valid=np.array([[[True] * 14], [[False] * 14]]))
    s = score_shelf(pred, gt)
    # Actors 0 and 2 are matched to the prediction in frame 0 (it is the nearest, 2 m off,
    # every part wrong) and to nobody in frame 1; actor 1 is right in frame 0 only.
    np.testing.assert_array_equal(s.matched_person, [[0, 0, 0], [-1, -1, -1]])
    np.testing.assert_allclose(s.pcp_per_actor, [0.0, 0.5, 0.0])
    np.testing.assert_array_equal(s.n_frames_matched, [1, 1, 1])
    # An empty prediction matches nobody.
    empty = _kp(np.zeros((2, 0, 14, 3)))
    e = score_shelf(empty, gt)
    np.testing.assert_array_equal(e.pcp_per_actor, [0.0, 0.0, 0.0])
    assert e.coverage == 0.0
    assert np.isnan(e.mpjpe_mm)


def test_frames_missing_from_the_prediction_score_zero() -> None:
    gt = _gt(frames=4)
    pred = _kp(gt.xyz_m[:2].copy())  # frames 0 and 1 only
    s = score_shelf(pred, gt)
    np.testing.assert_allclose(s.pcp_per_actor, [0.5, 0.5, 0.5])
    np.testing.assert_array_equal(s.matched_person[2:], -1)


def test_invalid_joint_makes_its_parts_wrong() -> None:
    gt = _gt(frames=1)
    valid = gt.valid.copy()
    valid[0, 0, J["left_elbow"]] = False
    valid[0, 0, J["left_hip"]] = False
    xyz = gt.xyz_m.copy()
    xyz[0, 0, J["left_hip"]] = np.nan  # what an invalid entry holds must not matter
    s = score_shelf(gt.replace(xyz_m=xyz, valid=valid), gt)
    wrong = {"left_upper_arm", "left_lower_arm", "left_upper_leg", "torso"}  # torso: hips midpoint
    for name in PART_NAMES:
        assert s.pcp_per_part[0, P[name]] == (0.0 if name in wrong else 1.0), name
    assert s.pcp_per_actor[0] == pytest.approx(0.6)
    assert s.mpjpe_mm == 0.0  # invalid joints are left out of MPJPE
    assert s.joints_valid_frac == pytest.approx((42 - 2) / 42)


def test_matching_picks_the_nearest_person_per_frame() -> None:
    gt = _gt(frames=2)
    # Predicted persons in reverse order in frame 0, in order in frame 1; a decoy near
    # actor 0 in frame 1 but 20 cm further off than the true one.
    xyz = np.zeros((2, 4, 14, 3))
    xyz[0, :3] = gt.xyz_m[0, ::-1]
    xyz[1, :3] = gt.xyz_m[1]
    xyz[:, 3] = gt.xyz_m[:, 0] + [0.0, 0.25, 0.0]
    xyz[1, 0] += [0.0, 0.05, 0.0]
    s = score_shelf(_kp(xyz), gt)
    np.testing.assert_array_equal(s.matched_person, [[2, 1, 0], [0, 1, 2]])
    np.testing.assert_array_equal(s.pcp_per_actor, [1.0, 1.0, 1.0])


def test_head_from_coco_follows_voxelpose() -> None:
    # Shoulders at 1.4 m, ears at 1.6 m, nose 10 cm in front at 1.58 m:
    # shoulder mid (0, 0, 1.4), ear mid (0, 0, 1.6); ear-based bottom (0, 0, 1.5), top (0, 0, 1.7);
    # nose-based bottom (0, 0.05, 1.49), top (0, 0.075, 1.67); blended 3:1.
    coco = np.zeros((1, 1, 17, 3))
    pts = {
        "nose": (0.0, 0.1, 1.58),
        "left_ear": (0.08, 0.0, 1.6),
        "right_ear": (-0.08, 0.0, 1.6),
        "left_shoulder": (0.2, 0.0, 1.4),
        "right_shoulder": (-0.2, 0.0, 1.4),
    }
    for name, p in pts.items():
        coco[0, 0, COCO17.index(name)] = p
    bottom, top = shelf_head(*(np.array(pts[n]) for n in pts))
    np.testing.assert_allclose(bottom, [0.0, 0.0375, 1.4925], atol=1e-12)
    np.testing.assert_allclose(top, [0.0, 0.05625, 1.6775], atol=1e-12)

    shelf = coco_to_shelf(_kp(coco, names=COCO17))
    assert shelf.joint_names == SHELF_JOINTS
    np.testing.assert_allclose(shelf.xyz_m[0, 0, J["head_bottom"]], bottom)
    np.testing.assert_allclose(shelf.xyz_m[0, 0, J["head_top"]], top)
    np.testing.assert_allclose(shelf.xyz_m[0, 0, J["left_shoulder"]], pts["left_shoulder"])
    # Without an ear there is no head.
    valid = np.ones((1, 1, 17), bool)
    valid[0, 0, COCO17.index("right_ear")] = False
    no_ear = coco_to_shelf(_kp(coco, valid=valid, names=COCO17))
    assert not no_ear.valid[0, 0, J["head_bottom"]] and not no_ear.valid[0, 0, J["head_top"]]
    assert no_ear.valid[0, 0, : J["head_bottom"]].all()


def test_mpjpe_of_a_10_mm_shift_is_10_mm() -> None:
    gt = _gt()
    s = score_shelf(gt.replace(xyz_m=gt.xyz_m + [0.006, -0.008, 0.0]), gt)
    assert s.mpjpe_mm == pytest.approx(10.0)
    assert s.pcp == 1.0


def test_bad_arguments_name_the_values() -> None:
    gt = _gt(frames=1)
    with pytest.raises(ValueError, match=r"actors \[5\]"):
        score_shelf(gt, gt, actors=(0, 5))
    with pytest.raises(ValueError, match="alpha"):
        score_shelf(gt, gt, alpha=0.0)
    with pytest.raises(ValueError, match="nose"):
        coco_to_shelf(_kp(np.zeros((1, 1, 3, 3)), names=("left_hip", "right_hip", "left_ear")))


@pytest.mark.requires_data
def test_real_ground_truth_loads(test_data_dir: Path) -> None:
    path = test_data_dir / "shelf" / "gt.npz"
    if not path.exists():
        pytest.skip(f"Shelf ground truth not found at {path}")
    gt = load_ground_truth(path)
    assert gt.joint_names == SHELF_JOINTS
    assert gt.xyz_m.shape == (301, 4, 14, 3)
    assert gt.fps == 25.0
    # Actors are present or absent as a whole, and present ones stand on the floor.
    present = gt.valid.any(-1)
    np.testing.assert_array_equal(present, gt.valid.all(-1))
    assert present[:, :3].sum() > 400
    assert np.isfinite(gt.xyz_m).all()
    z = gt.xyz_m[..., 2][gt.valid]
    assert -0.2 < z.min() < 0.2 and 1.4 < z.max() < 2.2
    rng = np.random.default_rng(0)
    noisy = gt.replace(xyz_m=gt.xyz_m + rng.normal(scale=0.05, size=gt.xyz_m.shape))
    assert score_shelf(gt, gt).pcp == 1.0
    assert 0.8 < score_shelf(noisy, gt).pcp < 1.0
