"""Which camera time offsets the tracks are put on one clock with (pure; the track stage's policy).

The offsets come from the calibration (``CameraRig.time_offset_s``), from the session
(``time_offsets="given"``), or are estimated from the keypoints' motion
(``pipeline.stages.sync``). On video sessions long enough to tell, the estimate is also
made when it is not used, and a disagreement with the offsets used is reported loudly:
unsynchronised cameras ruin every later stage.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D
from pipeline.stages.sync import SyncConfig, apply_offsets, offsets_to_frames
from pipeline.stages.sync import run as estimate_offsets
from pipeline.stages.track import TrackConfig

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrackStepConfig(TrackConfig):
    """The tracker's ``TrackConfig`` plus where the tracks come from and the time offsets."""

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
    """Disagreement (frames, >= 0) tolerated by the sync check and by pairwise consistency."""
    sync_min_duration_s: float = 5.0
    """The sync check only runs on clips at least this long (s; short clips give ambiguous peaks)."""
    sync_min_corr: float = 0.8
    """The sync check only warns when every camera's correlation peak reaches this value, in [0, 1]."""


def given_offsets_s(rig: CameraRig, cfg: TrackStepConfig) -> np.ndarray:
    """(views,) offsets in seconds the session gives: ``time_offsets_s`` or the calibration's.
    ``ValueError`` naming ``stage_config.track.time_offsets_s`` for an unknown camera."""
    if cfg.time_offsets == "given":
        unknown = sorted(set(cfg.time_offsets_s) - set(rig.names))
        if unknown:
            raise ValueError(f"stage_config.track.time_offsets_s: cameras {unknown} not in the calibration {list(rig.names)}")
        return np.array([float(cfg.time_offsets_s.get(n, 0.0)) for n in rig.names])
    return np.asarray(rig.time_offset_s, float)


def synchronise(tracks: Tracks2D, rig: CameraRig, cfg: TrackStepConfig, is_video: bool) -> tuple[Tracks2D, dict[str, Any]]:
    """``tracks`` re-indexed onto one clock, and what was decided (JSON-ready): the offsets
    used per camera (frames), and when estimated, the estimate, its consistency and whether
    it disagrees with the offsets used (``sync_warning``, also logged as a warning)."""
    fps = float(rig.fps)
    used = offsets_to_frames(given_offsets_s(rig, cfg), fps)
    info: dict[str, Any] = {}
    long_enough = tracks.n_frames >= cfg.sync_min_duration_s * fps
    if cfg.time_offsets == "estimate" or (cfg.check_sync and is_video and long_enough):
        est = estimate_offsets(tracks, rig, SyncConfig(tolerance_frames=cfg.sync_tolerance_frames))
        info["estimated_offset_frames"] = dict(zip(rig.names, est.offset_frames.tolist(), strict=True))
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
                    info["estimated_offset_frames"], dict(zip(rig.names, used.tolist(), strict=True)),
                )  # fmt: skip
                info["sync_warning"] = True
    info["offset_frames"] = dict(zip(rig.names, used.tolist(), strict=True))
    return apply_offsets(tracks, used), info
