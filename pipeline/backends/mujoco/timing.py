"""The cost of plain simulation, the yardstick of the physics stage's compute time.

``cornerman bench physics`` divides the stage's wall time by the time of a plain
``mj_step`` rollout of the same scene over the same motion (same model, timestep and
number of steps, open loop, no cost, no derivatives): a ratio that carries over between
machines and loads better than the real-time factor alone.
"""

from __future__ import annotations

import time

import mujoco
import numpy as np


def plain_rollout_seconds(mjcf: str, qpos0: np.ndarray, ctrl: np.ndarray, fps: float) -> float:
    """Wall time (s) of ``mujoco.mj_step`` over ``ctrl``'s frames from ``qpos0`` at rest.

    mjcf: the scene (``PhysicsOutput.mjcf``); qpos0: (nq,) the first state; ctrl: (frames,
    nu) one control vector per video frame, each held for the ``1 / (fps · timestep)``
    MuJoCo steps of its frame; fps: the video rate (> 0). ``ValueError`` when the shapes do
    not match the model or fps is not positive.
    """
    model = mujoco.MjModel.from_xml_string(mjcf)
    if not fps > 0:
        raise ValueError(f"plain_rollout_seconds: fps must be > 0, got {fps!r}")
    if qpos0.shape != (model.nq,) or ctrl.ndim != 2 or ctrl.shape[1] != model.nu:
        raise ValueError(
            f"plain_rollout_seconds: qpos0 {qpos0.shape} / ctrl {ctrl.shape} do not match the scene (nq={model.nq}, nu={model.nu})"
        )
    substeps = max(1, round(1.0 / (fps * model.opt.timestep)))
    data = mujoco.MjData(model)
    data.qpos[:] = qpos0
    mujoco.mj_forward(model, data)
    t0 = time.perf_counter()
    for u in ctrl:
        data.ctrl[:] = u
        for _ in range(substeps):
            mujoco.mj_step(model, data)
    return time.perf_counter() - t0
