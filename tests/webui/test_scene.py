import dataclasses
from pathlib import Path

import numpy as np
import pytest

from pipeline.schema.joints import bone_indices
from tests.webui.fixtures import build_session
from webui.scene.meshes import box_mesh, capsule_mesh, cylinder_mesh, merge_meshes
from webui.scene.persons import skeleton_segments
from webui.scene.physics_geoms import load_physics_geoms
from webui.scene.session_data import load_session_data
from webui.scene.world import camera_pose, ring_segments, vertical_fov_rad


def test_skeleton_segments_fixed_size_and_invalid_bones_collapse(tmp_path: Path) -> None:
    kp = load_session_data(build_session(tmp_path, n_frames=4)).keypoints["filtered"]
    segs, joints, ok = skeleton_segments(kp, 2, 1)
    bones = bone_indices(kp.joint_names)
    assert ok and segs.shape == (len(bones), 2, 3) and joints.shape == (17, 3)
    a, b = bones[5]
    np.testing.assert_allclose(segs[5], kp.xyz_m[2, 1, [a, b]], atol=1e-6)
    valid = kp.valid.copy()
    valid[2, 1, a] = False
    segs2, _, ok2 = skeleton_segments(kp.replace(valid=valid), 2, 1)
    assert ok2 and np.allclose(segs2[5, 0], segs2[5, 1])  # zero length: not drawn
    _, _, none = skeleton_segments(kp, None, 0)
    assert not none


def test_primitive_meshes() -> None:
    v, f = capsule_mesh(0.1, 0.3)
    assert f.max() < len(v)
    np.testing.assert_allclose([v[:, 2].min(), v[:, 2].max()], [-0.4, 0.4], atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(v[:, :2], axis=1).max(), 0.1, atol=1e-9)
    v, f = cylinder_mesh(0.2, 0.5)
    assert np.abs(v[:, 2]).max() == pytest.approx(0.5)
    v, f = box_mesh(np.array([0.1, 0.2, 0.3]))
    assert v.shape == (8, 3) and f.shape == (12, 3)
    mv, mf = merge_meshes([box_mesh(np.ones(3)), box_mesh(np.ones(3))])
    assert mv.shape == (16, 3) and mf.max() == 15


def test_world_geometry(tmp_path: Path) -> None:
    d = load_session_data(build_session(tmp_path, n_frames=2))
    wxyz, pos = camera_pose(d.rig, 1)
    np.testing.assert_allclose(pos, d.rig.centers_world_m[1])
    assert np.isclose(np.linalg.norm(wxyz), 1.0)
    assert vertical_fov_rad(d.rig, 0) == pytest.approx(2 * np.arctan(180 / 500))
    segs, cols = ring_segments()
    assert segs.shape == cols.shape and segs.shape[1:] == (2, 3)
    assert (140, 20, 20) in {tuple(c) for c in cols[:, 0].tolist()}  # red corner post


def test_physics_geoms_follow_qpos(tmp_path: Path) -> None:
    pytest.importorskip("mujoco")
    d = load_session_data(build_session(tmp_path, n_frames=6, physics=True))
    pg = load_physics_geoms(d.physics_xml, d.physics)
    assert pg is not None and pg.person_ids == [0, 1]
    v0, f0 = pg.person_mesh(0, 0)
    v5, _ = pg.person_mesh(0, 5)
    assert f0.max() < len(v0)
    # person 0 (capsule + box foot) is lifted by 1 cm per frame in the fixture's qpos
    assert v5[:, 2].mean() - v0[:, 2].mean() == pytest.approx(0.05, abs=1e-4)
    v1, _ = pg.person_mesh(1, 0)
    np.testing.assert_allclose(v1.mean(axis=0), [1.0, 0.0, 1.0], atol=0.02)  # the sphere of person 1
    assert pg.person_mesh(2, 0) is None and pg.person_mesh(0, 99) is None
    # A person not seen in a frame is simulated but not drawn there.
    seen = np.ones((d.physics.frame_indices.shape[0], 2), dtype=bool)
    seen[3, 1] = False
    pg2 = load_physics_geoms(d.physics_xml, dataclasses.replace(d.physics, observed=seen))
    assert pg2.person_mesh(1, 3) is None and pg2.person_mesh(1, 2) is not None and pg2.person_mesh(0, 3) is not None


def test_physics_geoms_bad_xml_falls_back(tmp_path: Path) -> None:
    pytest.importorskip("mujoco")
    d = load_session_data(build_session(tmp_path, n_frames=3, physics=True))
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body></mujoco>")
    assert load_physics_geoms(bad, d.physics) is None
    assert load_physics_geoms(None, d.physics) is None


@pytest.mark.slow
def test_body_meshes_are_posed_in_the_background() -> None:
    from pipeline.backends.anny.body import DEFAULT_RIG, bone_names
    from pipeline.schema.results import BodyFit
    from webui.scene.body import BodyMeshCache

    bones, n = bone_names(), 3
    root = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]])[None] + np.arange(n)[:, None, None] * np.array([0.0, 0.1, 0.0])
    fit = BodyFit(
        body_model="anny", rig=DEFAULT_RIG, bone_names=bones, person_ids=np.array([0, 1]), frame_indices=np.arange(n),
        fps=25.0, shape=np.full((2, 6), 0.5), pose=np.zeros((n, 2, len(bones), 3)), root_translation_m=root,
        valid=np.ones((n, 2), dtype=bool), loss_final=np.zeros(2),
    )  # fmt: skip
    cache = BodyMeshCache(fit)
    assert cache.get(0, 0) is None  # nothing before the thread ran
    cache.start()
    cache.join(120)
    assert cache.error is None and cache.progress == 1.0
    v00, v12 = cache.get(0, 0), cache.get(1, 2)
    assert v00.shape[1] == 3 and cache.faces is not None and cache.faces.max() < v00.shape[0]
    # the mesh follows the root translation: person 1 is 1 m along x and 0.2 m along y further at row 2
    np.testing.assert_allclose(v12.mean(axis=0) - v00.mean(axis=0), [1.0, 0.2, 0.0], atol=1e-3)
    assert 1.5 < v00[:, 2].max() - v00[:, 2].min() < 2.0  # a standing adult
    assert cache.get(0, 3) is None


def test_physics_mesh_geoms_are_drawn(tmp_path: Path) -> None:
    """Convex-hull (mesh) geoms of the BodyFit humanoid are drawn from the compiled model."""
    pytest.importorskip("mujoco")
    import dataclasses

    d = load_session_data(build_session(tmp_path, n_frames=3, physics=True))
    xml = tmp_path / "mesh.xml"
    xml.write_text(
        '<mujoco><asset><mesh name="tet" vertex="0 0 0  0.2 0 0  0 0.2 0  0 0 0.2"/></asset>'
        '<worldbody><body name="p0_pelvis"><freejoint/><geom type="mesh" mesh="tet"/></body>'
        '<body name="p1_pelvis"><freejoint/><geom type="sphere" size="0.1"/></body>'
        "</worldbody></mujoco>"
    )
    F = d.physics.qpos.shape[0]
    qpos = np.tile([0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0] * 2, (F, 1))
    qpos[:, 0] = np.arange(F) * 0.1  # person 0 slides along x
    res = dataclasses.replace(d.physics, qpos=qpos, qvel=np.zeros((F, 12)))
    pg = load_physics_geoms(xml, res)
    assert pg is not None and pg.person_ids == [0, 1]
    v0, f0 = pg.person_mesh(0, 0)
    v2, _ = pg.person_mesh(0, 2)
    assert v0.shape == (4, 3) and f0.shape[1] == 3 and f0.max() < 4
    np.testing.assert_allclose(v0.min(axis=0), [0.0, 0.0, 1.0], atol=1e-5)  # the tetrahedron at its pose
    np.testing.assert_allclose(v2 - v0, np.tile([0.2, 0.0, 0.0], (4, 1)), atol=1e-5)
