"""Triangulation stage: accuracy against ground truth, per-joint records, outlier views, config."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from pipeline.evaluate.consistency import reprojection_by_camera
from pipeline.evaluate.metrics import mpjpe, pcp, reprojection_error
from pipeline.schema import Association
from pipeline.stages.filtering import FilterConfig
from pipeline.stages.triangulate import TriangulateConfig, run, summary
from tests.stages.mv_fixtures import make_scene


def _gt_assoc(gt_pod: np.ndarray) -> Association:
    return Association(
        person_ids=np.array([0, 1]), person_names=("", ""), person_of_det=gt_pod.astype(np.int64), confidence=np.ones(gt_pod.size)
    )


def test_noise_free_recovers_ground_truth_exactly() -> None:
    s = make_scene(n_frames=10, noise_px=0.0, miss_joint=0.0)
    raw, filtered = run(s.tracks, _gt_assoc(s.gt_person_of_det), s.rig)
    assert raw.source == "raw" and filtered.source == "filtered"
    assert raw.valid.all() and (raw.n_views == 4).all()
    assert np.abs(raw.xyz_m - s.gt_xyz).max() < 1e-6  # distortion is undone exactly
    assert np.nanmax(raw.reproj_err_px) < 1e-4
    assert np.abs(filtered.xyz_m - s.gt_xyz).max() < 0.01


def test_noisy_accuracy_records_and_filtering() -> None:
    s = make_scene(n_frames=60, noise_px=2.0, referee=True)
    assoc = _gt_assoc(s.gt_person_of_det)
    raw, filtered = run(s.tracks, assoc, s.rig)
    gt = s.gt_keypoints()
    assert pcp(raw, gt) > 0.99 and mpjpe(raw, gt) < 25.0
    assert mpjpe(filtered, gt) < mpjpe(raw, gt)  # smoothing helps on noise
    med = np.nanmedian(raw.reproj_err_px[raw.valid])
    assert 0.5 < med < 4.0  # ~ the 2 px noise
    assert ((raw.confidence > 0) & (raw.confidence <= 1))[raw.valid].all()
    # The stage's error equals the metric's (undistorted vs distorted px: close).
    err = reprojection_error(raw, s.tracks, assoc, s.rig)
    assert abs(np.nanmedian(err) - med) < 0.5
    m = summary(raw, filtered, s.tracks, assoc, s.rig)
    assert m["valid_raw_pct"] > 95 and m["mean_views"] > 3.5
    # The summary's all-view error is the consistency metric's.
    assert m["reproj_median_px"] == round(reprojection_by_camera(filtered, s.tracks, assoc, s.rig).median_all_px, 2)


def test_outlier_view_is_rejected_per_joint() -> None:
    s = make_scene(n_frames=5, noise_px=0.5, miss_joint=0.0)
    kp = s.tracks.keypoints_px.copy()
    bad = (s.tracks.view == 2) & (s.gt_person_of_det == 0)
    kp[bad, 9] += [120.0, -80.0]  # left wrist of boxer 0 wrong in cam2
    tracks = dataclasses.replace(s.tracks, keypoints_px=kp)
    raw, _ = run(tracks, _gt_assoc(s.gt_person_of_det), s.rig)
    assert (raw.n_views[:, 0, 9] == 3).all() and (raw.n_views[:, 0, 8] == 4).all()
    assert np.abs(raw.xyz_m[:, 0, 9] - s.gt_xyz[:, 0, 9]).max() < 0.01
    # Without outlier rejection the wrist is pulled away.
    raw2, _ = run(tracks, _gt_assoc(s.gt_person_of_det), s.rig, TriangulateConfig(max_view_err_px=1e9))
    assert np.abs(raw2.xyz_m[:, 0, 9] - s.gt_xyz[:, 0, 9]).max() > 0.02


def test_duplicate_assignment_keeps_the_more_confident_detection() -> None:
    s = make_scene(n_frames=4, noise_px=0.0, miss_joint=0.0, referee=True)
    pod = s.gt_person_of_det.copy()
    ref = pod < 0
    pod[ref] = 0  # the referee is (wrongly) also given person 0
    conf = np.where(ref, 0.1, 0.9)
    assoc = Association(person_ids=np.array([0, 1]), person_names=("", ""), person_of_det=pod, confidence=conf)
    raw, _ = run(s.tracks, assoc, s.rig)
    assert np.abs(raw.xyz_m - s.gt_xyz).max() < 1e-6


def test_missing_views_and_weighting_variants() -> None:
    s = make_scene(n_frames=20, noise_px=2.0, empty_views=(1,), miss_det=0.2, seed=2)
    gt = s.gt_keypoints()
    for weighting in ("joint_conf", "view_mean_conf", "uniform"):
        raw, filtered = run(s.tracks, _gt_assoc(s.gt_person_of_det), s.rig, TriangulateConfig(weighting=weighting))
        assert raw.n_views.max() <= 3
        assert mpjpe(raw, gt) < 30.0
        assert filtered.valid.mean() >= raw.valid.mean()


def test_config_accepts_filter_dict_and_rejects_unknown_keys() -> None:
    cfg = TriangulateConfig(filter={"jerk_std": 80.0})  # type: ignore[arg-type]
    assert isinstance(cfg.filter, FilterConfig) and cfg.filter.jerk_std == 80.0
    with pytest.raises(ValueError, match="unknown keys"):
        TriangulateConfig(filter={"nope": 1})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="min_views"):
        TriangulateConfig(min_views=1)


def test_runner_steps_end_to_end(tmp_path: Path) -> None:
    """detect2d -> track -> associate -> triangulate through the runner; an identity edit
    makes ``associate`` (and ``triangulate``) stale and changes the result."""
    from pipeline.artifacts import ArtifactStore
    from pipeline.io.calibration import save_toml
    from pipeline.runner.core import run as run_session
    from pipeline.runner.core import stage_status
    from pipeline.schema import Keypoints3D, SessionConfig, SwapIdentities, save_annotations, save_npz

    s = make_scene(n_frames=20, referee=True)
    (tmp_path / "inputs").mkdir()
    save_toml(s.rig, tmp_path / "inputs" / "calibration.toml")
    save_npz(tmp_path / "inputs" / "tracks2d.npz", s.tracks)
    SessionConfig(
        name="t", source="tracks", calibration="inputs/calibration.toml", tracks="inputs/tracks2d.npz",
        stages=("detect2d", "track", "associate", "triangulate"), athletes=("Red", "Blue"),
        stage_config={"triangulate": {"filter": {"jerk_std": 120.0}}},
    ).save(tmp_path)
    run_session(tmp_path)
    store = ArtifactStore(tmp_path)
    assoc = store.load("associate", "association", Association)
    kp = store.load("triangulate", "keypoints3d", Keypoints3D)
    raw = store.load("triangulate", "raw", Keypoints3D)
    assert assoc.person_names == ("Red", "Blue") and kp.source == "filtered" and raw.source == "raw"
    assert mpjpe(kp, s.gt_keypoints()) < 25.0
    m = store.manifest("triangulate")
    assert m is not None and m.metrics["kept_views_median_px"] < 5 and m.metrics["reproj_median_px"] < 5 and m.config["filter"]["jerk_std"] == 120.0
    save_annotations(tmp_path / "annotations.json", [SwapIdentities(frame=10, person_a=0, person_b=1)])
    st = stage_status(tmp_path)
    assert st["track"] == "fresh" and st["associate"] != "fresh" and st["triangulate"] != "fresh"
    run_session(tmp_path)
    assoc2 = store.load("associate", "association", Association)
    late = (s.tracks.frame >= 10) & (assoc.person_of_det >= 0)
    assert (assoc2.person_of_det[late] == 1 - assoc.person_of_det[late]).all()
