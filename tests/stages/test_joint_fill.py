"""Joint filling: missing joints placed from rigid neighbours, flagged, measured ones untouched."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.geometry.rotations import R_from_rodrigues
from pipeline.schema.base import load_npz, save_npz
from pipeline.schema.joints import COCO17_FEET
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.stages.joint_fill import TEMPLATE_M, FillConfig, rigid_align, run

TEMPLATE = np.array([TEMPLATE_M[n] for n in COCO17_FEET])


def _moving_person(n_frames: int, scale: float = 1.0, seed: int = 0) -> np.ndarray:
    """(frames, 23, 3): the template (scaled) turning and walking rigidly."""
    rng = np.random.default_rng(seed)
    out = np.zeros((n_frames, len(COCO17_FEET), 3))
    for f in range(n_frames):
        R = R_from_rodrigues(np.array([0.0, 0.0, 0.05 * f]) + rng.normal(0, 0.02, 3))
        out[f] = scale * TEMPLATE @ R.T + np.array([0.01 * f, 0.0, 0.0])
    return out


def _kp(xyz: np.ndarray, valid: np.ndarray) -> Keypoints3D:
    f = xyz.shape[0]
    return Keypoints3D(
        joint_names=COCO17_FEET,
        person_ids=np.array([0]),
        frame_indices=np.arange(f),
        fps=50.0,
        xyz_m=xyz[:, None],
        valid=valid[:, None],
        confidence=np.where(valid, 0.9, 0.0)[:, None],
        n_views=np.where(valid, 3, 0)[:, None],
        reproj_err_px=np.where(valid, 2.0, np.nan)[:, None],
        source="filtered",
    )


@pytest.mark.parametrize("scale", [1.0, 1.2])
def test_rigid_align_recovers_a_similarity(scale: float) -> None:
    rng = np.random.default_rng(1)
    src = rng.normal(size=(7, 3))
    R = R_from_rodrigues(np.array([0.3, -0.8, 1.1]))
    dst = scale * src @ R.T + np.array([1.0, 2.0, 3.0])
    s, R_est, t = rigid_align(src, dst, scale=True)
    assert s == pytest.approx(scale) and np.allclose(R_est, R) and np.allclose(t, [1, 2, 3])
    s1, R1, _ = rigid_align(src, dst, scale=False)
    assert s1 == 1.0 and np.allclose(R1, R, atol=1e-9)


def test_a_joint_missing_in_some_frames_is_carried_from_measured_frames() -> None:
    xyz = _moving_person(40)
    valid = np.ones(xyz.shape[:2], bool)
    nose, ear = COCO17_FEET.index("nose"), COCO17_FEET.index("right_ear")
    valid[10:30, nose] = False  # face turned away for 20 frames
    valid[::3, ear] = False
    out = run(_kp(xyz, valid))
    assert out.valid.all()
    assert out.filled[:, 0].sum() == (~valid).sum() and (out.filled[:, 0] == ~valid).all()
    # Rigid motion: the carried joint is exact.
    assert np.abs(out.xyz_m[:, 0] - xyz).max() < 1e-9
    # Measured joints are untouched; filled ones have a lower confidence than their anchors.
    assert np.array_equal(out.xyz_m[valid[:, None]], _kp(xyz, valid).xyz_m[valid[:, None]])
    assert (out.confidence[:, 0][~valid] < 0.9).all() and (out.confidence[:, 0][~valid] > 0).all()


def test_a_joint_never_measured_comes_from_the_template() -> None:
    xyz = _moving_person(10, scale=1.1)
    valid = np.ones(xyz.shape[:2], bool)
    toe = COCO17_FEET.index("left_small_toe")
    valid[:, toe] = False  # a detector without small toes
    out = run(_kp(xyz, valid))
    assert out.filled[:, 0, toe].all() and out.valid[:, 0, toe].all()
    # The person is the template scaled by 1.1: the similarity alignment recovers it.
    assert np.abs(out.xyz_m[:, 0, toe] - xyz[:, toe]).max() < 1e-6


def test_frames_where_the_person_is_not_seen_stay_empty_and_fill_can_be_off() -> None:
    xyz = _moving_person(12)
    valid = np.ones(xyz.shape[:2], bool)
    valid[5] = False
    valid[5, :3] = True  # three face joints only: the person is not "seen"
    nose = COCO17_FEET.index("nose")
    valid[3, nose] = False
    out = run(_kp(xyz, valid), FillConfig(min_person_joints=6))
    assert not out.filled[5].any() and out.valid[5].sum() == 3
    assert out.filled[3, 0, nose]
    off = run(_kp(xyz, valid), FillConfig(enabled=False))
    assert not off.filled.any() and not off.valid[3, 0, nose]


def test_a_bad_alignment_is_not_used() -> None:
    xyz = _moving_person(20)
    valid = np.ones(xyz.shape[:2], bool)
    nose = COCO17_FEET.index("nose")
    valid[15, nose] = False
    # Frame 15's anchors are scrambled: no exemplar or template aligns within 2x the residual.
    xyz[15, [1, 2, 3, 4, 5, 6, 11, 12]] += np.random.default_rng(0).normal(0, 0.5, (8, 3))
    out = run(_kp(xyz, valid), FillConfig(max_residual_m=0.02))
    assert not out.filled[15, 0, nose] and not out.valid[15, 0, nose]


def test_config_is_checked() -> None:
    with pytest.raises(ValueError, match="min_anchors"):
        FillConfig(min_anchors=2)
    with pytest.raises(ValueError, match="confidence_scale"):
        FillConfig(confidence_scale=0.0)


def test_filled_round_trips_and_old_artifacts_load(tmp_path: Path) -> None:
    xyz = _moving_person(5)
    valid = np.ones(xyz.shape[:2], bool)
    valid[2, 0] = False
    kp = run(_kp(xyz, valid))
    save_npz(tmp_path / "k.npz", kp)
    back = load_npz(tmp_path / "k.npz", Keypoints3D)
    assert np.array_equal(back.filled, kp.filled) and back.filled.sum() == 1
    # An artifact written before the field existed has no "filled" array: none filled.
    with np.load(tmp_path / "k.npz") as z:
        arrays = {k: z[k] for k in z.files if k != "filled"}
    np.savez(tmp_path / "old.npz", **arrays)
    old = load_npz(tmp_path / "old.npz", Keypoints3D)
    assert old.filled.shape == kp.valid.shape and not old.filled.any()
    # Changing the extent without a new mask drops it instead of failing.
    assert kp.replace(person_ids=np.array([0]), xyz_m=kp.xyz_m).filled.sum() == 0
