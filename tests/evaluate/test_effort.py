"""Physics effort metrics: torque limits on hand-made torques, and the floor force of a body
at rest replayed in real MuJoCo (with and without a residual)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from pipeline.backends.mujoco.forces import body_masses_kg, ground_reaction_forces
from pipeline.evaluate.effort import (
    GRAVITY,
    HUMAN_PEAK_TORQUE_NM_PER_KG,
    force_balance_report,
    group_of_joint,
    joint_of_actuator,
    torque_limit_report,
)
from pipeline.schema.results import PhysicsResult


def test_actuator_names_map_to_joints_and_groups() -> None:
    assert joint_of_actuator("p0_left_hip_x") == "left_hip"
    assert joint_of_actuator("p12_right_elbow_twist") == "right_elbow_twist"
    assert joint_of_actuator("p1_left_wrist_flex") == "left_wrist"
    assert group_of_joint("right_elbow_twist") == "forearm_twist"
    assert group_of_joint("right_elbow") == "elbow"
    assert group_of_joint("left_knee_twist") == "shin_twist"
    with pytest.raises(ValueError, match="tail"):
        group_of_joint("tail")


def test_torque_over_limit_counts_joint_norms_per_group() -> None:
    mass = np.array([70.0, 50.0])
    names = ["p0_left_hip_x", "p0_left_hip_y", "p0_left_elbow", "p0_res_z", "p1_left_elbow"]
    hip_lim = HUMAN_PEAK_TORQUE_NM_PER_KG["hip"] * 70.0
    elbow_lim0 = HUMAN_PEAK_TORQUE_NM_PER_KG["elbow"] * 70.0
    elbow_lim1 = HUMAN_PEAK_TORQUE_NM_PER_KG["elbow"] * 50.0
    tau = np.zeros((4, 5))
    # Frame 0: each hip hinge below the limit, their norm above it.
    tau[0, 0] = tau[0, 1] = 0.8 * hip_lim
    # Frame 1: person 1's elbow over its (lighter) limit, but under person 0's.
    tau[1, 4] = 0.5 * (elbow_lim0 + elbow_lim1)
    # Frame 2: a huge residual force is not a joint torque.
    tau[2, 3] = 1e5
    tau[3, 2] = -2.0 * elbow_lim0
    r = torque_limit_report(tau, names, [0, 1], mass)
    assert r["torque_over_pct_hip"] == pytest.approx(100.0 * 1 / 4)
    assert r["torque_over_pct_elbow"] == pytest.approx(100.0 * 2 / 8)
    assert r["torque_over_pct_any"] == pytest.approx(100.0 * 3 / 8)
    assert r["torque_peak_ratio_max"] == pytest.approx(2.0)
    with pytest.raises(ValueError, match="positive mass"):
        torque_limit_report(tau, names, [0, 1], np.array([70.0, 0.0]))


_BLOCK = """
<mujoco>
  <option timestep="0.005"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    <body name="p0_pelvis" pos="0 0 0.2">
      <joint name="p0_root_x" type="slide" axis="1 0 0"/>
      <joint name="p0_root_y" type="slide" axis="0 1 0"/>
      <joint name="p0_root_z" type="slide" axis="0 0 1"/>
      <joint name="p0_root" type="ball"/>
      <geom name="p0_pelvis_g0" type="box" size="0.2 0.1 0.1" mass="60"/>
    </body>
  </worldbody>
</mujoco>
"""


def _settled_result(residual_up_n: float) -> PhysicsResult:
    m = mujoco.MjModel.from_xml_string(_BLOCK)
    d = mujoco.MjData(m)
    for _ in range(2000):
        mujoco.mj_step(m, d)
    F = 3
    res = np.zeros((F, 1, 6))
    res[:, 0, 2] = residual_up_n
    return PhysicsResult(
        person_ids=np.array([0]),
        frame_indices=np.arange(F),
        fps=50.0,
        qpos=np.tile(d.qpos, (F, 1)),
        qvel=np.tile(d.qvel, (F, 1)),
        ctrl=np.zeros((F, 0)),
        joint_torque_nm=np.zeros((F, 0)),
        residual_root_force=res,
        actuation="pd",
        contact_frame=np.zeros(0, dtype=np.int64),
        contact_person=np.zeros((0, 2), dtype=np.int64),
        contact_body=np.zeros((0, 2), dtype=np.int64),
        contact_depth_m=np.zeros(0),
        body_names=(),
    )


def test_floor_carries_a_resting_body_and_a_residual_takes_its_share() -> None:
    mass = body_masses_kg(_BLOCK, [0])
    assert mass[0] == pytest.approx(60.0)
    bw = 60.0 * GRAVITY
    grf = ground_reaction_forces(_BLOCK, _settled_result(0.0))
    assert grf.shape == (3, 1, 3)
    assert grf[..., 2] == pytest.approx(bw, rel=0.02)
    assert np.abs(grf[..., :2]).max() < 0.01 * bw
    held = _settled_result(0.3 * bw)
    grf_held = ground_reaction_forces(_BLOCK, held)
    assert grf_held[..., 2] == pytest.approx(0.7 * bw, rel=0.03)
    r = force_balance_report(grf_held, held.residual_root_force, mass)
    assert r["grf_z_mean_frac_bw"] == pytest.approx(0.7, abs=0.02)
    assert r["residual_z_mean_frac_bw"] == pytest.approx(0.3)
    assert r["residual_xy_mean_frac_bw"] == 0.0 and r["grf_airborne_pct"] == 0.0
