"""anny backend: folded keypoints against the skinned mesh, FK conventions, rest/posed meshes.

The first anny build of a cold cache takes ~1-2 min (then ~2 s per process); every test here
shares one model through a session fixture and ``anny_body``'s per-process cache.
"""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("anny")

from pipeline.backends.anny.body import RestMesh, posed_mesh, rest_mesh  # noqa: E402
from pipeline.backends.anny.fk import forward_kinematics, keypoints_from_bones, skin_vertices  # noqa: E402
from pipeline.backends.anny.model import DEFAULT_RIG, AnnyBody, anny_body  # noqa: E402
from pipeline.schema import COCO17_FEET, BodyFit  # noqa: E402


@pytest.fixture(scope="session")
def body() -> AnnyBody:
    torch.set_num_threads(1)
    return anny_body()


def _mesh_regressor(body: AnnyBody) -> torch.Tensor:
    from anny.paths import get_anny_root_dir

    kp = torch.load(get_anny_root_dir() / "data" / "keypoints" / "coco.pth", weights_only=True)
    idx = body.model.base_mesh_vertex_indices
    reg = torch.stack([kp[n][idx].to(torch.float64) for n in COCO17_FEET])
    return reg / reg.sum(dim=1, keepdim=True)


def test_folded_keypoints_match_mesh_regression(body: AnnyBody) -> None:
    g = torch.Generator().manual_seed(0)
    shape = torch.rand(1, 6, generator=g, dtype=torch.float64)
    coeffs = body.shape_coeffs(shape)
    heads = body.rest_heads(coeffs)
    pose = 0.5 * torch.randn(3, body.n_bones, 3, generator=g, dtype=torch.float64)
    root = torch.randn(3, 3, generator=g, dtype=torch.float64)
    G, x = forward_kinematics(body, pose, root, heads)
    kp = keypoints_from_bones(body, G, x, heads, body.rest_kp_points(coeffs))
    verts = skin_vertices(body, G, x, heads, body.rest_vertices(coeffs))
    kp_mesh = torch.einsum("kv,nvd->nkd", _mesh_regressor(body), verts)
    assert kp.shape == (3, len(COCO17_FEET), 3)
    assert float((kp - kp_mesh).abs().max()) < 1e-9


def test_zero_pose_is_rest_and_skinning_matches_anny(body: AnnyBody) -> None:
    shape = torch.full((1, 6), 0.3, dtype=torch.float64)
    coeffs = body.shape_coeffs(shape)
    heads = body.rest_heads(coeffs)
    zero = torch.zeros(1, body.n_bones, 3, dtype=torch.float64)
    G, x = forward_kinematics(body, zero, heads[:, 0], heads)
    assert torch.allclose(x, heads, atol=1e-12)
    rest = body.rest_vertices(coeffs)
    assert torch.allclose(skin_vertices(body, G, x, heads, rest), rest, atol=1e-12)
    anny_out = body.model(None, phenotype_kwargs=shape)
    assert torch.allclose(anny_out["rest_vertices"], rest, atol=1e-12)


def test_parent_rotation_moves_child_head_rigidly(body: AnnyBody) -> None:
    coeffs = body.shape_coeffs(torch.full((1, 6), 0.5, dtype=torch.float64))
    heads = body.rest_heads(coeffs)
    knee = body.bone_names.index("lowerleg01.L")
    ankle = body.bone_names.index("foot.L")
    pose = torch.zeros(1, body.n_bones, 3, dtype=torch.float64)
    pose[0, knee, 0] = np.pi / 2  # flex 90 deg about +x
    G, x = forward_kinematics(body, pose, heads[:, 0], heads)
    shin = heads[0, ankle] - heads[0, knee]
    moved = x[0, ankle] - x[0, knee]
    assert torch.allclose(moved.norm(), shin.norm(), atol=1e-12)
    # rotation about +x maps -z to +y: the foot swings backwards (+y; the body faces -y)
    assert float(moved[1]) > 0.8 * float(shin.norm())


def test_rest_mesh_conventions() -> None:
    rm = rest_mesh()
    assert isinstance(rm, RestMesh)
    v = rm.verts_m
    assert v.shape[1] == 3 and rm.faces.shape[1] == 3 and rm.vertex_bone.shape == (v.shape[0],)
    assert abs(v[:, 2].min()) < 1e-9 and 1.4 < v[:, 2].max() < 1.9
    names = rm.bone_names
    nose_side = rm.bone_tail_m[names.index("head")]
    assert nose_side[1] < rm.bone_head_m[names.index("head")][1]  # the head tail is forward (-y)
    assert rm.bone_head_m[names.index("upperarm01.L"), 0] > 0.1  # subject's left is +x
    toes = rm.bone_tail_m[names.index("foot.L")]
    assert toes[1] < -0.1 and toes[2] < 0.05
    assert rm.bone_parent[0] == -1 and np.all(rm.bone_parent[1:] < np.arange(1, len(names)))
    a, b, c = (v[rm.faces[:, i]] for i in range(3))
    volume = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6
    assert 0.03 < volume < 0.12  # outward-facing triangles, human-sized volume (m^3)
    tall = rest_mesh(np.array([1.0, 0.5, 0.5, 0.5, 1.0, 0.5]))
    assert tall.verts_m[:, 2].max() > v[:, 2].max() + 0.1
    with pytest.raises(ValueError, match="phenotype"):
        rest_mesh(np.array([2.0, 0, 0, 0, 0, 0]))


def test_posed_mesh_full_and_decimated(body: AnnyBody) -> None:
    nb = body.n_bones
    pose = np.zeros((4, 1, nb, 3))
    pose[:, 0, body.bone_names.index("lowerarm01.R"), 2] = np.linspace(0, 1.2, 4)
    root = np.tile(np.array([0.5, -1.0, 0.95]), (4, 1, 1))
    fit = BodyFit(
        body_model="anny",
        rig=DEFAULT_RIG,
        bone_names=body.bone_names,
        person_ids=np.array([7]),
        frame_indices=np.arange(4),
        fps=50.0,
        shape=np.full((1, 6), 0.5),
        pose=pose,
        root_translation_m=root,
        valid=np.ones((4, 1), dtype=bool),
        loss_final=np.zeros(1),
    )
    full, f_full = posed_mesh(fit, 0, np.array([0, 3]), decimate=False)
    dec, f_dec = posed_mesh(fit, 0, np.array([0, 3]), decimate=True)
    assert full.shape == (2, body.model.template_vertices.shape[0], 3) and f_full.shape[1] == 3
    assert dec.shape[0] == 2 and dec.shape[1] < full.shape[1] // 5 and f_dec.max() < dec.shape[1]
    # the decimated surface lies on the full one
    from scipy.spatial import cKDTree

    d, _ = cKDTree(full[1]).query(dec[1])
    assert np.median(d) < 0.01
    # the elbow bend moves the right forearm between frame rows 0 and 3, not the left one
    moved = np.linalg.norm(full[1] - full[0], axis=1)
    wrist_r = body.vertex_bone == body.bone_names.index("wrist.R")
    wrist_l = body.vertex_bone == body.bone_names.index("wrist.L")
    assert moved[wrist_r].mean() > 0.1 and moved[wrist_l].max() < 1e-9
    with pytest.raises(ValueError, match="out of range"):
        posed_mesh(fit, 1, np.array([0]))


def test_gradients_are_finite_at_zero_pose(body: AnnyBody) -> None:
    shape = torch.full((1, 6), 0.5, dtype=torch.float64, requires_grad=True)
    pose = torch.zeros(2, body.n_bones, 3, dtype=torch.float64, requires_grad=True)
    root = torch.zeros(2, 3, dtype=torch.float64, requires_grad=True)
    coeffs = body.shape_coeffs(shape)
    heads = body.rest_heads(coeffs)
    G, x = forward_kinematics(body, pose, root, heads)
    kp = keypoints_from_bones(body, G, x, heads, body.rest_kp_points(coeffs))
    kp.square().sum().backward()
    for t in (shape, pose, root):
        assert t.grad is not None and torch.all(torch.isfinite(t.grad))
    assert float(shape.grad.abs().sum()) > 0 and float(pose.grad.abs().sum()) > 0


def test_joint_limits_penalise_knee_hyperextension_not_flexion(body: AnnyBody) -> None:
    from pipeline.backends.anny.body import rest_mesh
    from pipeline.backends.anny.priors import joint_limit_penalty, joint_limit_tables

    rm = rest_mesh()
    frames, lo, hi = (
        torch.as_tensor(a) for a in joint_limit_tables(rm.bone_names, rm.bone_head_m, rm.bone_tail_m)
    )
    knee = rm.bone_names.index("lowerleg01.L")
    pose = torch.zeros(2, body.n_bones, 3, dtype=torch.float64)
    pose[0, knee, 0] = 1.5  # flexion about +x (heel backwards), inside the range
    pose[1, knee, 0] = -0.5  # hyper-extension
    lo, hi = torch.nan_to_num(lo, neginf=-1e6), torch.nan_to_num(hi, posinf=1e6)
    flex = joint_limit_penalty(pose[:1], frames, lo, hi)
    hyper = joint_limit_penalty(pose[1:], frames, lo, hi)
    assert float(flex) == 0.0 and float(hyper) > 0.1


def test_gmm_prior_fit_save_load(tmp_path) -> None:  # noqa: ANN001
    from pipeline.backends.anny.priors import GMMPrior

    rng = np.random.default_rng(0)
    centres = np.array([[0.5, 0.0, 0.0], [-0.5, 0.3, 0.0]])
    poses = np.concatenate([c + 0.05 * rng.normal(size=(200, 3)) for c in centres])
    gmm = GMMPrior.fit(poses, n_components=2, seed=0)
    inside = gmm(torch.as_tensor(centres))
    outside = gmm(torch.as_tensor([[2.0, -2.0, 1.0]]))
    assert float(outside) > float(inside) / 2 + 10
    gmm.save(tmp_path / "gmm.npz")
    again = GMMPrior.load(tmp_path / "gmm.npz")
    assert torch.allclose(again(torch.as_tensor(centres)), inside, atol=1e-6)
    with pytest.raises(ValueError, match="dimension"):
        gmm(torch.zeros(1, 4, dtype=torch.float64))
