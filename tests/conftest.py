"""Shared fixtures: a small synthetic rig + tracks built in code, and shared-resource paths."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.geometry import project
from pipeline.geometry.rotations import look_at_T_world_cam
from pipeline.io.calibration import save_toml
from pipeline.schema import (
    COCO17,
    COCO17_FEET,
    Association,
    CameraRig,
    Keypoints3D,
    SessionConfig,
    Tracks2D,
    save_npz,
)
from pipeline.shared import describe_lookup, shared_data_dir, shared_models_dir


def make_rig(
    n_views: int = 3, radius_m: float = 6.0, height_m: float = 2.5, fps: float = 50.0, phase_rad: float = 0.3
) -> CameraRig:
    """Cameras on a circle around the origin (first at ``phase_rad``), looking at the ring centre."""
    Ts, Ks = [], []
    for i in range(n_views):
        a = 2 * np.pi * i / n_views + phase_rad
        eye = np.array([radius_m * np.cos(a), radius_m * np.sin(a), height_m])
        Ts.append(look_at_T_world_cam(eye, np.array([0.0, 0.0, 1.0])))
        Ks.append(np.array([[1100.0, 0, 640], [0, 1100.0, 360], [0, 0, 1]]))
    return CameraRig(
        names=tuple(f"cam{i + 1}" for i in range(n_views)),
        K=np.stack(Ks),
        dist=np.zeros((n_views, 5)),
        T_world_cam=np.stack(Ts),
        image_size_wh=np.array([[1280, 720]] * n_views),
        fps=fps,
    )


def make_tracks(rig: CameraRig, n_frames: int = 20, seed: int = 0) -> tuple[Tracks2D, np.ndarray]:
    """Two persons (17 joints) drifting slowly, seen by every view; returns tracks and 3D truth."""
    rng = np.random.default_rng(seed)
    base = rng.normal(0, 0.25, size=(2, 17, 3)) + np.array([[[-0.6, 0, 1.0]], [[0.6, 0, 1.0]]])
    t = np.arange(n_frames)[:, None, None, None] / rig.fps
    X = base[None] + 0.2 * np.sin(t + np.arange(2)[None, :, None, None])  # (F, 2, 17, 3)
    uv, _ = project(rig, X)  # (V, F, 2, 17, 2)
    V, F, P, J = uv.shape[0], n_frames, 2, 17
    view = np.repeat(np.arange(V), F * P)
    frame = np.tile(np.repeat(np.arange(F), P), V)
    track = np.tile(np.arange(P), V * F)
    kp = uv.reshape(V * F * P, J, 2) + rng.normal(0, 1.0, size=(V * F * P, J, 2))
    lo, hi = kp.min(axis=1), kp.max(axis=1)
    tracks = Tracks2D(
        joint_names=COCO17,
        n_views=V,
        n_frames=F,
        view=view.astype(np.int64),
        frame=frame.astype(np.int64),
        bbox_xyxy_px=np.concatenate([lo, hi], axis=1),
        bbox_score=np.full(V * F * P, 0.9),
        keypoints_px=kp,
        keypoint_conf=np.full((V * F * P, J), 0.9),
        keypoint_valid=np.ones((V * F * P, J), dtype=bool),
        track_id=track.astype(np.int64),
    )
    return tracks, X


def fit_stage_inputs(
    rig: CameraRig, xyz: np.ndarray, fps: float = 50.0, noise_3d_m: float = 0.0, noise_px: float = 0.0, seed: int = 0
) -> tuple[Keypoints3D, Tracks2D, Association]:
    """Inputs of the fit stage from known joints ``xyz`` (frames, persons, 23, 3) in
    ``COCO17_FEET`` order: filtered 3D keypoints, every person seen by every view, identities
    known. Optional Gaussian noise on the 3D points and on the 2D projections."""
    rng = np.random.default_rng(seed)
    nf, npers, nj = xyz.shape[:3]
    kp3d = Keypoints3D(
        joint_names=COCO17_FEET,
        person_ids=np.arange(npers),
        frame_indices=np.arange(nf),
        fps=fps,
        xyz_m=xyz + rng.normal(0, noise_3d_m, xyz.shape) if noise_3d_m else xyz.copy(),
        valid=np.ones((nf, npers, nj), dtype=bool),
        confidence=np.full((nf, npers, nj), 0.9),
        n_views=np.full((nf, npers, nj), rig.n_views),
        reproj_err_px=np.zeros((nf, npers, nj)),
        source="filtered",
    )
    uv, _ = project(rig, xyz)  # (V, F, P, J, 2)
    if noise_px:
        uv = uv + rng.normal(0, noise_px, uv.shape)
    nv = rig.n_views
    view, frame, person = (
        a.ravel() for a in np.meshgrid(np.arange(nv), np.arange(nf), np.arange(npers), indexing="ij")
    )
    kp = uv[view, frame, person]
    tracks = Tracks2D(
        joint_names=COCO17_FEET,
        n_views=nv,
        n_frames=nf,
        view=view.astype(np.int64),
        frame=frame.astype(np.int64),
        bbox_xyxy_px=np.concatenate([kp.min(axis=1), kp.max(axis=1)], axis=1),
        bbox_score=np.full(view.size, 0.9),
        keypoints_px=kp,
        keypoint_conf=np.full((view.size, nj), 0.95),
        keypoint_valid=np.ones((view.size, nj), dtype=bool),
        track_id=person.astype(np.int64),
    )
    assoc = Association(
        person_ids=np.arange(npers),
        person_names=("",) * npers,
        person_of_det=person.astype(np.int64),
        confidence=np.ones(view.size),
    )
    return kp3d, tracks, assoc


def write_tiny_session(session_dir: Path, stages: tuple[str, ...] = ("detect2d", "track"), n_frames: int = 20) -> Path:
    """A 'tracks' session with a 3-camera rig (no dependence on the synthetic generator)."""
    (session_dir / "inputs").mkdir(parents=True, exist_ok=True)
    rig = make_rig()
    tracks, _ = make_tracks(rig, n_frames=n_frames)
    save_toml(rig, session_dir / "inputs" / "calibration.toml")
    save_npz(session_dir / "inputs" / "tracks2d.npz", tracks)
    SessionConfig(
        name="tiny",
        source="tracks",
        calibration="inputs/calibration.toml",
        tracks="inputs/tracks2d.npz",
        stages=stages,
    ).save(session_dir)
    return session_dir


@pytest.fixture
def tiny_session(tmp_path: Path) -> Path:
    return write_tiny_session(tmp_path / "tiny")


@pytest.fixture
def models_dir() -> Path:
    p = shared_models_dir()
    if p is None:
        pytest.skip(f"shared ONNX models not available ({describe_lookup()})")
    return p


@pytest.fixture
def test_data_dir() -> Path:
    p = shared_data_dir()
    if p is None:
        pytest.skip(f"shared test data not available ({describe_lookup()})")
    return p
