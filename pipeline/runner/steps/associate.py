"""associate step: global person identities across views (+ the human identity edits)."""

from __future__ import annotations

from typing import Any

import numpy as np

from pipeline.runner.spec import StageContext, StageSpec
from pipeline.schema.detections import Tracks2D
from pipeline.stages.associate import AssociateConfig
from pipeline.stages.associate import run as run_associate


def _execute(ctx: StageContext, cfg: AssociateConfig) -> dict[str, Any]:
    tracks = ctx.load("track", "tracks", Tracks2D)
    edits = ctx.annotations
    assoc = run_associate(tracks, ctx.rig, cfg, edits, person_names=tuple(ctx.session.athletes))
    pod = assoc.person_of_det
    ctx.metrics.update(
        persons=int(assoc.n_persons),
        assigned_pct=round(100.0 * float(np.mean(pod >= 0)), 1) if pod.size else 0.0,
        mean_confidence=round(float(assoc.confidence[pod >= 0].mean()), 3) if np.any(pod >= 0) else 0.0,
        edits_applied=len(edits),
    )
    return {"association": assoc}


SPEC = StageSpec(
    name="associate",
    deps=("track",),
    config_cls=AssociateConfig,
    execute=_execute,
    consumes_annotations=True,
    uses_rig_fps=True,
    description="cross-view identity association (epipolar + multi-view 3D tracking)",
)
