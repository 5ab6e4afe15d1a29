"""evaluate stage: the physics effort per frame (residual root force, joint torque over the
human limit) as problem flags and counts, on hand-made physics results."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pipeline.evaluate.effort import GRAVITY, HUMAN_PEAK_TORQUE_NM_PER_KG
from pipeline.schema import COCO17, Association, Keypoints3D
from pipeline.schema.results import PhysicsResult
from pipeline.stages.evaluate import (
    FLAG_KINDS,
    LEGACY_FLAG_KINDS,
    EvaluateConfig,
    EvaluateInputs,
    PhysicsEffortInputs,
    ProblemFlags,
    run,
)
from tests.conftest import make_rig, make_tracks

MASS = np.array([80.0, 60.0])
NAMES = ("p0_left_knee", "p0_res_x", "p1_left_knee", "p1_right_elbow")
PHYS_FRAMES = np.arange(2, 12)
"""Video frames of the physics result: 2..11, the shown result has 0..9."""


def _physics() -> PhysicsEffortInputs:
    F = PHYS_FRAMES.size
    tau = np.zeros((F, len(NAMES)))
    tau[:, 1] = 1e4  # residual servos are not joints
    tau[4 - 2, 2] = 1.5 * HUMAN_PEAK_TORQUE_NM_PER_KG["knee"] * 60.0  # frame 4: person 1's knee at 1.5x
    tau[7 - 2, 0] = 0.9 * HUMAN_PEAK_TORQUE_NM_PER_KG["knee"] * 80.0  # frame 7: under the limit
    tau[10 - 2, 3] = 5.0 * HUMAN_PEAK_TORQUE_NM_PER_KG["elbow"] * 60.0  # frame 10: not shown
    res = np.zeros((F, 2, 6))
    res[5 - 2, 0, :2] = [0.06 * 80.0 * GRAVITY, 0.08 * 80.0 * GRAVITY]  # frame 5: 0.1 BW on person 0
    res[6 - 2, 1, 2] = 0.04 * 60.0 * GRAVITY  # frame 6: 0.04 BW, under the default 0.05
    res[11 - 2, 1, 2] = 1.0 * 60.0 * GRAVITY  # frame 11: not shown
    result = PhysicsResult(
        person_ids=np.array([0, 1]), frame_indices=PHYS_FRAMES, fps=50.0, qpos=np.zeros((F, 14)),
        qvel=np.zeros((F, 12)), ctrl=np.zeros((F, len(NAMES))), joint_torque_nm=tau, residual_root_force=res,
        actuation="pd", contact_frame=np.zeros(0, np.int64), contact_person=np.zeros((0, 2), np.int64),
        contact_body=np.zeros((0, 2), np.int64), contact_depth_m=np.zeros(0), body_names=(),
    )  # fmt: skip
    return PhysicsEffortInputs(result, NAMES, MASS)


def _inputs(physics: PhysicsEffortInputs | None) -> EvaluateInputs:
    rig = make_rig(3)
    tracks, X = make_tracks(rig, n_frames=10)
    kp = Keypoints3D.empty(COCO17, np.array([0, 1]), np.arange(10), 50.0, "physics").replace(
        xyz_m=X, valid=np.ones((10, 2, 17), bool), confidence=np.ones((10, 2, 17))
    )
    assoc = Association(np.array([0, 1]), ("A", "B"), tracks.track_id.copy(), np.ones(tracks.n_dets))
    return EvaluateInputs(rig, tracks, assoc, {"physics": kp}, physics=physics)


def _col(flags: ProblemFlags, key: str) -> list[int]:
    col = flags.column(key)
    assert col is not None
    return np.flatnonzero(col).tolist()


def test_residual_and_torque_flags_per_frame() -> None:
    metrics, flags = run(_inputs(_physics()), EvaluateConfig())
    assert flags.flags.shape == (10, len(FLAG_KINDS))
    assert flags.flag_kinds.tolist() == [k.key for k in FLAG_KINDS]
    expected_res = np.zeros(10)
    expected_res[5], expected_res[6] = 0.1, 0.04
    np.testing.assert_allclose(flags.residual_frac_bw, expected_res, atol=1e-12)
    assert flags.torque_ratio_max[4] == pytest.approx(1.5) and flags.torque_ratio_max[7] == pytest.approx(0.9)
    assert flags.torque_ratio_max[[0, 1, 8, 9]].tolist() == [0.0] * 4  # no physics at 0, 1; 8, 9 are quiet
    assert _col(flags, "residual_high") == [5]
    assert _col(flags, "torque_high") == [4]
    assert metrics["problem_frames"]["residual_high"] == 1 and metrics["problem_frames"]["torque_high"] == 1
    assert set(metrics["problem_frames"]) == {k.key for k in FLAG_KINDS}
    assert metrics["physics_residual_max_frac_bw"] == pytest.approx(0.1)
    assert metrics["physics_torque_ratio_max"] == pytest.approx(1.5)
    # The thresholds come from the config.
    metrics, flags = run(
        _inputs(_physics()), EvaluateConfig(residual_high_frac_bw=0.03, torque_high_ratio=0.8)
    )
    assert _col(flags, "residual_high") == [5, 6]
    assert _col(flags, "torque_high") == [4, 7]
    assert metrics["problem_frames"]["torque_high"] == 2


def test_without_physics_the_effort_is_zero_and_unflagged() -> None:
    metrics, flags = run(_inputs(None), EvaluateConfig())
    assert not flags.residual_frac_bw.any() and not flags.torque_ratio_max.any()
    assert _col(flags, "residual_high") == [] and _col(flags, "torque_high") == []
    assert "physics_residual_max_frac_bw" not in metrics
    assert metrics["problem_frames"]["residual_high"] == 0


def test_bad_physics_inputs_and_thresholds_are_refused() -> None:
    ph = _physics()
    with pytest.raises(ValueError, match="need 4 actuator names and 2 positive masses"):
        dataclasses.replace(ph, actuator_names=NAMES[:3])
    with pytest.raises(ValueError, match="need 4 actuator names and 2 positive masses"):
        dataclasses.replace(ph, mass_kg=np.array([80.0, 0.0]))
    with pytest.raises(ValueError, match="residual_high_frac_bw"):
        EvaluateConfig(residual_high_frac_bw=-0.1)
    with pytest.raises(ValueError, match="torque_high_ratio"):
        EvaluateConfig(torque_high_ratio=0.0)


def test_flags_written_before_the_physics_kinds_still_load() -> None:
    """An older problems.npz has three unnamed columns and no effort arrays."""
    old = {
        "frame_indices": np.arange(4), "identity_conf_min": np.ones(4), "reproj_err_px": np.zeros(4),
        "penetration_mm": np.zeros(4), "reproj_rel": np.zeros(4), "flags": np.array([[1, 0, 0]] * 2 + [[0, 0, 1]] * 2, bool),
    }  # fmt: skip
    pf = ProblemFlags(**old)
    assert pf.flag_kinds.tolist() == list(LEGACY_FLAG_KINDS)
    assert _col(pf, "identity_low") == [0, 1] and _col(pf, "penetration_high") == [2, 3]
    assert pf.column("residual_high") is None and pf.residual_frac_bw.size == 0
    with pytest.raises(ValueError, match=r"flags of shape \(4, 3\) for \(4,\) frames"):
        ProblemFlags(**old, flag_kinds=np.array([k.key for k in FLAG_KINDS]))


def test_untrackable_physics_windows_are_a_physics_flag_per_frame() -> None:
    """``PhysicsResult.untrackable`` (per frame and athlete) becomes the ``untrackable``
    column on the shown frames, any athlete; a result that did not record it flags nothing."""
    assert next(k for k in FLAG_KINDS if k.key == "untrackable").group == "physics"
    ph = _physics()
    bad = np.zeros((PHYS_FRAMES.size, 2), bool)
    bad[3 - 2 : 6 - 2, 1] = True  # frames 3-5: person 1's window
    bad[9 - 2, 0] = True  # frame 9: person 0
    bad[11 - 2, 0] = True  # frame 11: not shown
    metrics, flags = run(_inputs(dataclasses.replace(ph, result=dataclasses.replace(ph.result, untrackable=bad))), EvaluateConfig())
    assert _col(flags, "untrackable") == [3, 4, 5, 9]
    assert metrics["problem_frames"]["untrackable"] == 4
    _, flags = run(_inputs(ph), EvaluateConfig())  # written before the flag existed: (0, 0)
    assert ph.result.untrackable.shape == (0, 0) and _col(flags, "untrackable") == []
