"""Per-frame physics effort on hand-made torques and residual wrenches: the worst athlete's
residual in body weights and the largest joint torque over its human limit, frame by frame,
and the bout-level torque report agreeing with them."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.evaluate.effort import (
    GRAVITY,
    HUMAN_PEAK_TORQUE_NM_PER_KG,
    joint_torque_ratios,
    residual_frac_bw,
    residual_per_frame,
    torque_limit_report,
    torque_ratio_per_frame,
)

NAMES = ["p0_left_hip_x", "p0_left_hip_y", "p0_left_elbow", "p0_res_z", "p1_left_elbow"]
MASS = np.array([70.0, 50.0])


def _torques() -> np.ndarray:
    hip_lim = HUMAN_PEAK_TORQUE_NM_PER_KG["hip"] * 70.0
    elbow_lim0 = HUMAN_PEAK_TORQUE_NM_PER_KG["elbow"] * 70.0
    elbow_lim1 = HUMAN_PEAK_TORQUE_NM_PER_KG["elbow"] * 50.0
    tau = np.zeros((5, 5))
    tau[0, 0] = tau[0, 1] = 0.8 * hip_lim  # each hinge under, their norm over: sqrt(2) * 0.8
    tau[1, 4] = 0.5 * (elbow_lim0 + elbow_lim1)  # person 1's elbow (lighter limit)
    tau[2, 3] = 1e5  # a residual actuator is not a joint
    tau[3, 2] = -2.0 * elbow_lim0
    tau[4, 2] = 0.5 * elbow_lim0
    tau[4, 4] = 0.25 * elbow_lim1
    return tau


def test_torque_ratio_per_frame_is_the_worst_joint_of_the_worst_athlete() -> None:
    ratios, keys = joint_torque_ratios(_torques(), NAMES, [0, 1], MASS)
    assert keys == [(0, "left_hip"), (0, "left_elbow"), (1, "left_elbow")]
    assert ratios.shape == (5, 3)
    per_frame = torque_ratio_per_frame(_torques(), NAMES, [0, 1], MASS)
    lim1 = HUMAN_PEAK_TORQUE_NM_PER_KG["elbow"] * 50.0
    expected = [
        np.sqrt(2) * 0.8,
        0.5 * (70.0 + 50.0) * HUMAN_PEAK_TORQUE_NM_PER_KG["elbow"] / lim1,
        0.0,
        2.0,
        0.5,
    ]
    np.testing.assert_allclose(per_frame, expected, rtol=1e-12)
    # The bout-level report is built on the same ratios.
    r = torque_limit_report(_torques(), NAMES, [0, 1], MASS)
    assert r["torque_peak_ratio_max"] == pytest.approx(per_frame.max())
    assert r["torque_over_pct_any"] == pytest.approx(100.0 * 3 / 10)
    assert r["torque_over_pct_elbow"] == pytest.approx(100.0 * 2 / 10)


def test_torque_ratio_without_joint_actuators_is_zero_and_bad_input_is_refused() -> None:
    np.testing.assert_array_equal(
        torque_ratio_per_frame(np.zeros((3, 0)), [], [0], np.array([60.0])), np.zeros(3)
    )
    with pytest.raises(ValueError, match="do not match 4 actuator names"):
        torque_ratio_per_frame(_torques(), NAMES[:4], [0, 1], MASS)
    with pytest.raises(ValueError, match="positive mass"):
        torque_ratio_per_frame(_torques(), NAMES, [0, 1], np.array([70.0]))


def test_residual_per_frame_in_body_weights_of_the_worst_athlete() -> None:
    w = np.zeros((3, 2, 6))
    w[0, 0, :3] = [3.0, 4.0, 0.0]  # 5 N on person 0
    w[0, 1, 3:] = 100.0  # a residual torque is not a force
    w[1, 1, 2] = 0.1 * 50.0 * GRAVITY  # 0.1 BW upwards on person 1
    w[1, 0, 0] = -0.05 * 70.0 * GRAVITY
    frac = residual_frac_bw(w, MASS)
    np.testing.assert_allclose(frac[0], [5.0 / (70.0 * GRAVITY), 0.0])
    np.testing.assert_allclose(residual_per_frame(w, MASS), [5.0 / (70.0 * GRAVITY), 0.1, 0.0])
    with pytest.raises(ValueError, match=r"\(frames, 3, 6\)"):
        residual_frac_bw(w, np.array([70.0, 50.0, 60.0]))
