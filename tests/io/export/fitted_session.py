"""A small fitted session for the body-model exports: two anny athletes fitted by the fit stage.

Ground truth: two ``make_anny_motion`` bodies seen by 3 synthetic cameras; the fit stage runs on
their keypoints with few iterations (the exports read whatever the fit wrote, so its accuracy
does not matter) and its ``BodyFit`` is written as the session's fit artifact. Person 1 is
marked not fitted on two frames, so that the exporters meet a ``valid`` mask.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from pipeline.artifacts import ArtifactStore
from pipeline.artifacts.store import Manifest
from pipeline.schema import SessionConfig
from pipeline.schema.results import BodyFit
from tests.conftest import fit_stage_inputs, make_rig, write_tiny_session

FPS = 50.0
N_FRAMES = 8
INVALID_ROWS = (2, 3)
"""Frame rows where person 1 is marked not fitted."""
ATHLETES = ("Red", "Blue")
"""Athlete names of persons 0 and 1 (the session's ``athletes``)."""


def write_fitted_session(session_dir: Path) -> BodyFit:
    """Fit two anny athletes on ``N_FRAMES`` frames (video frames 10..17) and store the fit in
    a session at ``session_dir`` (athletes ``ATHLETES``); returns the stored ``BodyFit``."""
    from pipeline.stages.fit import FitConfig, run
    from pipeline.synthetic.anny_motion import make_anny_motion

    motions = [
        make_anny_motion(N_FRAMES, fps=FPS, seed=3, centre_m=(-0.6, 0.0)),
        make_anny_motion(N_FRAMES, fps=FPS, seed=5, centre_m=(0.6, 0.2)),
    ]
    rig = make_rig(3, fps=FPS, phase_rad=0.4)
    xyz = np.stack([m.keypoints_m for m in motions], axis=1)
    kp3d, tracks, assoc = fit_stage_inputs(rig, xyz, FPS)
    cfg = FitConfig(shape_iters=20, pose_iters_3d=10, pose_iters=20)
    fit = run(kp3d, tracks, assoc, rig, cfg).bodyfit
    valid = fit.valid.copy()
    valid[list(INVALID_ROWS), 1] = False
    fit = dataclasses.replace(fit, frame_indices=fit.frame_indices + 10, valid=valid)
    write_tiny_session(session_dir)
    dataclasses.replace(SessionConfig.load(session_dir), athletes=ATHLETES).save(session_dir)
    manifest = Manifest(
        stage="fit", code_version="test", config=dataclasses.asdict(cfg), config_hash="0", inputs={}
    )
    ArtifactStore(session_dir).write(manifest, {"bodyfit": fit})
    return fit
