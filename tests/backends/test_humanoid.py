"""MJCF humanoid generator: compiles, masses from geometry, layout, stability."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from pipeline.backends.mujoco.config import HumanoidConfig  # noqa: E402
from pipeline.backends.mujoco.humanoid import (  # noqa: E402
    DENSITY_KG_M3,
    build_scene_mjcf,
    load_model,
    scene_layout,
)
from pipeline.backends.mujoco.skeleton import (  # noqa: E402
    _DEFAULT_LENGTHS,
    build_skeleton,
    measure_lengths,
    rest_site_positions,
    skeleton_from_keypoints,
)
from pipeline.schema.joints import COCO17_FEET  # noqa: E402
from pipeline.schema.keypoints3d import Keypoints3D  # noqa: E402
from tests.backends.humanoid_checks import assert_random_servo_targets_stay_stable  # noqa: E402


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


def test_floor_contact_parameters_govern_floor_contacts() -> None:
    """The floor has priority: its solref/solimp/margin (HumanoidConfig) are the ones
    MuJoCo uses for every floor contact, whatever the body geom's own settings."""
    skel = build_skeleton(dict(_DEFAULT_LENGTHS))
    cfg = HumanoidConfig(floor_solref=(0.03, 1.2), floor_solimp=(0.8, 0.9, 0.002), floor_margin_m=0.004)
    model = load_model(build_scene_mjcf([skel], [0], 50.0, cfg))
    lay = scene_layout(model, [0])
    data = mujoco.MjData(model)
    data.qpos[lay.persons[0].qpos_adr + 2] -= 0.2  # sink the person into the floor
    mujoco.mj_forward(model, data)
    floor = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    on_floor = [c for c in range(data.ncon) if floor in data.contact.geom[c]]
    assert on_floor, "a sunk person must touch the floor"
    for c in on_floor:
        con = data.contact[c]
        np.testing.assert_allclose(con.solref, (0.03, 1.2))
        np.testing.assert_allclose(con.solimp[:3], (0.8, 0.9, 0.002))
        assert con.includemargin == pytest.approx(0.004)
    # The defaults are the physics stage's floor.
    from pipeline.stages.physics import PhysicsConfig

    default = load_model(build_scene_mjcf([skel], [0], 50.0))
    np.testing.assert_allclose(default.geom_solref[floor], PhysicsConfig().humanoid.floor_solref)
    assert default.geom_margin[floor] == pytest.approx(PhysicsConfig().humanoid.floor_margin_m)


def test_random_servo_targets_stay_stable() -> None:
    """The actuation choice: PD servos at the video rate survive random targets
    (two overlapping people, ground contact) without MuJoCo instabilities."""
    skel = build_skeleton(dict(_DEFAULT_LENGTHS))
    model = load_model(build_scene_mjcf([skel, skel], [0, 1], 50.0))
    lay = scene_layout(model, [0, 1])
    assert_random_servo_targets_stay_stable(model, lay, rounds=4)


def test_sole_height_is_median_lowest_foot_point() -> None:
    from pipeline.backends.mujoco.skeleton import sole_height_m

    kp = _rest_keypoints(1.0, n_frames=9)
    xyz = kp.xyz_m.copy()
    xyz[..., 2] += 0.02  # feet keypoints 2 cm above the floor
    xyz[2, 0, :, 2] -= 0.03  # one bad frame dips below the floor
    assert sole_height_m(kp.replace(xyz_m=xyz), 0) == pytest.approx(0.02, abs=2e-3)
    assert measure_lengths(kp.replace(xyz_m=xyz), 0)["sole_offset"] == pytest.approx(0.02, abs=2e-3)


def test_contact_inverse_dynamics_feet_carry_the_weight() -> None:
    """Standing still: the feet take the body weight, the residual root wrench is
    ~0; with no foot low enough to touch the floor the root needs ~1 body weight."""
    from pipeline.backends.mujoco.reference import contact_inverse_dynamics

    skel = build_skeleton(dict(_DEFAULT_LENGTHS))
    model = load_model(build_scene_mjcf([skel], [0], 50.0))
    lay = scene_layout(model, [0])
    p = lay.persons[0]
    q = np.tile(model.qpos0, (4, 1))
    q[:, p.qpos_adr : p.qpos_adr + 3] = [0.0, 0.0, skel.pelvis_height_m]
    v = np.zeros((4, model.nv))
    bw = p.mass_kg * 9.81
    tau, res = contact_inverse_dynamics(model, lay, q, v, 50.0)
    assert np.abs(res[:, 0, :3]).max() < 0.02 * bw
    assert np.abs(res[:, 0, 3:]).max() < 0.02 * bw * 0.3
    knee = model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "p0_left_knee")]
    _, res_air = contact_inverse_dynamics(model, lay, q, v, 50.0, contact_height_m=-1.0)
    assert res_air[:, 0, 2] == pytest.approx(bw, rel=1e-3)
    assert np.all(np.isfinite(tau[:, knee]))


def test_plant_feet_holds_planted_foot_still() -> None:
    from pipeline.backends.mujoco.reference import plant_feet

    names = ("left_heel", "left_big_toe", "left_small_toe", "right_heel", "right_big_toe", "right_small_toe")
    F = 30
    rng = np.random.default_rng(2)
    base = np.array([[-0.05, 0.1, 0.02], [0.15, 0.1, 0.02], [0.12, 0.15, 0.02]])
    xyz = np.zeros((F, 1, 6, 3))
    xyz[:, 0, :3] = base + rng.normal(scale=0.004, size=(F, 3, 3))  # planted, noisy
    t = np.arange(F) / 50.0
    xyz[:, 0, 3:] = base + [0.0, -0.3, 0.0]
    xyz[:, 0, 3:, 0] += 1.0 * t[:, None]  # right foot slides forward at 1 m/s
    xyz[:, 0, 3:, 2] += 0.05  # and is lifted
    out, contact = plant_feet(xyz, np.ones((F, 1, 6)), names, 50.0, np.array([0.02]))
    assert contact[:, 0, 0].all() and not contact[:, 0, 1].any()
    assert np.abs(np.diff(out[:, 0, :3], axis=0)).max() < 1e-9
    assert np.all(out[..., 2] >= 0.02 - 1e-9)
    assert np.allclose(out[:, 0, 3:], xyz[:, 0, 3:])


def test_plant_feet_catches_the_landing_frame() -> None:
    """A foot that swings in low and lands at frame 10 (still from there on): the
    5-frame smoothed speed finds the plant two frames late; the one-frame extension
    starts it a frame earlier, not before the touchdown, held at the stance position."""
    from pipeline.backends.mujoco.reference import plant_feet

    names = ("left_heel", "left_big_toe", "left_small_toe")
    F, land, fps = 30, 10, 60.0
    base = np.array([[-0.05, 0.1, 0.02], [0.15, 0.1, 0.02], [0.12, 0.15, 0.02]])
    step = np.zeros(F)  # forward position of the foot (m): decelerating swing, then still
    step[:land] = -0.01 * (land - np.arange(land)) ** 1.5
    xyz = np.repeat(base[None, None], F, axis=0).copy()
    xyz[:, 0, :, 0] += step[:, None]
    xyz[:land, 0, :, 2] += 0.003 * (land - np.arange(land))[:, None]  # coming down to the floor
    w = np.ones((F, 1, 3))
    _, late = plant_feet(xyz, w, names, fps, np.array([0.02]), extend_frames=0)
    out, contact = plant_feet(xyz, w, names, fps, np.array([0.02]))
    first_late, first = int(np.argmax(late[:, 0, 0])), int(np.argmax(contact[:, 0, 0]))
    assert first_late > land  # the smoothed speed alone misses the touchdown
    assert first == first_late - 1 and first >= land and contact[first:, 0, 0].all()
    assert np.abs(np.diff(out[first:, 0], axis=0)).max() < 1e-9  # held from the touchdown
    assert np.allclose(out[first:, 0], base)


def test_separate_reference_removes_overlap_keeping_feet() -> None:
    """Two athletes 0.16 m apart (bodies overlap by centimetres): every frame of the
    separated reference is contact-free, and legs/root height barely move."""
    from pipeline.backends.mujoco.reference import build_scene, separate_reference
    from pipeline.backends.mujoco.tracking import collision_depths

    skel = build_skeleton(dict(_DEFAULT_LENGTHS))
    scene = build_scene([skel, skel], [0, 1], 50.0, COCO17_FEET, HumanoidConfig())
    m, lay = scene.model, scene.layout
    q = m.qpos0.copy()
    for p, x, y, quat in ((lay.persons[0], 0.0, 0.0, [1, 0, 0, 0]), (lay.persons[1], 0.16, 0.1, [0, 0, 0, 1])):
        q[p.qpos_adr : p.qpos_adr + 3] = [x, y, skel.pelvis_height_m]
        q[p.qpos_adr + 3 : p.qpos_adr + 7] = quat
    qref = np.tile(q, (3, 1))
    data = mujoco.MjData(m)

    def depth(qp: np.ndarray) -> float:
        data.qpos[:] = qp
        mujoco.mj_fwdPosition(m, data)
        d, _ = collision_depths(m, data, lay.geom_person, False)
        return float(d.max(initial=0.0))

    assert depth(qref[0]) > 0.02
    out = separate_reference(scene, qref)
    assert max(depth(qf) for qf in out) < 0.005
    legs = [m.jnt_qposadr[j] for j in range(m.njnt) if any(k in m.joint(j).name for k in ("_knee", "_ankle_", "_hip_"))]
    roots_z = [p.qpos_adr + 2 for p in lay.persons]
    assert np.abs(out[:, legs] - qref[:, legs]).max() < 0.05
    assert np.abs(out[:, roots_z] - qref[:, roots_z]).max() < 0.01
