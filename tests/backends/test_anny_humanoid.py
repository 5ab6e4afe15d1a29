"""Physics humanoid from an anny BodyFit: MJCF loads, masses from volume, sites, ranges, standing."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")
pytest.importorskip("anny")

from pipeline.backends.anny.body import bone_names, fitted_keypoints, rest_mesh  # noqa: E402
from pipeline.backends.anny.humanoid import (  # noqa: E402
    BODY_BONES,
    MIN_BODY_MASS_KG,
    R_ANNY_TO_PHYS,
    SITE_BODY,
    closed_mesh_volume_m3,
    pose_fk,
    qpos_from_bodyfit,
    skeleton_from_bodyfit,
)
from pipeline.backends.anny.model import DEFAULT_RIG, anny_body  # noqa: E402
from pipeline.backends.mujoco.humanoid import DENSITY_KG_M3, build_scene_mjcf, load_model, scene_layout  # noqa: E402
from pipeline.backends.mujoco.skeleton import rest_site_positions  # noqa: E402
from pipeline.schema.joints import COCO17_FEET  # noqa: E402
from pipeline.schema.keypoints3d import Keypoints3D  # noqa: E402
from pipeline.schema.results import BodyFit  # noqa: E402
from pipeline.synthetic.anny_motion import make_anny_motion  # noqa: E402
from tests.backends.humanoid_checks import assert_random_servo_targets_stay_stable  # noqa: E402

N_FRAMES = 30


def _bodyfit(shape: np.ndarray, pose: np.ndarray, root: np.ndarray) -> BodyFit:
    """pose (F, P, bones, 3), root (F, P, 3)."""
    F, P = pose.shape[:2]
    return BodyFit(
        body_model="anny", rig=DEFAULT_RIG, bone_names=bone_names(), person_ids=np.arange(P) + 4,
        frame_indices=np.arange(F) + 100, fps=50.0, shape=shape, pose=pose, root_translation_m=root,
        valid=np.ones((F, P), bool), loss_final=np.zeros(P),
    )


def _keypoints(bf: BodyFit, xyz: np.ndarray) -> Keypoints3D:
    F, P, J = xyz.shape[:3]
    return Keypoints3D(
        joint_names=COCO17_FEET, person_ids=bf.person_ids.copy(), frame_indices=bf.frame_indices.copy(), fps=bf.fps,
        xyz_m=xyz, valid=np.ones((F, P, J), bool), confidence=np.ones((F, P, J)),
        n_views=np.full((F, P, J), 4, np.int64), reproj_err_px=np.zeros((F, P, J)), source="fit",
    )


@pytest.fixture(scope="module")
def bout() -> tuple[BodyFit, Keypoints3D]:
    """Two synthetic anny boxers (random shapes, smooth in-range motion) and their keypoints."""
    ms = [make_anny_motion(N_FRAMES, seed=s, centre_m=(0.0, 1.2 * s)) for s in (0, 1)]
    bf = _bodyfit(
        np.stack([m.shape for m in ms]), np.stack([m.pose_aa for m in ms], 1), np.stack([m.root_m for m in ms], 1)
    )
    return bf, _keypoints(bf, np.stack([m.keypoints_m for m in ms], 1))


@pytest.mark.parametrize("geometry", ["mesh", "capsule"])
def test_mjcf_loads_and_mass_matches_volume(bout: tuple[BodyFit, Keypoints3D], geometry: str) -> None:
    bf, kp = bout
    skels = [skeleton_from_bodyfit(bf, p, kp, geometry) for p in (0, 1)]  # type: ignore[arg-type]
    model = load_model(build_scene_mjcf(skels, [4, 5], 50.0))
    layout = scene_layout(model, [4, 5])
    for p, (skel, person) in enumerate(zip(skels, layout.persons, strict=True)):
        kinds = {g.kind for b in skel.bodies for g in b.geoms}
        assert ("mesh" in kinds) == (geometry == "mesh")
        # MuJoCo's mass (hull / primitive volumes at 985 kg/m³) vs the skeleton's geometry volume...
        assert person.mass_kg == pytest.approx(skel.geom_volume_m3() * DENSITY_KG_M3, rel=1e-3)
        # ... and vs the closed anny mesh of that shape (hulls shrunk where they overfill).
        mesh_mass = closed_mesh_volume_m3(rest_mesh(bf.shape[p], decimate=True)) * DENSITY_KG_M3
        assert person.mass_kg == pytest.approx(mesh_mass, rel=0.12)
        body_mass = closed_mesh_volume_m3(rest_mesh(bf.shape[p], decimate=False)) * DENSITY_KG_M3  # full mesh
        assert person.mass_kg == pytest.approx(body_mass, rel=0.15)
        assert len(skel.bodies) == len(BODY_BONES) == 19
        assert person.nv == 6 + skel.n_hinges and skel.n_hinges == 44
        assert person.servo_ids.size == skel.n_hinges
        assert set(person.site_ids) == set(COCO17_FEET)
        masses = model.body_mass[person.body_ids]
        assert masses.min() >= MIN_BODY_MASS_KG * 0.99
    feet = [model.geom(g).name for g in np.flatnonzero(layout.geom_is_foot)]
    assert sorted(feet) == sorted(f"p{i}_{s}_foot_g0" for i in (4, 5) for s in ("left", "right"))


def test_rest_sites_are_the_rest_regressor_keypoints(bout: tuple[BodyFit, Keypoints3D]) -> None:
    bf, _ = bout
    skel = skeleton_from_bodyfit(bf, 1, keypoints=None, geometry="capsule")
    rm = rest_mesh(bf.shape[1], decimate=True)
    root = rm.bone_head_m[0]
    kp = fitted_keypoints(bf.shape[1], np.zeros((1, 36, 3)), root[None])[0]  # rest pose, RestMesh frame
    want = (kp - root) @ R_ANNY_TO_PHYS.T
    got = rest_site_positions(skel)
    for j, name in enumerate(COCO17_FEET):
        np.testing.assert_allclose(got[name], want[j], atol=1e-6, err_msg=name)
    assert skel.pelvis_height_m == pytest.approx(root[2], abs=1e-9)
    # the rest body faces +x with its left on +y
    assert got["nose"][0] > 0.05 and got["left_hip"][1] > 0.05 > -0.05 > got["right_hip"][1]


def _site_error_m(bf: BodyFit, kp: Keypoints3D, p: int, row: int) -> np.ndarray:
    skel = skeleton_from_bodyfit(bf, p, kp, "capsule")
    model = load_model(build_scene_mjcf([skel], [int(bf.person_ids[p])], 50.0))
    person = scene_layout(model, [int(bf.person_ids[p])]).persons[0]
    data = mujoco.MjData(model)
    data.qpos[:] = qpos_from_bodyfit(skel, bf, p, np.array([row]))[0]
    mujoco.mj_kinematics(model, data)
    site = np.array([data.site_xpos[person.site_ids[n]] for n in COCO17_FEET])
    return np.linalg.norm(site - kp.xyz_m[row, p], axis=-1)


def test_posed_sites_reproduce_keypoints_with_landmark_offsets() -> None:
    """Random rotations of the root and of the first bone of every 3-hinge body (the rest
    of the rig at zero: exactly representable), keypoints with constant per-person offsets
    rigid in their bodies: sites at the BodyFit pose reproduce them."""
    rng = np.random.default_rng(3)
    names = bone_names()
    F = 8
    pose = np.zeros((F, 1, len(names), 3))
    pose[:, 0, 0] = rng.normal(scale=0.3, size=(F, 3))
    for body in ("spine", "torso", "neck", "head", "left_upper_arm", "right_upper_arm", "left_thigh", "right_thigh"):
        pose[:, 0, names.index(BODY_BONES[body][1][0])] = rng.normal(scale=0.25, size=(F, 3))
    root = np.array([0.3, -0.2, 0.9]) + rng.normal(scale=0.05, size=(F, 1, 3))
    shape = np.full((1, 6), 0.5)
    bf = _bodyfit(shape, pose, root)
    G, x, kp = pose_fk(DEFAULT_RIG, shape[0], pose[:, 0], root[:, 0])
    offset = rng.normal(scale=0.02, size=(len(COCO17_FEET), 3))  # per-keypoint landmark offsets (body frame)
    for name in ("heel", "big_toe", "small_toe"):  # foot points below the sole are lifted (next test)
        for side in ("left", "right"):
            offset[COCO17_FEET.index(f"{side}_{name}"), 2] = abs(offset[COCO17_FEET.index(f"{side}_{name}"), 2])
    for j, name in enumerate(COCO17_FEET):
        b = names.index(BODY_BONES[SITE_BODY[name]][1][-1])
        kp[:, j] += G[:, b] @ offset[j]
    kps = _keypoints(bf, kp[:, None])
    kp_w = anny_body().kp_w.numpy()
    rigid = []
    for j, name in enumerate(COCO17_FEET):
        frame = G[:, names.index(BODY_BONES[SITE_BODY[name]][1][-1])]
        bones = np.flatnonzero(kp_w[j] > 1e-3)
        if all(np.abs(G[:, b] - frame).max() < 1e-9 for b in bones):
            rigid.append(j)
    for row in (0, 5):
        err = _site_error_m(bf, kps, 0, row)
        # Exact where the keypoint is rigid in its body; a keypoint regressed from vertices
        # skinned to bones that rotate differently (shoulder, hip) only approximately.
        msg = dict(zip(COCO17_FEET, np.round(err * 1000, 2), strict=True))
        assert np.median(err) < 1e-4 and err.max() < 0.015, msg
        assert err[rigid].max() < 1e-4 and len(rigid) >= 12, msg


def test_sites_track_a_synthetic_bout(bout: tuple[BodyFit, Keypoints3D]) -> None:
    """A full anny pose (every bone moving, twist segments included) is only approximated by
    the merged 19-body humanoid: sites stay within a few cm of the fitted keypoints."""
    bf, kp = bout
    err = np.concatenate([_site_error_m(bf, kp, p, 12) for p in (0, 1)])
    assert np.median(err) < 0.03 and err.max() < 0.08


def test_joint_ranges_contain_a_synthetic_bout(bout: tuple[BodyFit, Keypoints3D]) -> None:
    bf, kp = bout
    for p in (0, 1):
        skel = skeleton_from_bodyfit(bf, p, kp, "capsule")
        q = qpos_from_bodyfit(skel, bf, p, np.arange(N_FRAMES))[:, 7:]
        joints = [j for b in skel.bodies for j in b.joints]
        lo = np.array([j.range_rad[0] for j in joints])
        hi = np.array([j.range_rad[1] for j in joints])
        outside = [(j.name, float(q[:, k].min()), float(q[:, k].max())) for k, j in enumerate(joints)
                   if q[:, k].min() < lo[k] or q[:, k].max() > hi[k]]
        assert not outside
        assert np.abs(q).max() > 0.3  # the bout does move the joints


@pytest.mark.parametrize("geometry", ["mesh", "capsule"])
def test_stands_on_the_floor(bout: tuple[BodyFit, Keypoints3D], geometry: str) -> None:
    """Servos at rest, 0.5 s: the soles carry the person (no fall-through, no collapse)."""
    bf, kp = bout
    skel = skeleton_from_bodyfit(bf, 0, kp, geometry)  # type: ignore[arg-type]
    model = load_model(build_scene_mjcf([skel], [4], 50.0))
    layout = scene_layout(model, [4])
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    root = layout.persons[0].root_body
    z0 = float(data.xpos[root, 2])
    assert z0 == pytest.approx(skel.pelvis_height_m, abs=1e-4)  # MJCF has 5 digits
    feet = np.flatnonzero(layout.geom_is_foot)
    floor = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    for _ in range(int(round(0.5 / model.opt.timestep))):
        mujoco.mj_step(model, data)
    assert abs(float(data.xpos[root, 2]) - z0) < 0.03
    sole = [c for c in range(data.ncon) if floor in data.contact.geom[c] and set(data.contact.geom[c]) & set(feet)]
    assert sole, "no sole-floor contact"
    assert min(float(data.contact.dist[c]) for c in sole) > -0.01


def test_bad_inputs_raise(bout: tuple[BodyFit, Keypoints3D]) -> None:
    bf, _ = bout
    with pytest.raises(ValueError, match="person_index"):
        skeleton_from_bodyfit(bf, 2)
    with pytest.raises(ValueError, match="geometry"):
        skeleton_from_bodyfit(bf, 0, geometry="boxes")  # type: ignore[arg-type]


def test_physics_stage_picks_the_bodyfit_skeleton(bout: tuple[BodyFit, Keypoints3D]) -> None:
    from pipeline.stages.physics import PhysicsConfig, build_skeletons

    bf, kp = bout
    skels, kind = build_skeletons(kp, [0, 1], bf, PhysicsConfig(skeleton="bodyfit", geometry="mesh"))
    assert kind == "bodyfit" and skels[0].body("left_clavicle").parent == "torso"
    assert any(g.kind == "mesh" for g in skels[0].body("torso").geoms)
    skels, kind = build_skeletons(kp, [0, 1], None, PhysicsConfig())
    assert kind == "keypoints" and len(skels[0].bodies) == 13
    skels, kind = build_skeletons(kp, [0, 1], bf, PhysicsConfig(skeleton="keypoints"))
    assert kind == "keypoints"


@pytest.mark.parametrize("geometry", ["mesh", "capsule"])
def test_random_servo_targets_stay_stable(bout: tuple[BodyFit, Keypoints3D], geometry: str) -> None:
    """Light bodies (hands, clavicles at the minimum mass) survive random servo targets at
    the video rate, two overlapping people on the floor, as the keypoint humanoid does."""
    bf, kp = bout
    skels = [skeleton_from_bodyfit(bf, p, kp, geometry) for p in (0, 1)]  # type: ignore[arg-type]
    model = load_model(build_scene_mjcf(skels, [4, 5], 50.0))
    lay = scene_layout(model, [4, 5])
    assert_random_servo_targets_stay_stable(model, lay, rounds=3)


def test_unobserved_keypoint_falls_back_to_the_rest_regressor(bout: tuple[BodyFit, Keypoints3D]) -> None:
    bf, kp = bout
    valid = kp.valid.copy()
    valid[:, 0, COCO17_FEET.index("nose")] = False
    skel = skeleton_from_bodyfit(bf, 0, kp.replace(valid=valid), "capsule")
    rest = rest_site_positions(skeleton_from_bodyfit(bf, 0, None, "capsule"))
    got = rest_site_positions(skel)
    assert set(got) == set(COCO17_FEET)
    np.testing.assert_allclose(got["nose"], rest["nose"], atol=1e-9)
    assert np.linalg.norm(got["left_wrist"] - rest["left_wrist"]) > 1e-4  # observed: from the keypoints


def test_foot_points_are_lifted_onto_the_sole(bout: tuple[BodyFit, Keypoints3D]) -> None:
    """Keypoints the fit places below anny's sole (its landmark offsets) become sites on the
    sole's plane: a foot standing flat on the floor then has no point under it."""
    bf, kp = bout
    xyz = kp.xyz_m.copy()
    for side in ("left", "right"):
        for name in ("heel", "big_toe", "small_toe"):
            xyz[:, :, COCO17_FEET.index(f"{side}_{name}"), 2] -= 0.03  # 3 cm under the mesh
    sk = skeleton_from_bodyfit(bf, 0, kp.replace(xyz_m=xyz), "mesh")
    for side in ("left", "right"):
        foot = sk.body(f"{side}_foot")
        zmin = min(v[2] for v in foot.geoms[0].vertices_m or ())
        sites = dict(foot.sites)
        for name in ("heel", "big_toe", "small_toe"):
            assert sites[f"{side}_{name}"][2] >= zmin - 1e-9
        assert min(sites[f"{side}_{n}"][2] for n in ("heel", "big_toe", "small_toe")) < zmin + 0.02


def test_foot_hull_contains_the_foot_points(bout: tuple[BodyFit, Keypoints3D]) -> None:
    """A toe keypoint the fit places beyond anny's toes (3 cm further along the foot) is
    still inside the foot's collision hull, so it cannot pass below the floor while the
    sole stands on it; the other foot points are inside too."""
    from scipy.spatial import ConvexHull

    bf, kp = bout
    xyz = kp.xyz_m.copy()
    for side in ("left", "right"):
        heel, toe = COCO17_FEET.index(f"{side}_heel"), COCO17_FEET.index(f"{side}_big_toe")
        along = xyz[:, :, toe] - xyz[:, :, heel]
        xyz[:, :, toe] += 0.03 * along / np.linalg.norm(along, axis=-1, keepdims=True)
    plain = skeleton_from_bodyfit(bf, 0, kp, "mesh")
    sk = skeleton_from_bodyfit(bf, 0, kp.replace(xyz_m=xyz), "mesh")
    for side in ("left", "right"):
        hull = ConvexHull(np.array(sk.body(f"{side}_foot").geoms[0].vertices_m))
        sites = dict(sk.body(f"{side}_foot").sites)
        for name in ("heel", "big_toe", "small_toe"):
            outside = hull.equations[:, :3] @ np.array(sites[f"{side}_{name}"]) + hull.equations[:, 3]
            assert outside.max() <= 1e-9, f"{side}_{name} is {outside.max() * 1000:.1f} mm outside the foot hull"
        # ... which had to grow for it: the moved toe is beyond the hull of the plain fit.
        before = ConvexHull(np.array(plain.body(f"{side}_foot").geoms[0].vertices_m))
        toe = np.array(sites[f"{side}_big_toe"])
        assert (before.equations[:, :3] @ toe + before.equations[:, 3]).max() > 0.01


def test_hands_are_boxing_gloves(bout: tuple[BodyFit, Keypoints3D]) -> None:
    """Each hand is one ball of the glove radius, one radius past the wrist along the
    hand, with its volume's mass; ``glove_radius_m=0`` keeps anny's open hand (a hull
    reaching further out)."""
    bf, kp = bout
    gloved = skeleton_from_bodyfit(bf, 0, kp, "mesh", glove_radius_m=0.065)
    bare = skeleton_from_bodyfit(bf, 0, kp, "mesh", glove_radius_m=0.0)
    for side in ("left", "right"):
        hand = next(b for b in gloved.bodies if b.name == f"{side}_hand")
        assert [g.kind for g in hand.geoms] == ["sphere"]
        g = hand.geoms[0]
        assert g.radius_m == pytest.approx(0.065)
        assert np.linalg.norm(g.a_m) == pytest.approx(0.065, abs=1e-9)  # body origin = wrist joint
        assert g.volume_m3() * DENSITY_KG_M3 == pytest.approx(4 / 3 * np.pi * 0.065**3 * 985.0)
        open_hand = next(b for b in bare.bodies if b.name == f"{side}_hand").geoms[0]
        assert open_hand.kind == "mesh"
        reach = np.linalg.norm(np.array(open_hand.vertices_m), axis=1).max()
        assert reach > 0.13  # anny's flat hand: fingers 13+ cm past the wrist
