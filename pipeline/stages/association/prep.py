"""Per-detection arrays the association needs, computed once and vectorised over all rows."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.geometry.dlt import normalized_projections
from pipeline.geometry.projection import undistort_rig_points
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D


@dataclass(frozen=True)
class PreparedDets:
    """Flat detection rows, undistorted and normalised (``dets`` rows of the input ``Tracks2D``).

    Fields:
        uv_px: (dets, joints, 2) undistorted pixels (0 where ``w == 0``).
        xn: (dets, joints, 2) normalised image coordinates ``K^-1 [u, v, 1]`` (0 where ``w == 0``).
        w: (dets, joints) joint weight = confidence where valid and confident enough, else 0.
        inv_scale: (dets,) focal length / box size: multiplies a normalised-coordinate
            distance into a distance relative to the person's size in that image.
        view, frame: (dets,) int.
        tracklet: (dets,) dense index of the (view, track_id) pair, -1 for untracked rows.
        n_tracklets: number of distinct tracklets.
        order: (dets,) row indices sorted by frame; ``starts[f]:starts[f+1]`` are frame ``f``'s.
        starts: (frames + 1,).
        P: (views, 3, 4) normalised projections (world shifted by ``offset_m``).
        offset_m: (3,) world offset of ``P``.
        focal_px: (views,) mean focal length (pixels per normalised unit).
    """

    uv_px: np.ndarray
    xn: np.ndarray
    w: np.ndarray
    inv_scale: np.ndarray
    view: np.ndarray
    frame: np.ndarray
    tracklet: np.ndarray
    n_tracklets: int
    order: np.ndarray
    starts: np.ndarray
    P: np.ndarray
    offset_m: np.ndarray
    focal_px: np.ndarray


def prepare(tracks: Tracks2D, rig: CameraRig, min_conf: float) -> PreparedDets:
    """Undistort and normalise every detection; ``ValueError`` if the rig does not match."""
    if tracks.n_views != rig.n_views:
        raise ValueError(f"tracks have {tracks.n_views} views but the rig has {rig.n_views} ({rig.names})")
    ok = tracks.keypoint_valid & (tracks.keypoint_conf >= min_conf)
    kp = np.where(tracks.keypoint_valid[..., None], tracks.keypoints_px, 0.0)
    uv = undistort_rig_points(rig, kp, tracks.view) if tracks.n_dets else kp.astype(float)
    uv = np.where(ok[..., None], uv, 0.0)
    Kinv = np.linalg.inv(rig.K)[tracks.view]  # (dets, 3, 3)
    xn = np.einsum("dij,dkj->dki", Kinv[:, :2, :2], uv) + Kinv[:, None, :2, 2]
    xn = np.where(ok[..., None], xn, 0.0)
    w = np.where(ok, tracks.keypoint_conf, 0.0)
    focal = 0.5 * (rig.K[:, 0, 0] + rig.K[:, 1, 1])
    bw = tracks.bbox_xyxy_px[:, 2] - tracks.bbox_xyxy_px[:, 0]
    bh = tracks.bbox_xyxy_px[:, 3] - tracks.bbox_xyxy_px[:, 1]
    size = np.maximum(np.maximum(bw, bh), 1.0)
    # A box that does not cover its own keypoints (or a degenerate one) is replaced by the keypoint extent.
    lo = np.where(ok[..., None], uv, np.inf).min(axis=1)
    hi = np.where(ok[..., None], uv, -np.inf).max(axis=1)
    ext = np.where(np.isfinite(hi - lo), hi - lo, 0.0).max(axis=1)
    size = np.maximum(size, ext)
    inv_scale = focal[tracks.view] / size
    tracked = tracks.track_id >= 0
    key = tracks.view.astype(np.int64) * (1 << 32) + tracks.track_id.astype(np.int64)
    uniq, inv = np.unique(key[tracked], return_inverse=True)
    tracklet = np.full(tracks.n_dets, -1, np.int64)
    tracklet[tracked] = inv
    order = np.argsort(tracks.frame, kind="stable")
    starts = np.searchsorted(tracks.frame[order], np.arange(tracks.n_frames + 1))
    P, offset = normalized_projections(rig)
    return PreparedDets(
        uv_px=uv,
        xn=xn,
        w=w,
        inv_scale=inv_scale,
        view=tracks.view.astype(np.int64),
        frame=tracks.frame.astype(np.int64),
        tracklet=tracklet,
        n_tracklets=int(uniq.size),
        order=order,
        starts=starts,
        P=P,
        offset_m=offset,
        focal_px=focal,
    )
