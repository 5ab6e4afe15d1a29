"""Physics stage on a short two-person clip built in code."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("mujoco")

from pipeline.backends.mujoco.config import ReferenceConfig  # noqa: E402
from pipeline.backends.mujoco.skeleton import _DEFAULT_LENGTHS, build_skeleton, rest_site_positions  # noqa: E402
from pipeline.evaluate.physics_metrics import inter_person_penetration_mm  # noqa: E402
from pipeline.schema.base import from_arrays, to_arrays  # noqa: E402
from pipeline.schema.joints import COCO17_FEET  # noqa: E402
from pipeline.schema.keypoints3d import Keypoints3D  # noqa: E402
from pipeline.schema.results import PhysicsResult  # noqa: E402
from pipeline.stages.physics import PhysicsConfig, PhysicsInputs, run  # noqa: E402

FAST = PhysicsConfig(solver={"window": 5, "commit": 3, "ilqr": {"max_iter": 2, "n_alpha": 3}})


def _facing_pair(gap_m: float, n_frames: int = 10) -> Keypoints3D:
    """Two upright persons facing each other, pelvis origins ``gap_m`` apart along x
    and 0.1 m apart along y (so that their feet interleave without overlapping),
    with a slow sway; at gap 0.18 m their torsos overlap by ~5 cm."""
    sk = build_skeleton(dict(_DEFAULT_LENGTHS))
    rs = rest_site_positions(sk)
    base = np.array([rs[n] for n in COCO17_FEET])
    base[:, 2] += sk.pelvis_height_m
    xyz = np.zeros((n_frames, 2, len(COCO17_FEET), 3))
    for f in range(n_frames):
        sway = 0.01 * np.sin(f / 5.0)
        xyz[f, 0] = base + [0.0, sway, 0.0]
        xyz[f, 1] = base @ np.diag([-1.0, -1.0, 1.0]) + [gap_m, 0.1 + sway, 0.0]
    F, J = n_frames, len(COCO17_FEET)
    return Keypoints3D(
        joint_names=COCO17_FEET,
        person_ids=np.array([0, 1]),
        frame_indices=np.arange(100, 100 + F),
        fps=50.0,
        xyz_m=xyz,
        valid=np.ones((F, 2, J), bool),
        confidence=np.ones((F, 2, J)),
        n_views=np.zeros((F, 2, J), np.int64),
        reproj_err_px=np.full((F, 2, J), np.nan),
        source="fit",
    )


def test_two_person_clip_ends_with_less_penetration() -> None:
    kp = _facing_pair(0.18)
    out = run(PhysicsInputs(kp), FAST)
    pen_in = inter_person_penetration_mm(kp)
    pen_out = inter_person_penetration_mm(out.keypoints)
    assert pen_in[-1] > 30.0
    assert pen_out[-1] < 0.5 * pen_in[-1]
    assert pen_out.mean() < pen_in.mean()
    # Outputs are complete and round-trip through the schema.
    res = out.result
    assert res.qpos.shape[0] == kp.n_frames and res.actuation == "pd"
    assert np.array_equal(res.frame_indices, kp.frame_indices)
    assert out.keypoints.source == "physics" and out.keypoints.joint_names == COCO17_FEET
    assert from_arrays(PhysicsResult, to_arrays(res)).qpos.shape == res.qpos.shape
    assert "<mujoco" in out.mjcf and out.stats["windows"] >= 3
    # Recorded contacts include both feet of both persons on the ground.
    ground = res.contact_person.min(axis=1) == -1
    assert ground.any() and set(res.contact_person[ground].max(axis=1).tolist()) == {0, 1}
    # Tracking the overlapping reference as it is (no separation first): the
    # simulation's contacts alone still push the two bodies apart.
    raw = run(PhysicsInputs(kp), dataclasses.replace(FAST, reference=ReferenceConfig(separate=False)))
    pen_raw = inter_person_penetration_mm(raw.keypoints)
    assert pen_raw[-1] < 0.5 * pen_in[-1]


def test_the_result_does_not_depend_on_the_blas_thread_count() -> None:
    """OpenBLAS sums a product's parts in another order on 2 threads than on 1, and the
    iLQR grows that rounding into another trajectory (a 150-frame bench bout: deepest
    overlap 25.6 against 6.3 mm), so the stage pins BLAS to one thread and restores it.
    This short clip happens to agree either way; the thread count seen inside the stage
    is what fails without the pin."""
    from threadpoolctl import threadpool_info, threadpool_limits

    def blas_threads() -> list[int]:
        return [int(i["num_threads"]) for i in threadpool_info() if i.get("user_api") == "blas"]

    kp = _facing_pair(0.18)
    with threadpool_limits(limits=1, user_api="blas"):
        one = run(PhysicsInputs(kp), FAST)  # also loads every BLAS the stage uses
    inside: list[int] = []
    with threadpool_limits(limits=2, user_api="blas"):
        before = blas_threads()
        two = run(PhysicsInputs(kp), FAST, progress=lambda d, n, m: inside.extend(blas_threads()))
        assert blas_threads() == before  # restored afterwards
    assert before and set(before) == {2}
    assert inside and set(inside) == {1}
    assert np.array_equal(two.result.qpos, one.result.qpos)
    assert np.array_equal(two.result.ctrl, one.result.ctrl)


def test_body_penetration_measures_overlap_of_the_humanoids() -> None:
    from pipeline.stages.physics import body_penetration_mm

    close, apart = _facing_pair(0.18, n_frames=4), _facing_pair(1.2, n_frames=4)
    pen_close = body_penetration_mm(close)
    assert pen_close.shape == (4,) and pen_close.min() > 20.0
    assert body_penetration_mm(apart).max() == 0.0
    # Scored in the bodies built from another motion: the same overlap.
    assert np.allclose(body_penetration_mm(close, body_keypoints=apart), pen_close, atol=2.0)
    # The physics output reports it for its own motion, which separates the pair.
    out = run(PhysicsInputs(close), FAST)
    assert out.stats["body_penetration_max_mm"] < 0.5 * pen_close.max()
    with pytest.raises(ValueError, match="two persons"):
        body_penetration_mm(close, person_ids=[0])
    with pytest.raises(ValueError, match=r"persons \[1\] are not in body_keypoints"):
        body_penetration_mm(close, body_keypoints=close.replace(person_ids=np.array([0, 7])))


def test_single_person_mode_and_config_checks() -> None:
    kp = _facing_pair(1.5, n_frames=6)
    out = run(PhysicsInputs(kp), PhysicsConfig(mode="single", solver={"window": 5, "commit": 3, "ilqr": {"max_iter": 1, "n_alpha": 2}}, residual={"mode": "off"}))
    assert out.stats["mode"] == "single" and out.stats["windows_with_residual"] == 0
    assert np.abs(out.result.residual_root_force).max() == 0.0
    # Far apart, standing still: the simulation stays close to the input.
    err = np.linalg.norm(out.keypoints.xyz_m - kp.xyz_m, axis=-1).mean()
    assert err < 0.05
    with pytest.raises(ValueError, match="commit"):
        PhysicsConfig(solver={"window": 4, "commit": 5})
    with pytest.raises(ValueError, match="ik_posture_weight"):
        PhysicsConfig(reference={"ik_posture_weight": -1.0})
    empty = kp.replace(valid=np.zeros_like(kp.valid))
    with pytest.raises(ValueError, match="no person"):
        run(PhysicsInputs(empty), FAST)


def test_a_floor_stiffer_than_two_steps_is_reported() -> None:
    from pipeline.stages.physics import floor_timeconst_warning

    assert floor_timeconst_warning(PhysicsConfig(), 60.0) is None  # 5 ms against 2 x 2.08 ms
    msg = floor_timeconst_warning(PhysicsConfig(humanoid={"substeps": 4}), 60.0)  # 2 x 4.17 ms > 5 ms
    assert msg is not None and "substeps >= 7" in msg and "0.00833" in msg
    assert floor_timeconst_warning(PhysicsConfig(), 25.0) is not None  # 2 x 5 ms at 25 fps
    assert floor_timeconst_warning(PhysicsConfig(humanoid={"floor_solref": (-5000.0, -100.0)}), 25.0) is None  # direct stiffness


def test_floor_settings_reach_the_mjcf_and_bad_ones_are_refused() -> None:
    from pipeline.schema.config_types import build_config

    where = "session.json: stage_config.physics"
    cfg = build_config(
        PhysicsConfig,
        {"humanoid": {"floor_solref": [0.03, 1.1], "floor_solimp": [0.8, 0.9, 0.002], "floor_margin_m": 0.003, "armature": 0.1, "floor_friction": 1.5}},
        where,
    )
    h = cfg.humanoid  # the object the scene builder takes, as given
    assert (h.floor_solref, h.floor_solimp, h.floor_margin_m, h.armature, h.floor_friction) == ((0.03, 1.1), (0.8, 0.9, 0.002), 0.003, 0.1, 1.5)
    with pytest.raises(ValueError, match="floor_friction must be > 0"):
        PhysicsConfig(humanoid={"floor_friction": 0.0})
    with pytest.raises(ValueError, match="floor_solref"):
        PhysicsConfig(humanoid={"floor_solref": (0.02,)})
    with pytest.raises(ValueError, match="floor_solimp"):
        PhysicsConfig(humanoid={"floor_solimp": (1.5, 0.9, 0.001)})
    with pytest.raises(ValueError, match="floor_margin_m"):
        PhysicsConfig(humanoid={"floor_margin_m": -0.01})
    # A wrong type from a Python caller names the field (it was a bare TypeError from "<").
    with pytest.raises(ValueError, match=r"HumanoidConfig\.floor_margin_m must be float, got '0\.01' \(str\)"):
        PhysicsConfig(humanoid={"floor_margin_m": "0.01"})
    with pytest.raises(ValueError, match=r"ILQRConfig\.jacobian_reuse must be int"):
        PhysicsConfig(solver={"ilqr": {"jacobian_reuse": 2.0}})
    with pytest.raises(ValueError, match="threads"):
        PhysicsConfig(solver={"ilqr": {"threads": -1}})
    # A flat key of the settings before they were nested says where it went.
    with pytest.raises(ValueError, match=r"w_pos is now stage_config\.physics\.solver\.weights\.w_pos"):
        build_config(PhysicsConfig, {"w_pos": 50.0}, where)
    with pytest.raises(ValueError, match=r"stage_config\.physics\.solver\.ilqr\.max_iter must be int"):
        build_config(PhysicsConfig, {"solver": {"ilqr": {"max_iter": "x"}}}, where)


def test_step_is_registered() -> None:
    from pipeline.runner.steps.physics import SPEC

    assert SPEC.name == "physics" and SPEC.deps == ("fit",)
    assert SPEC.config_cls is PhysicsConfig


class _FakeCtx:
    """The parts of ``StageContext`` the physics step uses (no files)."""

    def __init__(self, kp: Keypoints3D) -> None:
        self.kp = kp
        self.metrics: dict = {}
        self.events: list[tuple[float, float | None, str]] = []

    def has(self, stage: str, name: str) -> bool:
        return False

    def load(self, stage: str, name: str, cls: type) -> object:
        assert (stage, name, cls) == ("fit", "keypoints3d", Keypoints3D)
        return self.kp

    def progress(self, done: float, total: float | None = None, message: str = "") -> None:
        self.events.append((done, total, message))

    def reusable_previous(self, enabled: bool) -> None:
        self.metrics["incremental"] = "full run: no previous run"

    def reusable_with(self, enabled: bool, output: str, what: str) -> None:
        self.reusable_previous(enabled)


def test_step_execute_outputs_and_metrics() -> None:
    from pipeline.runner.steps.physics import SPEC

    ctx = _FakeCtx(_facing_pair(1.5, n_frames=8))
    outputs = SPEC.execute(ctx, PhysicsConfig(solver={"window": 5, "commit": 3, "ilqr": {"max_iter": 1, "n_alpha": 2}}))  # type: ignore[arg-type]
    assert set(outputs) == {"result", "keypoints3d", "scene.xml", "checkpoints"}
    assert isinstance(outputs["result"], PhysicsResult) and outputs["keypoints3d"].source == "physics"
    assert ctx.metrics["windows"] == 2 and ctx.metrics["realtime_factor"] > 0
    assert [e[0] for e in ctx.events] == [1, 2] and all(e[1] == 2 for e in ctx.events)


def test_a_window_that_diverges_even_from_the_reference_keeps_the_reference(monkeypatch: pytest.MonkeyPatch) -> None:
    """The job survives a window the simulation cannot run (it used to raise): those
    frames hold the separated reference, the stats count them, and later windows
    simulate again from there."""
    import pipeline.backends.mujoco.physics as mp

    real = mp._first_stable

    def diverge_at_frame_3(m, d, cost, qpos0, qvel0, inits, cfg, active, t0, warm, substeps, blocks=None):  # type: ignore[no-untyped-def]
        return None if t0 == 3 else real(m, d, cost, qpos0, qvel0, inits, cfg, active, t0, warm, substeps, blocks)

    monkeypatch.setattr(mp, "_first_stable", diverge_at_frame_3)
    kp = _facing_pair(0.4)
    out = run(PhysicsInputs(kp), FAST)
    assert out.stats["kinematic_frames"] == 3 and out.stats["resets"] == 1
    assert np.isfinite(out.result.qpos).all() and out.keypoints.n_frames == kp.n_frames
    # Frames 4-6 hold the reference: the keypoints follow the input closely there.
    err = np.linalg.norm(out.keypoints.xyz_m - kp.xyz_m, axis=-1).mean(axis=(1, 2))
    assert err[4:7].max() < 0.005  # the reference (IK of the input); simulated frames here are 7-10 mm off
    assert out.stats["windows"] >= 3


def test_standing_still_stays_still() -> None:
    """A person standing still (rest pose, 1 mm keypoint noise): the simulated joints stay
    nearly still and the planted feet do not slide. The servo schedule's feed-forward uses
    smoothed accelerations: unsmoothed, the twice-differentiated noise of the reference
    shook the body (measured 0.56 rad/s RMS and 0.7 mm/frame of foot sliding, against
    0.18 and 0.12-0.15 with the default smoothing)."""
    from tests.backends.test_humanoid import _rest_keypoints

    kp = _rest_keypoints(1.0, n_frames=60).replace(fps=60.0)

    def shake(cfg: PhysicsConfig) -> tuple[float, float]:
        out = run(PhysicsInputs(kp), cfg)
        names = out.keypoints.joint_names
        slide = []
        for side in ("left", "right"):
            idx = [names.index(f"{side}_{n}") for n in ("heel", "big_toe", "small_toe")]
            xy = out.keypoints.xyz_m[:, 0, idx, :2].mean(axis=1)
            slide.append(float(np.linalg.norm(np.diff(xy, axis=0), axis=1).mean()))
        return float(np.sqrt(np.mean(out.result.qvel**2))), 1000.0 * max(slide)

    rms, slide_mm = shake(PhysicsConfig(skeleton="keypoints"))
    rms_raw, slide_raw_mm = shake(PhysicsConfig(skeleton="keypoints", reference={"feedforward_smooth_frames": 0.0}))
    assert rms < 0.3 and slide_mm < 0.3
    assert rms_raw > 1.5 * rms and slide_raw_mm > 2.0 * slide_mm


def test_reference_balance_reaches_the_stage() -> None:
    """``reference.balance = "zmp"`` goes from the stage config to the reference: with the
    upper body shaken fore and aft over still feet (the zero-moment point far outside the
    feet), the balanced reference, and so the tracked motion, differs from the plain one."""
    kp = _facing_pair(1.5, n_frames=8)
    xyz = kp.xyz_m.copy()
    upper = xyz[..., 2] > 0.5
    shake = 0.04 * np.sin(np.arange(8) * 2 * np.pi / 6)[:, None, None]
    xyz[..., 0] += np.where(upper, shake, 0.0)
    kp = kp.replace(xyz_m=xyz)
    cfg = {"mode": "single", "solver": {"window": 5, "commit": 3, "ilqr": {"max_iter": 1, "n_alpha": 2}}}
    plain = run(PhysicsInputs(kp), PhysicsConfig(**cfg))
    balanced = run(PhysicsInputs(kp), PhysicsConfig(**cfg, reference={"balance": "zmp"}))
    moved = np.linalg.norm(balanced.keypoints.xyz_m - plain.keypoints.xyz_m, axis=-1).max()
    assert moved > 1e-3
