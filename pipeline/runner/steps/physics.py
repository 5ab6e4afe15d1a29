"""physics step: fitted joints (+ body fit) -> simulated motion of every athlete."""

from __future__ import annotations

from typing import Any

from pipeline.runner.spec import StageContext, StageSpec
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit
from pipeline.stages.physics import PhysicsConfig, PhysicsInputs, run


def _execute(ctx: StageContext, cfg: PhysicsConfig) -> dict[str, Any]:
    bodyfit = ctx.load("fit", "bodyfit", BodyFit) if ctx.has("fit", "bodyfit.npz") else None
    kp = ctx.load("fit", "keypoints3d", Keypoints3D)
    out = run(PhysicsInputs(keypoints=kp, bodyfit=bodyfit), cfg, progress=ctx.progress)
    ctx.metrics.update({k: v for k, v in out.stats.items() if isinstance(v, (int, float, str))})
    return {"result": out.result, "keypoints3d": out.keypoints, "scene.xml": out.mjcf}


SPEC = StageSpec(
    name="physics",
    deps=("fit",),
    config_cls=PhysicsConfig,
    execute=_execute,
    description="per-athlete MuJoCo humanoids + multi-person iLQR (removes penetration, foot skating)",
)
