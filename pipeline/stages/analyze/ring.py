"""Ring-craft and stance series: distance between the athletes, stance (from the feet),
stance width and guard height."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import median_filter

from pipeline.stages.analyze.body import Body
from pipeline.stages.analyze.config import RingConfig


def distance(a: Body, b: Body) -> tuple[np.ndarray, np.ndarray]:
    """(frames,) horizontal mid-hip distance in metres and its validity."""
    pa, oka = a.point("mid:left_hip+right_hip")
    pb, okb = b.point("mid:left_hip+right_hip")
    ok = oka & okb
    return np.where(ok, np.linalg.norm((pa - pb)[:, :2], axis=1), 0.0), ok


def stance(body: Body, R: np.ndarray, r_ok: np.ndarray, cfg: RingConfig) -> tuple[np.ndarray, np.ndarray]:
    """(frames,) stance codes (+1 orthodox: left foot ahead towards the opponent, -1
    southpaw, 0 square or unknown) and (frames,) stance width (ankle to ankle, horizontal, m).

    The left-minus-right ankle offset along the facing direction is smoothed by a running
    median over ``stance_smooth_s`` first, so that a step does not flip the stance."""
    la, lok = body.point("left_ankle")
    ra, rok = body.point("right_ankle")
    ok = lok & rok & r_ok
    ahead = np.einsum("fi,fi->f", la - ra, R[:, :, 0])
    size = max(1, int(round(cfg.stance_smooth_s * body.fps)) | 1)
    if ok.any():
        filled = np.interp(np.arange(ahead.shape[0]), np.flatnonzero(ok), ahead[ok])
        ahead = median_filter(filled, size=size, mode="nearest")
    code = np.where(ahead > cfg.square_m, 1, np.where(ahead < -cfg.square_m, -1, 0))
    width = np.where(lok & rok, np.linalg.norm((la - ra)[:, :2], axis=1), 0.0)
    return np.where(ok, code, 0).astype(np.int64), width


def guard_height(body: Body, cfg: RingConfig) -> np.ndarray:
    """(frames, 2) height of the (left, right) wrist above the chin (the ears' midpoint
    lowered by ``chin_below_ears_m``), metres; 0 where unknown."""
    ears, eok = body.point("mid:left_ear+right_ear")
    chin_z = ears[:, 2] - cfg.chin_below_ears_m
    out = np.zeros((body.n_frames, 2))
    for k, hand in enumerate(("left", "right")):
        w, wok = body.point(f"{hand}_wrist")
        out[:, k] = np.where(wok & eok, w[:, 2] - chin_z, 0.0)
    return out
