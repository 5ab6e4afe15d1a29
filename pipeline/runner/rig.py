"""Which camera rig a stage sees: the input calibration, or the one ``calibrate`` chose.

``detect2d``, ``track``, ``associate`` and ``calibrate`` itself work with the session's
input calibration (``pipeline.io.session_rig``). Every later stage, the viewer and the
exports use the rig the ``calibrate`` stage stored (the refined rig when it was adopted,
the input rig otherwise), as long as that stage is enabled and has run. One rule, here.

The rig ``calibrate`` stores lives in the *floor world*: the input calibration's world
lowered by the floor height that stage measured (``floor_shift_m`` in its manifest), so that
the floor is at ``z = 0``. Every 3D result downstream is in that world; ``world_shift_m``
converts to and from the input calibration's (ground truth given in it, for one).
"""

from __future__ import annotations

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


def world_shift_m(session_dir: Path, session: SessionConfig) -> float:
    """How far (m) the downstream world lies below the input calibration's world: a point at
    height ``z`` in the input world is at ``z - world_shift_m`` downstream (0 when ``calibrate``
    is disabled, has not run, or kept the floor)."""
    if not uses_calibrated_rig("downstream", session):
        return 0.0
    manifest = ArtifactStore(session_dir).manifest(CALIBRATE)
    if manifest is None:
        return 0.0
    return float(manifest.metrics.get("floor_shift_m", 0.0))


def in_floor_world(kp: Keypoints3D, shift_m: float) -> Keypoints3D:
    """``kp``, given in the input calibration's world, in the downstream world lowered by
    ``shift_m`` (m, ``world_shift_m``)."""
    return kp if shift_m == 0.0 else kp.replace(xyz_m=kp.xyz_m - np.array([0.0, 0.0, shift_m]))
