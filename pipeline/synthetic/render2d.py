"""Simulated 2D detector + tracker output: projected joints with noise, confidences,
occlusion, cropping, missed detections, boxes and per-view track ids (with swaps)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.geometry.projection import project, undistort_points, world_to_cam
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D
from pipeline.schema.joints import COCO17_FEET

MIN_JOINTS_IN_IMAGE = 5
MIN_JOINTS_VISIBLE = 3
OCCLUDED_DROP_PROB = 0.5
"""An occluded joint is dropped (invalid) with this probability, else kept with conf < 0.3."""
SWAP_IOU = 0.5
"""Boxes must overlap at least this much (IoU) for an injected track-id swap."""
SWAP_IOU_FALLBACK = 0.1
"""If no view reaches ``SWAP_IOU``, the swap goes to the most-overlapping frame above this."""


@dataclass(frozen=True)
class Render2D:
    """Detections of all persons in all views (rows ordered by frame, view, person).

    Fields: tracks; person_of_det (dets,) true person id (-1 = bystander); clean_px
    (dets, joints, 2) noise-free projections (distorted image); occluded (dets, joints)
    bool, joint hidden behind a body volume; swap_frames (S, 2) [view, frame];
    n_views_visible (frames, persons, joints) how many views see each joint unoccluded.
    """

    tracks: Tracks2D
    person_of_det: np.ndarray
    clean_px: np.ndarray
    occluded: np.ndarray
    swap_frames: np.ndarray
    n_views_visible: np.ndarray


def _inside_image(rig: CameraRig, xyz: np.ndarray, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """(V, ...) True where a point projects inside the image, in front of the camera.

    Points far outside the field of view can fold back into the image under strong barrel
    distortion, so the undistorted radius must also stay within the image corners'.
    """
    w = rig.image_size_wh[:, 0].reshape((-1,) + (1,) * (uv.ndim - 2))
    h = rig.image_size_wh[:, 1].reshape(w.shape)
    ok = (depth > 0.2) & (uv[..., 0] >= 0) & (uv[..., 0] <= w - 1) & (uv[..., 1] >= 0) & (uv[..., 1] <= h - 1)
    xc = world_to_cam(xyz, rig.T_cam_world)
    r_norm = np.linalg.norm(xc[..., :2] / np.maximum(xc[..., 2:3], 1e-6), axis=-1)
    for v in range(rig.n_views):
        W, H = rig.image_size_wh[v]
        corners = np.array([[0.0, 0.0], [W - 1, 0.0], [0.0, H - 1], [W - 1, H - 1]])
        und = undistort_points(corners, rig.K[v], rig.dist[v])
        r_max = np.max(np.linalg.norm((und - rig.K[v, :2, 2]) / np.diag(rig.K[v])[:2], axis=1))
        ok[v] &= r_norm[v] <= 1.05 * r_max
    return ok


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    x0 = np.maximum(a[..., 0], b[..., 0])
    y0 = np.maximum(a[..., 1], b[..., 1])
    x1 = np.minimum(a[..., 2], b[..., 2])
    y1 = np.minimum(a[..., 3], b[..., 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    area = lambda r: (r[..., 2] - r[..., 0]) * (r[..., 3] - r[..., 1])  # noqa: E731
    return inter / np.maximum(area(a) + area(b) - inter, 1e-9)


def render_tracks(
    rig: CameraRig,
    xyz_m: np.ndarray,
    person_ids: np.ndarray,
    occluded: np.ndarray,
    noise_px: float,
    miss_rate: float,
    id_swaps: bool,
    rng: np.random.Generator,
) -> Render2D:
    """Detections of persons ``xyz_m`` (F, P, 23, 3) with true ids ``person_ids`` (P,) (the
    boxers 0 and 1 first, -1 for a bystander); ``occluded`` (V, F, P, 23) from
    ``pipeline.synthetic.occlusion.occluded``."""
    n_v = rig.n_views
    n_f, n_p, n_j = xyz_m.shape[:3]
    uv, depth = project(rig, xyz_m)  # (V, F, P, J, 2)
    in_img = _inside_image(rig, xyz_m, uv, depth)
    visible = in_img & ~occluded
    detected = (in_img.sum(-1) >= MIN_JOINTS_IN_IMAGE) & (visible.sum(-1) >= MIN_JOINTS_VISIBLE)
    detected &= rng.random((n_v, n_f, n_p)) >= miss_rate

    noise = rng.normal(0.0, 1.0, (n_v, n_f, n_p, n_j, 2)) * noise_px
    noise = np.where(occluded[..., None], 2.5 * noise, noise)
    kp = uv + noise
    nn = np.linalg.norm(noise, axis=-1)
    sharp = np.exp(-(nn**2) / (8.0 * noise_px**2)) if noise_px > 0 else np.ones_like(nn)
    conf = 0.75 + 0.25 * sharp * rng.uniform(0.9, 1.0, nn.shape)
    occ_conf = rng.uniform(0.05, 0.29, nn.shape)
    keep_occ = rng.random(nn.shape) >= OCCLUDED_DROP_PROB
    conf = np.where(occluded, occ_conf, conf)
    valid = in_img & (~occluded | keep_occ)
    kp = np.where(valid[..., None], kp, 0.0)
    conf = np.where(valid, conf, 0.0)

    # Boxes around the valid keypoints with a margin (more on top for the skull).
    big = 1e9
    x_min = np.where(valid, kp[..., 0], big).min(-1)
    x_max = np.where(valid, kp[..., 0], -big).max(-1)
    y_min = np.where(valid, kp[..., 1], big).min(-1)
    y_max = np.where(valid, kp[..., 1], -big).max(-1)
    detected &= valid.sum(-1) >= MIN_JOINTS_VISIBLE
    bw, bh = np.maximum(x_max - x_min, 1.0), np.maximum(y_max - y_min, 1.0)
    W = rig.image_size_wh[:, 0][:, None, None].astype(np.float64)
    H = rig.image_size_wh[:, 1][:, None, None].astype(np.float64)
    bbox = np.stack(
        [
            np.clip(x_min - 0.1 * bw - 4, 0, W - 1),
            np.clip(y_min - 0.12 * bh - 4, 0, H - 1),
            np.clip(x_max + 0.1 * bw + 4, 0, W - 1),
            np.clip(y_max + 0.06 * bh + 4, 0, H - 1),
        ],
        axis=-1,
    )
    bbox = np.where(detected[..., None], bbox, 0.0)
    frac_vis = visible.sum(-1) / n_j
    bbox_score = np.clip(0.55 + 0.45 * frac_vis * rng.uniform(0.9, 1.0, frac_vis.shape), 0.0, 1.0)

    track_ids = np.stack([rng.choice(20, n_p, replace=False) for _ in range(n_v)])  # (V, P)
    track = np.broadcast_to(track_ids[:, None, :], (n_v, n_f, n_p)).copy()
    swaps: list[tuple[int, int]] = []
    if id_swaps and n_p >= 2:
        both = detected[:, :, 0] & detected[:, :, 1]
        iou = np.where(both, _iou(bbox[:, :, 0], bbox[:, :, 1]), 0.0)
        iou[:, :2] = 0.0
        iou[:, max(3, n_f - 5) :] = 0.0  # a swap in the last frames would hardly matter
        cand_views = [v for v in range(n_v) if np.any(iou[v] >= SWAP_IOU)]
        if not cand_views and iou.max() > SWAP_IOU_FALLBACK:
            cand_views = [int(np.unravel_index(np.argmax(iou), iou.shape)[0])]
        n_swaps = min(len(cand_views), 1 if n_v <= 4 else 2)
        chosen = sorted(rng.choice(cand_views, n_swaps, replace=False).tolist()) if n_swaps else []
        for v in chosen:
            frames = np.flatnonzero(iou[v] >= min(SWAP_IOU, iou[v].max()))
            f0 = int(rng.choice(frames))
            track[v, f0:, 0], track[v, f0:, 1] = track_ids[v, 1], track_ids[v, 0]
            swaps.append((int(v), f0))

    # Flat rows ordered by (frame, view, person).
    fvp = np.transpose(detected, (1, 0, 2))
    f_idx, v_idx, p_idx = np.nonzero(fvp)
    sel = (v_idx, f_idx, p_idx)
    tracks = Tracks2D(
        joint_names=COCO17_FEET,
        n_views=n_v,
        n_frames=n_f,
        view=v_idx.astype(np.int64),
        frame=f_idx.astype(np.int64),
        bbox_xyxy_px=bbox[sel].astype(np.float64),
        bbox_score=bbox_score[sel].astype(np.float64),
        keypoints_px=kp[sel].astype(np.float64),
        keypoint_conf=conf[sel].astype(np.float64),
        keypoint_valid=valid[sel],
        track_id=track[sel].astype(np.int64),
    )
    return Render2D(
        tracks=tracks,
        person_of_det=person_ids[p_idx].astype(np.int64),
        clean_px=uv[sel],
        occluded=occluded[sel],
        swap_frames=np.array(swaps, dtype=np.int64).reshape(-1, 2),
        n_views_visible=visible.sum(0).astype(np.int64),
    )
