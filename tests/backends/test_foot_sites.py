"""Foot sites calibrated onto the planted keypoints (``backends.mujoco.foot_sites``)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mujoco")

from pipeline.backends.mujoco.config import HumanoidConfig  # noqa: E402
from pipeline.backends.mujoco.foot_sites import move_sites, planted_site_offsets  # noqa: E402
from pipeline.backends.mujoco.reference import build_scene  # noqa: E402
from pipeline.backends.mujoco.skeleton import _DEFAULT_LENGTHS, build_skeleton  # noqa: E402
from pipeline.schema.joints import COCO17_FEET  # noqa: E402
from tests.backends.test_humanoid import _rest_keypoints  # noqa: E402

TOES = ("left_big_toe", "left_small_toe", "right_big_toe", "right_small_toe")


def test_planted_offsets_find_a_landmark_convention_and_moving_the_sites_removes_it() -> None:
    """A standing person whose toe keypoints sit 12 mm higher than the humanoid's toe sites
    (another landmark convention): with the soles flat the toe sites miss by ~12 mm; the
    offsets say so, and once the sites are moved a new calibration finds nothing left."""
    kp = _rest_keypoints(1.0, n_frames=20)
    xyz = kp.xyz_m.copy()
    for n in TOES:
        xyz[:, 0, COCO17_FEET.index(n), 2] += 0.012
    kp = kp.replace(xyz_m=xyz)
    skel = build_skeleton(dict(_DEFAULT_LENGTHS))
    scene = build_scene([skel], [0], kp.fps, COCO17_FEET, HumanoidConfig())
    offs = planted_site_offsets(scene, kp, [0])
    assert set(offs[0]) == {f"{s}_{n}" for s in ("left", "right") for n in ("ankle", "heel", "big_toe", "small_toe")}
    for n in TOES:
        assert offs[0][n][2] == pytest.approx(0.012, abs=0.003)
    for n in ("left_heel", "right_heel", "left_ankle", "right_ankle"):
        assert np.linalg.norm(offs[0][n]) < 0.004
    moved = move_sites(skel, offs[0])
    again = planted_site_offsets(build_scene([moved], [0], kp.fps, COCO17_FEET, HumanoidConfig()), kp, [0])
    assert max(np.linalg.norm(v) for v in again[0].values()) < 0.002


def test_offsets_are_capped_and_need_planted_frames() -> None:
    kp = _rest_keypoints(1.0, n_frames=20)
    xyz = kp.xyz_m.copy()
    xyz[:, 0, COCO17_FEET.index("left_big_toe"), 2] += 0.08  # not a convention: a bad keypoint
    scene = build_scene([build_skeleton(dict(_DEFAULT_LENGTHS))], [0], kp.fps, COCO17_FEET, HumanoidConfig())
    offs = planted_site_offsets(scene, kp.replace(xyz_m=xyz), [0], max_offset_m=0.03)
    assert np.linalg.norm(offs[0]["left_big_toe"]) == pytest.approx(0.03, abs=1e-9)
    short = _rest_keypoints(1.0, n_frames=4)  # planted for fewer frames than min_frames
    assert planted_site_offsets(scene, short, [0], min_frames=5) == [{}]


def test_move_sites_names_unknown_sites() -> None:
    skel = build_skeleton(dict(_DEFAULT_LENGTHS))
    with pytest.raises(ValueError, match="no sites"):
        move_sites(skel, {"left_hoof": np.zeros(3)})
    assert move_sites(skel, {}) is skel
