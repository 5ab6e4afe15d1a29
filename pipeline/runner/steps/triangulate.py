"""triangulate step: weighted DLT with outlier-view rejection, then temporal filtering."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from pipeline.runner.spec import StageContext, StageSpec
from pipeline.schema.association import Association
from pipeline.schema.bones import BoneLengths
from pipeline.schema.detections import Tracks2D
from pipeline.stages.triangulate import TriangulateConfig, run_holding, sparse_persons, summary

log = logging.getLogger(__name__)


def _execute(ctx: StageContext, cfg: TriangulateConfig) -> dict[str, Any]:
    tracks = ctx.load("track", "tracks", Tracks2D)
    assoc = ctx.load("associate", "association", Association)
    held = None
    if ctx.reusable_with(cfg.incremental, "bone_lengths.npz", "bone lengths") is not None:
        held = ctx.load_previous("bone_lengths", BoneLengths)
        ctx.metrics["incremental"] = (
            "bone lengths held from the previous run where they moved <= hold_bone_rel or hold_bone_m"
        )
    raw, filtered, bones = run_holding(tracks, assoc, ctx.rig, cfg, held)
    if held is not None:
        same = (
            np.isclose(bones.rigid_m, held.rigid_m, equal_nan=True)
            if bones.rigid_m.shape == held.rigid_m.shape
            else False
        )
        ctx.metrics["bones_held_pct"] = round(100.0 * float(np.mean(same)), 1)
    ctx.metrics.update(summary(raw, filtered, tracks, assoc, ctx.rig))
    for msg in sparse_persons(filtered, dict(enumerate(ctx.session.athletes))):
        log.warning("%s: triangulate: %s", ctx.session_dir, msg)
    return {"raw": raw, "keypoints3d": filtered, "bone_lengths": bones}


SPEC = StageSpec(
    name="triangulate",
    deps=("associate", "track"),
    optional_deps=("calibrate",),
    config_cls=TriangulateConfig,
    execute=_execute,
    uses_rig_fps=True,
    description="weighted triangulation + spline/Kalman filtering and bone-length checks",
)
