"""The evaluate step on a session whose physics stage ran (the real, cheap physics of
``tests/io/export``): problems.npz gets the residual and torque columns and metrics.json
their counts, from the physics result and its scene's masses and actuators."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.artifacts import ArtifactStore, Manifest
from pipeline.backends.mujoco.forces import actuator_names, body_masses_kg
from pipeline.evaluate.effort import GRAVITY, torque_limit_report
from pipeline.runner import run
from pipeline.runner.spec import StageContext
from pipeline.runner.steps.evaluate import SPEC
from pipeline.schema import SessionConfig
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import PhysicsResult
from pipeline.stages.evaluate import FLAG_KINDS, EvaluateConfig, ProblemFlags
from tests.conftest import write_tiny_session
from tests.io.export.export_session import FIRST_FRAME, write_export_artifacts

SPIKE_ROW = 3
"""Physics row given a residual of 0.2 body weights on person 1 (all other rows: none)."""


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    stages = ("detect2d", "track", "associate", "triangulate", "fit", "physics", "evaluate")
    s = write_tiny_session(tmp_path_factory.mktemp("effort") / "s", stages=stages)
    run(s, to_stage="triangulate")
    write_export_artifacts(s, n_frames=8)
    store = ArtifactStore(s)
    xml = store.path("physics", "scene.xml").read_text()
    res = store.load("physics", "result", PhysicsResult)
    mass = body_masses_kg(xml, [0, 1])
    wrench = np.zeros_like(res.residual_root_force)
    wrench[SPIKE_ROW, 1, 1] = 0.2 * mass[1] * GRAVITY
    outputs = {
        "result": dataclasses.replace(res, residual_root_force=wrench),
        "keypoints3d": store.load("physics", "keypoints3d", Keypoints3D),
        "scene.xml": xml,
    }
    store.write(
        Manifest(stage="physics", code_version="test", config={}, config_hash="0", inputs={}), outputs
    )
    return s


def _evaluate(s: Path, cfg: EvaluateConfig) -> tuple[dict, ProblemFlags]:
    store = ArtifactStore(s)
    out = SPEC.execute(StageContext(s, SessionConfig.load(s), store, "evaluate"), cfg)
    store.write(Manifest(stage="evaluate", code_version="test", config={}, config_hash="0", inputs={}), out)
    with np.load(store.path("evaluate", "problems.npz"), allow_pickle=False) as z:
        flags = ProblemFlags(**{k: z[k] for k in z.files})
    return json.loads(store.path("evaluate", "metrics.json").read_text()), flags


def test_evaluate_step_reports_the_physics_effort_per_frame(session: Path) -> None:
    store = ArtifactStore(session)
    res = store.load("physics", "result", PhysicsResult)
    xml = store.path("physics", "scene.xml").read_text()
    metrics, pf = _evaluate(session, EvaluateConfig())
    assert pf.frame_indices.tolist() == list(range(FIRST_FRAME, FIRST_FRAME + 8))
    assert pf.flags.shape == (8, len(FLAG_KINDS))
    expected = np.zeros(8)
    expected[SPIKE_ROW] = 0.2
    np.testing.assert_allclose(pf.residual_frac_bw, expected, atol=1e-9)
    col = pf.column("residual_high")
    assert col is not None and np.flatnonzero(col).tolist() == [SPIKE_ROW]
    # The real humanoid's torques: the per-frame maximum is the bout report's peak.
    report = torque_limit_report(
        res.joint_torque_nm, actuator_names(xml), [0, 1], body_masses_kg(xml, [0, 1])
    )
    assert pf.torque_ratio_max.max() == pytest.approx(report["torque_peak_ratio_max"])
    assert (pf.torque_ratio_max > 0).all()
    # A threshold inside the range splits the frames; the counts follow the flags.
    mid = float(np.median(pf.torque_ratio_max))
    metrics, pf = _evaluate(session, EvaluateConfig(torque_high_ratio=mid))
    torque = pf.column("torque_high")
    assert torque is not None and np.array_equal(torque, pf.torque_ratio_max > mid) and 0 < torque.sum() < 8
    assert metrics["problem_frames"] == {k.key: int(pf.flags[:, i].sum()) for i, k in enumerate(FLAG_KINDS)}
    assert metrics["problem_frames"]["residual_high"] == 1
    assert metrics["physics_residual_max_frac_bw"] == pytest.approx(0.2)
