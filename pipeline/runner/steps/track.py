"""track step: persistent per-view track ids, time offsets, then the human track edits overlay.

Order: tracker (or the ids that came with the input) → camera time offsets (given,
from the calibration, or estimated from keypoint speeds; frames are re-indexed onto
one clock so that later stages see synchronised frames) → track edits.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from pipeline.runner.spec import StageContext, StageSpec
from pipeline.schema.detections import Detections2D, Tracks2D
from pipeline.stages.track import TrackConfig
from pipeline.stages.track_edits import apply_track_edits

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrackStepConfig(TrackConfig):
    """The tracker's ``TrackConfig`` plus the step's options."""

    use_source_ids: bool = True
    """Keep the track ids that came with the input (synthetic bout, tracked keypoints)."""
    time_offsets: Literal["calibration", "given", "estimate"] = "calibration"
    """Camera start-time offsets: the calibration's ``time_offset_s`` (zeros when it has
    none), ``time_offsets_s`` below, or estimated by cross-correlating keypoint speeds."""
    time_offsets_s: dict[str, float] = field(default_factory=dict)
    """Camera name -> start offset in seconds (``time_offsets="given"``; missing cameras 0)."""
    check_sync: bool = True
    """On video sessions, also estimate the offsets and warn loudly when they disagree with
    the ones used by more than ``sync_tolerance_frames`` (unsynchronised cameras)."""
    sync_tolerance_frames: float = 2.0
    """Disagreement (frames) tolerated by the sync check and by pairwise consistency."""
    sync_min_duration_s: float = 5.0
    """The sync check only runs on clips at least this long (short clips give ambiguous peaks)."""
    sync_min_corr: float = 0.8
    """The sync check only warns when every camera's correlation peak reaches this value."""


def _given_offsets(ctx: StageContext, cfg: TrackStepConfig) -> np.ndarray:
    names = ctx.rig.names
    if cfg.time_offsets == "given":
        unknown = sorted(set(cfg.time_offsets_s) - set(names))
        if unknown:
            raise ValueError(f"stage_config.track.time_offsets_s: cameras {unknown} not in the calibration {list(names)}")
        return np.array([float(cfg.time_offsets_s.get(n, 0.0)) for n in names])
    return np.asarray(ctx.rig.time_offset_s, float)


def _sync(ctx: StageContext, cfg: TrackStepConfig, tracks: Tracks2D) -> tuple[Tracks2D, dict[str, Any]]:
    from pipeline.stages.sync import SyncConfig, apply_offsets, offsets_to_frames
    from pipeline.stages.sync import run as estimate_offsets

    fps = float(ctx.rig.fps)
    used = offsets_to_frames(_given_offsets(ctx, cfg), fps)
    info: dict[str, Any] = {}
    long_enough = tracks.n_frames >= cfg.sync_min_duration_s * fps
    if cfg.time_offsets == "estimate" or (cfg.check_sync and ctx.session.source == "video" and long_enough):
        est = estimate_offsets(tracks, ctx.rig, SyncConfig(tolerance_frames=cfg.sync_tolerance_frames))
        info["estimated_offset_frames"] = dict(zip(ctx.rig.names, est.offset_frames.tolist(), strict=True))
        info["sync_consistent"] = bool(est.consistent)
        if cfg.time_offsets == "estimate":
            used = est.offset_frames
            if float(np.min(est.peak_corr)) < cfg.sync_min_corr:
                log.warning(
                    "estimated camera offsets %s (frames) have weak correlation peaks %s: check them",
                    info["estimated_offset_frames"], np.round(est.peak_corr, 2).tolist(),
                )  # fmt: skip
        elif est.consistent and float(np.min(est.peak_corr)) >= cfg.sync_min_corr:
            diff = (est.offset_frames - used) - (est.offset_frames - used)[0]
            if np.any(np.abs(diff) > cfg.sync_tolerance_frames):
                log.warning(
                    "CAMERAS MAY BE UNSYNCHRONISED: keypoint motion suggests offsets %s (frames) but %s are used; "
                    "set stage_config.track.time_offsets to 'estimate' or give time_offsets_s",
                    info["estimated_offset_frames"], dict(zip(ctx.rig.names, used.tolist(), strict=True)),
                )  # fmt: skip
                info["sync_warning"] = True
    info["offset_frames"] = dict(zip(ctx.rig.names, used.tolist(), strict=True))
    return apply_offsets(tracks, used), info


def _execute(ctx: StageContext, cfg: TrackStepConfig) -> dict[str, Any]:
    dets = ctx.load("detect2d", "detections", Detections2D)
    if cfg.use_source_ids and ctx.has("detect2d", "source_tracks.npz"):
        with np.load(ctx.store.path("detect2d", "source_tracks.npz"), allow_pickle=False) as z:
            ids = z["track_id"]
        tracks = Tracks2D.from_detections(dets, ids)
    else:
        from pipeline.stages.track import run as run_tracker

        tracks = run_tracker(dets, ctx.rig, cfg)
    tracks, sync_info = _sync(ctx, cfg, tracks)
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
