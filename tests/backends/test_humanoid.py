"""MJCF humanoid generator: compiles, masses from geometry, layout, stability."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from pipeline.backends.humanoid_skeleton import (  # noqa: E402
    _DEFAULT_LENGTHS,
    build_skeleton,
    rest_site_positions,
    skeleton_from_keypoints,
)
from pipeline.backends.mujoco_humanoid import (  # noqa: E402
    DENSITY_KG_M3,
    HumanoidConfig,
    build_scene_mjcf,
    load_model,
    scene_layout,
)
from pipeline.schema.joints import COCO17_FEET  # noqa: E402
from pipeline.schema.keypoints3d import Keypoints3D  # noqa: E402


def _rest_keypoints(scale: float, n_frames: int = 5) -> Keypoints3D:
    """One person in the rest pose of a skeleton with lengths × scale (+ small noise)."""
    lengths = {k: v * scale for k, v in _DEFAULT_LENGTHS.items()}
    sk = build_skeleton(lengths)
    rs = rest_site_positions(sk)
    base = np.array([rs[n] for n in COCO17_FEET])
    base[:, 2] += sk.pelvis_height_m
    rng = np.random.default_rng(0)
    xyz = base[None, None] + rng.normal(scale=1e-3, size=(n_frames, 1, len(COCO17_FEET), 3))
    F, J = n_frames, len(COCO17_FEET)
    return Keypoints3D(
        joint_names=COCO17_FEET,
        person_ids=np.array([0]),
        frame_indices=np.arange(F),
        fps=50.0,
        xyz_m=xyz,
        valid=np.ones((F, 1, J), bool),
        confidence=np.ones((F, 1, J)),
        n_views=np.zeros((F, 1, J), np.int64),
        reproj_err_px=np.full((F, 1, J), np.nan),
        source="fit",
    )


def test_mjcf_loads_and_mass_matches_volume() -> None:
    small = skeleton_from_keypoints(_rest_keypoints(0.9), 0)
    big = skeleton_from_keypoints(_rest_keypoints(1.1), 0)
    xml = build_scene_mjcf([small, big], [3, 7], 50.0)
    model = load_model(xml)
    layout = scene_layout(model, [3, 7])
    assert model.opt.timestep == pytest.approx(1 / 50.0 / HumanoidConfig().substeps)
    for skel, person in zip((small, big), layout.persons, strict=True):
        expected = skel.geom_volume_m3() * DENSITY_KG_M3
        assert person.mass_kg == pytest.approx(expected, rel=0.10)
        assert 40.0 < person.mass_kg < 140.0
        # 26 hinges, a 6-DOF root, one servo per hinge, 23 keypoint sites.
        assert person.nq == 7 + 26 and person.nv == 6 + 26
        assert person.servo_ids.size == 26
        assert set(person.site_ids) == set(COCO17_FEET)
    assert layout.persons[1].mass_kg > layout.persons[0].mass_kg * 1.5  # ~(1.1/0.9)^3


def test_skeleton_reproduces_measured_bone_lengths() -> None:
    kp = _rest_keypoints(1.05)
    skel = skeleton_from_keypoints(kp, 0)
    rs = rest_site_positions(skel)
    for a, b in (("left_hip", "left_knee"), ("left_knee", "left_ankle"), ("left_shoulder", "left_elbow"), ("left_elbow", "left_wrist")):
        ia, ib = COCO17_FEET.index(a), COCO17_FEET.index(b)
        measured = np.median(np.linalg.norm(kp.xyz_m[:, 0, ia] - kp.xyz_m[:, 0, ib], axis=-1))
        assert np.linalg.norm(rs[a] - rs[b]) == pytest.approx(measured, abs=2e-3)


def test_bad_inputs_raise() -> None:
    skel = build_skeleton(dict(_DEFAULT_LENGTHS))
    with pytest.raises(ValueError, match="fps"):
        build_scene_mjcf([skel], [0], 0.0)
    with pytest.raises(ValueError, match="one skeleton per person"):
        build_scene_mjcf([skel], [0, 1], 50.0)
    with pytest.raises(ValueError, match="no person 5"):
        scene_layout(load_model(build_scene_mjcf([skel], [0], 50.0)), [5])


def test_self_collision_filtering() -> None:
    skel = build_skeleton(dict(_DEFAULT_LENGTHS))
    filtered = build_scene_mjcf([skel], [0], 50.0, HumanoidConfig(self_collision="adjacent_filtered"))
    assert '<exclude body1="p0_left_thigh" body2="p0_right_thigh"/>' in filtered
    none = load_model(build_scene_mjcf([skel, skel], [0, 1], 50.0, HumanoidConfig(self_collision="none")))
    lay = scene_layout(none, [0, 1])
    data = mujoco.MjData(none)
    # Put person 1 onto person 0: only cross-person and floor contacts may appear.
    data.qpos[lay.persons[1].qpos_adr : lay.persons[1].qpos_adr + 3] = data.qpos[lay.persons[0].qpos_adr : lay.persons[0].qpos_adr + 3]
    mujoco.mj_forward(none, data)
    g = data.contact.geom[: data.ncon]
    pa, pb = lay.geom_person[g[:, 0]], lay.geom_person[g[:, 1]]
    assert data.ncon > 0
    assert not np.any((pa == pb) & (pa >= 0))


def test_random_servo_targets_stay_stable() -> None:
    """The actuation choice: PD servos at the video rate survive random targets
    (two overlapping people, ground contact) without MuJoCo instabilities."""
    skel = build_skeleton(dict(_DEFAULT_LENGTHS))
    model = load_model(build_scene_mjcf([skel, skel], [0, 1], 50.0))
    lay = scene_layout(model, [0, 1])
    data = mujoco.MjData(model)
    rng = np.random.default_rng(1)
    lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    for _ in range(4):
        mujoco.mj_resetData(model, data)
        p1 = lay.persons[1]
        data.qpos[p1.qpos_adr] = rng.uniform(0.3, 0.6)
        data.qpos[p1.qpos_adr + 1] = 0.0
        data.qpos[p1.qpos_adr + 3 : p1.qpos_adr + 7] = [0.0, 0.0, 0.0, 1.0]
        for _ in range(60):
            data.ctrl[:] = rng.uniform(lo, hi)
            mujoco.mj_step(model, data)
        assert np.all(np.isfinite(data.qpos))
        assert np.abs(data.qvel).max() < 100.0
        assert data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number == 0
