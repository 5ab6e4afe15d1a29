"""triangulate step: weighted DLT with outlier-view rejection, then temporal filtering."""

from __future__ import annotations

from typing import Any

from pipeline.runner.spec import StageContext, StageSpec
from pipeline.schema.association import Association
from pipeline.schema.detections import Tracks2D
from pipeline.stages.triangulate import TriangulateConfig, summary
from pipeline.stages.triangulate import run as run_triangulate


def _execute(ctx: StageContext, cfg: TriangulateConfig) -> dict[str, Any]:
    tracks = ctx.load("track", "tracks", Tracks2D)
    assoc = ctx.load("associate", "association", Association)
    raw, filtered = run_triangulate(tracks, assoc, ctx.rig, cfg)
    ctx.metrics.update(summary(raw, filtered, tracks, assoc, ctx.rig))
    return {"raw": raw, "keypoints3d": filtered}


SPEC = StageSpec(
    name="triangulate",
    deps=("associate", "track"),
    optional_deps=("calibrate",),
    config_cls=TriangulateConfig,
    execute=_execute,
    uses_rig_fps=True,
    description="weighted triangulation + spline/Kalman filtering and bone-length checks",
)
