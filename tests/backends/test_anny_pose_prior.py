"""The shipped anny pose prior (GMM fitted to the DeepMimic clips): metadata, held-out
likelihood, gradients, and a fit with it on a short synthetic clip.

``data/anny_deepmimic_poses.npz`` holds the retargeted poses (the GMM's bones, every 2nd frame,
float16) written by ``build_pose_prior(..., poses_out=...)``, so the held-out test needs no
pybullet; the DeepMimic-loading tests skip without it.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

import torch  # noqa: E402

from pipeline.backends.anny.model import DEFAULT_RIG, anny_body  # noqa: E402
from pipeline.backends.anny.priors import (  # noqa: E402
    BUILTIN_PRIOR,
    GMMPrior,
    joint_limit_tables,
    load_pose_prior,
)
from pipeline.priors.build import PRIOR_BONES  # noqa: E402

SAMPLE = Path(__file__).parent / "data" / "anny_deepmimic_poses.npz"
HELD_OUT = "punch"
needs_pybullet = pytest.mark.skipif(
    importlib.util.find_spec("pybullet_data") is None, reason="pybullet (DeepMimic clips) not installed"
)


@pytest.fixture(scope="module")
def body():  # noqa: ANN201
    return anny_body(DEFAULT_RIG)


@pytest.fixture(scope="module")
def sample() -> tuple[np.ndarray, np.ndarray]:
    with np.load(SAMPLE) as z:
        assert tuple(str(b) for b in z["bone_names"]) == PRIOR_BONES
        return z["poses"].astype(np.float64), np.asarray([str(c) for c in z["clip"]])


def _random_poses_within_limits(body, n: int, seed: int) -> np.ndarray:  # noqa: ANN001
    """(n, len(PRIOR_BONES) * 3) poses uniform within the joint limits (local components
    clipped to +-1.5 rad), in the prior's representation."""
    from pipeline.backends.anny.body import bone_tails

    with torch.no_grad():
        c = body.shape_coeffs(torch.full((1, 6), 0.5, dtype=torch.float64))
        heads = body.rest_heads(c)[0].numpy()
        verts = body.rest_vertices(c)[0].numpy()
    frames, lo, hi = joint_limit_tables(
        body.bone_names, heads, bone_tails(body, heads, verts, body.vertex_bone)
    )
    idx = [body.bone_names.index(b) for b in PRIOR_BONES]
    rng = np.random.default_rng(seed)
    lo_c, hi_c = np.clip(lo[idx], -1.5, 1.5), np.clip(hi[idx], -1.5, 1.5)
    local = rng.uniform(lo_c, hi_c, size=(n, len(idx), 3))
    pose = np.einsum("bji,nbj->nbi", frames[idx], local)
    return pose.reshape(n, -1)


def test_shipped_prior_loads_with_metadata(body) -> None:  # noqa: ANN001
    assert BUILTIN_PRIOR.is_file() and BUILTIN_PRIOR.stat().st_size < 2_000_000
    prior = GMMPrior.load(BUILTIN_PRIOR)
    assert prior.rig == DEFAULT_RIG
    assert prior.bone_names == PRIOR_BONES
    assert set(PRIOR_BONES) <= set(body.bone_names)
    assert prior.dim == 3 * len(PRIOR_BONES)
    assert "walk" in prior.meta["source_clips"] and "zlib" in prior.meta["licence"]
    assert np.isclose(prior.weights.sum(), 1.0)
    bound = load_pose_prior("builtin", body.bone_names, DEFAULT_RIG)
    assert bound is not None and load_pose_prior("", body.bone_names) is None
    with pytest.raises(ValueError, match="rig"):
        load_pose_prior("builtin", body.bone_names, "some-other-rig")
    with pytest.raises(ValueError, match="not found"):
        load_pose_prior("/nonexistent/prior.npz", body.bone_names)


def test_held_out_clip_is_much_more_likely_than_random_poses(body, sample) -> None:  # noqa: ANN001
    poses, clip = sample
    held = np.char.startswith(clip.astype(str), HELD_OUT)
    assert held.sum() >= 20 and (~held).sum() > 500
    gmm = GMMPrior.fit(poses[~held], n_components=4, seed=0, reg=1e-3)
    nll_held = gmm.nll_numpy(poses[held])
    nll_rand = gmm.nll_numpy(_random_poses_within_limits(body, 500, seed=1))
    nll_train = gmm.nll_numpy(poses[~held])
    # held-out motion is a bit less likely than the training poses, far more than random ones
    assert np.median(nll_held) < np.median(nll_train) + 60
    assert np.median(nll_rand) > 10 * np.median(nll_held) + 100
    assert np.mean(nll_rand > np.percentile(nll_held, 95)) > 0.99
    # the shipped prior agrees
    shipped = GMMPrior.load(BUILTIN_PRIOR)
    assert np.median(shipped.nll_numpy(_random_poses_within_limits(body, 200, seed=2))) > 10 * np.median(
        shipped.nll_numpy(poses)
    )


def test_prior_gradient_is_finite(body, sample) -> None:  # noqa: ANN001
    prior = load_pose_prior("builtin", body.bone_names, DEFAULT_RIG)
    assert prior is not None
    rng = np.random.default_rng(0)
    full = torch.zeros(4, body.n_bones, 3, dtype=torch.float64)
    idx = [body.bone_names.index(b) for b in PRIOR_BONES]
    full[0, idx] = torch.as_tensor(sample[0][0].reshape(-1, 3))
    full[1, idx] = prior.means[0].reshape(-1, 3)  # exactly at a mode
    full[2:] = torch.as_tensor(rng.normal(0, 2.0, (2, body.n_bones, 3)))  # far away
    full.requires_grad_(True)
    nll = prior.pose_nll(full)
    nll.backward()
    assert torch.isfinite(nll) and torch.isfinite(full.grad).all()
    assert float(full.grad[3].norm()) > 0 and float(full.grad[3, 0].norm()) == 0.0  # root untouched
    # the float32 fit gets the same NLL per frame, computed in float32
    with torch.no_grad():
        per64 = prior.per_frame(full[:, prior._bone_index].reshape(4, -1))
        per32 = prior.per_frame(full.float()[:, prior._bone_index].reshape(4, -1))
    assert per32.dtype == torch.float32
    np.testing.assert_allclose(per32.double().numpy(), per64.numpy(), rtol=1e-4, atol=1e-3)


def _projections(n_views: int) -> np.ndarray:
    """(views, 3, 4) pixel projection matrices of cameras on a 6 m circle looking at the body."""
    from pipeline.geometry.rotations import look_at_T_world_cam

    K = np.array([[1100.0, 0, 640], [0, 1100.0, 360], [0, 0, 1]])
    out = []
    for i in range(n_views):
        a = 2 * np.pi * i / n_views + 0.4
        T = look_at_T_world_cam(np.array([6 * np.cos(a), 6 * np.sin(a), 2.5]), np.array([0.0, 0.0, 1.0]))
        out.append(K @ np.linalg.inv(T)[:3])
    return np.stack(out)


def test_fit_with_prior_not_worse_than_without(body) -> None:  # noqa: ANN001
    from dataclasses import replace

    from pipeline.backends.anny.fit import PersonObservations, fit_anny
    from pipeline.stages.fit_config import FitConfig
    from pipeline.synthetic.anny_motion import make_anny_motion

    motion = make_anny_motion(30, seed=3, body=body)
    rng = np.random.default_rng(0)
    gt = motion.keypoints_m
    nf, nj = gt.shape[:2]
    P = _projections(2)
    h = np.einsum("vij,fkj->vfki", P[:, :, :3], gt) + P[:, None, None, :, 3]
    uv = h[..., :2] / h[..., 2:] + rng.normal(0, 3.0, h[..., :2].shape)
    obs = PersonObservations(
        kp3d_m=gt + rng.normal(0, 0.03, gt.shape), w3d=np.ones((nf, nj)), uv_px=uv, w2d=np.ones((2, nf, nj))
    )
    base = FitConfig(pose_iters_3d=20, pose_iters=60)
    err = {}
    for name, cfg in (("with", base), ("without", replace(base, pose_prior_path=""))):
        out = fit_anny([obs], P, cfg, body=body)
        err[name] = float(np.linalg.norm(out.keypoints_m[:, 0] - gt, axis=-1).mean())
        assert ("prior" in out.loss_terms) == (name == "with")
    assert err["with"] <= err["without"] * 1.02 + 1e-4, err
    assert err["with"] < 0.03, err


@needs_pybullet
def test_deepmimic_keypoints_and_mirror() -> None:
    from pipeline.priors.build import clip_keypoints, load_clip, load_skeleton
    from pipeline.schema.joints import COCO17_FEET
    from pipeline.schema.joints import mirror_joints as mirror_keypoints

    kp = clip_keypoints(load_clip("walk"), load_skeleton())
    j = {n: COCO17_FEET.index(n) for n in COCO17_FEET}
    thigh = np.linalg.norm(kp[:, j["left_hip"]] - kp[:, j["left_knee"]], axis=-1)
    assert np.allclose(thigh, 0.4215, atol=1e-3)  # rigid DeepMimic segment, metres
    # z-up, facing -y, left on +x (our convention)
    assert (kp[:, j["nose"], 2] > kp[:, j["left_hip"], 2] + 0.4).all()
    assert (kp[:, j["left_hip"], 0] > kp[:, j["right_hip"], 0]).mean() > 0.9
    assert (kp[:, j["nose"], 1] < kp[:, j["left_ear"], 1]).mean() > 0.9
    m = mirror_keypoints(kp)
    assert np.allclose(m[:, j["right_knee"], 0], -kp[:, j["left_knee"], 0])
    assert np.allclose(mirror_keypoints(m), kp)


def test_build_without_pybullet_fails_clearly(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from pipeline.priors import build as prior_build

    real = importlib.util.find_spec
    monkeypatch.setattr(
        prior_build.importlib.util,
        "find_spec",
        lambda name, *a: None if name == "pybullet_data" else real(name, *a),
    )
    with pytest.raises(ImportError, match=r"pip install 'cornerman\[priors\]'"):
        prior_build.build_pose_prior(tmp_path / "prior.npz")


def test_prior_file_with_nan_is_refused(tmp_path: Path) -> None:
    """A corrupt prior (NaN means) names the file and the problem instead of NaN losses."""
    from pipeline.backends.anny.priors import GMMPrior

    path = tmp_path / "nan_prior.npz"
    d = 6
    np.savez(path, means=np.full((2, d), np.nan), precisions=np.tile(np.eye(d), (2, 1, 1)), weights=np.array([0.5, 0.5]))
    with pytest.raises(ValueError, match=r"nan_prior\.npz.*NaN"):
        GMMPrior.load(path)
