"""detect2d step: 2D person detections + keypoints from the session's source.

- ``source="tracks"``: the Tracks2D npz is loaded (its track ids are kept for the
  ``track`` stage as ``source_track_id``).
- ``source="keypoints"``: OpenPose / COCO JSON keypoints are imported.
- ``source="video"``: the ONNX detector + top-down keypoint model run on the videos.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from pipeline.runner.spec import StageContext, StageSpec
from pipeline.schema.base import load_npz
from pipeline.schema.detections import Tracks2D


@dataclass(frozen=True)
class Detect2DStepConfig:
    """Config of the 2D stage as seen by the runner (the video models' config lives in
    ``pipeline.stages.detect2d`` once videos are used)."""

    min_keypoint_conf: float = 0.0
    """Keypoints below this confidence are marked invalid on import."""
    detector: Literal["rtmdet_nano", "yolox_nano", "yolox_s", "yolox_m"] = "rtmdet_nano"
    """Video source: person detector (``cornerman models list``)."""
    pose_model: Literal[
        "blazepose_full", "movenet_lightning", "rtmpose_m", "rtmpose_l", "vitpose_b", "vitpose_l", "vitpose_h"
    ] = "blazepose_full"
    """Video source: top-down keypoint model."""
    models_dir: str | None = None
    """Video source: folder searched first for model files (else CORNERMAN_MODELS_DIR, then the cache)."""
    det_score_thr: float = 0.3
    """Video source: person boxes below this score are dropped."""
    max_persons: int = 12
    """Video source: at most this many people per frame."""
    batch_size: int = 8
    """Video source: frames per detector call."""
    frame_step: int = 1
    """Video source: process every n-th frame."""
    max_frames: int = 0
    """Video source: stop after this many frames per camera (0 = all)."""
    num_threads: int = 0
    """Video source: onnxruntime threads (0 = all cores)."""


def _input_files(ctx: StageContext) -> list[Path]:
    s = ctx.session
    files = [ctx.resolve(s.calibration)]
    if s.source == "tracks":
        files.append(ctx.resolve(s.tracks))
    elif s.source == "keypoints":
        files += [ctx.resolve(p) for p in s.keypoints.values()]
    else:
        files += [ctx.resolve(p) for p in s.videos.values()]
    return files


def _execute(ctx: StageContext, cfg: Detect2DStepConfig) -> dict[str, Any]:
    s = ctx.session
    if s.source == "tracks":
        tracks = load_npz(ctx.resolve(s.tracks), Tracks2D)
        if tracks.n_views != ctx.rig.n_views:
            raise ValueError(
                f"{ctx.resolve(s.tracks)}: tracks have {tracks.n_views} views but the calibration has {ctx.rig.n_views}"
            )
        dets = tracks.detections()
        out: dict[str, Any] = {"detections": dets, "source_tracks": {"track_id": tracks.track_id}}
    elif s.source == "keypoints":
        from pipeline.io.keypoints2d import load_keypoints_with_ids

        dets, ids = load_keypoints_with_ids({k: ctx.resolve(v) for k, v in s.keypoints.items()}, s.keypoint_format, ctx.rig)
        out = {"detections": dets}
        if ids is not None and np.all(ids >= 0):
            # Tracked keypoints (OpenPose person_id / COCO track_id): keep their ids.
            out["source_tracks"] = {"track_id": ids.astype(np.int64)}
    else:
        from pipeline.stages.detect2d import Detect2DConfig, run_videos

        vcfg = Detect2DConfig(
            detector=cfg.detector,
            pose_model=cfg.pose_model,
            models_dir=str(ctx.resolve(cfg.models_dir)) if cfg.models_dir else None,
            det_score_thr=cfg.det_score_thr,
            max_persons=cfg.max_persons,
            batch_size=cfg.batch_size,
            frame_step=cfg.frame_step,
            max_frames=cfg.max_frames,
            num_threads=cfg.num_threads,
        )
        dets = run_videos({k: ctx.resolve(v) for k, v in s.videos.items()}, ctx.rig, ctx.progress, vcfg)
        out = {"detections": dets}
    if cfg.min_keypoint_conf > 0:
        low = dets.keypoint_conf < cfg.min_keypoint_conf
        kw = dict(dets.__dict__)
        kw["keypoint_valid"] = dets.keypoint_valid & ~low
        out["detections"] = type(dets)(**kw)
    ctx.metrics.update(
        detections=int(dets.n_dets),
        mean_dets_per_view_frame=round(float(dets.n_dets) / max(1, dets.n_views * dets.n_frames), 2),
        valid_keypoints_pct=round(100 * float(np.mean(dets.keypoint_valid)) if dets.n_dets else 0.0, 1),
    )
    return out


SPEC = StageSpec(
    name="detect2d",
    deps=(),
    config_cls=Detect2DStepConfig,
    execute=_execute,
    input_files=_input_files,
    description="2D person detection and keypoints per camera",
)
