"""The physics stage's reference between video frames (``backends.mujoco.schedule``), its flat
planted feet, the separation of two athletes, gloves and the arm-arm contact switch."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from pipeline.backends.mujoco.config import HumanoidConfig  # noqa: E402
from pipeline.backends.mujoco.reference import (  # noqa: E402
    build_reference,
    build_scene,
    inverse_kinematics,
    separate_reference,
    site_targets,
)
from pipeline.backends.mujoco.schedule import (  # noqa: E402
    contact_inverse_dynamics_point,
    foot_site_ids,
    servo_schedule,
    tangent_path,
)
from pipeline.backends.mujoco.skeleton import _DEFAULT_LENGTHS, build_skeleton  # noqa: E402
from pipeline.schema.joints import COCO17_FEET  # noqa: E402
from tests.backends.test_humanoid import _rest_keypoints  # noqa: E402
from tests.stages.test_physics import _facing_pair  # noqa: E402

FPS = 50.0


def _one_person_scene(cfg: HumanoidConfig = HumanoidConfig()):  # type: ignore[no-untyped-def]
    skel = build_skeleton(dict(_DEFAULT_LENGTHS))
    return build_scene([skel], [0], FPS, COCO17_FEET, cfg)


def _swinging_joints(model: mujoco.MjModel) -> list[int]:
    """qpos addresses of the shoulder flexion and elbow hinges."""
    return [
        int(model.jnt_qposadr[j])
        for j in range(model.njnt)
        if any(k in model.joint(j).name for k in ("shoulder_y", "elbow")) and model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE
    ]


def _swinging_arms(model: mujoco.MjModel, n_frames: int) -> np.ndarray:
    """qpos (frames, nq): the rest pose held at pelvis height, both shoulders and elbows
    swinging fast (a 2.5 Hz, 0.8 rad swing: a few metres per second at the wrist)."""
    q = np.tile(model.qpos0, (n_frames, 1))
    t = np.arange(n_frames) / FPS
    for a in _swinging_joints(model):
        j = int(np.flatnonzero(model.jnt_qposadr == a)[0])
        q[:, a] = model.jnt_range[j].mean() + 0.4 * np.sin(2 * np.pi * 2.5 * t)
    return q


def _track(scene, qref: np.ndarray, schedule, per_substep: bool) -> float:  # type: ignore[no-untyped-def]
    """Open-loop tracking of ``qref`` with the root held by the residual servos, contacts
    off: the mean angle error (rad) of the swinging hinges over the frames."""
    m = scene.model
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    m.opt.disableactuator = 0  # residual root servos on
    d = mujoco.MjData(m)
    d.qpos[:] = qref[0]
    d.qvel[:] = schedule.qvel[0, 0]
    S = schedule.substeps
    hinge = _swinging_joints(m)
    err = []
    for f in range(qref.shape[0] - 1):
        for k in range(S):
            d.ctrl[:] = schedule.ctrl[f, k if per_substep else 0]
            mujoco.mj_step(m, d)
        err.append(np.abs(d.qpos[hinge] - qref[f + 1, hinge]).mean())
    return float(np.mean(err))


def test_schedule_interpolates_the_reference_between_frames() -> None:
    scene = _one_person_scene()
    m = scene.model
    qref = _swinging_arms(m, 40)
    sch = servo_schedule(m, scene.layout, qref, FPS, 4, planted=None)
    # Substep 0 is the frame itself; the path through the frames is continuous.
    np.testing.assert_allclose(sch.qpos[:, 0], qref, atol=1e-9)
    path = tangent_path(m, sch.qpos.reshape(-1, m.nq))
    assert np.abs(np.diff(path, axis=0)).max() < 0.05
    assert sch.ctrl.shape == (40, 4, m.nu) and sch.root_torque.shape == (40, 4, 1, 3)


def test_servo_targets_between_frames_track_fast_limbs_better() -> None:
    """Targets that move at every substep (with their feed-forward) follow a fast swing;
    targets held for the whole video frame lag behind it."""
    scene = _one_person_scene()
    qref = _swinging_arms(scene.model, 40)
    sch = servo_schedule(scene.model, scene.layout, qref, FPS, HumanoidConfig().substeps, planted=None)
    moving = _track(_one_person_scene(), qref, sch, per_substep=True)
    held = _track(_one_person_scene(), qref, sch, per_substep=False)
    assert moving < 0.35 * held  # measured 0.0051 against 0.033 rad (8 substeps; 4: 0.0078)
    assert moving < 0.015


def test_ground_reactions_load_only_the_planted_feet() -> None:
    """A person standing still: with both feet loaded the feet carry the weight (no
    residual); with only the left foot loaded, the right leg's hinge torques are the
    same as with no foot loaded (it only holds its own weight), and the left foot then
    carries all of it."""
    scene = _one_person_scene()
    m, lay = scene.model, scene.layout
    d = mujoco.MjData(m)
    d.qpos[:] = m.qpos0
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    feet = foot_site_ids(lay)[0]
    tau_both, res_both = contact_inverse_dynamics_point(m, d, lay, [feet[0] + feet[1]])
    tau_left, _ = contact_inverse_dynamics_point(m, d, lay, [feet[0]])
    tau_none, res_none = contact_inverse_dynamics_point(m, d, lay, [[]])
    weight = lay.persons[0].mass_kg * 9.81
    assert np.linalg.norm(res_both[0, :3]) < 0.02 * weight
    assert res_none[0, 2] == pytest.approx(weight, rel=1e-3)
    right_leg = [m.jnt_dofadr[j] for j in range(m.njnt) if m.joint(j).name.startswith("p0_right_") and any(
        k in m.joint(j).name for k in ("hip", "knee", "ankle"))]
    assert right_leg
    np.testing.assert_allclose(tau_left[right_leg], tau_none[right_leg], atol=1e-6)
    assert np.abs(tau_both[right_leg] - tau_none[right_leg]).max() > 1.0  # loaded: it pushes


def test_planted_feet_stand_flat_on_the_floor() -> None:
    """A planted foot whose keypoints say it is tilted (heel 3 cm up) comes out of the
    inverse kinematics level, its sole at the requested height; without ``flat`` it
    follows the keypoints' tilt."""
    kp = _rest_keypoints(1.0, n_frames=3)
    xyz = kp.xyz_m.copy()
    xyz[:, 0, COCO17_FEET.index("left_heel"), 2] += 0.03
    kp = kp.replace(xyz_m=xyz)
    scene = build_scene([build_skeleton(dict(_DEFAULT_LENGTHS))], [0], FPS, COCO17_FEET, HumanoidConfig())
    targets, weight = site_targets(scene, kp, [0])
    flat = np.zeros((3, 1, 2), dtype=bool)
    flat[:, 0, 0] = True
    m = scene.model
    foot = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "p0_left_foot")
    d = mujoco.MjData(m)

    def tilt_deg(q: np.ndarray) -> float:
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        return float(np.degrees(np.arccos(np.clip(d.xmat[foot].reshape(3, 3)[2, 2], -1.0, 1.0))))

    level = inverse_kinematics(scene, targets, weight, flat=flat, sole_lift_m=0.005)
    tilted = inverse_kinematics(scene, targets, weight)
    assert tilt_deg(level[-1]) < 1.0
    assert tilt_deg(tilted[-1]) > 3.0
    d.qpos[:] = level[-1]
    mujoco.mj_fwdPosition(m, d)
    floor = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    gap = min(mujoco.mj_geomDistance(m, d, g, floor, 1.0, None) for g in range(m.ngeom) if m.geom_bodyid[g] == foot)
    assert gap == pytest.approx(0.005, abs=1.5e-3)


def test_separation_leaves_no_overlap_and_stays_smooth() -> None:
    """Two athletes whose torsos overlap by ~5 cm: the separated reference keeps them
    ~clearance apart in every frame, and moves each frame by about the same amount."""
    kp = _facing_pair(0.18, n_frames=12)
    skel = build_skeleton(dict(_DEFAULT_LENGTHS))
    scene = build_scene([skel, skel], [0, 1], FPS, COCO17_FEET, HumanoidConfig())
    targets, weight = site_targets(scene, kp, [0, 1])
    qref = inverse_kinematics(scene, targets, weight)
    out = separate_reference(scene, qref, clearance_m=0.01)
    m = scene.probe_model()
    d = mujoco.MjData(m)
    for f in range(out.shape[0]):
        d.qpos[:] = out[f]
        mujoco.mj_fwdPosition(m, d)
        depth = [-d.contact.dist[c] for c in range(d.ncon) if min(scene.layout.geom_person[d.contact.geom[c]]) >= 0
                 and scene.layout.geom_person[d.contact.geom[c][0]] != scene.layout.geom_person[d.contact.geom[c][1]]]
        assert max(depth, default=0.0) < 0.003
    m_sim = scene.model
    moved = np.zeros((out.shape[0], m_sim.nv))
    for f in range(out.shape[0]):
        mujoco.mj_differentiatePos(m_sim, moved[f], 1.0, qref[f], out[f])
    size = np.linalg.norm(moved, axis=1)
    assert size.min() > 0.02  # every frame had to change (5 cm of overlap)
    assert np.abs(np.diff(moved, axis=0)).max() < 0.1 * size.max()  # and changes smoothly


def test_arm_contacts_between_athletes_are_left_out_of_the_simulation_only() -> None:
    """With ``inter_person_arm_contacts`` off (the default) the simulated model excludes
    every arm-arm pair of the two athletes, while the probe model (separation, reported
    contacts) keeps them; arm-trunk contacts stay in both."""
    skel = build_skeleton(dict(_DEFAULT_LENGTHS))
    scene = build_scene([skel, skel], [0, 1], FPS, COCO17_FEET, HumanoidConfig())
    assert 'body1="p0_left_forearm" body2="p1_right_forearm"' in scene.mjcf
    assert 'p0_left_forearm" body2="p1_' not in scene.probe_mjcf
    assert 'body1="p0_left_forearm" body2="p1_torso"' not in scene.mjcf
    on = build_scene([skel, skel], [0, 1], FPS, COCO17_FEET, HumanoidConfig(arm_contacts="simulate"))
    assert 'p0_left_forearm" body2="p1_' not in on.mjcf


def test_foot_contacts_between_athletes_are_left_out_of_the_simulation_only() -> None:
    """With ``foot_contacts`` "reference" (the default) the simulated model excludes
    the four foot-foot pairs of the two athletes and no other pair of a foot; the probe
    model keeps them all."""
    skel = build_skeleton(dict(_DEFAULT_LENGTHS))
    scene = build_scene([skel, skel], [0, 1], FPS, COCO17_FEET, HumanoidConfig())
    for a in ("left_foot", "right_foot"):
        for b in ("left_foot", "right_foot"):
            assert f'body1="p0_{a}" body2="p1_{b}"' in scene.mjcf
            assert f'body1="p0_{a}" body2="p1_{b}"' not in scene.probe_mjcf
    assert 'body1="p0_left_foot" body2="p1_left_shin"' not in scene.mjcf
    feet = [line for line in scene.mjcf.splitlines() if "<exclude" in line and "_foot" in line and 'body1="p0_' in line and 'body2="p1_' in line]
    assert len(feet) == 4
    on = build_scene([skel, skel], [0, 1], FPS, COCO17_FEET, HumanoidConfig(foot_contacts="simulate"))
    assert 'p0_left_foot" body2="p1_' not in on.mjcf
    both = build_scene([skel, skel], [0, 1], FPS, COCO17_FEET, HumanoidConfig(foot_contacts="simulate", arm_contacts="simulate"))
    assert both.probe_mjcf == both.mjcf


def test_the_physics_stage_nests_the_humanoid_settings_unchanged() -> None:
    from pipeline.stages.physics import PhysicsConfig

    assert PhysicsConfig().humanoid == HumanoidConfig()
    assert PhysicsConfig(humanoid={"substeps": 4}).humanoid == HumanoidConfig(substeps=4)


def test_reference_carries_its_schedule() -> None:
    kp = _rest_keypoints(1.0, n_frames=6)
    scene = build_scene([build_skeleton(dict(_DEFAULT_LENGTHS))], [0], FPS, COCO17_FEET, HumanoidConfig())
    ref, _, _ = build_reference(scene, kp, [0], substeps=4, flat_feet=True, sole_lift_m=0.007)
    assert ref.schedule is not None and ref.schedule.ctrl.shape == (6, 4, scene.model.nu)
    np.testing.assert_allclose(ref.ctrl, ref.schedule.ctrl[:, 0])
    held, _, _ = build_reference(scene, kp, [0], substeps=0)
    assert held.schedule is None


def test_inverse_kinematics_restarts_a_person_left_far_from_its_targets() -> None:
    """A frame whose warm-started iterations leave a site more than ``restart_tol_m``
    off (here: no warm iterations at all, so the previous frame's pose is kept while
    the arms are thrown up) is solved again from the rest angles; without the restart
    the arms stay off by decimetres."""
    scene = _one_person_scene()
    m = scene.model
    d = mujoco.MjData(m)
    q = np.tile(m.qpos0, (4, 1))
    q[:, 2] += 0.95
    for a in _swinging_joints(m):
        j = int(np.flatnonzero(m.jnt_qposadr == a)[0])
        q[2:, a] = m.jnt_range[j, 0] + 0.8 * (m.jnt_range[j, 1] - m.jnt_range[j, 0])
    targets = np.zeros((4, 1, len(scene.site_names), 3))
    for f in range(4):
        d.qpos[:] = q[f]
        mujoco.mj_kinematics(m, d)
        targets[f, 0] = d.site_xpos[scene.site_ids[0]]
    weight = np.ones(targets.shape[:3])

    def worst_error_m(qs: np.ndarray, f: int) -> float:
        d.qpos[:] = qs[f]
        mujoco.mj_kinematics(m, d)
        return float(np.linalg.norm(d.site_xpos[scene.site_ids[0]] - targets[f, 0], axis=-1).max())

    stuck = inverse_kinematics(scene, targets, weight, iters=0, restart_tol_m=1e9)
    fixed = inverse_kinematics(scene, targets, weight, iters=0, restart_tol_m=0.05)
    assert worst_error_m(stuck, 2) > 0.05
    assert worst_error_m(fixed, 2) < 0.01
    assert worst_error_m(fixed, 3) < 0.01


def test_inverse_kinematics_posture_weight_stops_free_joints_drifting() -> None:
    """Noisy keypoints of a person standing still: each frame, warm-started from the
    last, lets the joints the keypoints leave free (the upper arm's twist) wander; the
    posture pull holds them near rest at the same site error."""
    scene = _one_person_scene()
    m = scene.model
    d = mujoco.MjData(m)
    q0 = m.qpos0.copy()
    q0[2] += 0.95
    d.qpos[:] = q0
    mujoco.mj_kinematics(m, d)
    rest = d.site_xpos[scene.site_ids[0]].copy()
    frames = 120
    targets = rest[None, None] + np.random.default_rng(0).normal(0.0, 0.01, (frames, 1, *rest.shape))
    weight = np.ones(targets.shape[:3])
    hinges = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    hq = np.array([m.jnt_qposadr[j] for j in hinges])

    def drift_and_error(posture_weight: float) -> tuple[float, float]:
        q = inverse_kinematics(scene, targets, weight, posture_weight=posture_weight)
        drift = float(np.abs(q[-20:, hq]).mean(axis=0).max())  # the most-wandered hinge, rad
        err = []
        for f in range(frames):
            d.qpos[:] = q[f]
            mujoco.mj_kinematics(m, d)
            err.append(np.linalg.norm(d.site_xpos[scene.site_ids[0]] - targets[f, 0], axis=-1).mean())
        return drift, float(np.mean(err))

    free_drift, free_err = drift_and_error(0.0)
    held_drift, held_err = drift_and_error(3e-4)
    assert free_drift > 0.8
    assert held_drift < 0.3
    assert abs(held_err - free_err) < 0.0005


def test_inverse_kinematics_holds_a_hinge_at_its_limit_out_of_the_step() -> None:
    """Knee keypoints 5 cm behind the knees ask for hyperextension past the knee's limit,
    with both feet planted flat. Clamping each step after the solve keeps the ankle and hip
    moves made as if the knee had given way: the feet end up tilted by ~10 degrees. Solving the
    step again without the held knee keeps them level and fits the keypoints better."""
    kp = _rest_keypoints(1.0, n_frames=3)
    xyz = kp.xyz_m.copy()
    for side in ("left", "right"):
        xyz[:, 0, COCO17_FEET.index(f"{side}_knee"), 0] -= 0.05
    scene = _one_person_scene()
    targets, weight = site_targets(scene, kp.replace(xyz_m=xyz), [0])
    flat = np.ones((3, 1, 2), dtype=bool)
    m = scene.model
    d = mujoco.MjData(m)
    feet = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"p0_{s}_foot") for s in ("left", "right")]
    knees = [m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"p0_{s}_knee")] for s in ("left", "right")]

    def solve(active: bool) -> tuple[float, float, np.ndarray]:
        """(worst foot tilt deg, mean site error m, knee angles) of the last frame."""
        q = inverse_kinematics(scene, targets, weight, flat=flat, sole_lift_m=0.005, limit_active_set=active)[-1]
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        tilt = max(float(np.degrees(np.arccos(np.clip(d.xmat[b].reshape(3, 3)[2, 2], -1.0, 1.0)))) for b in feet)
        err = float(np.linalg.norm(d.site_xpos[scene.site_ids[0]] - targets[-1, 0], axis=-1).mean())
        return tilt, err, q[knees]

    tilt_clamped, err_clamped, knee_clamped = solve(False)
    tilt_held, err_held, knee_held = solve(True)
    lo = m.jnt_range[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "p0_left_knee"), 0]
    np.testing.assert_allclose(np.concatenate([knee_clamped, knee_held]), lo, atol=1e-6)  # both at the limit
    assert tilt_clamped > 5.0
    assert tilt_held < 1.0
    assert err_held < 0.5 * err_clamped


def test_inverse_kinematics_of_two_persons_equals_each_alone() -> None:
    """The solve accumulates each person's normal equations in that person's block of
    degrees of freedom: two persons solved in one scene land where each lands alone
    (sites and flat planted feet, one site unseen, swinging arms), so no term is lost or
    put in the other's block."""
    skel = build_skeleton(dict(_DEFAULT_LENGTHS))
    both = build_scene([skel, skel], [0, 1], FPS, COCO17_FEET, HumanoidConfig())
    alone = _one_person_scene()
    m1 = alone.model
    d = mujoco.MjData(m1)
    n = 6
    q = _swinging_arms(m1, n)
    sites = len(alone.site_names)
    targets = np.zeros((n, 2, sites, 3))
    for f in range(n):
        d.qpos[:] = q[f]
        mujoco.mj_kinematics(m1, d)
        targets[f, 0] = d.site_xpos[alone.site_ids[0]]
        targets[f, 1] = targets[f, 0] + np.array([1.5, 0.2, 0.0])  # the same motion, beside
    rng = np.random.default_rng(0)
    targets += rng.normal(0.0, 0.01, targets.shape)
    weight = rng.uniform(0.5, 1.0, targets.shape[:3])
    weight[:, 1, 3] = 0.0
    flat = np.zeros((n, 2, 2), dtype=bool)
    flat[:, 0, 0] = flat[:, 1, 1] = True
    together = inverse_kinematics(both, targets, weight, flat=flat, sole_lift_m=0.005)
    for i, p in enumerate(both.layout.persons):
        single = inverse_kinematics(alone, targets[:, i : i + 1], weight[:, i : i + 1], flat=flat[:, i : i + 1], sole_lift_m=0.005)
        np.testing.assert_allclose(together[:, p.qpos_adr : p.qpos_adr + p.nq], single, atol=1e-9)


def test_inverse_kinematics_names_a_non_finite_weight_or_target() -> None:
    """A NaN weight, or a NaN target with a weight, is an error naming the frame, person and
    site (it used to turn every later frame's pose into NaN); a NaN target of weight 0 is
    ignored."""
    scene = _one_person_scene()
    m = scene.model
    d = mujoco.MjData(m)
    n = 3
    q = _swinging_arms(m, n)
    targets = np.zeros((n, 1, len(scene.site_names), 3))
    for f in range(n):
        d.qpos[:] = q[f]
        mujoco.mj_kinematics(m, d)
        targets[f, 0] = d.site_xpos[scene.site_ids[0]]
    weight = np.ones(targets.shape[:3])
    bad_w = weight.copy()
    bad_w[1, 0, 5] = np.nan
    with pytest.raises(ValueError, match=f"frame 1, person 0, site {scene.site_names[5]}"):
        inverse_kinematics(scene, targets, bad_w)
    bad_t = targets.copy()
    bad_t[2, 0, 3, 1] = np.nan
    with pytest.raises(ValueError, match=f"frame 2, person 0, site {scene.site_names[3]}"):
        inverse_kinematics(scene, bad_t, weight)
    unseen = weight.copy()
    unseen[2, 0, 3] = 0.0
    assert np.isfinite(inverse_kinematics(scene, bad_t, unseen)).all()


def test_site_targets_give_an_invalid_joint_weight_zero_whatever_its_confidence() -> None:
    """A NaN confidence on an invalid joint weighs 0 (0 × NaN reached the solve as NaN before);
    on a valid joint the keypoints themselves refuse it (``Keypoints3D``)."""
    scene = _one_person_scene()
    kp = _rest_keypoints(1.0)
    j = COCO17_FEET.index(scene.site_names[4])
    valid = kp.valid.copy()
    conf = kp.confidence.copy()
    valid[1, 0, j] = False
    conf[1, 0, j] = np.nan
    _, weight = site_targets(scene, kp.replace(valid=valid, confidence=conf), [0])
    assert weight[1, 0, 4] == 0.0
    assert np.isfinite(weight).all()
    conf[2, 0, j] = np.nan
    with pytest.raises(ValueError, match=r"Keypoints3D.confidence: .* index \(2, 0, " + str(j) + r"\)"):
        kp.replace(valid=valid, confidence=conf)
