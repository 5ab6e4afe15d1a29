"""Small bout folders for tests, the load test and ``cornerman serve --demo``.

``make_session(folder, n_frames, n_cameras, seed)`` writes a session whose input is
a ``Tracks2D`` npz (``source="tracks"``): the built-in synthetic sparring bout
(``pipeline.synthetic.make_demo_session``) when that module is present, otherwise two
athletes made of ``COCO17_FEET`` points on a fixed-seed trajectory, projected into a
ring of cameras (geometrically consistent, so association and triangulation work).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

FAST_STAGES: tuple[str, ...] = ("detect2d", "track", "associate", "triangulate")


def available_stages(wanted: tuple[str, ...] = FAST_STAGES) -> tuple[str, ...]:
    """The ``wanted`` stages the runner knows."""
    from pipeline.runner import get_specs

    return tuple(s for s in wanted if s in get_specs())


def make_session(folder: Path, n_frames: int = 60, n_cameras: int = 3, seed: int = 0,
                 stages: tuple[str, ...] | None = None, use_synthetic: bool = True) -> Path:
    """Write a small bout session into ``folder`` (created) and return it."""
    from dataclasses import replace

    from pipeline.schema.session import SessionConfig

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    stages = available_stages() if stages is None else stages
    if use_synthetic:
        from pipeline.synthetic import SyntheticConfig, make_demo_session

        make_demo_session(folder, SyntheticConfig(n_frames=n_frames, n_cameras=n_cameras, seed=seed))
        cfg = SessionConfig.load(folder)
        cfg.save(folder) if cfg.stages == stages else replace(cfg, stages=stages).save(folder)
        return folder
    _write_simple_bout(folder, n_frames, n_cameras, seed, stages)
    return folder


def _write_simple_bout(folder: Path, n_frames: int, n_cameras: int, seed: int, stages: tuple[str, ...]) -> None:
    from pipeline.geometry.projection import project
    from pipeline.geometry.rotations import look_at_T_world_cam
    from pipeline.io.calibration_toml import save_toml
    from pipeline.schema.base import save_npz
    from pipeline.schema.camera import CameraRig
    from pipeline.schema.detections import Tracks2D
    from pipeline.schema.joints import COCO17_FEET
    from pipeline.schema.session import SessionConfig

    rng = np.random.default_rng(seed)
    w, h, fps = 1280, 720, 50.0
    angles = 2 * np.pi * np.arange(n_cameras) / n_cameras + 0.3
    Ts = [look_at_T_world_cam(np.array([6.5 * np.cos(a), 6.5 * np.sin(a), 2.2]), np.array([0.0, 0.0, 0.9])) for a in angles]
    K = np.array([[1100.0, 0.0, w / 2], [0.0, 1100.0, h / 2], [0.0, 0.0, 1.0]])
    rig = CameraRig(names=tuple(f"cam{i}" for i in range(n_cameras)), K=np.stack([K] * n_cameras),
                    dist=np.zeros((n_cameras, 5)), T_world_cam=np.stack(Ts),
                    image_size_wh=np.tile([w, h], (n_cameras, 1)), fps=fps)
    # A standing body template (metres, z-up), then two athletes circling each other.
    J = len(COCO17_FEET)
    template = np.zeros((J, 3))
    heights = np.linspace(1.7, 0.0, J)
    template[:, 2] = heights
    template[:, 0] = 0.18 * np.sin(np.arange(J) * 1.7)
    template[:, 1] = 0.12 * np.cos(np.arange(J) * 2.3)
    t = np.arange(n_frames) / fps
    X = np.zeros((n_frames, 2, J, 3))
    for p in range(2):
        phase = np.pi * p + rng.uniform(-0.2, 0.2)
        centre = np.stack([1.0 * np.cos(0.6 * t + phase), 1.0 * np.sin(0.6 * t + phase), np.zeros_like(t)], axis=1)
        X[:, p] = template[None] + centre[:, None, :] + rng.normal(0, 0.01, (n_frames, J, 3))
    uv, depth = project(rig, X.reshape(-1, 3))
    uv = uv.reshape(n_cameras, n_frames, 2, J, 2) + rng.normal(0, 1.0, (n_cameras, n_frames, 2, J, 2))
    views, frames, tracks, kps = [], [], [], []
    for v in range(n_cameras):
        for f in range(n_frames):
            for p in range(2):
                views.append(v)
                frames.append(f)
                tracks.append(p)
                kps.append(uv[v, f, p])
    kp = np.asarray(kps)
    bbox = np.concatenate([kp.min(axis=1), kp.max(axis=1)], axis=1)
    n = len(views)
    tr = Tracks2D(joint_names=COCO17_FEET, n_views=n_cameras, n_frames=n_frames, view=np.asarray(views, np.int64),
                  frame=np.asarray(frames, np.int64), bbox_xyxy_px=bbox, bbox_score=np.full(n, 0.95),
                  keypoints_px=kp, keypoint_conf=np.full((n, J), 0.9), keypoint_valid=np.ones((n, J), bool),
                  track_id=np.asarray(tracks, np.int64))
    (folder / "inputs").mkdir(exist_ok=True)
    save_toml(rig, folder / "inputs" / "calibration.toml")
    save_npz(folder / "inputs" / "tracks2d.npz", tr)
    SessionConfig(name=folder.name, source="tracks", calibration="inputs/calibration.toml", tracks="inputs/tracks2d.npz",
                  fps=fps, stages=stages).save(folder)
