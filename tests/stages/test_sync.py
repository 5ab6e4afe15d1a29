from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

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


def test_apply_offsets_reindexes_frames_onto_one_clock() -> None:
    from pipeline.stages.sync import apply_offsets, offsets_to_frames

    tr = _signal_tracks([np.zeros((10, 2))] * 3, 10)
    shift = offsets_to_frames(np.array([0.0, 2 / 60, -1 / 60]), 60.0)
    np.testing.assert_array_equal(shift, [0, 2, -1])
    out = apply_offsets(tr, shift)
    # The earliest camera (view 2, shift -1) keeps its numbering; the others move later.
    np.testing.assert_array_equal(out.frame[out.view == 0], np.arange(10) + 1)
    np.testing.assert_array_equal(out.frame[out.view == 1], np.arange(10) + 3)
    np.testing.assert_array_equal(out.frame[out.view == 2], np.arange(10))
    assert out.n_frames == 13
    assert apply_offsets(tr, np.zeros(3, np.int64)) is tr
    with pytest.raises(ValueError, match="expected"):
        apply_offsets(tr, np.zeros(2, np.int64))


def test_track_step_applies_given_offsets(tmp_path: Path) -> None:
    import json

    from pipeline.artifacts import ArtifactStore
    from pipeline.io.calibration import load_calibration
    from pipeline.runner import run as run_session
    from pipeline.schema.detections import Tracks2D as T2
    from tests.conftest import write_tiny_session

    sess = write_tiny_session(tmp_path / "s")
    cfg = json.loads((sess / "session.json").read_text())
    cfg["stage_config"] = {"track": {"time_offsets": "given", "time_offsets_s": {"cam1": 0.0}}}
    (sess / "session.json").write_text(json.dumps(cfg))
    run_session(sess)
    base = ArtifactStore(sess).load("track", "tracks", T2)
    rig = load_calibration(sess / "inputs" / "calibration.toml")
    names, fps = rig.names, rig.fps
    cfg["stage_config"] = {"track": {"time_offsets": "given", "time_offsets_s": {names[1]: 3 / fps}}}
    (sess / "session.json").write_text(json.dumps(cfg))
    run_session(sess)
    shifted = ArtifactStore(sess).load("track", "tracks", T2)
    np.testing.assert_array_equal(shifted.frame[shifted.view == 1], base.frame[base.view == 1] + 3)
    np.testing.assert_array_equal(shifted.frame[shifted.view == 0], base.frame[base.view == 0])
    cfg["stage_config"] = {"track": {"time_offsets": "given", "time_offsets_s": {"nocam": 1.0}}}
    (sess / "session.json").write_text(json.dumps(cfg))
    with pytest.raises(ValueError, match="nocam"):
        run_session(sess)
