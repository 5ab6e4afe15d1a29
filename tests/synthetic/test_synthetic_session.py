"""write_session / make_demo_session produce a loadable cornerman session."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.io.calibration import load_calibration
from pipeline.schema import Keypoints3D, SessionConfig, Tracks2D, load_npz
from pipeline.synthetic import SyntheticBout, SyntheticConfig, make_demo_session, write_session


def test_write_session_roundtrip(default_bout: SyntheticBout, tmp_path: Path) -> None:
    out = write_session(default_bout, tmp_path / "bout", name="test bout")
    cfg = SessionConfig.load(out)
    assert cfg.name == "test bout" and cfg.source == "tracks"
    assert cfg.fps == pytest.approx(50.0)
    assert (cfg.calibration, cfg.tracks) == ("inputs/calibration.toml", "inputs/tracks2d.npz")
    assert (cfg.ground_truth, cfg.ground_truth_labels) == ("inputs/ground_truth.npz", "inputs/gt_labels.npz")
    rig = load_calibration(out / cfg.calibration)
    assert rig.names == default_bout.rig.names
    np.testing.assert_allclose(rig.K, default_bout.rig.K)
    np.testing.assert_allclose(rig.T_world_cam, default_bout.rig.T_world_cam, atol=1e-9)
    assert rig.fps == pytest.approx(50.0)
    tracks = load_npz(out / cfg.tracks, Tracks2D)
    np.testing.assert_array_equal(tracks.keypoints_px, default_bout.tracks.keypoints_px)
    np.testing.assert_array_equal(tracks.track_id, default_bout.tracks.track_id)
    gt = load_npz(out / cfg.ground_truth, Keypoints3D)
    assert gt.source == "gt"
    np.testing.assert_array_equal(gt.xyz_m, default_bout.gt.xyz_m)
    with np.load(out / cfg.ground_truth_labels, allow_pickle=False) as z:
        np.testing.assert_array_equal(z["person_of_det"], default_bout.gt_person_of_det)
        np.testing.assert_array_equal(z["foot_contact"], default_bout.foot_contact)
        np.testing.assert_array_equal(z["swap_frames"], default_bout.swap_frames)
        assert z["person_of_det"].shape == (tracks.n_dets,)


def test_demo_session_is_reused_when_identical(tmp_path: Path) -> None:
    cfg = SyntheticConfig(n_frames=40, n_cameras=2)
    d = make_demo_session(tmp_path / "demo", cfg)
    tracks = d / "inputs" / "tracks2d.npz"
    stamp = tracks.stat().st_mtime_ns
    before = tracks.read_bytes()
    assert make_demo_session(d, cfg) == d
    assert tracks.stat().st_mtime_ns == stamp  # untouched
    # A different config regenerates the inputs.
    make_demo_session(d, SyntheticConfig(n_frames=40, n_cameras=2, seed=1))
    assert tracks.read_bytes() != before
    # Tampered inputs are regenerated too, and the arrays are the same as before.
    make_demo_session(d, cfg)
    ref = load_npz(tracks, Tracks2D)
    tracks.write_bytes(b"garbage")
    make_demo_session(d, cfg)
    again = load_npz(tracks, Tracks2D)
    np.testing.assert_array_equal(again.keypoints_px, ref.keypoints_px)
    assert SessionConfig.load(d).name == "demo bout"


@pytest.mark.parametrize(
    "kw",
    [
        {"n_cameras": 1},
        {"n_cameras": 9},
        {"n_frames": 1},
        {"noise_px": -1.0},
        {"miss_rate": 1.0},
        {"fps": 0.0},
    ],
)
def test_config_validation(kw: dict) -> None:
    with pytest.raises(ValueError):
        SyntheticConfig(**kw)


def test_bout_stats(default_bout: SyntheticBout) -> None:
    from pipeline.synthetic.stats import bout_stats

    s = bout_stats(default_bout)
    assert s["frames"] == 300 and s["cameras"] == 4
    assert s["detections"] == default_bout.tracks.n_dets
    assert 6.0 <= s["fist_peak_min_mps"] <= s["fist_peak_max_mps"] <= 10.0
    assert s["clinch_frames"] >= 5 and s["swaps"] >= 1 and s["steps"] >= 12
    assert 1 <= s["bystander_views"] < 4
