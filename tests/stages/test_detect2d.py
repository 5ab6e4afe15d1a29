from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipeline.schema.joints import COCO17_FEET
from pipeline.stages.detect2d import Detect2DConfig, duplicate_pose_keep, merge_feet, run_videos
from tests.conftest import make_rig


def _grey_video(path: Path, w: int, h: int, n: int = 3) -> Path:
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 60.0, (w, h))
    for _ in range(n):
        vw.write(np.full((h, w, 3), 128, np.uint8))
    vw.release()
    return path


def test_camera_names_must_match_rig(tmp_path: Path) -> None:
    rig = make_rig(2)
    v = _grey_video(tmp_path / "a.avi", 64, 48)
    with pytest.raises(ValueError, match="camX"):
        run_videos({"cam1": v, "camX": v}, rig)
    with pytest.raises(ValueError, match="cam2"):
        run_videos({"cam1": v}, rig)


def test_corrupt_video_names_file(tmp_path: Path) -> None:
    rig = make_rig(1)
    bad = tmp_path / "cam1_broken.mp4"
    bad.write_bytes(b"garbage" * 50)
    with pytest.raises(ValueError, match="cam1_broken.mp4"):
        run_videos({"cam1": bad}, rig)


def test_missing_model_is_a_clear_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CORNERMAN_MODELS_DIR", raising=False)
    monkeypatch.setenv("CORNERMAN_CACHE_DIR", str(tmp_path / "cache"))
    rig = make_rig(1)
    v = _grey_video(tmp_path / "a.avi", 64, 48)
    with pytest.raises(ValueError, match="model 'yolox_m' not found.*cornerman models download yolox_m"):
        run_videos(
            {"cam1": v}, rig, None, Detect2DConfig(detector="yolox_m", models_dir=str(tmp_path / "empty"))
        )


@pytest.mark.requires_models
@pytest.mark.requires_data
def test_real_video_and_camera_without_people(
    models_dir: Path, test_data_dir: Path, caplog: pytest.LogCaptureFixture, tmp_path: Path
) -> None:
    from pipeline.io.calibration import load_calibration

    data = test_data_dir / "pose2sim_multiperson"
    rig = load_calibration(data / "calibration" / "Calib.qca.txt").subset([0, 1])
    rig = dataclasses.replace(rig, fps=60.0)
    w, h = (int(x) for x in rig.image_size_wh[1])
    empty = _grey_video(tmp_path / "empty.avi", w, h, n=3)
    progress: list[tuple[float, float | None, str]] = []
    cfg = Detect2DConfig(models_dir=str(models_dir), max_frames=3, batch_size=2, num_threads=1)
    with caplog.at_level(logging.WARNING, logger="pipeline.stages.detect2d"):
        dets = run_videos(
            {rig.names[0]: data / "videos" / f"{rig.names[0]}.mp4", rig.names[1]: empty},
            rig,
            lambda d, t, m: progress.append((d, t, m)),
            cfg,
        )
    assert f"camera {rig.names[1]}" in caplog.text and "no person detected" in caplog.text
    assert dets.joint_names == COCO17_FEET and dets.n_views == 2 and dets.n_frames == 3
    assert np.all(dets.view == 0)  # the empty camera has no rows
    for f in range(3):
        rows = dets.rows(0, f)
        assert len(rows) >= 2
        big = rows[np.argsort(-(dets.bbox_xyxy_px[rows, 3] - dets.bbox_xyxy_px[rows, 1]))[:2]]
        assert dets.keypoint_valid[big][:, :17].all()
    small_toes = [COCO17_FEET.index("left_small_toe"), COCO17_FEET.index("right_small_toe")]
    assert not dets.keypoint_valid[:, small_toes].any()
    assert progress[-1][0] == progress[-1][1] == 6.0


@pytest.mark.slow
@pytest.mark.requires_models
@pytest.mark.requires_data
def test_pose2sim_short_end_to_end(models_dir: Path, test_data_dir: Path) -> None:
    """12 frames × 4 cameras: two performers, one track each per view, ≤ 15 px reprojection."""
    from pipeline.evaluate.metrics import reprojection_error
    from pipeline.io.calibration import load_calibration
    from pipeline.stages import associate, triangulate
    from pipeline.stages.association.config import AssociateConfig
    from pipeline.stages.track import run as run_tracker
    from pipeline.stages.triangulate import TriangulateConfig

    data = test_data_dir / "pose2sim_multiperson"
    rig = dataclasses.replace(load_calibration(data / "calibration" / "Calib.qca.txt"), fps=60.0)
    F = 12
    cfg = Detect2DConfig(models_dir=str(models_dir), max_frames=F, num_threads=1)
    dets = run_videos({n: data / "videos" / f"{n}.mp4" for n in rig.names}, rig, None, cfg)
    tracks = run_tracker(dets, rig)
    assoc = associate.run(tracks, rig, AssociateConfig(n_persons=2), [])
    raw, _ = triangulate.run(tracks, assoc, rig, TriangulateConfig())
    assert raw.n_persons == 2
    for v in range(rig.n_views):
        for p in raw.person_ids:
            m = (tracks.view == v) & (assoc.person_of_det == p)
            assert np.unique(tracks.track_id[m]).size == 1, (rig.names[v], p)
            assert m.sum() == F, (rig.names[v], p, int(m.sum()))
    assert np.nanmedian(reprojection_error(raw, tracks, assoc, rig)) <= 15.0


@pytest.mark.requires_models
@pytest.mark.requires_data
def test_runner_video_session(models_dir: Path, test_data_dir: Path, tmp_path: Path) -> None:
    """The runner's detect2d (video branch) and track steps on 4 cameras × 6 frames."""
    from pipeline.artifacts import ArtifactStore
    from pipeline.runner import run
    from pipeline.schema import SessionConfig, Tracks2D

    data = test_data_dir / "pose2sim_multiperson"
    session = tmp_path / "s"
    session.mkdir()
    SessionConfig(
        name="p2s",
        source="video",
        calibration=str(data / "calibration" / "Calib.qca.txt"),
        videos={c: str(data / "videos" / f"{c}.mp4") for c in ("cam01", "cam02", "cam03", "cam04")},
        fps=60.0,
        stage_config={"detect2d": {"models_dir": str(models_dir), "max_frames": 6, "num_threads": 1}},
        stages=("detect2d", "track"),
    ).save(session)
    reports = run(session)
    assert [(r.stage, r.action) for r in reports] == [("detect2d", "ran"), ("track", "ran")]
    assert reports[0].metrics["detections"] >= 4 * 6 * 2
    tracks = ArtifactStore(session).load("track", "tracks", Tracks2D)
    assert tracks.n_views == 4 and tracks.n_frames == 6
    for v in range(4):
        ids = tracks.track_id[(tracks.view == v) & (tracks.track_id >= 0)]
        assert np.unique(ids).size >= 2  # both performers have a track in every view


def test_pose_nms_drops_the_box_holding_another_persons_pose() -> None:
    rng = np.random.default_rng(0)
    J = 17
    woman = np.c_[rng.uniform(600, 900, J), rng.uniform(420, 940, J)]
    man = np.c_[rng.uniform(180, 800, J), rng.uniform(420, 1250, J)]
    boxes = np.array([[580.0, 400, 920, 960], [160, 400, 990, 1260], [170, 410, 820, 1270]])
    # Detection 1 is the man's large box, but the model returned the woman's pose in it.
    kp = np.stack([woman, woman + rng.normal(0, 3, (J, 2)), man])
    conf = np.full((3, J), 0.9)
    valid = np.ones((3, J), bool)
    keep = duplicate_pose_keep(boxes, kp, conf, valid, 0.1)
    assert keep.tolist() == [True, False, True]
    # Order does not matter: the box that fits its keypoints wins.
    keep = duplicate_pose_keep(boxes[[1, 0, 2]], kp[[1, 0, 2]], conf, valid, 0.1)
    assert keep.tolist() == [False, True, True]
    # Off, or too few shared confident keypoints: everything is kept.
    assert duplicate_pose_keep(boxes, kp, conf, valid, 0.0).all()
    few = conf.copy()
    few[1, 4:] = 0.1
    assert duplicate_pose_keep(boxes, kp, few, valid, 0.1).all()
    with pytest.raises(ValueError, match="pose_nms_dist"):
        Detect2DConfig(pose_nms_dist=1.5)


def test_foot_points_come_from_the_foot_model_where_the_ankles_agree() -> None:
    J = len(COCO17_FEET)
    la, ra = COCO17_FEET.index("left_ankle"), COCO17_FEET.index("right_ankle")
    lh, rh = COCO17_FEET.index("left_heel"), COCO17_FEET.index("right_heel")
    boxes = np.array([[0.0, 0.0, 100.0, 400.0]])
    main_kp = np.zeros((1, J, 2))
    main_kp[0, la], main_kp[0, ra] = (40, 390), (60, 390)
    main_valid = np.zeros((1, J), bool)
    main_valid[0, :17] = True  # a COCO-17 model: no feet
    feet_kp = main_kp.copy()
    feet_kp[0, ra] = (60, 330)  # its right ankle is 60 px (15 % of the box) off: that side is refused
    feet_kp[0, lh], feet_kp[0, rh] = (35, 398), (55, 398)
    feet_valid = np.ones((1, J), bool)
    kp, conf, valid = merge_feet((main_kp, np.full((1, J), 0.9), main_valid), (feet_kp, np.full((1, J), 0.8), feet_valid), boxes, 0.05)
    assert valid[0, lh] and tuple(kp[0, lh]) == (35, 398) and conf[0, lh] == 0.8
    assert not valid[0, rh]
    assert np.array_equal(kp[0, :17], main_kp[0, :17])  # the body stays the main model's
    with pytest.raises(ValueError, match="foot_ankle_max_frac"):
        Detect2DConfig(foot_ankle_max_frac=0.0)
    with pytest.raises(ValueError, match="pose_refine_scale"):
        Detect2DConfig(pose_refine_scale=-1.0)
