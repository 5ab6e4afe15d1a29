"""Shared checks of generated MuJoCo humanoids (keypoint and BodyFit skeletons)."""

from __future__ import annotations

import mujoco
import numpy as np

from pipeline.backends.mujoco.humanoid import SceneLayout


def assert_random_servo_targets_stay_stable(
    model: mujoco.MjModel, lay: SceneLayout, rounds: int, steps: int = 60, seed: int = 1
) -> None:
    """Two overlapping people on the floor under random servo targets at the video rate:
    the state stays finite and bounded and MuJoCo reports no bad accelerations."""
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    for _ in range(rounds):
        mujoco.mj_resetData(model, data)
        p1 = lay.persons[1]
        data.qpos[p1.qpos_adr] = rng.uniform(0.3, 0.6)
        data.qpos[p1.qpos_adr + 1] = 0.0
        data.qpos[p1.qpos_adr + 3 : p1.qpos_adr + 7] = [0.0, 0.0, 0.0, 1.0]
        for _ in range(steps):
            data.ctrl[:] = rng.uniform(lo, hi)
            mujoco.mj_step(model, data)
        assert np.all(np.isfinite(data.qpos))
        assert np.abs(data.qvel).max() < 100.0
        assert data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number == 0
