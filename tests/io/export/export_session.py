"""A session folder holding what the exports read, built in code: the fit stage's 3D keypoints of
two athletes (a few joints without an estimate) and the real physics stage's result and scene."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.artifacts import ArtifactStore, Manifest
from pipeline.schema.joints import COCO17_FEET
from pipeline.schema.keypoints3d import Keypoints3D
from tests.conftest import write_tiny_session

FIRST_FRAME = 100
"""Video frame index of the first keypoint row (not 0, so that frame offsets are checked)."""
FPS = 50.0
INVALID = ((2, 0, 9), (3, 1, 0), (5, 1, 22))
"""(row, person, joint) entries without an estimate in the fit keypoints."""


def standing_pair(n_frames: int) -> Keypoints3D:
    """Two upright athletes 0.8 m apart facing each other, swaying; every joint valid."""
    from pipeline.backends.mujoco.skeleton import _DEFAULT_LENGTHS, build_skeleton, rest_site_positions

    sk = build_skeleton(dict(_DEFAULT_LENGTHS))
    rs = rest_site_positions(sk)
    base = np.array([rs[n] for n in COCO17_FEET]) + [0.0, 0.0, sk.pelvis_height_m]
    xyz = np.zeros((n_frames, 2, len(COCO17_FEET), 3))
    for f in range(n_frames):
        sway = 0.02 * np.sin(f / 3.0)
        xyz[f, 0] = base + [0.0, sway, 0.0]
        xyz[f, 1] = base @ np.diag([-1.0, -1.0, 1.0]) + [0.8, 0.1 - sway, 0.0]
    shape = xyz.shape[:3]
    return Keypoints3D(
        joint_names=COCO17_FEET,
        person_ids=np.array([0, 1]),
        frame_indices=np.arange(FIRST_FRAME, FIRST_FRAME + n_frames),
        fps=FPS,
        xyz_m=xyz,
        valid=np.ones(shape, dtype=bool),
        confidence=np.linspace(0.5, 1.0, xyz[..., 0].size).reshape(shape),
        n_views=np.zeros(shape, dtype=np.int64),
        reproj_err_px=np.full(shape, np.nan),
        source="fit",
    )


def _manifest(stage: str) -> Manifest:
    return Manifest(stage=stage, code_version="test", config={}, config_hash="0", inputs={})


def write_export_session(root: Path, n_frames: int = 8, physics: bool = True) -> Path:
    """A session (athletes Red = person 0, Blue = person 1) under ``root`` with fit keypoints
    and, when ``physics``, the physics stage's artifacts computed from them."""
    session = write_tiny_session(
        root, stages=("detect2d", "track", "associate", "triangulate", "fit", "physics")
    )
    return write_export_artifacts(session, n_frames, physics)


def write_export_artifacts(session: Path, n_frames: int = 8, physics: bool = True) -> Path:
    """Write the fit (and physics) artifacts of ``write_export_session`` into ``session``."""
    kp = standing_pair(n_frames)
    valid, xyz = kp.valid.copy(), kp.xyz_m.copy()
    for f, p, j in INVALID:
        valid[f, p, j] = False
        xyz[f, p, j] = np.nan
    store = ArtifactStore(session)
    store.write(_manifest("fit"), {"keypoints3d": kp.replace(valid=valid, xyz_m=xyz)})
    if physics:
        from pipeline.stages.physics import PhysicsConfig, PhysicsInputs, run

        solver = {"window": 5, "commit": 3, "ilqr": {"max_iter": 2, "n_alpha": 3}}
        cfg = PhysicsConfig(solver=solver)  # type: ignore[arg-type]  # the config takes nested dicts
        out = run(PhysicsInputs(kp), cfg)
        outputs = {"result": out.result, "keypoints3d": out.keypoints, "scene.xml": out.mjcf}
        store.write(_manifest("physics"), outputs)
    return session
