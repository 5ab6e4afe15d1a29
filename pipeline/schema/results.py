"""Outputs of the kinematic fit and the physics stage."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.schema.base import check_array


@dataclass(frozen=True)
class BodyFit:
    """A parametric body model fitted to every person over the whole sequence.

    Fields:
        body_model: ``"anny"`` (default), ``"smpl"`` or ``"smplx"``.
        rig: body-model-specific rig / topology name (e.g. anny's reduced rig).
        bone_names: (bones,) names of the posed bones, in ``pose`` order.
        person_ids: (persons,) global person ids.
        frame_indices: (frames,) video frame indices.
        fps: frame rate.
        shape: (persons, shape_dims) shape parameters; one per person for the bout
            (anny: phenotype values in [0, 1]; SMPL: betas).
        pose: (frames, persons, bones, 3) per-bone rotations as axis-angle
            (``*_aa``), relative to the rest pose, parent-local.
        root_translation_m: (frames, persons, 3) world translation of the root.
        valid: (frames, persons) bool; False where the person was not fitted.
        loss_final: (persons,) final objective value per person.
    """

    body_model: str
    rig: str
    bone_names: tuple[str, ...]
    person_ids: np.ndarray
    frame_indices: np.ndarray
    fps: float
    shape: np.ndarray
    pose: np.ndarray
    root_translation_m: np.ndarray
    valid: np.ndarray
    loss_final: np.ndarray

    def __post_init__(self) -> None:
        f = self.frame_indices.shape[0] if isinstance(self.frame_indices, np.ndarray) else -1
        p = self.person_ids.shape[0] if isinstance(self.person_ids, np.ndarray) else -1
        b = len(self.bone_names)
        if self.body_model not in ("anny", "smpl", "smplx"):
            raise ValueError(f"BodyFit.body_model must be anny/smpl/smplx, got {self.body_model!r}")
        check_array("BodyFit.frame_indices", self.frame_indices, (f,), "iu")
        check_array("BodyFit.person_ids", self.person_ids, (p,), "iu")
        check_array("BodyFit.shape", self.shape, (p, None), "f", finite=True)
        check_array("BodyFit.pose", self.pose, (f, p, b, 3), "f", finite=True)
        check_array("BodyFit.root_translation_m", self.root_translation_m, (f, p, 3), "f", finite=True)
        check_array("BodyFit.valid", self.valid, (f, p), "b")
        check_array("BodyFit.loss_final", self.loss_final, (p,), "f")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"BodyFit.fps must be positive, got {self.fps}")


@dataclass(frozen=True)
class PhysicsResult:
    """Physically simulated motion of all persons in one MuJoCo model.

    Fields:
        person_ids: (persons,) global person ids (body prefixes ``p{id}_`` in the MJCF).
        frame_indices: (frames,) video frame indices.
        fps: frame rate of the trajectories.
        qpos: (frames, nq) MuJoCo generalised positions (free root per person:
            xyz + quat_wxyz, then hinge angles in radians).
        qvel: (frames, nv) generalised velocities.
        ctrl: (frames, nu) optimised controls (PD targets or torques, see
            ``actuation``).
        joint_torque_nm: (frames, nu) actuator forces applied, N·m.
        residual_root_force: (frames, persons, 6) residual root wrench used when a
            window could not be tracked (zero when unused).
        actuation: ``"pd"`` or ``"torque"``.
        contact_frame: (contacts,) frame row of each recorded contact.
        contact_person: (contacts, 2) person ids of both geoms (``-1`` = ground).
        contact_body: (contacts, 2) body names' indices into ``body_names``.
        contact_depth_m: (contacts,) penetration depth (positive = overlap).
        body_names: names of MuJoCo bodies referenced by ``contact_body``.
        untrackable: (frames, persons) bool, True where the person's receding-horizon
            window could not be tracked without the residual root force (diverged, or
            missed the joints by more than ``ResidualConfig.fallback_tol_m`` on average;
            residual modes ``off`` and ``fallback``, all False in ``always``); (0, 0) in
            a result written before it was recorded.
        observed: (frames, persons) bool, True where the person had valid input joints
            (seen by the cameras); the humanoid is still simulated elsewhere, but those
            samples are not the athlete's motion. (0, 0) in a result written before it
            was recorded (read as observed everywhere).
    """

    person_ids: np.ndarray
    frame_indices: np.ndarray
    fps: float
    qpos: np.ndarray
    qvel: np.ndarray
    ctrl: np.ndarray
    joint_torque_nm: np.ndarray
    residual_root_force: np.ndarray
    actuation: str
    contact_frame: np.ndarray
    contact_person: np.ndarray
    contact_body: np.ndarray
    contact_depth_m: np.ndarray
    body_names: tuple[str, ...]
    untrackable: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=bool))
    observed: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=bool))

    def __post_init__(self) -> None:
        f = self.frame_indices.shape[0] if isinstance(self.frame_indices, np.ndarray) else -1
        p = self.person_ids.shape[0] if isinstance(self.person_ids, np.ndarray) else -1
        for name in ("untrackable", "observed"):
            value = getattr(self, name)
            if not (isinstance(value, np.ndarray) and value.shape == (0, 0)):
                check_array(f"PhysicsResult.{name}", value, (f, p), "b")
        check_array("PhysicsResult.frame_indices", self.frame_indices, (f,), "iu")
        check_array("PhysicsResult.person_ids", self.person_ids, (p,), "iu")
        check_array("PhysicsResult.qpos", self.qpos, (f, None), "f", finite=True)
        check_array("PhysicsResult.qvel", self.qvel, (f, None), "f", finite=True)
        nu = self.ctrl.shape[1] if isinstance(self.ctrl, np.ndarray) and self.ctrl.ndim == 2 else -1
        check_array("PhysicsResult.ctrl", self.ctrl, (f, nu), "f", finite=True)
        check_array("PhysicsResult.joint_torque_nm", self.joint_torque_nm, (f, nu), "f", finite=True)
        check_array("PhysicsResult.residual_root_force", self.residual_root_force, (f, p, 6), "f", finite=True)
        c = self.contact_frame.shape[0] if isinstance(self.contact_frame, np.ndarray) else -1
        check_array("PhysicsResult.contact_frame", self.contact_frame, (c,), "iu")
        check_array("PhysicsResult.contact_person", self.contact_person, (c, 2), "iu")
        check_array("PhysicsResult.contact_body", self.contact_body, (c, 2), "iu")
        check_array("PhysicsResult.contact_depth_m", self.contact_depth_m, (c,), "f", finite=True)
        if self.actuation not in ("pd", "torque"):
            raise ValueError(f"PhysicsResult.actuation must be 'pd' or 'torque', got {self.actuation!r}")

    def observed_mask(self) -> np.ndarray:
        """(frames, persons) bool: ``observed``, or all True for a result written before it was recorded."""
        if self.observed.shape == (0, 0):
            return np.ones((self.frame_indices.shape[0], self.person_ids.shape[0]), dtype=bool)
        return self.observed
