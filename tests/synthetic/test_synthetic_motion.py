"""Ground-truth motion of the synthetic bout: rigid bones, planted feet, punches, clinch."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.schema.joints import BONES, COCO17_FEET
from pipeline.synthetic import SOLE_HEIGHT_M, SyntheticBout, SyntheticConfig, make_bout
from pipeline.synthetic.skeleton import J
from pipeline.synthetic.stats import CLINCH_TORSO_DISTANCE_M

FEET_POINTS = {
    0: ("left_ankle", "left_heel", "left_big_toe", "left_small_toe"),
    1: ("right_ankle", "right_heel", "right_big_toe", "right_small_toe"),
}


def _torso_centres(xyz: np.ndarray) -> np.ndarray:
    idx = [J["left_shoulder"], J["right_shoulder"], J["left_hip"], J["right_hip"]]
    return xyz[:, :, idx].mean(axis=2)  # (F, P, 3)


def test_determinism_same_seed_same_arrays() -> None:
    cfg = SyntheticConfig(seed=5, n_frames=80, n_cameras=3)
    a, b = make_bout(cfg), make_bout(cfg)
    for field in (
        "view",
        "frame",
        "track_id",
        "keypoints_px",
        "keypoint_conf",
        "keypoint_valid",
        "bbox_xyxy_px",
    ):
        assert getattr(a.tracks, field).tobytes() == getattr(b.tracks, field).tobytes(), field
    assert a.gt.xyz_m.tobytes() == b.gt.xyz_m.tobytes()
    assert a.rig.T_world_cam.tobytes() == b.rig.T_world_cam.tobytes()
    assert a.foot_contact.tobytes() == b.foot_contact.tobytes()
    assert a.gt_person_of_det.tobytes() == b.gt_person_of_det.tobytes()
    assert a.swap_frames.tobytes() == b.swap_frames.tobytes()
    c = make_bout(SyntheticConfig(seed=6, n_frames=80, n_cameras=3))
    assert not np.array_equal(a.gt.xyz_m, c.gt.xyz_m)


def test_gt_schema(default_bout: SyntheticBout) -> None:
    gt = default_bout.gt
    assert gt.source == "gt"
    assert gt.joint_names == COCO17_FEET and len(gt.joint_names) == 23
    assert gt.person_ids.tolist() == [0, 1]
    assert gt.xyz_m.shape == (300, 2, 23, 3)
    assert gt.valid.all() and np.isfinite(gt.xyz_m).all()
    assert default_bout.tracks.joint_names == COCO17_FEET
    assert default_bout.foot_contact.shape == (300, 2, 2) and default_bout.foot_contact.dtype == bool


def test_bone_lengths_constant(default_bout: SyntheticBout) -> None:
    people = [default_bout.gt.xyz_m[:, 0], default_bout.gt.xyz_m[:, 1], default_bout.bystander_xyz_m]
    for xyz in people:
        for a, b in BONES:
            length = np.linalg.norm(xyz[:, J[a]] - xyz[:, J[b]], axis=1)
            assert length.std() < 1e-6, (a, b, length.std())
            assert length.min() > 0.01


def test_planted_feet_do_not_slide_and_stay_on_ground(default_bout: SyntheticBout) -> None:
    xyz, contact = default_bout.gt.xyz_m, default_bout.foot_contact
    limbs = default_bout.limb_lengths_m
    for p in range(2):
        for k in range(2):
            c = contact[:, p, k]
            assert 0.3 < c.mean() < 0.98, "a foot should be planted most of the time but also step"
            n_steps = int(np.sum(c[:-1] & ~c[1:]))
            assert n_steps >= 3, f"person {p} foot {k}: only {n_steps} steps"
            both = c[:-1] & c[1:]
            for name in FEET_POINTS[k]:
                pos = xyz[:, p, J[name]]
                step_xy = np.linalg.norm(np.diff(pos[:, :2], axis=0), axis=1)
                assert step_xy[both].max() < 1e-6, (p, name, step_xy[both].max())
                z = pos[c, 2]
                want = limbs[p]["ankle_height_m"] if name.endswith("ankle") else SOLE_HEIGHT_M
                assert np.abs(z - want).max() < 1e-9, (p, name)
            # Swinging feet lift off the ground.
            assert xyz[~c, p, J[FEET_POINTS[k][1]], 2].max() > SOLE_HEIGHT_M + 0.02


def test_fist_peak_speeds_in_boxing_range(default_bout: SyntheticBout) -> None:
    ch = default_bout.choreography
    kinds = {p.kind for p in ch.punches}
    assert {"jab", "cross", "lead_hook"} <= kinds
    xyz, fps = default_bout.gt.xyz_m, default_bout.gt.fps
    t = np.arange(xyz.shape[0]) / fps
    for p in ch.punches:
        wrist = xyz[:, p.person, J[f"{p.hand}_wrist"]]
        speed = np.linalg.norm(np.diff(wrist, axis=0), axis=1) * fps
        sel = (t[:-1] >= p.t0_s - 0.02) & (t[:-1] <= p.end_s)
        assert 6.0 <= speed[sel].max() <= 10.0, (p.kind, p.t0_s, speed[sel].max())
    np.testing.assert_allclose(default_bout.punch_peak_speed_mps.size, len(ch.punches))


def test_motion_is_continuous(default_bout: SyntheticBout) -> None:
    # No teleports: every joint's speed stays human (hands are the fastest at <= 10 m/s).
    v = np.linalg.norm(np.diff(default_bout.gt.xyz_m, axis=0), axis=-1) * default_bout.gt.fps
    assert v.max() < 15.0
    # C1: velocity changes per frame stay bounded (a velocity jump would show up as a spike).
    a = np.linalg.norm(np.diff(default_bout.gt.xyz_m, n=2, axis=0), axis=-1) * default_bout.gt.fps**2
    assert a.max() < 800.0


def test_boxers_differ_in_limb_lengths(default_bout: SyntheticBout) -> None:
    a, b = default_bout.limb_lengths_m[0], default_bout.limb_lengths_m[1]
    assert a["height_m"] == pytest.approx(1.70) and b["height_m"] == pytest.approx(1.85)
    for seg in ("thigh_m", "shank_m", "upper_arm_m", "forearm_m", "torso_m"):
        assert b[seg] > 1.03 * a[seg], seg
    xyz = default_bout.gt.xyz_m
    fore = np.linalg.norm(xyz[0, :, J["left_wrist"]] - xyz[0, :, J["left_elbow"]], axis=-1)
    np.testing.assert_allclose(fore, [a["forearm_m"], b["forearm_m"]], atol=1e-9)
    # Face and feet at sensible anatomical heights while standing.
    for p, body in ((0, a), (1, b)):
        nose_z = xyz[:, p, J["nose"], 2]
        assert 0.80 * body["height_m"] < np.median(nose_z) < 0.95 * body["height_m"]


def test_clinch_bodies_touch_and_arms_wrap(default_bout: SyntheticBout) -> None:
    xyz = default_bout.gt.xyz_m
    tc = _torso_centres(xyz)
    d = np.linalg.norm(tc[:, 0] - tc[:, 1], axis=1)
    clinch = np.flatnonzero(d < CLINCH_TORSO_DISTANCE_M)
    assert clinch.size >= 5, d.min()
    # In the clinch each boxer has a hand behind the other's back.
    for p in range(2):
        o = 1 - p
        across = xyz[clinch, o, J["left_shoulder"]] - xyz[clinch, o, J["right_shoulder"]]
        up = tc[clinch, o] - 0.5 * (xyz[clinch, o, J["left_hip"]] + xyz[clinch, o, J["right_hip"]])
        fwd = np.cross(across, up)
        fwd /= np.linalg.norm(fwd, axis=1, keepdims=True)
        behind = [
            np.einsum("fi,fi->f", xyz[clinch, p, J[w]] - tc[clinch, o], fwd)
            for w in ("left_wrist", "right_wrist")
        ]
        assert np.mean(np.minimum(*behind) < 0.0) > 0.8
    # Without clinches the bodies never touch.
    far = make_bout(SyntheticConfig(clinch=False, n_frames=160, bystander=False))
    tc2 = _torso_centres(far.gt.xyz_m)
    assert np.linalg.norm(tc2[:, 0] - tc2[:, 1], axis=1).min() > 0.6


def test_boxers_face_each_other_inside_the_ring(default_bout: SyntheticBout) -> None:
    xyz = default_bout.gt.xyz_m
    assert np.abs(xyz[..., :2]).max() < 2.5  # inside a 5 x 5 m ring centred at the origin
    nose_dir = xyz[:, :, J["nose"], :2] - 0.5 * (xyz[:, :, J["left_ear"], :2] + xyz[:, :, J["right_ear"], :2])
    to_other = xyz[:, ::-1, J["nose"], :2] - xyz[:, :, J["nose"], :2]
    cos = np.einsum("fpi,fpi->fp", nose_dir, to_other) / (
        np.linalg.norm(nose_dir, axis=-1) * np.linalg.norm(to_other, axis=-1)
    )
    far = np.linalg.norm(to_other, axis=-1) > 0.8
    assert np.median(cos[far]) > 0.9


def test_trajectories_are_c1() -> None:
    """Velocity is continuous: the largest per-frame velocity change halves when the frame
    rate doubles (a velocity jump would not shrink)."""
    from pipeline.synthetic.bout import BOXER_ARM_RATIOS, BOXER_HEIGHTS_M, _calibrated_boxers
    from pipeline.synthetic.choreo import make_choreography
    from pipeline.synthetic.skeleton import make_body

    dv_max = []
    for fps in (200.0, 400.0):
        rng = np.random.default_rng(0)
        bodies = [make_body(h, a, rng) for h, a in zip(BOXER_HEIGHTS_M, BOXER_ARM_RATIOS, strict=True)]
        ch = make_choreography(int(2.5 * fps), fps, True, np.random.default_rng(1))
        _, joints, _, _ = _calibrated_boxers(ch, bodies, fps)
        v = np.diff(joints, axis=0) * fps
        dv_max.append(np.linalg.norm(np.diff(v, axis=0), axis=-1).max())
    assert dv_max[1] < 0.65 * dv_max[0], dv_max


def test_two_bone_ik_exact_lengths_and_pole_side() -> None:
    from pipeline.synthetic.skeleton import two_bone_ik

    rng = np.random.default_rng(3)
    n = 500
    root = rng.normal(size=(n, 3))
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    a, b = 0.33, 0.26
    reach = rng.uniform(0.2, 1.2, n) * (a + b)  # includes unreachable targets
    target = root + reach[:, None] * direction
    pole = rng.normal(size=(n, 3))
    mid, end = two_bone_ik(root, target, pole, a, b)
    np.testing.assert_allclose(np.linalg.norm(mid - root, axis=1), a, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(end - mid, axis=1), b, atol=1e-12)
    ok = (reach < 0.92 * (a + b)) & (reach > abs(a - b) + 0.1 * (a + b))
    np.testing.assert_allclose(end[ok], target[ok], atol=1e-12)
    assert np.all(np.linalg.norm(end - root, axis=1) <= 0.985 * (a + b) + 1e-12)
    # The middle joint bends towards the pole.
    u = direction
    w = pole - np.sum(pole * u, axis=1, keepdims=True) * u
    assert np.all(np.sum((mid - root) * w, axis=1) > 0)
