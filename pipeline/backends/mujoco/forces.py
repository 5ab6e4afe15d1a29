"""Ground reaction forces of a physics result, by replaying its stored states in MuJoCo.

At each stored frame the state (qpos, qvel), the servo targets (ctrl) and the residual
root wrench the optimiser applied are set, ``mj_forward`` solves the contacts, and the
floor's contact forces on each athlete are summed. This is the force at the first
substep of each video frame, the one the simulation itself computed there.
"""

from __future__ import annotations

import mujoco
import numpy as np

from pipeline.backends.mujoco.humanoid import load_model, scene_layout
from pipeline.schema.results import PhysicsResult

RESIDUAL_GROUP = 3
"""Actuator group of the residual root servos (``humanoid``); replaced here by the stored wrench."""


def ground_reaction_forces(mjcf: str, result: PhysicsResult) -> np.ndarray:
    """(frames, persons, 3) force of the floor on each athlete, newtons, world z-up.

    ``mjcf`` is the physics stage's ``scene.xml``; ``result`` its ``PhysicsResult`` (any
    frame subset). ``ValueError`` when they do not belong together.
    """
    m = load_model(mjcf)
    if result.qpos.shape[1] != m.nq or result.ctrl.shape[1] != m.nu:
        raise ValueError(
            f"physics result (nq {result.qpos.shape[1]}, nu {result.ctrl.shape[1]}) does not match its scene "
            f"(nq {m.nq}, nu {m.nu})"
        )
    lay = scene_layout(m, [int(p) for p in result.person_ids])
    m.opt.disableactuator |= 1 << RESIDUAL_GROUP
    d = mujoco.MjData(m)
    F, P = result.qpos.shape[0], len(lay.persons)
    out = np.zeros((F, P, 3))
    wrench = np.zeros(6)
    for f in range(F):
        d.qpos[:] = result.qpos[f]
        d.qvel[:] = result.qvel[f]
        d.ctrl[:] = result.ctrl[f]
        d.qfrc_applied[:] = 0.0
        for i, p in enumerate(lay.persons):
            force, torque = result.residual_root_force[f, i, :3], result.residual_root_force[f, i, 3:]
            d.qfrc_applied[p.qvel_adr : p.qvel_adr + 3] = force
            # The root ball's dofs are angular velocity in the root body's frame.
            quat = result.qpos[f, p.qpos_adr + 3 : p.qpos_adr + 7]
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, quat)
            d.qfrc_applied[p.qvel_adr + 3 : p.qvel_adr + 6] = rot.reshape(3, 3).T @ torque
        mujoco.mj_forward(m, d)
        for c in range(d.ncon):
            con = d.contact[c]
            g1, g2 = int(con.geom[0]), int(con.geom[1])
            b1, b2 = m.geom_bodyid[g1], m.geom_bodyid[g2]
            if (b1 == 0) == (b2 == 0):
                continue  # not a floor contact
            mujoco.mj_contactForce(m, d, c, wrench)
            world = con.frame.reshape(3, 3).T @ wrench[:3]  # force of geom1 on geom2
            person = lay.geom_person[g2] if b1 == 0 else lay.geom_person[g1]
            if person >= 0:
                out[f, person] += world if b1 == 0 else -world
    return out


def body_masses_kg(mjcf: str, person_ids: list[int]) -> np.ndarray:
    """(persons,) total mass of each athlete's humanoid, kg."""
    m = load_model(mjcf)
    lay = scene_layout(m, person_ids)
    return np.array([float(m.body_subtreemass[p.root_body]) for p in lay.persons])


def actuator_names(mjcf: str) -> list[str]:
    """(actuators,) MuJoCo names of the scene's actuators, the columns of ``PhysicsResult.ctrl``
    and ``joint_torque_nm`` (``p{pid}_<joint>[_axis]``, residual servos ``p{pid}_res_*``)."""
    m = load_model(mjcf)
    return [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) or "" for a in range(m.nu)]
