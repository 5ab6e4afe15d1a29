"""Physics metrics on hand-built motions with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.evaluate.physics_metrics import (
    CapsuleProxy,
    foot_contact_from_height,
    inter_person_penetration_mm,
    physics_metrics,
    stance_edge_steps,
)
from pipeline.geometry.segments import point_weights, segment_distance
from pipeline.schema.joints import COCO17_FEET
from pipeline.schema.keypoints3d import Keypoints3D


def _standing(offset_x: float, n_frames: int = 6) -> np.ndarray:
    """(frames, 23, 3) joints of a simple upright person at x = offset_x, facing +x."""
    j = {
        "nose": (0.1, 0.0, 1.65), "left_eye": (0.08, 0.03, 1.68), "right_eye": (0.08, -0.03, 1.68),
        "left_ear": (0.0, 0.075, 1.66), "right_ear": (0.0, -0.075, 1.66),
        "left_shoulder": (0.0, 0.18, 1.45), "right_shoulder": (0.0, -0.18, 1.45),
        "left_elbow": (0.0, 0.2, 1.15), "right_elbow": (0.0, -0.2, 1.15),
        "left_wrist": (0.0, 0.2, 0.9), "right_wrist": (0.0, -0.2, 0.9),
        "left_hip": (0.0, 0.1, 0.95), "right_hip": (0.0, -0.1, 0.95),
        "left_knee": (0.0, 0.1, 0.52), "right_knee": (0.0, -0.1, 0.52),
        "left_ankle": (0.0, 0.1, 0.09), "right_ankle": (0.0, -0.1, 0.09),
        "left_big_toe": (0.17, 0.08, 0.0), "left_small_toe": (0.15, 0.13, 0.0), "left_heel": (-0.06, 0.1, 0.0),
        "right_big_toe": (0.17, -0.08, 0.0), "right_small_toe": (0.15, -0.13, 0.0), "right_heel": (-0.06, -0.1, 0.0),
    }
    xyz = np.array([j[n] for n in COCO17_FEET], dtype=float)
    xyz[:, 0] += offset_x
    return np.repeat(xyz[None], n_frames, axis=0)


def _kp(xyz: np.ndarray) -> Keypoints3D:
    F, P, J, _ = xyz.shape
    return Keypoints3D(
        joint_names=COCO17_FEET,
        person_ids=np.arange(P),
        frame_indices=np.arange(F),
        fps=50.0,
        xyz_m=xyz,
        valid=np.ones((F, P, J), bool),
        confidence=np.ones((F, P, J)),
        n_views=np.zeros((F, P, J), np.int64),
        reproj_err_px=np.full((F, P, J), np.nan),
        source="physics",
    )


def test_segment_distance_matches_brute_force() -> None:
    rng = np.random.default_rng(0)
    p0, p1, q0, q1 = rng.normal(size=(4, 200, 3))
    p1[::5] = p0[::5]  # degenerate segments (spheres)
    q1[1::7] = q0[1::7] + 0.5 * (p1[1::7] - p0[1::7])  # parallel segments
    d = segment_distance(p0, p1, q0, q1)
    s = np.linspace(0.0, 1.0, 301)
    P = p0[:, None] + (p1 - p0)[:, None] * s[None, :, None]
    Q = q0[:, None] + (q1 - q0)[:, None] * s[None, :, None]
    brute = np.linalg.norm(P[:, :, None] - Q[:, None, :], axis=-1).min(axis=(1, 2))
    assert np.all(d <= brute + 1e-9)
    assert np.all(brute - d < 5e-3)


def test_inter_person_penetration_known_overlap() -> None:
    far = _kp(np.stack([_standing(0.0), _standing(2.0)], axis=1))
    assert inter_person_penetration_mm(far).max() == 0.0
    # Two torsos (radius 0.13 each) 0.2 m apart overlap by 60 mm; facing persons'
    # other parts overlap less than the torsos here.
    close = _kp(np.stack([_standing(0.0), _standing(0.2)], axis=1))
    pen = inter_person_penetration_mm(close, CapsuleProxy(segments=(("mid:left_hip+right_hip", "mid:left_shoulder+right_shoulder", 0.13),)))
    assert pen == pytest.approx(np.full(6, 60.0), abs=1e-6)


def test_ground_penetration_skating_and_errors() -> None:
    xyz = np.stack([_standing(0.0, 10), _standing(2.0, 10)], axis=1)
    gt = _kp(xyz.copy())
    pred = xyz.copy()
    left = [COCO17_FEET.index(n) for n in ("left_heel", "left_big_toe", "left_small_toe")]
    pred[:, 0, left, 0] += 0.004 * np.arange(10)[:, None]  # planted foot sliding 4 mm/frame
    pred[:, 1, :, 2] -= 0.003  # person 1 sunk 3 mm into the floor
    contact = np.ones((10, 2, 2), dtype=bool)
    m = physics_metrics(_kp(pred), gt, contact)
    assert m["foot_skate_mm_per_frame"] == pytest.approx(4.0 / 4, abs=1e-9)  # 1 of 4 feet slides
    assert m["foot_speed_contact_mm_s"] == pytest.approx(50.0, abs=1e-6)
    assert m["ground_penetration_max_mm"] == pytest.approx(3.0, abs=1e-9)
    assert m["mpjpe_mm"] > 0.0
    assert m["foot_height_err_contact_mm"] == pytest.approx(1.5, abs=1e-9)
    same = physics_metrics(gt, gt, contact)
    assert same["mpjpe_mm"] == 0.0 and same["accel_err_mm_per_frame2"] == 0.0 and same["foot_skate_mm_per_frame"] == 0.0


def test_skating_is_split_into_stance_edges_and_interior() -> None:
    c = np.array([1, 1, 1, 0, 1, 1, 1, 0, 1, 1], dtype=bool)
    # Steps in stance: 0-1 (interior: the stance runs on before the clip), 1-2 (last),
    # 4-5 (first), 5-6 (last), 8-9 (first, of a stance that runs on after the clip).
    assert stance_edge_steps(c).tolist() == [False, True, False, False, True, True, False, False, True]
    # Per column; a stance of two frames is one step, both first and last; a foot planted
    # throughout has no edges.
    two = np.zeros(10, dtype=bool)
    two[1:3] = True
    cols = stance_edge_steps(np.stack([c, two, np.ones(10, dtype=bool)], axis=1))
    assert cols[:, 1].tolist() == [False, True] + [False] * 7 and not cols[:, 2].any()
    xyz = np.stack([_standing(0.0, 10), _standing(2.0, 10)], axis=1)
    pred = xyz.copy()
    left = [COCO17_FEET.index(n) for n in ("left_heel", "left_big_toe", "left_small_toe")]
    contact = np.broadcast_to(c[:, None, None], (10, 2, 2)).copy()
    pred[1:, 0, left, 0] += 0.003  # person 0's left foot creeps 3 mm in interior step 0-1
    m = physics_metrics(_kp(pred), _kp(xyz), contact)
    # 4 feet x 5 stance steps: 4 interior steps, 16 at a stance's edge.
    assert m["foot_skate_interior_mm_per_frame"] == pytest.approx(3.0 / 4, abs=1e-9)
    assert m["foot_skate_edge_mm_per_frame"] == 0.0
    assert m["foot_skate_mm_per_frame"] == pytest.approx(3.0 / 20, abs=1e-9)
    pred[5:, 0, left, 0] += 0.006  # and lands 6 mm off (first step 4-5 of the next stance)
    m = physics_metrics(_kp(pred), _kp(xyz), contact)
    assert m["foot_skate_edge_mm_per_frame"] == pytest.approx(6.0 / 16, abs=1e-9)
    assert m["foot_skate_interior_mm_per_frame"] == pytest.approx(3.0 / 4, abs=1e-9)
    assert m["foot_skate_mm_per_frame"] == pytest.approx(9.0 / 20, abs=1e-9)


def test_foot_contact_from_height_and_shape_check() -> None:
    xyz = np.stack([_standing(0.0, 4), _standing(2.0, 4)], axis=1)
    xyz[2:, 1, [COCO17_FEET.index(n) for n in ("right_heel", "right_big_toe", "right_small_toe")], 2] += 0.2
    kp = _kp(xyz)
    c = foot_contact_from_height(kp)
    assert c[:, 0].all() and c[:2, 1, 1].all() and not c[2:, 1, 1].any()
    with pytest.raises(ValueError, match="foot_contact shape"):
        physics_metrics(kp, foot_contact=np.ones((4, 2, 3), bool))


def test_proxy_points_joint_midpoint_and_fraction() -> None:
    names = ("a", "b", "c")
    assert point_weights("b", names) == ([1], [1.0])
    assert point_weights("mid:a+c", names) == ([0, 2], [0.5, 0.5])
    idx, w = point_weights("frac:a,b,1.25", names)  # a quarter past b
    assert idx == [0, 1] and w == pytest.approx([-0.25, 1.25])
    with pytest.raises(ValueError, match="frac:a,x,0.5"):
        point_weights("frac:a,x,0.5", names)
    with pytest.raises(ValueError, match="frac:a,b"):
        point_weights("frac:a,b", names)


def test_glove_sphere_sits_past_the_wrist() -> None:
    """Two persons whose wrists are 20 cm apart along the forearm line, gloves facing:
    the gloves (6.5 cm past the wrists) overlap; wrist spheres would not."""
    n = len(COCO17_FEET)
    xyz = np.zeros((1, 2, n, 3))
    xyz[..., 2] = 10.0  # everything else far away, stacked per person
    xyz[0, 1, :, 2] = 20.0
    ie, iw = COCO17_FEET.index("right_elbow"), COCO17_FEET.index("right_wrist")
    xyz[0, 0, ie] = [-0.36, 0.0, 1.0]
    xyz[0, 0, iw] = [-0.10, 0.0, 1.0]
    xyz[0, 1, ie] = [0.36, 0.0, 1.0]
    xyz[0, 1, iw] = [0.10, 0.0, 1.0]
    kp = _kp(xyz)
    proxy = CapsuleProxy(segments=(("frac:right_elbow,right_wrist,1.25", "frac:right_elbow,right_wrist,1.25", 0.065),))
    pen = inter_person_penetration_mm(kp, proxy)
    # glove centres at x = -0.035 and +0.035: 70 mm apart, radii 130 mm -> 60 mm overlap
    assert pen[0] == pytest.approx(60.0, abs=1e-6)
