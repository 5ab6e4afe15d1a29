"""analyze step: events.npz + series.npz from the latest 3D result (physics, else fit,
else filtered; ``AnalyzeConfig.source`` can pin one)."""

from __future__ import annotations

from typing import Any

from pipeline.runner.registry import STAGE_ORDER
from pipeline.runner.spec import StageContext, StageSpec
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import PhysicsResult
from pipeline.schema.sources import RESULT_ARTIFACTS
from pipeline.stages.analyze import AnalyzeConfig, AnalyzeInputs, run

SOURCE_ORDER: tuple[str, ...] = ("physics", "fit", "filtered")
"""Results analysed by ``source="auto"``, first present wins."""


def _execute(ctx: StageContext, cfg: AnalyzeConfig) -> dict[str, Any]:
    # Only stages this session runs: an artifact left by a stage since disabled is stale.
    enabled = set(ctx.session.stages or STAGE_ORDER)
    order = SOURCE_ORDER if cfg.source == "auto" else (cfg.source,)
    present = [n for n in order if RESULT_ARTIFACTS[n][0] in enabled and ctx.has(*_file(n))]
    if not present:
        raise ValueError(f"analyze: no 3D result to analyse among {list(order)} (run the stages before it)")
    name = present[0]
    stage, art = RESULT_ARTIFACTS[name]
    kp = ctx.load(stage, art, Keypoints3D)
    physics = ctx.load("physics", "result", PhysicsResult) if name == "physics" and ctx.has("physics", "result.npz") else None
    raw = ctx.load(*RESULT_ARTIFACTS["raw"], Keypoints3D) if ctx.has(*_file("raw")) else None
    out = run(AnalyzeInputs(keypoints=kp, physics=physics, raw=raw), cfg)
    ctx.metrics.update(out.stats)
    ctx.metrics["source"] = name
    return {"events": out.events, "series": out.series}


def _file(name: str) -> tuple[str, str]:
    stage, art = RESULT_ARTIFACTS[name]
    return stage, f"{art}.npz"


SPEC = StageSpec(
    name="analyze",
    deps=("triangulate",),
    optional_deps=("fit", "physics"),
    config_cls=AnalyzeConfig,
    execute=_execute,
    description="boxing analytics: punches (type, speed, outcome), slips and ducks, clinches, stance, work rate",
)
