"""Stage ``fit``: recovery of a known anny body, robustness to an outlier view, SMPL errors.

Ground truth comes from anny itself (``make_anny_motion``), so a noise-free fit can be exact.
The anny model is built once per process (``anny_body`` cache; ~2 s with a warm cache).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.geometry import project
from pipeline.schema import COCO17_FEET, Association, CameraRig, Keypoints3D, Tracks2D
from pipeline.stages.fit import FitConfig, FitResult, gather_inputs, run
from tests.conftest import fit_stage_inputs, make_rig

pytest.importorskip("torch")
pytest.importorskip("anny")

from pipeline.backends.anny.fk import forward_kinematics  # noqa: E402
from pipeline.backends.anny.model import anny_body  # noqa: E402
from pipeline.synthetic.anny_motion import AnnyMotion, make_anny_motion  # noqa: E402

FPS = 50.0


def _rig(n_views: int = 4) -> CameraRig:
    return make_rig(n_views, fps=FPS, phase_rad=0.4)


def _inputs(
    rig: CameraRig, motions: list[AnnyMotion], noise_3d_m: float = 0.0, noise_px: float = 0.0, seed: int = 0
) -> tuple[Keypoints3D, Tracks2D, Association]:
    xyz = np.stack([m.keypoints_m for m in motions], axis=1)  # (F, P, J, 3)
    return fit_stage_inputs(rig, xyz, FPS, noise_3d_m, noise_px, seed)


@pytest.fixture(scope="session")
def motion() -> AnnyMotion:
    return make_anny_motion(12, fps=FPS, seed=3)


def _joint_centres(shape: np.ndarray, pose: np.ndarray, root: np.ndarray) -> np.ndarray:
    import torch

    body = anny_body()
    with torch.no_grad():
        coeffs = body.shape_coeffs(torch.as_tensor(shape, dtype=torch.float64)[None])
        heads = body.rest_heads(coeffs)
        _, x = forward_kinematics(body, torch.as_tensor(pose), torch.as_tensor(root), heads)
    return x.numpy()


def test_recovers_known_shape_and_pose_from_clean_keypoints(motion: AnnyMotion) -> None:
    rig = _rig(4)
    kp3d, tracks, assoc = _inputs(rig, [motion])
    # regularisers (which bias a fit of exact data) nearly off
    cfg = FitConfig(
        calibrate_landmarks=False, w_accel=0.0, w_smooth=1e-6, w_reg=1e-5, shape_iters=100, pose_iters=150,
        girth_prior_weight=1e-4,
    )
    res = run(kp3d, tracks, assoc, rig, cfg)
    assert isinstance(res, FitResult)
    fit = res.keypoints3d
    assert fit.source == "fit" and fit.valid.all()
    err = np.linalg.norm(fit.xyz_m[:, 0] - motion.keypoints_m, axis=-1)
    assert err.mean() < 0.004 and err.max() < 0.015
    # the skeleton itself (joint centres of every bone, i.e. shape and pose) is recovered
    bf = res.bodyfit
    got = _joint_centres(bf.shape[0], bf.pose[:, 0], bf.root_translation_m[:, 0])
    want = _joint_centres(motion.shape, motion.pose_aa, motion.root_m)
    assert np.linalg.norm(got - want, axis=-1).mean() < 0.01
    assert np.abs(bf.root_translation_m[:, 0] - motion.root_m).max() < 0.02
    assert res.metrics["reproj_median_px"] < 2.0 and res.metrics["reproj_p95_px"] < 5.0


def test_shape_keeps_girth_near_its_prior(motion: AnnyMotion) -> None:
    """Bone lengths do not tell girth: muscle and weight stay at ``girth_prior`` while the
    length-giving phenotypes fit the limbs (free, they ran to their bounds: an obese body)."""
    from pipeline.backends.anny.fit_init import fit_shapes
    from pipeline.backends.anny.model import PHENOTYPE_LABELS
    from pipeline.backends.fitting.common import PersonObservations

    obs = PersonObservations(
        kp3d_m=motion.keypoints_m, w3d=np.ones(motion.keypoints_m.shape[:2]),
        uv_px=np.zeros((0, *motion.keypoints_m.shape[:2], 2)), w2d=np.zeros((0, *motion.keypoints_m.shape[:2])),
    )
    girth = [PHENOTYPE_LABELS.index("muscle"), PHENOTYPE_LABELS.index("weight")]
    for prior in ((0.5, 0.5), (0.8, 0.3)):
        shape = fit_shapes(anny_body(), [obs], FitConfig(girth_prior=prior)).numpy()[0]
        np.testing.assert_allclose(shape[girth], prior, atol=0.03)
        got = _joint_centres(shape, motion.pose_aa[:1], motion.root_m[:1])
        want = _joint_centres(motion.shape, motion.pose_aa[:1], motion.root_m[:1])
        assert np.linalg.norm(got - want, axis=-1).mean() < 0.02  # the skeleton still fits
    free = fit_shapes(anny_body(), [obs], FitConfig(girth_prior_weight=0.0)).numpy()[0]
    assert np.abs(free[girth] - 0.5).max() > 0.05  # without the prior, girth moves off it


def test_robust_loss_ignores_an_outlier_view(motion: AnnyMotion) -> None:
    rig = _rig(4)
    kp3d, tracks, assoc = _inputs(rig, [motion], noise_3d_m=0.03, seed=1)
    bad = tracks.view == 2
    kp = tracks.keypoints_px.copy()
    kp[bad] += np.array([90.0, -60.0])  # a whole view shifted: e.g. a wrong calibration
    shifted = Tracks2D(**{**tracks.__dict__, "keypoints_px": kp})
    errors = {}
    # The kernel alone (the whole-view rejection off), then with it (the default).
    for name, trk, robust, frac in (
        ("clean", tracks, "gm", 0.0),
        ("gm", shifted, "gm", 0.0),
        ("l2", shifted, "l2", 0.0),
        ("l2 + view rejection", shifted, "l2", FitConfig().outlier_view_frac),
    ):
        cfg = FitConfig(robust_2d=robust, gm_sigma_px=20.0, outlier_view_frac=frac)
        res = run(kp3d, trk, assoc, rig, cfg)
        errors[name] = float(np.linalg.norm(res.keypoints3d.xyz_m[:, 0] - motion.keypoints_m, axis=-1).mean())
    assert errors["clean"] < 0.01
    assert errors["gm"] < errors["clean"] + 0.003  # the bad view is (nearly) ignored
    assert errors["l2"] > 5 * errors["gm"]  # a plain squared loss is dragged by it
    assert errors["l2 + view rejection"] < errors["clean"] + 0.003  # ... unless the view is rejected


def test_gather_inputs_maps_views_persons_and_threshold(motion: AnnyMotion) -> None:
    rig = _rig(3)
    kp3d, tracks, assoc = _inputs(rig, [motion, motion])
    conf = tracks.keypoint_conf.copy()
    conf[:, COCO17_FEET.index("nose")] = 0.5  # below the paper's 0.7
    tracks = Tracks2D(**{**tracks.__dict__, "keypoint_conf": conf})
    inp = gather_inputs(kp3d, tracks, assoc, rig, FitConfig())
    assert len(inp) == 2 and inp[1].uv_px.shape == (3, 12, 23, 2)
    uv, _ = project(rig, motion.keypoints_m)
    np.testing.assert_allclose(inp[1].uv_px[:, :, 1:], uv[:, :, 1:], atol=1e-9)
    assert np.all(inp[0].w2d[:, :, COCO17_FEET.index("nose")] == 0)
    assert np.all(inp[0].w2d[:, :, 1:] == pytest.approx(0.95))


def test_a_detection_the_other_views_disagree_with_is_left_out(motion: AnnyMotion) -> None:
    rig = _rig(3)
    kp3d, tracks, assoc = _inputs(rig, [motion, motion])
    h = tracks.bbox_xyxy_px[:, 3] - tracks.bbox_xyxy_px[:, 1]
    kp = tracks.keypoints_px.copy()
    bad = (tracks.frame == 4) & (tracks.view == 1) & (tracks.track_id == 0)
    near = (tracks.frame == 6) & (tracks.view == 2) & (tracks.track_id == 0)
    kp[bad] += 0.2 * h[bad, None, None]  # a failed pose: 20 % of the person's height off
    kp[near] += 0.01 * h[near, None, None]  # noise
    tracks = Tracks2D(**{**tracks.__dict__, "keypoints_px": kp})
    inp = gather_inputs(kp3d, tracks, assoc, rig, FitConfig())
    assert np.all(inp[0].w2d[1, 4] == 0) and np.all(inp[0].w2d[2, 6] > 0)
    assert np.all(inp[0].w2d[0, 4] > 0)  # the other views of that frame stay
    kept = gather_inputs(kp3d, tracks, assoc, rig, FitConfig(outlier_view_frac=0.0))
    assert np.all(kept[0].w2d[1, 4] > 0)
    with pytest.raises(ValueError, match="outlier_view_frac"):
        FitConfig(outlier_view_frac=1.0)


def test_missing_person_frames_are_marked_invalid(motion: AnnyMotion) -> None:
    rig = _rig(3)
    kp3d, tracks, assoc = _inputs(rig, [motion])
    valid = kp3d.valid.copy()
    valid[4:6] = False
    kp3d = kp3d.replace(valid=valid)
    res = run(kp3d, tracks, assoc, rig, FitConfig(pose_iters=20, pose_iters_3d=20))
    assert not res.bodyfit.valid[4:6, 0].any() and res.bodyfit.valid[:4, 0].all()
    assert np.all(np.isfinite(res.bodyfit.pose)) and np.all(
        np.isfinite(res.keypoints3d.xyz_m[res.keypoints3d.valid])
    )


@pytest.mark.parametrize("model", ["smpl", "smplx"])
def test_smpl_path_errors_clearly_without_files(model: str, tmp_path: Path, motion: AnnyMotion) -> None:
    rig = _rig(2)
    kp3d, tracks, assoc = _inputs(rig, [motion])
    with pytest.raises(ValueError, match="body-model-path"):
        run(kp3d, tracks, assoc, rig, FitConfig(body_model=model))
    expected = "SMPL_NEUTRAL.pkl" if model == "smpl" else "SMPLX_NEUTRAL.npz"
    with pytest.raises(ValueError, match=expected):
        run(kp3d, tracks, assoc, rig, FitConfig(body_model=model, body_model_path=str(tmp_path)))
    with pytest.raises(ValueError, match="not a folder"):
        run(kp3d, tracks, assoc, rig, FitConfig(body_model=model, body_model_path=str(tmp_path / "nope")))


def test_config_validation() -> None:
    with pytest.raises(ValueError, match="w_2d"):
        FitConfig(w_2d=-1.0)
    with pytest.raises(ValueError, match="min_conf_2d"):
        FitConfig(min_conf_2d=1.5)
    with pytest.raises(ValueError, match="precision"):
        FitConfig(precision="float16")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="accel_whole_body"):
        FitConfig(accel_whole_body=-0.1)
    with pytest.raises(ValueError, match="accel_adapt_after"):
        FitConfig(accel_adapt_after=-1)
    with pytest.raises(ValueError, match="accel_adapt_scale_m"):
        FitConfig(accel_adapt_scale_m=0.0)
    with pytest.raises(ValueError, match="landmark_step must be positive, got nan"):
        FitConfig(landmark_step=float("nan"))
    with pytest.raises(ValueError, match=r"girth_prior must be \(muscle, weight\) in \[0, 1\]"):
        FitConfig(girth_prior=(0.5, 1.5))
    with pytest.raises(ValueError, match="girth_prior_weight must be >= 0, got nan"):
        FitConfig(girth_prior_weight=float("nan"))
    with pytest.raises(ValueError, match="w_jerk must be >= 0, got nan"):
        FitConfig(w_jerk=float("nan"))
    with pytest.raises(ValueError, match="w_jerk must be >= 0, got -1"):
        FitConfig(w_jerk=-1.0)
    # session.json values arrive untyped: a wrong type is refused with the field named
    with pytest.raises(ValueError, match=r"accel_adapt_after must be int, got '100' \(str\)"):
        FitConfig(accel_adapt_after="100")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="use_2d must be bool"):
        FitConfig(use_2d=1)  # type: ignore[arg-type]
    assert FitConfig(w_accel=500).w_accel == 500  # an int where a float is expected is fine
    assert FitConfig(pose_iters=np.int64(20)).pose_iters == 20  # and numpy integers


def test_accel_term_splits_whole_body_and_relative_acceleration() -> None:
    import torch

    from pipeline.backends.fitting.terms import FOOT_KEYPOINTS, accel_term

    assert [COCO17_FEET[i] for i in FOOT_KEYPOINTS] == [
        "left_ankle", "right_ankle", "left_big_toe", "left_small_toe", "left_heel",
        "right_big_toe", "right_small_toe", "right_heel",
    ]  # fmt: skip
    nj, nb = len(COCO17_FEET), len(COCO17_FEET) - len(FOOT_KEYPOINTS)
    t = torch.arange(6, dtype=torch.float64)
    base = torch.tensor(np.random.default_rng(0).normal(size=(1, 1, nj, 3))).repeat(1, 6, 1, 1)

    def moved(joints: list[int], axis: int) -> torch.Tensor:
        """``joints`` accelerate by 2 cm per frame² along ``axis`` (4 second differences)."""
        x = base.clone()
        x[0, :, joints, axis] += 0.01 * t[:, None] ** 2
        return x

    a2 = 0.02**2
    # The whole body accelerating: the part above the feet costs whole_body x its plain
    # sum, the feet their plain sum (a planted foot is not part of a weight shift).
    whole = moved(list(range(nj)), 0)
    for lam in (1.0, 0.3, 0.0):
        assert float(accel_term(whole, 0.0, lam)) == pytest.approx(4 * a2 * (lam * nb + len(FOOT_KEYPOINTS)))
    # One wrist alone: its acceleration relative to the body mean in full, the mean's share
    # weighted; whole_body = 1 gives the plain cost.
    wrist = COCO17_FEET.index("left_wrist")
    a = np.zeros((nb, 3))
    a[wrist, 1] = 0.02
    rel, mean2 = ((a - a.mean(0)) ** 2).sum(), nb * (a.mean(0) ** 2).sum()
    assert float(accel_term(moved([wrist], 1), 0.0, 0.3)) == pytest.approx(4 * (rel + 0.3 * mean2))
    assert float(accel_term(moved([wrist], 1), 0.0, 1.0)) == pytest.approx(4 * a2)
    # A heel alone: plain, whatever whole_body.
    heel = COCO17_FEET.index("left_heel")
    for lam in (1.0, 0.3):
        assert float(accel_term(moved([heel], 2), 0.0, lam)) == pytest.approx(4 * a2)


def test_adaptive_accel_weights_follow_local_acceleration() -> None:
    """Weights are gain at rest and gain * s^2 / (s^2 + m^2) where the keypoint accelerates,
    m the RMS acceleration over the window; they replace the pseudo-Huber in accel_term."""
    import torch

    from pipeline.backends.fitting.common import adaptive_accel_weights
    from pipeline.backends.fitting.terms import accel_term

    nj, nf = len(COCO17_FEET), 12
    x = torch.zeros(2, nf, nj, 3, dtype=torch.float64)
    x[:, :, :, 0] = 0.01 * torch.arange(nf, dtype=torch.float64)[None, :, None]  # constant velocity
    wrist = COCO17_FEET.index("right_wrist")
    x[1, 6, wrist, 2] += 0.01  # one frame off by 1 cm: second differences +1, -2, +1 cm
    s, gain = 0.002, 4.0
    w0 = adaptive_accel_weights(x, s, 0, gain)
    w1 = adaptive_accel_weights(x, s, 1, gain)
    assert w0.shape == (2, nf - 2, nj)
    assert torch.allclose(w0[0], torch.full_like(w0[0], gain))  # person 0 never accelerates
    # Person 1's wrist: second differences at frames 5, 6, 7 (rows 4, 5, 6) are 1, 2, 1 cm.
    m2 = torch.tensor([0.01, 0.02, 0.01], dtype=torch.float64) ** 2
    assert torch.allclose(w0[1, 4:7, wrist], gain * s**2 / (s**2 + m2))
    assert float(w0[1, 3, wrist]) == pytest.approx(gain) and float(w0[1, 7, wrist]) == pytest.approx(gain)
    # Window 1: frame 4 (row 3) sees (0 + 0 + 1 cm^2) / 3 from its neighbours.
    assert float(w1[1, 3, wrist]) == pytest.approx(gain * s**2 / (s**2 + 0.01**2 / 3))
    assert float(w1[1, 2, wrist]) == pytest.approx(gain)
    # In accel_term: unit weights are the plain squared penalty; a zero weight drops a term.
    ones = torch.ones(2, nf - 2, nj, dtype=torch.float64)
    assert float(accel_term(x, 0.005, 1.0, ones)) == pytest.approx(float(accel_term(x, 0.0, 1.0)))
    assert float(accel_term(x, 0.0, 1.0)) == pytest.approx(6 * 0.01**2)
    drop = ones.clone()
    drop[1, 5, wrist] = 0.0  # the wrist's own (split) term at its 2 cm second difference
    nb = nj - 8
    wrist_term = (0.02 * (1 - 1 / nb)) ** 2 + (0.02 / nb) ** 2
    assert float(accel_term(x, 0.0, 1.0, drop)) == pytest.approx(6 * 0.01**2 - wrist_term)
    with pytest.raises(ValueError, match="weights of shape"):
        accel_term(x, 0.0, 1.0, ones[:, 1:])


def test_pose_passes_reweight_after_the_configured_iterations(monkeypatch: pytest.MonkeyPatch) -> None:
    """run_pose_passes runs the full loss unweighted for accel_adapt_after iterations, then
    with weights from the motion so far; 0 keeps the pseudo-Huber throughout."""
    import torch

    import pipeline.backends.fitting.common as fc
    from pipeline.backends.fitting.common import run_pose_passes
    from pipeline.backends.fitting.terms import accel_term

    budgets: list[int] = []  # iteration budget of every L-BFGS run
    real_lbfgs = fc.run_lbfgs
    monkeypatch.setattr(fc, "run_lbfgs", lambda p, c, iters, cfg: (budgets.append(iters), real_lbfgs(p, c, iters, cfg)))
    nf, nj = 20, len(COCO17_FEET)
    rng = np.random.default_rng(0)
    target = torch.tensor(rng.normal(scale=0.01, size=(1, nf, nj, 3)))
    calls: list[bool] = []

    def fit(cfg: FitConfig) -> tuple[torch.Tensor | None, torch.Tensor]:
        calls.clear()
        budgets.clear()
        x = torch.zeros(nf, nj, 3, dtype=torch.float64, requires_grad=True)

        def evaluate(use_2d: bool, w: torch.Tensor | None) -> tuple[torch.Tensor, dict, torch.Tensor]:
            calls.append(w is not None)
            acc = accel_term(x[None], cfg.accel_scale_m, 1.0, w)
            loss = (x - target[0]).square().sum() + cfg.w_accel * acc
            return loss, {}, x

        return run_pose_passes([x], evaluate, cfg, 1, nf), x.detach()

    w, x_adapt = fit(FitConfig(pose_iters_3d=2, pose_iters=10, accel_adapt_after=4, w_accel=1.0))
    assert w is not None and w.shape == (1, nf - 2, nj) and calls.count(True) > 0
    assert not any(calls[: calls.index(True)]) and all(calls[calls.index(True) :])
    assert budgets == [2, 4, 6]
    w, x_plain = fit(FitConfig(pose_iters_3d=2, pose_iters=10, accel_adapt_after=0, w_accel=1.0))
    assert w is None and not any(calls) and budgets == [2, 10]
    assert not torch.allclose(x_adapt, x_plain)
    # Without an acceleration penalty nothing is re-weighted, and every iteration still runs.
    w, x_free = fit(FitConfig(pose_iters_3d=0, pose_iters=10, accel_adapt_after=4, w_accel=0.0))
    assert w is None and not any(calls) and budgets == [0, 10]
    assert torch.allclose(x_free, target[0], atol=1e-6)


def test_float32_fit_matches_float64(motion: AnnyMotion) -> None:
    """The default float32 fit gives the float64 fit's joints and shape; outputs stay float64."""
    import torch

    rig = _rig(4)
    kp3d, tracks, assoc = _inputs(rig, [motion], noise_3d_m=0.01, noise_px=2.0, seed=2)
    res = {p: run(kp3d, tracks, assoc, rig, FitConfig(precision=p)) for p in ("float32", "float64")}
    a, b = res["float32"], res["float64"]
    assert a.keypoints3d.xyz_m.dtype == np.float64 and a.bodyfit.pose.dtype == np.float64
    diff = np.linalg.norm(a.keypoints3d.xyz_m - b.keypoints3d.xyz_m, axis=-1)
    # metres; measured 0.55 / 2.0 mm (0.22 / 0.9 mm with accel_whole_body=1, whose stiffer
    # whole-body term leaves float32 rounding less room), against a 5.4 mm error to the truth
    assert diff.mean() < 1e-3 and diff.max() < 5e-3
    # the skeletons agree (phenotypes themselves are weakly observed from 12 frames of keypoints)
    centres = [
        _joint_centres(r.bodyfit.shape[0], r.bodyfit.pose[:, 0], r.bodyfit.root_translation_m[:, 0]) for r in (a, b)
    ]
    assert np.linalg.norm(centres[0] - centres[1], axis=-1).mean() < 3e-3
    err = {p: float(np.linalg.norm(r.keypoints3d.xyz_m[:, 0] - motion.keypoints_m, axis=-1).mean()) for p, r in res.items()}
    assert abs(err["float32"] - err["float64"]) < 5e-4
    # the float32 body is a converted copy: same keypoints to float32 rounding
    body = anny_body()
    b32 = body.to(torch.float32)
    assert b32.dtype == torch.float32 and body.dtype == torch.float64 and body.to(torch.float64) is body
    shape = torch.full((1, 6), 0.5)
    k64 = body.rest_kp_points(body.shape_coeffs(shape.double()))
    k32 = b32.rest_kp_points(b32.shape_coeffs(shape))
    assert float((k64 - k32.double()).abs().max()) < 1e-5


@pytest.mark.slow
def test_fit_step_runs_in_the_runner(tmp_path: Path) -> None:
    from pipeline.runner.core import run as run_session
    from pipeline.schema import BodyFit, load_npz
    from pipeline.synthetic import SyntheticConfig, make_demo_session

    session = tmp_path / "bout"
    make_demo_session(session, SyntheticConfig(n_frames=30, n_cameras=3, seed=2))
    run_session(session, to_stage="fit")
    fit = load_npz(session / "artifacts" / "fit" / "bodyfit.npz", BodyFit)
    kp = load_npz(session / "artifacts" / "fit" / "keypoints3d.npz", Keypoints3D)
    assert fit.body_model == "anny" and fit.pose.shape == (30, 2, len(fit.bone_names), 3)
    assert kp.source == "fit" and kp.valid.mean() > 0.9
    tri = load_npz(session / "artifacts" / "triangulate" / "keypoints3d.npz", Keypoints3D)
    ok = kp.valid & tri.valid
    assert np.linalg.norm(kp.xyz_m - tri.xyz_m, axis=-1)[ok].mean() < 0.05


def test_user_pose_prior_is_loaded_and_used(tmp_path: Path, motion: AnnyMotion) -> None:
    from pipeline.backends.anny.priors import pose_prior_from_poses

    more = make_anny_motion(60, fps=FPS, seed=5)
    prior = pose_prior_from_poses(more.pose_aa[:, None], np.ones((60, 1), dtype=bool), n_components=2)
    prior.save(tmp_path / "prior.npz")
    rig = _rig(3)
    kp3d, tracks, assoc = _inputs(rig, [motion])
    res = run(kp3d, tracks, assoc, rig, FitConfig(pose_prior_path=str(tmp_path / "prior.npz"), pose_iters=20))
    assert "loss_prior" in res.metrics and np.isfinite(res.metrics["loss_prior"])
    with pytest.raises(ValueError, match="GMM"):
        run(kp3d, tracks, assoc, rig, FitConfig(pose_prior_path=str(tmp_path / "missing.npz")))


def test_jerk_term_weights_third_differences_and_acts_only_when_reweighted() -> None:
    """jerk_term: squared third differences, each weighted by the smaller of the two
    acceleration weights it spans; zero for constant acceleration. The ``Jerk`` loss term
    applies only with re-weighted acceleration weights (after ``accel_adapt_after``)."""
    import torch

    from pipeline.backends.fitting.body_model import FitState, Rest, Skeleton
    from pipeline.backends.fitting.terms import Targets, TermContext, build_terms, evaluate_terms, jerk_term

    nj, nf = len(COCO17_FEET), 8
    t = torch.arange(nf, dtype=torch.float64)
    x = torch.zeros(2, nf, nj, 3, dtype=torch.float64)
    x[0, :, :, 0] = 0.01 * t[:, None] ** 2  # constant acceleration: no jerk
    wrist = COCO17_FEET.index("left_wrist")
    x[1, :, wrist, 1] = 0.001 * t**3  # third difference 6 mm at every frame
    ones = torch.ones(2, nf - 2, nj, dtype=torch.float64)
    assert float(jerk_term(x[:1], ones[:1])) == pytest.approx(0.0, abs=1e-18)
    assert float(jerk_term(x, ones)) == pytest.approx((nf - 3) * 0.006**2)
    w = ones.clone()
    w[1, 2, wrist] = 0.25  # rows 1-2 and 2-3 of the jerk take the smaller weight
    w[1, 4, wrist] = 4.0  # a larger neighbour does not raise a term
    expect = (nf - 3 - 2) * 0.006**2 + 2 * 0.25 * 0.006**2
    assert float(jerk_term(x, w)) == pytest.approx(expect)
    with pytest.raises(ValueError, match="jerk_term: weights of shape"):
        jerk_term(x, ones[:, 1:])

    n = 2 * nf
    kp = x.reshape(n, nj, 3)
    z = torch.zeros(n, 4, 3, dtype=torch.float64)
    targets = Targets(
        kp, torch.ones(n, nj, dtype=torch.float64), torch.zeros(1, n, nj, 2), torch.zeros(1, n, nj),
        torch.zeros(1, 3, 4), torch.ones(2, nf, dtype=torch.bool), n_persons=2, n_frames=nf,
    )

    def state(weights: torch.Tensor | None) -> FitState:
        G = torch.eye(3, dtype=torch.float64).expand(n, 4, 3, 3)
        sk = Skeleton(G, z, kp)
        return FitState(z[:, :3], G[:, 0], z, z[:, 0], Rest(z), sk, kp, z[:2], z[:2, 0], True, weights)

    cfg = FitConfig(w_jerk=10.0, w_accel=0.0, w_2d=0.0, w_smooth=0.0)
    (jerk,) = build_terms(("jerk",), TermContext(cfg, None, targets))  # type: ignore[arg-type]
    assert "jerk" not in evaluate_terms([jerk], state(None))
    assert float(evaluate_terms([jerk], state(w))["jerk"]) == pytest.approx(10.0 * expect)
    off = FitConfig(w_jerk=0.0, w_accel=0.0, w_2d=0.0, w_smooth=0.0)
    assert build_terms(("jerk",), TermContext(off, None, targets)) == []  # type: ignore[arg-type]


def test_temporal_weights_follow_the_frame_rate() -> None:
    """The same motion costs the same at any frame rate: a k-th difference of a sampled
    motion scales as fps^-k, so the weights scale as fps^(2k) and the robust scales as fps^-k."""
    from pipeline.backends.fitting.terms import accel_term

    torch = pytest.importorskip("torch")
    cfg = FitConfig(accel_whole_body=1.0)
    assert cfg.at_rate(cfg.reference_fps) is cfg
    for fps in (25.0, 60.0):
        c = cfg.at_rate(fps)
        r = fps / cfg.reference_fps
        assert c.w_accel == pytest.approx(cfg.w_accel * r**4) and c.w_jerk == pytest.approx(cfg.w_jerk * r**6)
        assert c.w_smooth == pytest.approx(cfg.w_smooth * r**2)
        assert c.accel_scale_m == pytest.approx(cfg.accel_scale_m / r**2)
        # A 3 m/s^2 oscillation sampled at 50 fps and at ``fps``: the per-frame acceleration
        # penalty, summed over one second, is the same once the weights are converted
        # (per-frame sums scale with the number of frames, as the data terms do).
        def per_second(rate: float, conf: FitConfig) -> float:
            t = np.arange(int(rate)) / rate
            x = np.zeros((1, t.size, 1, 3))
            x[0, :, 0, 0] = 3.0 / (2 * np.pi) ** 2 * np.sin(2 * np.pi * t)
            kp = torch.tensor(x, dtype=torch.float64)
            return float(conf.w_accel * accel_term(kp, conf.accel_scale_m, 1.0, None)) / t.size

        assert per_second(fps, c) == pytest.approx(per_second(cfg.reference_fps, cfg), rel=0.05)
    with pytest.raises(ValueError, match="fps must be positive"):
        cfg.at_rate(0.0)
