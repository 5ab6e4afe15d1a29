"""Which camera rig a stage sees: the input calibration, or the one ``calibrate`` chose.

``detect2d``, ``track``, ``associate`` and ``calibrate`` itself work with the session's
input calibration (``pipeline.io.session_rig``). Every later stage, the viewer and the
exports use the rig the ``calibrate`` stage stored (the refined rig when it was adopted,
the input rig otherwise), as long as that stage is enabled and has run. One rule, here.

The rig ``calibrate`` stores lives in the *floor world*: the input calibration's world turned
so that the floor is level and lowered by the floor height that stage measured
(``world.json``), so that the floor is the plane ``z = 0``. Every 3D result downstream is in
that world; ``world_from_input`` converts from the input calibration's (ground truth given in
it, for one).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pipeline.artifacts import ArtifactStore
from pipeline.io.session_rig import session_rig
from pipeline.runner.registry import STAGE_ORDER
from pipeline.schema.camera import CameraRig
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.session import SessionConfig

CALIBRATE = "calibrate"
RIG_ARTIFACT = "rig"
"""The ``calibrate`` stage's output holding the rig for the later stages (``rig.npz``)."""
WORLD_ARTIFACT = "world.json"
"""The ``calibrate`` stage's output giving that rig's world against the input calibration's."""


def uses_calibrated_rig(stage: str, session: SessionConfig) -> bool:
    """Whether ``stage`` (or, for ``"downstream"``, the viewer and exports) reads the rig
    ``calibrate`` chose: the stage comes after it and ``calibrate`` is enabled."""
    enabled = session.stages or STAGE_ORDER
    if CALIBRATE not in enabled:
        return False
    return stage == "downstream" or (stage in STAGE_ORDER and STAGE_ORDER.index(stage) > STAGE_ORDER.index(CALIBRATE))


def rig_for(stage: str, session_dir: Path, session: SessionConfig, input_rig: CameraRig | None = None) -> CameraRig:
    """The rig ``stage`` works with (``"downstream"``: the viewer's and the exports').

    Falls back to the input calibration while ``calibrate`` has not run."""
    base = input_rig if input_rig is not None else session_rig(session_dir, session)
    if not uses_calibrated_rig(stage, session):
        return base
    store = ArtifactStore(session_dir)
    if not store.has(CALIBRATE, f"{RIG_ARTIFACT}.npz"):
        return base
    return store.load(CALIBRATE, RIG_ARTIFACT, CameraRig)


def world_from_input(session_dir: Path, session: SessionConfig) -> np.ndarray:
    """(4, 4) rigid transform from the input calibration's world to the downstream one: a
    point ``x`` of the input world is at ``W @ [x, 1]`` downstream (identity when ``calibrate``
    is disabled or has not run). Sessions run before the floor was levelled have only the
    lowering (``floor_shift_m`` in the manifest)."""
    W = np.eye(4)
    if not uses_calibrated_rig("downstream", session):
        return W
    store = ArtifactStore(session_dir)
    if store.has(CALIBRATE, WORLD_ARTIFACT):
        path = store.path(CALIBRATE, WORLD_ARTIFACT)
        try:
            W = np.asarray(json.loads(path.read_text())["world_from_input"], float)
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
            raise ValueError(f"{path}: not a calibrate world file ({e!r}); re-run the calibrate stage") from e
        if W.shape != (4, 4) or not np.isfinite(W).all():
            raise ValueError(f"{path}: world_from_input must be a finite 4x4 matrix; re-run the calibrate stage")
        return W
    manifest = store.manifest(CALIBRATE)
    if manifest is not None:
        W[2, 3] = -float(manifest.metrics.get("floor_shift_m", 0.0))
    return W


def in_floor_world(kp: Keypoints3D, world_from_input: np.ndarray) -> Keypoints3D:
    """``kp``, given in the input calibration's world, in the downstream world
    (``world_from_input``, 4x4)."""
    W = np.asarray(world_from_input, float)
    if np.array_equal(W, np.eye(4)):
        return kp
    return kp.replace(xyz_m=kp.xyz_m @ W[:3, :3].T + W[:3, 3])
