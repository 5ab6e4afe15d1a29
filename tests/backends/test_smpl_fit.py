"""SMPL/SMPL-X fitting through ``smplx`` on a *synthetic* SMPL-format model file.

No real SMPL file may be used here (licence), so ``write_synthetic_smpl`` builds a crude
procedural body in SMPL's pickle layout: 6890 vertices (so that ``smplx``'s vertex ids for
the nose, eyes, ears, toes and heels are valid and placed where they belong), SMPL's
24-joint kinematic tree, rigid skinning weights, a sparse ``J_regressor`` that reproduces the
designed joints, four non-zero shape directions, zero (or random) pose blend shapes and a
face list. Ground truth comes from the same model, so a noise-free fit can be exact.
"""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pipeline.geometry import project
from pipeline.schema import COCO17_FEET, Association, CameraRig, Keypoints3D, Tracks2D
from pipeline.stages.fit import FitConfig, run
from tests.conftest import fit_stage_inputs, make_rig

torch = pytest.importorskip("torch")
pytest.importorskip("smplx")
sparse = pytest.importorskip("scipy.sparse")

import roma  # noqa: E402

from pipeline.backends.fitting.common import PersonObservations  # noqa: E402
from pipeline.backends.smpl import body as sb  # noqa: E402
from pipeline.backends.smpl.fit import fit_smpl, load_gmm_prior  # noqa: E402
from pipeline.backends.smpl.vposer import VPoser, load_vposer  # noqa: E402

FPS = 50.0
N_VERTS = {"smpl": 6890, "smplx": 10475}
BODY_PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19)
# Rest joints, SMPL frame: y up, facing +z, the subject's left at +x (metres).
BODY_JOINTS = np.array(
    [
        [0.0, 0.95, 0.0],  # pelvis
        [0.09, 0.87, 0.0],  # left_hip
        [-0.09, 0.87, 0.0],
        [0.0, 1.05, -0.01],  # spine1
        [0.10, 0.48, 0.01],  # left_knee
        [-0.10, 0.48, 0.01],
        [0.0, 1.18, 0.0],  # spine2
        [0.10, 0.08, -0.02],  # left_ankle
        [-0.10, 0.08, -0.02],
        [0.0, 1.24, 0.01],  # spine3
        [0.11, 0.02, 0.10],  # left_foot (toes joint)
        [-0.11, 0.02, 0.10],
        [0.0, 1.45, -0.01],  # neck
        [0.07, 1.37, 0.0],  # left_collar
        [-0.07, 1.37, 0.0],
        [0.0, 1.52, 0.03],  # head
        [0.18, 1.40, -0.01],  # left_shoulder
        [-0.18, 1.40, -0.01],
        [0.44, 1.40, -0.02],  # left_elbow
        [-0.44, 1.40, -0.02],
        [0.69, 1.40, 0.0],  # left_wrist
        [-0.69, 1.40, 0.0],
    ]
)


def _skeleton(model: str) -> tuple[tuple[int, ...], np.ndarray]:
    """Parents and rest joints: SMPL adds two hand joints; SMPL-X jaw, eyes and 2 x 15 finger
    joints (index, middle, pinky, ring, thumb; 3 each, from the wrists)."""
    if model == "smpl":
        hands = np.array([[0.77, 1.40, 0.0], [-0.77, 1.40, 0.0]])
        return BODY_PARENTS + (20, 21), np.concatenate([BODY_JOINTS, hands])
    parents = list(BODY_PARENTS) + [15, 15, 15]
    joints = [*BODY_JOINTS, [0.0, 1.55, 0.05], [0.03, 1.62, 0.08], [-0.03, 1.62, 0.08]]
    for side, wrist in ((1.0, 20), (-1.0, 21)):
        for finger in range(5):
            for k in range(3):
                parents.append(wrist if k == 0 else len(parents) - 1)
                joints.append([side * (0.75 + 0.025 * k), 1.40, 0.02 * (finger - 2)])
    return tuple(parents), np.array(joints)


def _landmarks(model: str) -> dict[int, tuple[list[float], int]]:
    """smplx's vertex ids of the model -> (rest position, skinning joint)."""
    from smplx.vertex_ids import vertex_ids

    ids = vertex_ids["smplh" if model == "smpl" else "smplx"]
    pos = {
        "nose": ([0.0, 1.58, 0.12], 15),
        "leye": ([0.035, 1.62, 0.09], 15),
        "reye": ([-0.035, 1.62, 0.09], 15),
        "lear": ([0.075, 1.59, 0.0], 15),
        "rear": ([-0.075, 1.59, 0.0], 15),
        "LBigToe": ([0.09, 0.0, 0.20], 10),
        "LSmallToe": ([0.15, 0.0, 0.17], 10),
        "LHeel": ([0.10, 0.0, -0.07], 7),
        "RBigToe": ([-0.09, 0.0, 0.20], 11),
        "RSmallToe": ([-0.15, 0.0, 0.17], 11),
        "RHeel": ([-0.10, 0.0, -0.07], 8),
    }
    for i, tip in enumerate(("thumb", "index", "middle", "ring", "pinky")):
        pos["l" + tip] = ([0.86, 1.40, 0.02 * (i - 2)], 20)
        pos["r" + tip] = ([-0.86, 1.40, 0.02 * (i - 2)], 21)
    return {ids[name]: p for name, p in pos.items()}


def write_synthetic_smpl(root: Path, posedirs_scale: float = 0.0, seed: int = 0, model: str = "smpl") -> Path:
    """Write ``root/smpl/SMPL_NEUTRAL.pkl`` (the pickle layout ``smplx.SMPL`` reads) or, for
    ``model="smplx"``, ``root/smplx/SMPLX_NEUTRAL.npz`` (``smplx.SMPLX``'s npz layout)."""
    rng = np.random.default_rng(seed)
    parents, joints = _skeleton(model)
    nj, nv = len(parents), N_VERTS[model]
    n_reg = 2 * nj  # the last vertices: two per joint, averaged by the J_regressor
    ring = 10
    n_ring_verts = nv - n_reg
    n_rings = n_ring_verts // ring
    per_joint = np.full(nj, n_rings // nj)
    per_joint[: n_rings - per_joint.sum()] += 1
    tips = {10: [0.11, 0.01, 0.18], 11: [-0.11, 0.01, 0.18], 15: [0.0, 1.72, 0.03]}
    v = np.zeros((nv, 3))
    weights = np.zeros((nv, nj))
    faces = []
    i = 0
    for j in range(nj):
        a = joints[j]
        if j in tips:
            b = np.array(tips[j])
        elif j in parents:  # towards the first child
            b = joints[parents.index(j)]
        elif abs(a[0]) > 0.5:  # hand / finger tips point away from the body
            b = a + [0.03 * np.sign(a[0]), 0.0, 0.0]
        else:  # jaw, eyes
            b = a + [0.0, 0.0, 0.03]
        axis = (b - a) / np.linalg.norm(b - a)
        u = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        w = np.cross(axis, u)
        radius = 0.12 if j in (0, 3, 6, 9) else 0.05 if j < 22 else 0.01
        for r in range(per_joint[j]):
            t = (r + 0.5) / per_joint[j]
            ang = 2 * np.pi * np.arange(ring) / ring
            v[i : i + ring] = a + t * (b - a) + radius * (np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * w)
            weights[i : i + ring, j] = 1.0
            if r > 0:
                for k in range(ring):
                    p, q = i - ring + k, i - ring + (k + 1) % ring
                    faces += [[p, q, i + k], [q, i + (k + 1) % ring, i + k]]
            i += ring
    while i < n_ring_verts:  # leftovers: inside the pelvis
        v[i], weights[i, 0] = joints[0], 1.0
        i += 1
    for vid, (pos, j) in _landmarks(model).items():
        v[vid] = pos
        weights[vid] = 0.0
        weights[vid, j] = 1.0
    rows, cols = [], []
    for j in range(nj):
        for s in (-1, 1):
            k = n_ring_verts + 2 * j + (s > 0)
            v[k] = joints[j] + [0.01 * s, 0.0, 0.0]
            weights[k, j] = 1.0
            rows.append(j)
            cols.append(k)
    J_regressor = sparse.csc_matrix((np.full(n_reg, 0.5), (rows, cols)), shape=(nj, nv))
    shapedirs = np.zeros((nv, 3, 10))
    shapedirs[:, :, 0] = 0.06 * (v - joints[0])  # overall size
    legs = v[:, 1] < joints[1, 1]
    shapedirs[legs, 1, 1] = -0.06 * (joints[1, 1] - v[legs, 1])  # leg length
    arms = np.abs(v[:, 0]) > joints[16, 0]
    shapedirs[arms, 0, 2] = 0.08 * np.sign(v[arms, 0]) * (np.abs(v[arms, 0]) - joints[16, 0])  # arm length
    upper = (v[:, 1] > 1.3) & (np.abs(v[:, 0]) > 0.05)
    shapedirs[upper, 0, 3] = 0.03 * np.sign(v[upper, 0])  # shoulder width
    kintree = np.array([[4294967295, *parents[1:]], list(range(nj))], dtype=np.int64)
    data = {
        "v_template": v,
        "weights": weights,
        "J_regressor": J_regressor,
        "shapedirs": shapedirs,
        "posedirs": posedirs_scale * rng.normal(size=(nv, 3, 9 * (nj - 1))),
        "kintree_table": kintree,
        "f": np.array(faces, dtype=np.uint32),
    }
    if model == "smpl":
        out = root / "smpl" / "SMPL_NEUTRAL.pkl"
        out.parent.mkdir(parents=True, exist_ok=True)
        with open(out, "wb") as fh:
            pickle.dump(data, fh, protocol=2)
        return out
    data["J_regressor"] = J_regressor.toarray()
    data["shapedirs"] = np.concatenate([shapedirs, np.zeros((nv, 3, 10))], axis=2)  # + 10 expressions
    data.update(
        hands_componentsl=np.eye(45),
        hands_componentsr=np.eye(45),
        hands_meanl=np.zeros(45),
        hands_meanr=np.zeros(45),
        lmk_faces_idx=np.zeros(51, dtype=np.int64),
        lmk_bary_coords=np.full((51, 3), 1 / 3),
        dynamic_lmk_faces_idx=np.zeros((79, 17), dtype=np.int64),
        dynamic_lmk_bary_coords=np.full((79, 17, 3), 1 / 3),
    )
    out = root / "smplx" / "SMPLX_NEUTRAL.npz"
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez(out, **data)
    return out


def _rig(n_views: int = 4) -> CameraRig:
    return make_rig(n_views, fps=FPS, phase_rad=0.4)


def _motion(body: sb.SmplBody, nf: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Known betas (10,), pose (nf, 24, 3) (world pelvis + body_pose), pelvis (nf, 3) and
    keypoints (nf, 23, 3): a boxer-like stance with smoothly moving limbs."""
    rng = np.random.default_rng(seed)
    betas = np.zeros(10)
    betas[:4] = [1.0, -0.8, 0.6, 0.5]
    t = np.arange(nf) / FPS
    pose = np.zeros((nf, body.n_joints, 3))
    yaw = 0.3 * np.sin(2 * np.pi * 0.7 * t)
    c, s = np.cos(yaw), np.sin(yaw)
    Rz = np.zeros((nf, 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1.0
    pose[:, 0] = roma.rotmat_to_rotvec(torch.as_tensor(Rz @ sb.R_WORLD_SMPL)).numpy()  # upright, turning
    base = {
        "left_hip": [-0.4, 0.0, 0.15],
        "right_hip": [-0.2, 0.0, -0.15],
        "left_knee": [0.6, 0.0, 0.0],
        "right_knee": [0.4, 0.0, 0.0],
        "left_shoulder": [0.0, -0.6, -1.1],
        "right_shoulder": [0.0, 0.6, 1.1],
        "left_elbow": [0.0, -1.8, 0.0],
        "right_elbow": [0.0, 1.8, 0.0],
        "spine2": [0.15, 0.0, 0.0],
        "left_ankle": [-0.2, 0.0, 0.0],
    }
    names = body.joint_names
    for name, aa in base.items():
        pose[:, names.index(name)] = aa
    phase = rng.uniform(0, 2 * np.pi, 24)
    for j in range(1, 22):
        pose[:, j] += 0.15 * np.sin(2 * np.pi * 1.3 * t[:, None] + phase[j] + np.arange(3))
    root = np.stack([0.3 * np.sin(2 * np.pi * 0.5 * t), 0.2 * t, 0.93 + 0.02 * np.sin(2 * np.pi * t)], axis=1)
    return betas, pose, root, _keypoints_ref(body, betas, pose, root)


def _keypoints_ref(body: sb.SmplBody, betas: np.ndarray, pose: np.ndarray, root: np.ndarray) -> np.ndarray:
    """COCO17_FEET keypoints through smplx's own forward (the reference)."""
    p = {k: torch.as_tensor(v) for k, v in sb.smplx_params(body, betas, pose, root).items()}
    with torch.no_grad():
        joints = body.module(**p).joints.numpy() @ sb.R_WORLD_SMPL.T
    names = sb.output_joint_names(body.body_model)
    return joints[:, [names.index(n) for n in COCO17_FEET]]


def _posed(body: sb.SmplBody, betas: np.ndarray, pose: np.ndarray, root: np.ndarray) -> tuple[Any, ...]:
    """Our forward kinematics of a motion: per-frame betas, rest joints, bone frames G, x, R."""
    b = torch.as_tensor(betas)[None].expand(pose.shape[0], len(betas))
    J = body.rest_joints(b)
    G, x, R = sb.forward(
        body, J, roma.rotvec_to_rotmat(torch.as_tensor(pose[:, 0])), torch.as_tensor(pose[:, 1:]), torch.as_tensor(root)
    )
    return b, J, G, x, R


def _observations(rig: CameraRig, xyz: np.ndarray, outlier_view: int | None = None) -> PersonObservations:
    nf, nj = xyz.shape[:2]
    uv, _ = project(rig, xyz)  # (V, F, J, 2)
    uv = uv.copy()
    if outlier_view is not None:
        uv[outlier_view] += [90.0, -60.0]  # a whole view shifted: e.g. a wrong calibration
    return PersonObservations(
        kp3d_m=xyz.copy(),
        w3d=np.full((nf, nj), 0.9),
        uv_px=uv,
        w2d=np.full((rig.n_views, nf, nj), 0.95),
    )


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("smpl_models")
    write_synthetic_smpl(root)
    return root


@pytest.fixture(scope="module")
def body(model_dir: Path) -> sb.SmplBody:
    return sb.smpl_body("smpl", model_dir)


def _mpjpe_mm(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b, axis=-1).mean() * 1000)


def test_sparse_keypoints_match_smplx_forward(tmp_path: Path) -> None:
    """Our sparse skinning (joints + 11 landmark vertices, pose blend shapes included) equals
    smplx's full forward, mapped to the world frame."""
    write_synthetic_smpl(tmp_path, posedirs_scale=0.01, seed=1)
    body = sb.smpl_body("smpl", tmp_path)
    betas, pose, root, ref = _motion(body, 5, seed=2)
    b, J, G, x, R = _posed(body, betas, pose, root)
    kp = sb.keypoints(body, b, J, G, x, R).numpy()
    assert np.abs(kp - ref).max() < 1e-7  # smplx stores its buffers through float32
    assert np.allclose(x[:, 0].numpy(), root)  # root_translation_m is the pelvis
    verts = sb.posed_vertices(body, betas, pose, root)
    assert verts.shape == (5, N_VERTS["smpl"], 3)
    assert np.allclose(verts[:, 332], kp[:, COCO17_FEET.index("nose")])
    # world frame: standing upright (head above the feet, z-up)
    assert (kp[:, COCO17_FEET.index("nose"), 2] > kp[:, COCO17_FEET.index("left_ankle"), 2] + 1.0).all()


def test_recovers_known_shape_and_pose(body: sb.SmplBody) -> None:
    rig = _rig(4)
    betas, pose, root, xyz = _motion(body, 20, seed=0)
    obs = _observations(rig, xyz)
    # regularisers (which bias a fit of exact data) nearly off, as in the anny test
    cfg = FitConfig(
        body_model="smpl", calibrate_landmarks=False, w_accel=0.0, w_smooth=1e-6, w_reg=1e-5, w_ground=0.0
    )
    res = fit_smpl([obs], rig.P, cfg, body)
    fitted = res.keypoints_m[:, 0]
    assert _mpjpe_mm(fitted, xyz) < 1.0
    assert np.abs(res.shape[0, :4] - betas[:4]).max() < 0.05  # the four shape directions in use
    # the outputs are exactly smplx's forward of the returned parameters
    assert _mpjpe_mm(_keypoints_ref(body, res.shape[0], res.pose_aa[:, 0], res.root_m[:, 0]), fitted) < 1e-3
    # the elbow and knee bend angles (observable from COCO keypoints) are recovered
    for name in ("left_elbow", "right_elbow", "left_knee", "right_knee"):
        j = body.joint_names.index(name)
        got = np.linalg.norm(res.pose_aa[:, 0, j], axis=-1)
        assert np.abs(got - np.linalg.norm(pose[:, j], axis=-1)).max() < 0.1, name
    # pelvis: its tilt trades off against the spine (no COCO keypoint between hips and
    # shoulders), so only to a few centimetres
    assert np.linalg.norm(res.root_m[:, 0] - root, axis=-1).max() < 0.03
    assert res.joint_names[0] == "pelvis" and res.pose_aa.shape == (20, 1, 24, 3)


def test_robust_loss_ignores_an_outlier_view(body: sb.SmplBody) -> None:
    rig = _rig(4)
    _, _, _, xyz = _motion(body, 10, seed=1)
    noisy = xyz + np.random.default_rng(1).normal(0, 0.03, xyz.shape)  # 3D alone is poor
    errors = {}
    for name, outlier, robust in (("clean", None, "gm"), ("gm", 2, "gm"), ("l2", 2, "l2")):
        obs = _observations(rig, xyz, outlier_view=outlier)
        obs = PersonObservations(noisy, obs.w3d, obs.uv_px, obs.w2d)
        cfg = FitConfig(body_model="smpl", robust_2d=robust, gm_sigma_px=20.0, w_ground=0.0, pose_iters=60)
        errors[name] = _mpjpe_mm(fit_smpl([obs], rig.P, cfg, body).keypoints_m[:, 0], xyz)
    assert errors["clean"] < 10.0
    assert errors["gm"] < errors["clean"] + 3.0  # the bad view is (nearly) ignored
    assert errors["l2"] > 5 * errors["gm"]  # a plain squared loss is dragged by it


def test_gradients_are_finite(body: sb.SmplBody) -> None:
    betas, pose, root, _ = _motion(body, 4, seed=3)
    b = torch.as_tensor(betas)[None].expand(4, 10).clone().requires_grad_(True)
    aa = torch.as_tensor(pose).clone().requires_grad_(True)
    pose_body = aa[:, 1:]
    J = body.rest_joints(b)
    G, x, R = sb.forward(body, J, roma.rotvec_to_rotmat(aa[:, 0]), pose_body, torch.as_tensor(root))
    kp = sb.keypoints(body, b, J, G, x, R)
    kp.square().sum().backward()
    assert torch.isfinite(aa.grad).all() and torch.isfinite(b.grad).all()
    assert aa.grad.abs().sum() > 0 and b.grad.abs().sum() > 0


def test_stage_fits_smpl_and_writes_a_bodyfit(model_dir: Path, body: sb.SmplBody) -> None:
    rig = _rig(3)
    _, _, _, xyz = _motion(body, 8, seed=4)
    kp3d, tracks, assoc = _stage_inputs(rig, xyz[:, None])
    res = run(
        kp3d,
        tracks,
        assoc,
        rig,
        FitConfig(
            body_model="smpl", body_model_path=str(model_dir), pose_iters=40, pose_prior_path="builtin"
        ),
    )
    bf = res.bodyfit
    assert bf.body_model == "smpl" and bf.rig == "smpl-neutral" and bf.bone_names == body.joint_names
    assert bf.shape.shape == (1, 10) and bf.pose.shape == (8, 1, 24, 3)
    assert res.keypoints3d.source == "fit" and _mpjpe_mm(res.keypoints3d.xyz_m[:, 0], xyz) < 15.0
    verts, faces = sb.posed_mesh(bf, 0, np.arange(3), model_dir)
    assert verts.shape == (3, N_VERTS["smpl"], 3) and faces.max() < N_VERTS["smpl"]


def _stage_inputs(rig: CameraRig, xyz: np.ndarray) -> tuple[Keypoints3D, Tracks2D, Association]:
    return fit_stage_inputs(rig, xyz, FPS)


def test_missing_gender_file_and_package_are_named(model_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(ValueError, match=r"SMPL_FEMALE\.pkl"):
        sb.smpl_body("smpl", model_dir, gender="female")
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "smplx" else real(name, *a)
    )
    with pytest.raises(ValueError, match="pip install smplx"):
        sb.check_smpl_available("smpl", model_dir)


def test_unreadable_model_file_is_named(tmp_path: Path) -> None:
    bad = tmp_path / "smpl" / "SMPL_MALE.pkl"
    bad.parent.mkdir()
    bad.write_bytes(b"not a pickle")
    with pytest.raises(ValueError, match=r"SMPL_MALE\.pkl"):
        sb.smpl_body("smpl", tmp_path, gender="male")


def test_vposer_weights_load_and_give_a_differentiable_prior(tmp_path: Path) -> None:
    torch.manual_seed(0)
    net = VPoser(num_neurons=64, latent_dim=8)
    with torch.no_grad():  # non-trivial BatchNorm statistics
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm1d):
                m.running_mean.normal_(0, 0.1)
                m.running_var.uniform_(0.5, 1.5)
    ckpt = {"state_dict": {f"vp_model.{k}": v for k, v in net.state_dict().items()}, "epoch": 3}
    torch.save(ckpt, tmp_path / "vposer.ckpt")
    prior = load_vposer(tmp_path / "vposer.ckpt")
    pose = (0.3 * torch.randn(5, 21, 3, dtype=torch.float64)).requires_grad_(True)
    value = prior(pose)
    value.backward()
    assert torch.isfinite(value) and value > 0
    assert torch.isfinite(pose.grad).all() and pose.grad.abs().sum() > 0
    with torch.no_grad():  # same numbers as the network it was saved from
        mu = net.double().eval().encode_mean(pose)
    assert torch.allclose(mu, prior.model.encode_mean(pose))
    (tmp_path / "bad.pt").write_bytes(b"garbage")
    with pytest.raises(ValueError, match="bad.pt"):
        load_vposer(tmp_path / "bad.pt")
    torch.save({"encoder_net.2.weight": torch.zeros(4, 63)}, tmp_path / "partial.pt")
    with pytest.raises(ValueError, match="partial.pt"):
        load_vposer(tmp_path / "partial.pt")


def test_fit_uses_user_vposer_and_smplify_gmm(tmp_path: Path, body: sb.SmplBody) -> None:
    torch.manual_seed(1)
    torch.save(VPoser(num_neurons=32, latent_dim=4).state_dict(), tmp_path / "vposer.pt")
    rng = np.random.default_rng(0)
    a = rng.normal(size=(2, 69, 69)) * 0.1
    gmm = {
        "means": rng.normal(0, 0.1, (2, 69)),
        "covars": a @ a.transpose(0, 2, 1) + 0.1 * np.eye(69),
        "weights": np.array([0.3, 0.7]),
    }
    with open(tmp_path / "gmm_08.pkl", "wb") as fh:
        pickle.dump(gmm, fh, protocol=2)
    prior, joints = load_gmm_prior(tmp_path / "gmm_08.pkl", 23)
    assert joints == 23 and prior.dim == 69
    _, joints21 = load_gmm_prior(tmp_path / "gmm_08.pkl", 21)  # SMPL-X body: marginal
    assert joints21 == 21
    prec = np.linalg.inv(gmm["covars"][:, :63, :63])
    np.savez(tmp_path / "ours.npz", means=gmm["means"][:, :63], precisions=prec, weights=gmm["weights"])
    assert load_gmm_prior(tmp_path / "ours.npz", 23)[1] == 21  # our npz layout, 21 joints
    np.savez(
        tmp_path / "anny.npz", means=gmm["means"][:, :63], precisions=prec, weights=gmm["weights"], rig="anny"
    )
    with pytest.raises(ValueError, match="rig 'anny'"):
        load_gmm_prior(tmp_path / "anny.npz", 23)
    rig = _rig(3)
    _, _, _, xyz = _motion(body, 6, seed=5)
    cfg = FitConfig(
        body_model="smpl",
        vposer_path=str(tmp_path / "vposer.pt"),
        pose_prior_path=str(tmp_path / "gmm_08.pkl"),
        w_prior=1e-3,
        pose_iters=10,
        pose_iters_3d=5,
    )
    res = fit_smpl([_observations(rig, xyz)], rig.P, cfg, body)
    assert {"vposer", "prior"} <= set(res.loss_terms)
    assert all(np.isfinite(v) for v in res.loss_terms.values())
    with open(tmp_path / "evil.pkl", "wb") as fh:
        pickle.dump({"means": Path("x")}, fh)
    with pytest.raises(ValueError, match="evil.pkl"):
        load_gmm_prior(tmp_path / "evil.pkl", 23)


def test_viewer_mesh_cache_poses_smpl_fits(model_dir: Path, body: sb.SmplBody) -> None:
    from webui.scene.body import BodyMeshCache

    rig = _rig(3)
    _, _, _, xyz = _motion(body, 4, seed=6)
    bf = run(
        *_stage_inputs(rig, xyz[:, None]),
        rig,
        FitConfig(body_model="smpl", body_model_path=str(model_dir), pose_iters=5),
    ).bodyfit
    cache = BodyMeshCache(bf, body_model_path=str(model_dir))
    cache.start()
    cache.join(60)
    assert cache.error is None and cache.get(0, 3).shape == (N_VERTS["smpl"], 3)
    missing = BodyMeshCache(bf, body_model_path="")  # no files: skeleton only, with a reason
    missing.start()
    missing.join(60)
    assert missing.get(0, 0) is None and "body-model-path" in (missing.error or "")


def test_cli_body_model_flags(tmp_path: Path, model_dir: Path) -> None:
    import json

    from typer.testing import CliRunner

    from pipeline.cli.main import app
    from tests.conftest import write_tiny_session

    s = write_tiny_session(tmp_path / "s", stages=("detect2d",), n_frames=4)
    runner = CliRunner()
    r = runner.invoke(app, ["run", str(s), "--body-model", "smpl", "--body-model-path", str(model_dir)])
    assert r.exit_code == 0, r.output
    fit = json.loads((s / "session.json").read_text())["stage_config"]["fit"]
    assert fit == {"body_model": "smpl", "body_model_path": str(model_dir.resolve())}
    r = runner.invoke(app, ["run", str(s), "--body-model", "smpl-h"])
    assert r.exit_code == 2 and "smpl-h" in r.output
    before = (s / "session.json").read_text()
    r = runner.invoke(app, ["run", str(s), "--body-model", "smplx", "--body-model-path", str(tmp_path / "nope")])
    assert r.exit_code == 2 and "nope" in r.output and "not a folder" in r.output
    assert (s / "session.json").read_text() == before  # the bad path was not saved


def test_smplx_model_keypoints_and_fit(tmp_path: Path) -> None:
    """SMPL-X: 22 posed joints (jaw, eyes and fingers folded onto their body ancestors), the
    SMPL-X vertex landmarks, smplx's forward as the reference, and a short stage run."""
    write_synthetic_smpl(tmp_path, posedirs_scale=0.01, seed=2, model="smplx")
    body = sb.smpl_body("smplx", tmp_path)
    assert body.n_joints == 22 and body.joint_names[-1] == "right_wrist" and body.rig == "smplx-neutral"
    betas, pose, root, ref = _motion(body, 5, seed=7)
    b, J, G, x, R = _posed(body, betas, pose, root)
    assert np.abs(sb.keypoints(body, b, J, G, x, R).numpy() - ref).max() < 1e-7
    rig = _rig(3)
    res = run(
        *_stage_inputs(rig, ref[:, None]),
        rig,
        FitConfig(body_model="smplx", body_model_path=str(tmp_path), pose_iters=30),
    )
    assert res.bodyfit.body_model == "smplx" and res.bodyfit.pose.shape == (5, 1, 22, 3)
    assert _mpjpe_mm(res.keypoints3d.xyz_m[:, 0], ref) < 20.0
