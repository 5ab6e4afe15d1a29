"""A person absent from the physics input (not yet in view) is simulated but not output:
its keypoints are invalid there, and the effort metrics and stats skip those samples."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("mujoco")

from pipeline.evaluate.effort import (  # noqa: E402
    force_balance_report,
    residual_per_frame,
    torque_limit_report,
    torque_ratio_per_frame,
)
from pipeline.stages.physics import PhysicsInputs, run  # noqa: E402
from tests.stages.test_physics import FAST, _facing_pair  # noqa: E402


def test_frames_without_input_are_not_output_nor_counted() -> None:
    kp = _facing_pair(1.5, n_frames=10)
    absent = np.zeros(kp.valid.shape[:2], dtype=bool)
    absent[:4, 1] = True  # person 1 enters at row 4
    kp = kp.replace(valid=kp.valid & ~absent[..., None], confidence=np.where(absent[..., None], 0.0, kp.confidence))
    out = run(PhysicsInputs(kp), FAST)
    np.testing.assert_array_equal(out.result.observed, ~absent)
    assert not out.keypoints.valid[:4, 1].any() and out.keypoints.valid[4:, 1].all() and out.keypoints.valid[:, 0].all()
    assert (out.keypoints.confidence[:4, 1] == 0).all()
    assert out.stats["observed_pct"] == pytest.approx(100.0 * 16 / 20)
    # The humanoid was simulated all along (its qpos moves in the absent frames too) ...
    assert np.isfinite(out.result.qpos).all()
    # ... and the residual statistic is the mean over the observed samples only.
    mass = np.array(out.stats["mass_kg"])
    r = np.linalg.norm(out.result.residual_root_force[..., :3], axis=-1) / (mass * 9.81)
    assert out.stats["residual_force_mean_frac_bw"] == pytest.approx(float(r[~absent].mean()), rel=1e-4)  # masses rounded
    assert r.mean() != pytest.approx(r[~absent].mean(), rel=1e-2)  # the mask made a difference


def test_effort_metrics_skip_unobserved_samples() -> None:
    mass = np.array([70.0, 50.0])
    names = ["p0_left_elbow", "p1_left_elbow"]
    tau = np.zeros((4, 2))
    tau[:, 1] = 10.0 * 50.0  # person 1's elbow far over its limit in every frame ...
    seen = np.ones((4, 2), dtype=bool)
    seen[:2, 1] = False  # ... but seen only in frames 2-3
    tau[2, 1] = 0.0
    every = torque_limit_report(tau, names, [0, 1], mass)
    masked = torque_limit_report(tau, names, [0, 1], mass, seen)
    assert every["torque_over_pct_any"] == pytest.approx(100.0 * 3 / 8)
    assert masked["torque_over_pct_any"] == pytest.approx(100.0 * 1 / 6)
    np.testing.assert_array_equal(torque_ratio_per_frame(tau, names, [0, 1], mass, seen) > 1.0, [False, False, False, True])
    wrench = np.zeros((4, 2, 6))
    wrench[:, 1, 2] = 50.0 * 9.81  # one body weight on person 1, who is unseen in frames 0-1
    wrench[2:, 1, 2] = 0.5 * 50.0 * 9.81
    grf = np.zeros((4, 2, 3))
    grf[:, :, 2] = mass * 9.81
    rep = force_balance_report(grf, wrench, mass, seen)
    assert rep["residual_max_frac_bw"] == pytest.approx(0.5)
    assert rep["residual_mean_frac_bw"] == pytest.approx(0.5 * 2 / 6)
    assert force_balance_report(grf, wrench, mass)["residual_max_frac_bw"] == pytest.approx(1.0)
    np.testing.assert_allclose(residual_per_frame(wrench, mass, seen), [0.0, 0.0, 0.5, 0.5])
    with pytest.raises(ValueError, match="observed mask"):
        force_balance_report(grf, wrench, mass, seen[:3])


def test_results_written_before_the_mask_read_as_observed() -> None:
    kp = _facing_pair(1.5, n_frames=6)
    res = run(PhysicsInputs(kp), FAST).result
    old = dataclasses.replace(res, observed=np.zeros((0, 0), dtype=bool))
    assert old.observed_mask().shape == (6, 2) and old.observed_mask().all()
    with pytest.raises(ValueError, match="observed"):
        dataclasses.replace(res, observed=np.ones((5, 2), dtype=bool))
