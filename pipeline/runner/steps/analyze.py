"""analyze step: events.npz + series.npz from the latest 3D result (physics, else fit,
else filtered; ``AnalyzeConfig.source`` can pin one), with the annotators' event edits
(``correct_event``, ``add_event``, ``delete_event``) applied; the edits that found no event are
counted in the metric ``corrections_unmatched`` and listed in ``corrections_unmatched_edits``.
With ``AnalyzeConfig.views`` on (the speed lift by default, punches from the views opt-in) the
stage also gets the 2D tracks and their association (the track and associate artifacts)."""

from __future__ import annotations

import logging
from typing import Any

from pipeline.runner.registry import STAGE_ORDER
from pipeline.runner.spec import StageContext, StageSpec
from pipeline.schema.association import Association
from pipeline.schema.detections import Tracks2D
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import PhysicsResult
from pipeline.schema.sources import RESULT_ARTIFACTS
from pipeline.stages.analyze import AnalyzeConfig, AnalyzeInputs, run

log = logging.getLogger(__name__)

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
    # The filtered triangulation is where punches the fit flattened are looked for (opt-in).
    use_filtered = cfg.punch.flattened and name != "filtered" and ctx.has(*_file("filtered"))
    filtered = ctx.load(*RESULT_ARTIFACTS["filtered"], Keypoints3D) if use_filtered else None
    # The 2D tracks of every view: the speed of punches the raw triangulation cannot measure,
    # and (opt-in) punches the fit flattened.
    use_views = (cfg.views.enabled or cfg.views.lift_speed) and ctx.has("track", "tracks.npz") and ctx.has("associate", "association.npz")
    tracks = ctx.load("track", "tracks", Tracks2D) if use_views else None
    assoc = ctx.load("associate", "association", Association) if use_views else None
    inputs = AnalyzeInputs(
        keypoints=kp, physics=physics, raw=raw, filtered=filtered, corrections=tuple(ctx.annotations),
        tracks=tracks, association=assoc,
    )  # fmt: skip
    out = run(inputs, cfg)
    ctx.metrics.update(out.stats)
    for line in out.stats.get("corrections_unmatched_edits", []):
        log.warning("%s: analyze: edit not applied: %s", ctx.session_dir, line)
    ctx.metrics["source"] = name
    return {"events": out.events, "series": out.series}


def _file(name: str) -> tuple[str, str]:
    stage, art = RESULT_ARTIFACTS[name]
    return stage, f"{art}.npz"


SPEC = StageSpec(
    name="analyze",
    deps=("triangulate", "associate", "track"),
    optional_deps=("fit", "physics"),
    config_cls=AnalyzeConfig,
    execute=_execute,
    consumes_annotations=True,
    description="boxing analytics: punches (type, speed, outcome), slips, ducks, blocks and parries, clinches, stance, work rate",
)
