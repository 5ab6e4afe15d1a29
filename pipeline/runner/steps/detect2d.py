"""detect2d step: 2D person detections + keypoints from the session's source.

- ``source="tracks"``: the Tracks2D npz is loaded (its track ids are kept for the
  ``track`` stage as ``source_track_id``).
- ``source="keypoints"``: OpenPose / COCO JSON keypoints are imported.
- ``source="video"``: the ONNX detector + top-down keypoint model run on the videos.

The config is the video stage's ``Detect2DConfig``; only ``min_keypoint_conf`` applies
to every source.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.runner.spec import StageContext, StageSpec
from pipeline.schema.base import load_npz
from pipeline.schema.detections import Tracks2D
from pipeline.stages.detect2d import Detect2DConfig


def _input_files(ctx: StageContext) -> list[Path]:
    s = ctx.session
    files = [ctx.resolve(s.calibration)]
    if s.source == "tracks":
        files.append(ctx.resolve(s.tracks))
    else:  # the videos or keypoints of the cameras the session uses
        files += [ctx.resolve(p) for p in s.camera_inputs().values()]
    return files


def _tracks_of_session_cameras(ctx: StageContext, tracks: Tracks2D) -> Tracks2D:
    """The rows of the cameras ``session.cameras`` keeps, their views renumbered to the rig's
    order (a tracks file's views follow the full calibration's camera order)."""
    from pipeline.io.calibration import load_calibration

    full = load_calibration(ctx.resolve(ctx.session.calibration)).names
    if tracks.n_views != len(full):
        raise ValueError(
            f"{ctx.resolve(ctx.session.tracks)}: tracks have {tracks.n_views} views but the calibration has {len(full)}"
        )
    new_view = np.full(len(full), -1, np.int64)
    for i, name in enumerate(ctx.rig.names):
        new_view[full.index(name)] = i
    keep = new_view[tracks.view] >= 0
    fields = dict(tracks.select(keep).__dict__)
    fields.update(n_views=ctx.rig.n_views, view=new_view[fields["view"]])
    return Tracks2D(**fields)


def _execute(ctx: StageContext, cfg: Detect2DConfig) -> dict[str, Any]:
    s = ctx.session
    if s.source == "tracks":
        tracks = load_npz(ctx.resolve(s.tracks), Tracks2D)
        if s.cameras:
            tracks = _tracks_of_session_cameras(ctx, tracks)
        if tracks.n_views != ctx.rig.n_views:
            raise ValueError(
                f"{ctx.resolve(s.tracks)}: tracks have {tracks.n_views} views but the calibration has {ctx.rig.n_views}"
            )
        dets = tracks.detections()
        out: dict[str, Any] = {"detections": dets, "source_tracks": {"track_id": tracks.track_id}}
    elif s.source == "keypoints":
        from pipeline.io.keypoints2d import load_keypoints_with_ids

        dets, ids = load_keypoints_with_ids(
            {k: ctx.resolve(v) for k, v in s.camera_inputs().items()}, s.keypoint_format, ctx.rig
        )
        out = {"detections": dets}
        if ids is not None and np.all(ids >= 0):
            # Tracked keypoints (OpenPose person_id / COCO track_id): keep their ids.
            out["source_tracks"] = {"track_id": ids.astype(np.int64)}
    else:
        from pipeline.stages.detect2d import run_videos

        vcfg = replace(cfg, models_dir=str(ctx.resolve(cfg.models_dir)) if cfg.models_dir else None)
        dets = run_videos({k: ctx.resolve(v) for k, v in s.camera_inputs().items()}, ctx.rig, ctx.progress, vcfg)
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
    config_cls=Detect2DConfig,
    execute=_execute,
    input_files=_input_files,
    description="2D person detection and keypoints per camera",
)
