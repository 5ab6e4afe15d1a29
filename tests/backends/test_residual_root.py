"""The residual root torque of the physics stage (``TrackingCost.set_residual``): its
damping is the root joint's (implicit in MuJoCo), the rest is applied explicitly."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from pipeline.backends.mujoco.config import CostWeights, HumanoidConfig  # noqa: E402
from pipeline.backends.mujoco.reference import build_reference, build_scene  # noqa: E402
from pipeline.backends.mujoco.skeleton import skeleton_from_keypoints  # noqa: E402
from pipeline.backends.mujoco.tracking import TrackingCost  # noqa: E402
from tests.backends.test_humanoid import _rest_keypoints  # noqa: E402

SATURATION_RAD = 0.03


def _standing(n_frames: int = 40) -> tuple[object, TrackingCost, np.ndarray]:
    kp = _rest_keypoints(1.0, n_frames)
    scene = build_scene([skeleton_from_keypoints(kp, 0)], [0], kp.fps, kp.joint_names, HumanoidConfig())
    ref, _, _ = build_reference(scene, kp, [0], separate=False)
    cost = TrackingCost(scene.model, scene.layout, ref, CostWeights())
    bw = scene.layout.persons[0].mass_kg * 9.81
    return scene, cost, np.array([bw * 0.3])


def test_residual_damping_is_the_root_joints_and_is_restored() -> None:
    scene, cost, limit = _standing()
    m, p = scene.model, scene.layout.persons[0]
    rot = slice(p.qvel_adr + 3, p.qvel_adr + 6)
    before = m.dof_damping.copy()
    cost.set_residual(True, limit, SATURATION_RAD)
    kd = 2.0 * np.sqrt(limit[0] / SATURATION_RAD * p.mass_kg * 0.15**2)
    assert np.allclose(m.dof_damping[rot], before[rot] + kd)
    others = np.ones(m.nv, bool)
    others[rot] = False
    assert np.array_equal(m.dof_damping[others], before[others])
    # At the reference's orientation and angular velocity, only the feed-forward acts:
    # the explicit +kd ω̂ and the joint's −kd ω cancel.
    t = 5
    qpos, qvel = cost.ref.qpos[t].copy(), cost.ref.qvel[t].copy()
    ff = cost.ref.root_torque_ff[t, 0] if cost.ref.root_torque_ff is not None else np.zeros(3)
    ff = ff if np.linalg.norm(ff) <= limit[0] else ff * limit[0] / np.linalg.norm(ff)
    assert np.allclose(cost.root_torque(qpos, qvel, t)[0], ff, atol=1e-6)
    # Spinning 1 rad/s faster than the reference about the root's z axis: −kd about z.
    qvel[p.qvel_adr + 5] += 1.0
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, qpos[p.qpos_adr + 3 : p.qpos_adr + 7])
    expected = ff - kd * R.reshape(3, 3)[:, 2]
    assert np.allclose(cost.root_torque(qpos, qvel, t)[0], expected, atol=1e-6)
    cost.set_residual(False)
    assert np.array_equal(m.dof_damping, before)
    assert np.array_equal(cost.root_torque(qpos, qvel, t), np.zeros((1, 3)))


def _hold_tilted_root(scene: object, cost: TrackingCost, explicit_damping: bool) -> float:
    """Free-floating body (no gravity, no contacts) tilted 0.3 rad off its reference,
    held by a stiff residual for 0.5 s; returns the final orientation error (rad), or
    inf if the simulation blew up. ``explicit_damping``: the damping computed in Python
    before each step (the old scheme) instead of by the joint."""
    m, p = scene.model, scene.layout.persons[0]
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_GRAVITY) | int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    rot = slice(p.qvel_adr + 3, p.qvel_adr + 6)
    d = mujoco.MjData(m)
    d.qpos[:] = cost.ref.qpos[0]
    d.ctrl[:] = cost.ref.ctrl[0]
    tilt = np.zeros(4)
    mujoco.mju_axisAngle2Quat(tilt, np.array([1.0, 0.0, 0.0]), 0.3)
    q = np.zeros(4)
    mujoco.mju_mulQuat(q, cost.ref.qpos[0, p.qpos_adr + 3 : p.qpos_adr + 7], tilt)
    d.qpos[p.qpos_adr + 3 : p.qpos_adr + 7] = q
    kd = float(m.dof_damping[rot][0]) if explicit_damping else 0.0
    if explicit_damping:
        m.dof_damping[rot] = 0.0
    steps = int(round(0.5 / m.opt.timestep))
    for _ in range(steps):
        cost.prepare(m, d, 0)
        if explicit_damping:
            R = d.xmat[p.root_body].reshape(3, 3)
            d.xfrc_applied[p.root_body, 3:6] -= kd * (R @ d.qvel[rot])
        mujoco.mj_step(m, d)
        if not np.all(np.isfinite(d.qvel)) or np.abs(d.qvel).max() > 1e3:
            return float("inf")
    err = np.zeros(3)
    mujoco.mju_subQuat(err, d.qpos[p.qpos_adr + 3 : p.qpos_adr + 7], cost.ref.qpos[0, p.qpos_adr + 3 : p.qpos_adr + 7])
    return float(np.linalg.norm(err))


def test_a_stiff_residual_holds_the_root_where_explicit_damping_diverges() -> None:
    strong = 30.0  # 30 body weights x 0.3 m: the stiffness at which the old scheme failed
    scene, cost, limit = _standing()
    cost.set_residual(True, strong * limit, SATURATION_RAD)
    assert _hold_tilted_root(scene, cost, explicit_damping=False) < 0.01
    scene, cost, limit = _standing()
    cost.set_residual(True, strong * limit, SATURATION_RAD)
    assert _hold_tilted_root(scene, cost, explicit_damping=True) > 0.3
