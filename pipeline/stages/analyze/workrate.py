"""Work rate: punches per minute over a trailing window."""

from __future__ import annotations

import numpy as np

from pipeline.stages.analyze.config import WorkRateConfig


def punches_per_min(frame_indices: np.ndarray, fps: float, punch_frames: np.ndarray, cfg: WorkRateConfig) -> np.ndarray:
    """(frames,) punches whose strike falls in the trailing ``window_s`` up to each frame,
    per minute. Near the start the window is the time elapsed since the first frame, but
    at least ``min_window_s`` (so the first punch does not read as hundreds per minute).

    ``punch_frames``: video frames of the strikes of one athlete."""
    t = (frame_indices - frame_indices[0]) / fps if frame_indices.size else np.zeros(0)
    tp = np.sort((np.asarray(punch_frames) - (frame_indices[0] if frame_indices.size else 0)) / fps)
    upto = np.searchsorted(tp, t, side="right")
    since = np.searchsorted(tp, t - cfg.window_s, side="right")
    span = np.clip(t, cfg.min_window_s, cfg.window_s)
    return (upto - since) * 60.0 / span
