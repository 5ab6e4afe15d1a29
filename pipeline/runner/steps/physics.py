"""physics step: fitted joints (+ body fit) -> simulated motion of every athlete.

With ``PhysicsConfig.incremental`` the stage's previous result, scene and checkpoints are
passed back in (``PhysicsInputs.previous``), and the stage re-plans only what changed
(``pipeline.stages.physics_incremental``); the metrics say what was reused.
"""

from __future__ import annotations

from typing import Any

from pipeline.runner.spec import StageContext, StageSpec
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit, PhysicsResult
from pipeline.stages.physics import PhysicsConfig, PhysicsInputs, run
from pipeline.stages.physics_incremental import PhysicsCheckpoints, PhysicsPrevious

CHECKPOINTS = "checkpoints"
"""Name of the stage's checkpoints output (``checkpoints.npz``)."""


def _previous(ctx: StageContext, cfg: PhysicsConfig) -> PhysicsPrevious | None:
    if ctx.reusable_with(cfg.incremental, f"{CHECKPOINTS}.npz", "checkpoints") is None:
        return None
    return PhysicsPrevious(
        result=ctx.load_previous("result", PhysicsResult),
        mjcf=ctx.read_previous_text("scene.xml"),
        checkpoints=ctx.load_previous(CHECKPOINTS, PhysicsCheckpoints),
    )


def _execute(ctx: StageContext, cfg: PhysicsConfig) -> dict[str, Any]:
    bodyfit = ctx.load("fit", "bodyfit", BodyFit) if ctx.has("fit", "bodyfit.npz") else None
    kp = ctx.load("fit", "keypoints3d", Keypoints3D)
    previous = _previous(ctx, cfg)
    out = run(PhysicsInputs(keypoints=kp, bodyfit=bodyfit, previous=previous), cfg, progress=ctx.progress)
    stats = {k: v for k, v in out.stats.items() if isinstance(v, (int, float, str))}
    if previous is None and "incremental" in ctx.metrics:  # the runner's reason wins over the stage's
        stats["incremental"] = ctx.metrics["incremental"]
    ctx.metrics.update(stats)
    if previous is not None and out.stats.get("reused_frames", 0):
        assert ctx.previous is not None
        ctx.metrics["previous_outputs_hash"] = ctx.previous.manifest.outputs_hash
    outputs: dict[str, Any] = {"result": out.result, "keypoints3d": out.keypoints, "scene.xml": out.mjcf}
    if out.checkpoints is not None:
        outputs[CHECKPOINTS] = out.checkpoints
    return outputs


SPEC = StageSpec(
    name="physics",
    deps=("fit",),
    config_cls=PhysicsConfig,
    execute=_execute,
    description="per-athlete MuJoCo humanoids + multi-person iLQR (removes penetration, foot skating)",
)
