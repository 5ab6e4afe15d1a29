"""track step: persistent per-view track ids, time offsets, then the human track edits overlay.

Order: tracker (or the ids that came with the input) → camera time offsets (given,
from the calibration, or estimated from keypoint speeds; frames are re-indexed onto
one clock so that later stages see synchronised frames) → track edits.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pipeline.runner.spec import StageContext, StageSpec
from pipeline.schema.detections import Detections2D, Tracks2D
from pipeline.stages.track_edits import apply_track_edits
from pipeline.stages.track_sync import TrackStepConfig, synchronise


def _execute(ctx: StageContext, cfg: TrackStepConfig) -> dict[str, Any]:
    dets = ctx.load("detect2d", "detections", Detections2D)
    if cfg.use_source_ids and ctx.has("detect2d", "source_tracks.npz"):
        with np.load(ctx.store.path("detect2d", "source_tracks.npz"), allow_pickle=False) as z:
            ids = z["track_id"]
        tracks = Tracks2D.from_detections(dets, ids)
    else:
        from pipeline.stages.track import run as run_tracker

        tracks = run_tracker(dets, ctx.rig, cfg)
    tracks, sync_info = synchronise(tracks, ctx.rig, cfg, is_video=ctx.session.source == "video")
    edits = ctx.annotations
    if edits:
        tracks = apply_track_edits(tracks, ctx.rig.names, edits)
    n_tracks = sum(len(np.unique(tracks.track_id[(tracks.view == v) & (tracks.track_id >= 0)])) for v in range(tracks.n_views))
    ctx.metrics.update(tracks=int(n_tracks), edits_applied=len(edits), **sync_info)
    return {"tracks": tracks}


SPEC = StageSpec(
    name="track",
    deps=("detect2d",),
    config_cls=TrackStepConfig,
    execute=_execute,
    consumes_annotations=True,
    uses_rig_fps=True,
    description="per-view tracking with persistent ids, camera time offsets (+ human track edits)",
)
