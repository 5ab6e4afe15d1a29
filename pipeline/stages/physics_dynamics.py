"""How physically consistent a motion is: the root wrench its feet cannot supply.

A free-floating body moves only through external forces. For a kinematic motion
(triangulation, fit, ground truth or the physics output itself) this module poses the
physics stage's humanoids on it by inverse kinematics, runs MuJoCo's inverse dynamics,
and gives the foot sites near the floor as much of the needed root wrench as a
friction cone allows (``mujoco.reference.contact_inverse_dynamics``). What is left is
the *needed residual*: the "hand of God" force and torque at the pelvis that the
motion requires on top of its ground contacts.

Zero for a motion a person could perform alone on that floor; about one body weight
of force for a person hanging in the air. Between two athletes, forces from the
opponent (leaning in a clinch, a landed punch) also count as residual here, because
only the floor is modelled.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit
from pipeline.stages.physics import PhysicsConfig, posed_humanoids

if TYPE_CHECKING:
    from pipeline.backends.mujoco.reference import Scene

__all__ = ["NeededResidual", "needed_residual", "residual_of_pose"]

G = 9.81


@dataclass(frozen=True)
class NeededResidual:
    """Per frame and person: world force (N) at the pelvis and world torque (N·m).

    person_ids (P,), force_n (F, P, 3), torque_nm (F, P, 3), weight_n (P,): each
    humanoid's weight (mass from its geometry at the stage's density).
    """

    person_ids: np.ndarray
    force_n: np.ndarray
    torque_nm: np.ndarray
    weight_n: np.ndarray

    def summary(self) -> dict[str, float]:
        """Means over frames and persons: force in body weights, torque in N·m and in
        body weight × 1 m (comparable between athletes of different mass)."""
        f = np.linalg.norm(self.force_n, axis=-1)
        t = np.linalg.norm(self.torque_nm, axis=-1)
        return {
            "needed_force_frac_bw": float(np.mean(f / self.weight_n[None])),
            "needed_torque_nm": float(np.mean(t)),
            "needed_torque_bw_m": float(np.mean(t / self.weight_n[None])),
        }


def needed_residual(
    kp: Keypoints3D,
    bodyfit: BodyFit | None = None,
    cfg: PhysicsConfig = PhysicsConfig(),
    person_ids: list[int] | None = None,
    body_keypoints: Keypoints3D | None = None,
) -> NeededResidual:
    """The root wrench that ``kp``'s motion needs beyond its foot contacts, in the
    humanoids the physics stage builds (from ``bodyfit`` with ``cfg``'s geometry, sized
    from ``body_keypoints``, default ``kp``: pass the physics input to score ground
    truth or the physics output in the same bodies). ``person_ids`` restricts the
    persons. Velocities and accelerations are finite differences at ``kp.fps``,
    smoothed over 3 frames as in the stage's feed-forward.

    Raises ``ValueError`` when no person has motion or one is not in ``body_keypoints``.
    """
    _check_frames(kp.n_frames)  # before the posing, which is the expensive part
    scene, qpos = posed_humanoids(kp, bodyfit, cfg, person_ids, body_keypoints, 1, "needed_residual")
    return residual_of_pose(scene, qpos, kp.fps)


def _check_frames(n_frames: int) -> None:
    if n_frames < 3:
        raise ValueError(f"needed_residual: need at least 3 frames for accelerations, got {n_frames}")


def residual_of_pose(scene: Scene, qpos: np.ndarray, fps: float) -> NeededResidual:
    """``needed_residual`` of ``scene``'s persons posed at ``qpos`` (frames, nq) at
    ``fps``, e.g. from ``posed_humanoids``."""
    from pipeline.backends.mujoco import physics as mp

    _check_frames(qpos.shape[0])
    m = scene.model
    qvel = mp.reference_velocity(m, qpos, fps)
    _, resid = mp.contact_inverse_dynamics(m, scene.layout, qpos, qvel, fps)
    weight = np.array([p.mass_kg * G for p in scene.layout.persons])
    return NeededResidual(
        person_ids=np.asarray(scene.person_ids, dtype=np.int64),
        force_n=resid[..., :3],
        torque_nm=resid[..., 3:],
        weight_n=weight,
    )
