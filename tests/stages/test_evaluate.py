"""evaluate stage: penetration proxy, problem flags and metrics on hand-built cases."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.schema import COCO17, Association, Keypoints3D
from pipeline.stages.evaluate import EvaluateConfig, EvaluateInputs, capsule_penetration_mm, run
from tests.conftest import make_rig, make_tracks


def _two_people(F: int, gap_m: np.ndarray) -> Keypoints3D:
    """Two identical stick bodies separated along x by ``gap_m[f]``."""
    kp = Keypoints3D.empty(COCO17, np.array([0, 1]), np.arange(F), 50.0, "filtered")
    rng = np.random.default_rng(0)
    body = np.linspace([0, 0, 0.1], [0, 0, 1.7], 17)
    body[:, 1] += rng.normal(0, 0.05, 17)  # planar body (x = 0): gaps along x are exact
    xyz = np.zeros((F, 2, 17, 3))
    xyz[:, 0] = body
    xyz[:, 1] = body + np.stack([gap_m, np.zeros(F), np.zeros(F)], axis=1)[:, None]
    return kp.replace(xyz_m=xyz, valid=np.ones((F, 2, 17), bool), confidence=np.ones((F, 2, 17)))


def test_capsule_penetration_grows_as_bodies_overlap() -> None:
    kp = _two_people(3, np.array([2.0, 0.10, 0.0]))
    pen = capsule_penetration_mm(kp, radius_m=0.06)
    assert pen[0] == 0.0
    assert 15.0 < pen[1] < 25.0  # 2 * 60 mm - 100 mm = 20 mm
    assert pen[2] > 100.0


def test_evaluate_perfect_estimate_and_flags() -> None:
    rig = make_rig(3)
    tracks, X = make_tracks(rig, n_frames=10)
    gt = Keypoints3D.empty(COCO17, np.array([0, 1]), np.arange(10), 50.0, "gt").replace(
        xyz_m=X, valid=np.ones((10, 2, 17), bool), confidence=np.ones((10, 2, 17))
    )
    conf = np.ones(tracks.n_dets)
    conf[(tracks.frame == 4)] = 0.2  # frame 4 has an uncertain identity
    # Estimated ids swapped relative to gt (track 0 is gt person 0 but estimated person 1):
    # metrics must match persons first.
    assoc = Association(np.array([0, 1]), ("A", "B"), 1 - tracks.track_id, conf)
    est = gt.replace(source="filtered", person_ids=np.array([1, 0]))
    metrics, flags = run(
        EvaluateInputs(rig, tracks, assoc, {"filtered": est}, gt=gt, gt_person_of_det=tracks.track_id.copy()),
        EvaluateConfig(),
    )
    src = metrics["sources"]["filtered"]
    assert src["mpjpe_mm"] == 0.0 and src["pcp_pct"] == 100.0
    assert metrics["identity_accuracy_pct"] == 100.0
    assert flags.flags[:, 0].tolist() == [f == 4 for f in range(10)]
    # 1 px keypoint noise in make_tracks: no frame exceeds the 15 px threshold.
    assert not flags.flags[:, 1].any() and flags.reproj_err_px.max() < 5.0


def test_evaluate_reports_physical_plausibility() -> None:
    """Gap-free sources get penetration, ground penetration and foot skating; raw does not."""
    rig = make_rig(3)
    tracks, _ = make_tracks(rig, n_frames=4)
    kp = _two_people(4, np.full(4, 0.10))
    xyz = kp.xyz_m.copy()
    xyz[:, :, 0, 2] = -0.02  # the lowest point 2 cm under the floor
    xyz[:, :, 15:17, 2] = 0.01  # ankles on the floor: feet in contact
    xyz[:, 0, :, 0] += np.arange(4)[:, None] * 0.01  # person 0 slides 1 cm per frame, feet included
    kp = kp.replace(xyz_m=xyz)
    assoc = Association(np.array([0, 1]), ("A", "B"), tracks.track_id.copy(), np.ones(tracks.n_dets))
    metrics, _ = run(EvaluateInputs(rig, tracks, assoc, {"fit": kp, "raw": kp.replace(source="raw")}), EvaluateConfig())
    fit = metrics["sources"]["fit"]
    assert fit["ground_penetration_max_mm"] == 20.0
    assert fit["inter_penetration_max_mm"] > 0.0
    assert abs(fit["foot_skate_mm_per_frame"] - 5.0) < 0.01  # 10 mm/frame for one of two persons
    assert "foot_skate_mm_per_frame" not in metrics["sources"]["raw"]


def test_flags_need_most_views_of_an_athlete_to_disagree() -> None:
    """One bad view (a failed 2D detection, a doubtful identity) does not flag a frame;
    the same error in most views does, relative to the person's size in the image."""
    import dataclasses

    rig = make_rig(3)
    tracks, X = make_tracks(rig, n_frames=6)
    est = Keypoints3D.empty(COCO17, np.array([0, 1]), np.arange(6), 50.0, "fit").replace(
        xyz_m=X, valid=np.ones((6, 2, 17), bool), confidence=np.ones((6, 2, 17))
    )
    kp = tracks.keypoints_px.copy()
    conf = np.ones(tracks.n_dets)
    height = tracks.bbox_xyxy_px[:, 3] - tracks.bbox_xyxy_px[:, 1]
    one = (tracks.frame == 1) & (tracks.track_id == 0) & (tracks.view == 0)
    most = (tracks.frame == 3) & (tracks.track_id == 1) & (tracks.view >= 1)
    for sel in (one, most):
        kp[sel] += 0.2 * height[sel, None, None]  # 20 % of the person's height off
        conf[sel] = 0.1
    tracks = dataclasses.replace(tracks, keypoints_px=kp)
    assoc = Association(np.array([0, 1]), ("A", "B"), tracks.track_id.copy(), conf)
    _, flags = run(EvaluateInputs(rig, tracks, assoc, {"fit": est}), EvaluateConfig())
    assert flags.flags[:, 0].tolist() == [f == 3 for f in range(6)]
    assert flags.flags[:, 1].tolist() == [f == 3 for f in range(6)]
    assert 0.15 < flags.reproj_rel[3] < 0.35 and flags.reproj_err_px[1] < flags.reproj_err_px[3]
    with pytest.raises(ValueError, match="reproj_high_frac"):
        EvaluateConfig(reproj_high_frac=1.5)
