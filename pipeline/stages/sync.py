"""Time offsets between cameras from the motion of their 2D keypoints (as Pose2Sim).

For each view, a 1-D signal is built: the summed speed of every track's keypoints,
each normalised by its box height so that near and far cameras weigh alike. The
signals are low-pass filtered and each view is cross-correlated with the reference
view (normalised correlation over the overlapping frames); the lag of the peak is the
offset. Every camera pair is also correlated directly: when the pairwise lags
disagree with the differences of the per-view offsets, the result is flagged
inconsistent and a warning is logged.

Convention (``CameraRig.time_offset_s``): frame ``f`` of view ``v`` was captured at
``f / fps + time_offset_s[v]``; the reference view has offset 0.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.signal import butter, filtfilt

from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SyncConfig:
    """Settings of the offset estimation."""

    max_offset_s: float = 1.0
    """Largest offset searched, in seconds (both directions)."""
    cutoff_hz: float = 6.0
    """Low-pass cut-off of the speed signals (Butterworth, zero phase); 0 = no filter."""
    min_keypoint_conf: float = 0.3
    """Keypoints below this confidence do not contribute to the speed."""
    reference: str = ""
    """Reference camera name ('' = the rig's first camera)."""
    tolerance_frames: float = 2.0
    """Pairwise lags may differ from the per-view offsets by this much before warning."""
    min_overlap_frac: float = 0.5
    """A lag needs at least this fraction of the shorter signal overlapping."""


@dataclass(frozen=True)
class SyncResult:
    """Estimated offsets.

    Fields:
        time_offset_s: (views,) offsets in seconds (``CameraRig.time_offset_s`` convention).
        offset_frames: (views,) the same in frames (integers).
        peak_corr: (views,) normalised correlation at the chosen lag (1 for the reference).
        pair_lag_frames: (views, views) lag maximising the correlation of each pair;
            ideally ``offset_frames[i] - offset_frames[j]``.
        consistent: whether all pairs agree within the tolerance.
    """

    time_offset_s: np.ndarray
    offset_frames: np.ndarray
    peak_corr: np.ndarray
    pair_lag_frames: np.ndarray
    consistent: bool


def speed_signals(tracks: Tracks2D, min_conf: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-view keypoint speed ``(views, frames)`` (box heights per frame) and its validity mask."""
    V, F = tracks.n_views, tracks.n_frames
    sig = np.zeros((V, F))
    has = np.zeros((V, F), bool)
    ok = tracks.keypoint_valid & (tracks.keypoint_conf >= min_conf)
    h = np.maximum(tracks.bbox_xyxy_px[:, 3] - tracks.bbox_xyxy_px[:, 1], 1.0)
    for v in range(V):
        for t in np.unique(tracks.track_id[(tracks.view == v) & (tracks.track_id >= 0)]):
            rows = np.flatnonzero((tracks.view == v) & (tracks.track_id == t))
            rows = rows[np.argsort(tracks.frame[rows])]
            f = tracks.frame[rows]
            consecutive = np.flatnonzero(np.diff(f) == 1)
            a, b = rows[consecutive], rows[consecutive + 1]
            both = ok[a] & ok[b]
            d = np.linalg.norm(tracks.keypoints_px[b] - tracks.keypoints_px[a], axis=2)
            n = both.sum(axis=1)
            speed = np.where(n > 0, np.sum(d * both, axis=1) / np.maximum(n, 1), 0.0) / h[b]
            sig[v, f[consecutive + 1]] += speed
            has[v, f[consecutive + 1]] |= n > 0
    return sig, has


def _lowpass(x: np.ndarray, fps: float, cutoff_hz: float) -> np.ndarray:
    if cutoff_hz <= 0 or cutoff_hz >= fps / 2 or x.size < 16:
        return x
    b, a = butter(4, cutoff_hz / (fps / 2))
    return filtfilt(b, a, x, padlen=min(3 * max(len(a), len(b)), x.size - 1))


def best_lag(
    a: np.ndarray, ma: np.ndarray, b: np.ndarray, mb: np.ndarray, max_lag: int, min_overlap: int
) -> tuple[int, float]:
    """Lag ``k`` maximising the normalised correlation of ``a[f]`` with ``b[f + k]``."""
    F = a.size
    best, best_c = 0, -np.inf
    for k in range(-max_lag, max_lag + 1):
        lo, hi = max(0, -k), min(F, F - k)
        if hi - lo < min_overlap:
            continue
        x, y = a[lo:hi], b[lo + k : hi + k]
        m = ma[lo:hi] & mb[lo + k : hi + k]
        if m.sum() < min_overlap:
            continue
        x, y = x[m] - x[m].mean(), y[m] - y[m].mean()
        den = np.sqrt((x * x).sum() * (y * y).sum())
        c = float((x * y).sum() / den) if den > 0 else -np.inf
        if c > best_c:
            best, best_c = k, c
    return best, best_c


def run(tracks: Tracks2D, rig: CameraRig, cfg: SyncConfig = SyncConfig()) -> SyncResult:
    """Estimate per-camera time offsets from tracked 2D keypoints.

    ``ValueError`` if the views do not match the rig or the reference camera is unknown.
    """
    if tracks.n_views != rig.n_views:
        raise ValueError(f"tracks have {tracks.n_views} views but the rig has {rig.n_views}")
    ref = rig.index(cfg.reference) if cfg.reference else 0
    fps = float(rig.fps)
    raw, has = speed_signals(tracks, cfg.min_keypoint_conf)
    sig = np.stack([_lowpass(s, fps, cfg.cutoff_hz) for s in raw])
    V, F = sig.shape
    max_lag = min(int(round(cfg.max_offset_s * fps)), F - 1)
    min_overlap = max(2, int(cfg.min_overlap_frac * F))
    lag = np.zeros((V, V), np.int64)
    corr = np.ones((V, V))
    for i in range(V):
        for j in range(V):
            if i != j:
                lag[i, j], corr[i, j] = best_lag(sig[i], has[i], sig[j], has[j], max_lag, min_overlap)
    k = lag[ref]  # k_v: lag of view v against the reference
    offset_frames = -k
    incons = []
    for i in range(V):
        for j in range(i + 1, V):
            if abs(lag[i, j] - (k[j] - k[i])) > cfg.tolerance_frames:
                incons.append((rig.names[i], rig.names[j], int(lag[i, j]), int(k[j] - k[i])))
    if incons:
        log.warning(
            "INCONSISTENT camera time offsets: pairwise lags disagree with the per-camera offsets "
            "(camera a, camera b, pair lag, expected): %s; the offsets %s (frames) are unreliable",
            incons, dict(zip(rig.names, offset_frames.tolist(), strict=True)),
        )  # fmt: skip
    return SyncResult(
        time_offset_s=offset_frames / fps,
        offset_frames=offset_frames,
        peak_corr=corr[ref],
        pair_lag_frames=lag,
        consistent=not incons,
    )


def offsets_to_frames(time_offset_s: np.ndarray, fps: float) -> np.ndarray:
    """(views,) integer frame shifts ``round(offset * fps)`` that map video frames to the rig clock."""
    return np.round(np.asarray(time_offset_s, float) * float(fps)).astype(np.int64)


def apply_offsets(tracks: Tracks2D, offset_frames: np.ndarray) -> Tracks2D:
    """Re-index frames onto a common clock: row ``(v, f)`` moves to ``f + shift[v] - min(shift)``.

    The earliest-starting camera keeps its numbering; ``n_frames`` grows to hold every
    shifted row. Nothing is dropped or resampled (shifts are whole frames).
    ``ValueError`` if ``offset_frames`` does not have one entry per view.
    """
    shift = np.asarray(offset_frames, np.int64)
    if shift.shape != (tracks.n_views,):
        raise ValueError(f"offset_frames has shape {shift.shape}, expected ({tracks.n_views},)")
    shift = shift - shift.min()
    if not np.any(shift):
        return tracks
    kw = dict(tracks.__dict__)
    kw["frame"] = tracks.frame + shift[tracks.view]
    kw["n_frames"] = int(tracks.n_frames + shift.max())
    return type(tracks)(**kw)
