"""Finite differences that nudge one DOF of every person at once (``fd_split``): the same
Jacobians as ``mjd_transitionFD`` when the persons do not touch, and a refusal when they do."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from pipeline.backends.mujoco.fd_split import PersonBlocks, persons_in_contact, transition_fd

_PERSON = """
    <body name="p{i}_root" pos="{x} 0 0.92">
      <freejoint/>
      <geom name="p{i}_torso" type="capsule" size="0.1 0.3" mass="30"/>
      <body name="p{i}_arm" pos="0 0 0.3">
        <joint name="p{i}_shoulder" type="hinge" axis="0 1 0" range="-2 2" damping="1"/>
        <geom name="p{i}_arm_g" type="capsule" fromto="0 0 0 {reach} 0 0" size="0.04" mass="3"/>
      </body>
      <body name="p{i}_leg" pos="0 0 -0.3">
        <joint name="p{i}_hip" type="hinge" axis="0 1 0" range="-1.5 1.5" damping="1"/>
        <geom name="p{i}_foot" type="box" pos="0 0 -0.3" size="0.1 0.05 0.3" mass="8"/>
      </body>
    </body>"""


def _model(gap_m: float) -> tuple[mujoco.MjModel, PersonBlocks]:
    bodies = "".join(_PERSON.format(i=i, x=x, reach=r) for i, x, r in ((0, 0.0, 0.4), (1, gap_m, -0.4)))
    acts = "".join(
        f'<position name="p{i}_{j}" joint="p{i}_{j}" kp="200" ctrlrange="-1 1"/>'
        for i in (0, 1)
        for j in ("shoulder", "hip")
    )
    xml = f"""<mujoco><option timestep="0.004" integrator="implicitfast"/>
      <worldbody><geom name="floor" type="plane" size="5 5 0.1"/>{bodies}</worldbody>
      <actuator>{acts}</actuator></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    body_person = np.array([0 if m.body(b).name.startswith("p0_") else 1 if m.body(b).name.startswith("p1_") else -1 for b in range(m.nbody)])
    blocks = PersonBlocks(
        dofs=tuple(np.flatnonzero(body_person[m.dof_bodyid] == i) for i in (0, 1)),
        acts=tuple(np.array([a for a in range(m.nu) if m.actuator(a).name.startswith(f"p{i}_")]) for i in (0, 1)),
        geom_person=body_person[m.geom_bodyid],
    )
    return m, blocks


def _moving_state(m: mujoco.MjModel, steps: int = 60) -> mujoco.MjData:
    """A state some steps into a motion: feet on the floor, arms swinging, warm start set."""
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    for _ in range(steps):
        d.ctrl[:] = rng.uniform(-0.8, 0.8, m.nu)
        mujoco.mj_step(m, d)
    d.ctrl[:] = [0.3, -0.2, 1.0, 0.5]  # actuator 2 at its upper limit: nudged backwards
    return d


def test_split_differences_equal_mujocos_when_the_persons_are_apart() -> None:
    m, blocks = _model(gap_m=2.0)
    assert blocks.fits(m)
    d = _moving_state(m)
    mujoco.mj_forward(m, d)
    assert d.ncon > 0 and not persons_in_contact(d, blocks.geom_person)  # floor contacts only
    nx = 2 * m.nv
    A0, B0 = np.zeros((nx, nx)), np.zeros((nx, m.nu))
    before = (d.qpos.copy(), d.qvel.copy(), d.ctrl.copy(), d.qacc_warmstart.copy())
    mujoco.mjd_transitionFD(m, d, 1e-6, False, A0, B0, None, None)
    A1, B1 = np.full((nx, nx), np.nan), np.full((nx, m.nu), np.nan)
    assert transition_fd(m, d, 1e-6, blocks, A1, B1)
    # The same numbers from half the steps (MuJoCo solves independent contacts separately).
    np.testing.assert_allclose(A1, A0, rtol=0, atol=1e-9 * np.abs(A0).max())
    np.testing.assert_allclose(B1, B0, rtol=0, atol=1e-9 * np.abs(B0).max())
    assert np.abs(B0[:, 2]).max() > 0  # the control at its limit has a (backward) column
    # The input state is restored.
    for a, b in zip(before, (d.qpos, d.qvel, d.ctrl, d.qacc_warmstart), strict=True):
        np.testing.assert_array_equal(a, b)


def test_persons_in_contact_fall_back() -> None:
    m, blocks = _model(gap_m=0.15)  # the torsos overlap
    d = _moving_state(m, steps=1)
    mujoco.mj_forward(m, d)
    assert persons_in_contact(d, blocks.geom_person)
    qpos = d.qpos.copy()
    A = np.full((2 * m.nv, 2 * m.nv), 7.0)
    assert not transition_fd(m, d, 1e-6, blocks, A, np.zeros((2 * m.nv, m.nu)))
    assert (A == 7.0).all()
    np.testing.assert_array_equal(d.qpos, qpos)


def test_blocks_that_do_not_cover_the_model_are_not_used() -> None:
    m, blocks = _model(gap_m=2.0)
    partial = PersonBlocks(dofs=(blocks.dofs[0], blocks.dofs[1][:-1]), acts=blocks.acts, geom_person=blocks.geom_person)
    assert not partial.fits(m)
    d = _moving_state(m, steps=1)
    assert not transition_fd(m, d, 1e-6, partial, np.zeros((2 * m.nv, 2 * m.nv)), np.zeros((2 * m.nv, m.nu)))


def test_the_physics_stage_gives_the_same_motion_with_split_differences() -> None:
    pytest.importorskip("mujoco")
    from pipeline.stages.physics import PhysicsConfig, PhysicsInputs, run
    from tests.stages.test_physics import _facing_pair

    kp = _facing_pair(1.0, n_frames=10)
    solver = {"window": 5, "commit": 3, "ilqr": {"max_iter": 2, "n_alpha": 3, "deriv_every": 2}}
    on = run(PhysicsInputs(kp), PhysicsConfig(solver=solver))
    off = run(PhysicsInputs(kp), PhysicsConfig(solver={**solver, "ilqr": {**solver["ilqr"], "fd_split_persons": False}}))
    np.testing.assert_array_equal(on.result.qpos, off.result.qpos)
    np.testing.assert_array_equal(on.result.ctrl, off.result.ctrl)
