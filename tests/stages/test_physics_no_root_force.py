"""``residual.mode = "off"`` applies no force or torque to any root: read from the simulation
itself (``xfrc_applied``, ``qfrc_applied`` and the residual servos' forces at every step the
stage takes), not from the result's bookkeeping."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from pipeline.stages.physics import PhysicsConfig, PhysicsInputs, run
from tests.backends.test_humanoid import _rest_keypoints

SOLVER = {"window": 5, "commit": 3, "ilqr": {"max_iter": 2, "n_alpha": 3}}


def _root_forces_seen(mode: str, monkeypatch: pytest.MonkeyPatch) -> tuple[int, float, float, float]:
    """(steps, max |xfrc_applied|, max |qfrc_applied| on the root DOFs, max |residual servo
    force|) over every MuJoCo step of a physics run of a standing person."""
    seen = {"steps": 0, "xfrc": 0.0, "qfrc": 0.0, "servo": 0.0}
    originals = {"mj_step2": mujoco.mj_step2, "mj_step": mujoco.mj_step}

    def look(m: mujoco.MjModel, d: mujoco.MjData) -> None:
        res = [
            a for a in range(m.nu) if "_res_" in (mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) or "")
        ]
        roots = [
            j
            for j in range(m.njnt)
            if (mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or "").split("_", 1)[-1].startswith("root")
        ]
        dofs = [
            int(m.jnt_dofadr[j]) + k
            for j in roots
            for k in range(3 if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_BALL else 1)
        ]
        seen["steps"] += 1
        seen["xfrc"] = max(seen["xfrc"], float(np.abs(d.xfrc_applied).max()))
        seen["qfrc"] = max(seen["qfrc"], float(np.abs(d.qfrc_applied[dofs]).max()) if dofs else 0.0)
        seen["servo"] = max(seen["servo"], float(np.abs(d.actuator_force[res]).max()) if res else 0.0)

    def probe(name: str):  # type: ignore[no-untyped-def]
        def stepped(m: mujoco.MjModel, d: mujoco.MjData, *args: int) -> None:
            originals[name](m, d, *args)
            look(m, d)

        return stepped

    for name in originals:  # the first substep of a frame (step1/step2) and the others (mj_step)
        monkeypatch.setattr(mujoco, name, probe(name))
    run(
        PhysicsInputs(_rest_keypoints(1.0, 10)),
        PhysicsConfig(skeleton="keypoints", solver=SOLVER, residual={"mode": mode}),
    )
    return int(seen["steps"]), seen["xfrc"], seen["qfrc"], seen["servo"]


def test_off_applies_no_root_force_and_always_does(monkeypatch: pytest.MonkeyPatch) -> None:
    steps, xfrc, qfrc, servo = _root_forces_seen("off", monkeypatch)
    assert steps >= 3 * 10 * 8  # several whole rollouts of the 10 frames, every substep
    assert xfrc == 0.0 and qfrc == 0.0 and servo == 0.0
    # The same probe sees the residual when it is on: a root wrench, by torque or by servo.
    _, xfrc_on, qfrc_on, servo_on = _root_forces_seen("always", monkeypatch)
    assert max(xfrc_on, qfrc_on, servo_on) > 1.0
