from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest

from pipeline.schema import COCO17, Tracks2D
from pipeline.stages.sync import SyncConfig, run
from tests.conftest import make_rig


def _signal_tracks(motion: list[np.ndarray], n_frames: int) -> Tracks2D:
    """One track per view whose keypoints all move by ``motion[v][f]`` (px) at frame f."""
    V = len(motion)
    base = np.random.default_rng(1).uniform(0, 200, (17, 2))
    kp = np.concatenate([base[None] + motion[v][:, None, :] + 300 for v in range(V)])
    n = V * n_frames
    lo, hi = kp.min(axis=1), kp.max(axis=1)
    return Tracks2D(
        joint_names=COCO17,
        n_views=V,
        n_frames=n_frames,
        view=np.repeat(np.arange(V), n_frames),
        frame=np.tile(np.arange(n_frames), V),
        bbox_xyxy_px=np.concatenate([lo, hi + 1], axis=1),
        bbox_score=np.ones(n),
        keypoints_px=kp,
        keypoint_conf=np.ones((n, 17)),
        keypoint_valid=np.ones((n, 17), bool),
        track_id=np.zeros(n, np.int64),
    )


def _motion(rng: np.random.Generator, n: int) -> np.ndarray:
    """Bursty 2D motion (punches): smooth random steps with varying speed."""
    speed = np.convolve(rng.gamma(0.5, 4.0, n), np.ones(5) / 5, mode="same")
    ang = np.cumsum(rng.normal(0, 0.3, n))
    step = speed[:, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    return np.cumsum(step, axis=0)


def test_recovers_known_offsets() -> None:
    rng = np.random.default_rng(0)
    F, pad = 240, 20
    world = _motion(rng, F + 2 * pad)
    # View v started ``shift`` frames later: its frame f shows world frame f + shift.
    shifts = [0, 5, -3, 8]
    motion = [world[pad + s : pad + s + F] * (1.0 + 0.3 * v) for v, s in enumerate(shifts)]
    rig = dataclasses.replace(make_rig(4), fps=60.0)
    res = run(_signal_tracks(motion, F), rig, SyncConfig(max_offset_s=0.3, cutoff_hz=10.0))
    assert res.consistent
    np.testing.assert_array_equal(res.offset_frames, shifts)
    np.testing.assert_allclose(res.time_offset_s, np.array(shifts) / 60.0)


def test_inconsistent_offsets_warn(caplog: pytest.LogCaptureFixture) -> None:
    rng = np.random.default_rng(3)
    F = 200
    world = _motion(rng, F + 40)
    motion = [
        world[20 : 20 + F],
        world[24 : 24 + F],
        _motion(np.random.default_rng(99), F),
    ]  # view 3: unrelated
    rig = dataclasses.replace(make_rig(3), fps=60.0)
    with caplog.at_level(logging.WARNING, logger="pipeline.stages.sync"):
        res = run(
            _signal_tracks(motion, F), rig, SyncConfig(max_offset_s=0.3, cutoff_hz=10.0, tolerance_frames=1)
        )
    assert not res.consistent
    assert "INCONSISTENT" in caplog.text


def test_unknown_reference_camera() -> None:
    rig = make_rig(2)
    tr = _signal_tracks([np.zeros((30, 2)), np.zeros((30, 2))], 30)
    with pytest.raises(ValueError, match="camX"):
        run(tr, rig, SyncConfig(reference="camX"))
