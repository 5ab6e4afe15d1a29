"""Attribution of wrong Shelf limb parts (``pipeline.evaluate.shelf_attribution``) on a
hand-made rig, skeleton and detections."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.evaluate.shelf import SHELF_JOINTS, score_shelf
from pipeline.evaluate.shelf_attribution import (
    LIMB_JOINTS,
    associated_limb_keypoints,
    attribute_wrong_parts,
    hip_height_offset_mm,
)
from pipeline.geometry.projection import project
from pipeline.schema import COCO17, Association, Tracks2D
from tests.conftest import make_rig
from tests.evaluate.test_shelf_eval import STANDING, _kp

LW = SHELF_JOINTS.index("left_wrist")


def _case(detected_at: str) -> tuple:
    """One frame, one actor: the prediction's left wrist is 0.25 m off; the detections in
    every view give that wrist where ``detected_at`` ("ours" / "gt" / "none") puts it."""
    rig = make_rig(n_views=3)
    gt = _kp(STANDING[None, None].copy())
    pred_xyz = STANDING.copy()
    pred_xyz[LW] += [0.0, 0.25, 0.0]
    pred_xyz[[2, 3], 2] += 0.06  # hips 60 mm higher than the ground truth's
    pred = _kp(pred_xyz[None, None])
    coco = {n: i for i, n in enumerate(COCO17)}
    body = np.zeros((17, 3))
    for n in LIMB_JOINTS:
        body[coco[n]] = (pred_xyz if n != "left_wrist" or detected_at == "ours" else STANDING)[
            SHELF_JOINTS.index(n)
        ]
    uv, _ = project(rig, body)  # (V, 17, 2)
    conf = np.ones((3, 17))
    if detected_at == "none":
        conf[:, coco["left_wrist"]] = 0.0
    tracks = Tracks2D(
        joint_names=COCO17,
        n_views=3,
        n_frames=1,
        view=np.arange(3),
        frame=np.zeros(3, np.int64),
        bbox_xyxy_px=np.tile([0.0, 0.0, 1280.0, 720.0], (3, 1)),
        bbox_score=np.ones(3),
        keypoints_px=uv,
        keypoint_conf=conf,
        keypoint_valid=np.ones((3, 17), bool),
        track_id=np.zeros(3, np.int64),
    )
    assoc = Association(
        person_ids=np.array([0]),
        person_names=("a",),
        person_of_det=np.zeros(3, np.int64),
        confidence=np.ones(3),
    )
    score = score_shelf(pred, gt, actors=(0,))
    obs = associated_limb_keypoints(tracks, assoc, pred.person_ids, pred.frame_indices)
    return pred, gt, score, obs, rig


@pytest.mark.parametrize(
    ("detected_at", "field"),
    [("ours", "detections_agree_output"), ("gt", "detections_agree_gt"), ("none", "unobserved")],
)
def test_a_wrong_wrist_is_attributed_by_where_the_detections_put_it(detected_at: str, field: str) -> None:
    pred, gt, score, obs, rig = _case(detected_at)
    assert score.pcp_per_part[0, list(score.part_names).index("left_lower_arm")] == 0.0
    att = attribute_wrong_parts(pred, gt, score, obs, rig)
    assert att.wrong_parts == 1
    assert getattr(att, field) == 1
    others = {"detections_agree_output", "detections_agree_gt", "unobserved", "ambiguous"} - {field}
    assert all(getattr(att, f) == 0 for f in others)


def test_associated_keypoints_keep_only_confident_joints_of_the_person() -> None:
    _, _, _, obs, _ = _case("none")
    assert obs.shape == (1, 1, 3, 12, 2)
    assert np.isnan(obs[0, 0, :, LIMB_JOINTS.index("left_wrist")]).all()
    assert np.isfinite(obs[0, 0, :, LIMB_JOINTS.index("right_wrist")]).all()


def test_hip_height_offset_is_the_median_of_the_hips_heights() -> None:
    pred, gt, score, _, _ = _case("ours")
    assert hip_height_offset_mm(pred, gt, score) == pytest.approx(60.0, abs=1e-6)


def test_bad_inputs_name_the_problem() -> None:
    pred, gt, score, obs, rig = _case("ours")
    with pytest.raises(ValueError, match="agree_ratio"):
        attribute_wrong_parts(pred, gt, score, obs, rig, agree_ratio=1.5)
    with pytest.raises(ValueError, match="Shelf joints"):
        attribute_wrong_parts(gt.replace(joint_names=tuple(reversed(SHELF_JOINTS))), gt, score, obs, rig)
