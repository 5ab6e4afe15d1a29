"""DeepMimic scenes: retargeted clips keep the athlete's bone lengths, feet in contact on
the floor, loops without jumps, athletes apart, and 2D tracks that reproject the 3D
within the pixel noise, through the synthetic bout's own cameras.

Needs pybullet (the dev extra: the DeepMimic clips); skipped without it."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from pipeline.evaluate.physics_metrics import inter_person_penetration_mm
from pipeline.geometry.projection import project
from pipeline.synthetic.bout import make_bout
from pipeline.synthetic.config import SyntheticConfig
from pipeline.synthetic.deepmimic import (
    clip_keypoints_dm,
    floor_and_contact,
    loop_clip,
    neck_length_m,
    retarget_to_body,
    root_frame,
)
from pipeline.synthetic.mocap_scene import MocapScene, make_scene, parse_scene
from pipeline.synthetic.skeleton import SOLE_HEIGHT_M, J, make_body

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("pybullet_data") is None, reason="pybullet (DeepMimic clips) not installed"
)

FPS = 50.0
N = 40


def _dist(x: np.ndarray, a: str, b: str) -> np.ndarray:
    return np.linalg.norm(x[:, J[a]] - x[:, J[b]], axis=-1)


@pytest.fixture(scope="module")
def scene() -> MocapScene:
    s = make_scene("deepmimic:punch+walk", SyntheticConfig(seed=0, n_frames=N))
    assert isinstance(s, MocapScene)
    return s


@pytest.mark.parametrize("clip", ["walk", "punch", "spin", "backflip"])
def test_retargeted_bones_have_the_body_lengths_and_the_clip_directions(clip: str) -> None:
    body = make_body(1.85, 1.03, np.random.default_rng(1))
    kp, dt, loops = clip_keypoints_dm(clip)
    dm = loop_clip(kp, dt, loops, N, FPS)
    x = retarget_to_body(dm, body)
    mid = lambda a, b: 0.5 * (x[:, J[a]] + x[:, J[b]])  # noqa: E731
    expect = {
        ("left_hip", "left_knee"): body.thigh_m,
        ("right_knee", "right_ankle"): body.shank_m,
        ("left_shoulder", "left_elbow"): body.upper_arm_m,
        ("right_elbow", "right_wrist"): body.forearm_m,
        ("left_hip", "right_hip"): 2 * body.hip_half_m,
        ("left_shoulder", "right_shoulder"): 2 * body.shoulder_half_m,
        ("left_ankle", "left_heel"): float(np.hypot(body.heel_back_m, body.ankle_height_m - SOLE_HEIGHT_M)),
    }
    for (a, b), length in expect.items():
        np.testing.assert_allclose(_dist(x, a, b), length, atol=0.002, err_msg=f"{clip}: {a}-{b}")
    torso = np.linalg.norm(mid("left_shoulder", "right_shoulder") - mid("left_hip", "right_hip"), axis=-1)
    np.testing.assert_allclose(torso, body.torso_m, atol=0.002)
    head = np.linalg.norm(mid("left_ear", "right_ear") - mid("left_shoulder", "right_shoulder"), axis=-1)
    np.testing.assert_allclose(head, neck_length_m(body), atol=0.01)  # ear midpoint ~ head centre
    # The motion is the clip's: every limb points where the DeepMimic limb points.
    for a, b in (("left_hip", "left_knee"), ("right_elbow", "right_wrist"), ("left_knee", "left_ankle")):
        u = x[:, J[b]] - x[:, J[a]]
        v = dm[:, J[b]] - dm[:, J[a]]
        cos = np.sum(u * v, -1) / np.linalg.norm(u, axis=-1) / np.linalg.norm(v, axis=-1)
        assert cos.min() > 0.9999, (clip, a, b)


@pytest.mark.parametrize("clip", ["walk", "punch", "kick", "jump"])
def test_feet_in_contact_are_on_the_floor(clip: str) -> None:
    body = make_body(1.70, 0.98, np.random.default_rng(0))
    kp, dt, loops = clip_keypoints_dm(clip)
    x, contact = floor_and_contact(retarget_to_body(loop_clip(kp, dt, loops, 3 * N, FPS), body), FPS)
    assert contact.shape == (3 * N, 2) and contact.any(), clip
    for k, side in enumerate(("left", "right")):
        low = x[:, [J[f"{side}_heel"], J[f"{side}_big_toe"], J[f"{side}_small_toe"]], 2].min(axis=1)[
            contact[:, k]
        ]
        if low.size:
            assert np.all(np.abs(low - SOLE_HEIGHT_M) < 0.03), (clip, side, low.min(), low.max())
    lows = [
        x[contact[:, k]][:, [J[f"{side}_{p}"] for p in ("heel", "big_toe", "small_toe")], 2].min(axis=1)
        for k, side in enumerate(("left", "right"))
    ]
    assert abs(float(np.median(np.concatenate(lows))) - SOLE_HEIGHT_M) < 0.005, clip


@pytest.mark.parametrize("clip", ["walk", "punch"])
def test_looping_continues_without_jumps(clip: str) -> None:
    kp, dt, loops = clip_keypoints_dm(clip)
    clip_s = (kp.shape[0] - 1) * dt
    n = int(2.5 * clip_s * FPS)  # over two cycle boundaries
    x = loop_clip(kp, dt, loops, n, FPS)
    step = np.linalg.norm(np.diff(x, axis=0), axis=-1).max()
    assert step < 12.0 / FPS, (clip, step)  # no joint faster than 12 m/s: no pop at a cycle start
    pelvis, _ = root_frame(x)
    one = np.linalg.norm(root_frame(kp[-1])[0] - root_frame(kp[0])[0])
    assert np.linalg.norm(pelvis[-1] - pelvis[0]) > 1.5 * one  # the cycles add up, they do not restart


def test_the_planted_foot_keeps_its_place_across_a_cycle_boundary() -> None:
    """The walk's next cycle is placed on the foot that stands at the boundary: aligning the
    pelvis and heading instead left that foot 6-15 cm off, a 4-5 m/s jump in one frame."""
    kp, dt, loops = clip_keypoints_dm("walk")
    assert loops
    clip_s = (kp.shape[0] - 1) * dt
    n = int(3.5 * clip_s * FPS)
    x = loop_clip(kp, dt, loops, n, FPS)
    speed, height = [], []
    for side in ("left", "right"):
        sole = x[:, [J[f"{side}_{p}"] for p in ("heel", "big_toe", "small_toe")]]
        speed.append(np.linalg.norm(np.diff(sole.mean(axis=1)[:, :2], axis=0), axis=-1) * FPS)
        height.append(sole[1:, :, 2].min(axis=1))
    lower = np.where(height[0] <= height[1], speed[0], speed[1])  # the standing foot's speed
    bounds = [int(round(k * clip_s * FPS)) for k in (1, 2, 3)]
    at_bounds = max(float(lower[b - 3 : b + 3].max()) for b in bounds)
    assert np.median(lower) < 0.05  # a walk: one foot stands still most of the time
    assert at_bounds < 1.0, at_bounds  # measured 0.64 m/s; 4.2-4.6 with the pelvis alignment


def test_scene_uses_the_bouts_cameras_and_bodies(scene: MocapScene) -> None:
    bout = make_bout(SyntheticConfig(seed=0, n_frames=N))
    np.testing.assert_array_equal(scene.rig.K, bout.rig.K)
    np.testing.assert_array_equal(scene.rig.T_world_cam, bout.rig.T_world_cam)
    assert scene.limb_lengths_m == bout.limb_lengths_m
    x = scene.gt.xyz_m
    for p in range(2):
        lengths = scene.limb_lengths_m[p]
        np.testing.assert_allclose(
            np.linalg.norm(x[:, p, J["left_knee"]] - x[:, p, J["left_hip"]], axis=-1),
            lengths["thigh_m"],
            atol=0.002,
        )


def test_athletes_start_facing_each_other_and_never_overlap(scene: MocapScene) -> None:
    assert inter_person_penetration_mm(scene.gt).max() == 0.0
    pelvis, yaw = root_frame(scene.gt.xyz_m[0])
    gap = pelvis[1] - pelvis[0]
    assert 1.5 <= np.linalg.norm(gap) <= 1.75 + abs(scene.offset_m) + 1e-6
    assert abs(np.angle(np.exp(1j * yaw[0]))) < 1e-6 and abs(np.angle(-np.exp(1j * yaw[1]))) < 1e-6
    assert gap[0] > 0  # athlete 1 in front of athlete 0
    ground = scene.gt.xyz_m[..., 2].min()
    assert ground > -0.03


def test_tracks_reproject_the_ground_truth_within_the_noise(scene: MocapScene) -> None:
    cfg = SyntheticConfig()
    t = scene.tracks
    rows = np.flatnonzero(scene.gt_person_of_det >= 0)
    uv, _ = project(scene.rig, scene.gt.xyz_m)  # (V, F, P, J, 2)
    truth = uv[t.view[rows], t.frame[rows], scene.gt_person_of_det[rows]]
    np.testing.assert_allclose(scene.clean_keypoints_px[rows], truth, atol=1e-6)
    ok = t.keypoint_valid[rows] & ~scene.occluded[rows]
    err = np.linalg.norm(t.keypoints_px[rows] - truth, axis=-1)[ok]
    assert err.size > 1000
    # Rayleigh distribution of a 2D Gaussian of sigma noise_px per axis: median 1.18 sigma.
    assert 1.0 * cfg.noise_px < np.median(err) < 1.4 * cfg.noise_px
    assert np.percentile(err, 99.9) < 5.0 * cfg.noise_px


def test_bad_scenes_are_refused() -> None:
    assert parse_scene("synthetic") is None
    assert parse_scene("deepmimic:kick+spin") == ("kick", "spin")
    for bad in ("deepmimic:punch", "deepmimic:punch+moonwalk", "mocap:punch+walk"):
        with pytest.raises(ValueError, match="expected 'synthetic' or 'deepmimic:<clip>\\+<clip>'"):
            parse_scene(bad)
    with pytest.raises(ValueError, match="use fewer frames"):
        make_scene("deepmimic:run+run", SyntheticConfig(n_frames=400))
