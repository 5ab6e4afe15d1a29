"""Per-view multi-person tracking: detections → persistent track ids.

ByteTrack / OC-SORT style, per camera:

1. Every track has a constant-velocity Kalman filter on its box centre and size.
2. Matching cost = 1 − (w·IoU + (1−w)·OKS), OKS comparing the detection's keypoints
   with the track's last keypoints moved by the predicted displacement.
3. Two stages: confident detections first (against every recent track), then the
   low-score ones against the tracks left over (IoU only), as ByteTrack.
4. A track unmatched for more than ``max_age_s`` is *lost*. A new confident detection
   is first compared with lost tracks through a keypoint-geometry embedding
   (normalised limb-length ratios) plus a position gate, so an athlete hidden behind
   the other for a while gets the old id back (long-term re-identification).
5. Offline clean-up: tracks with fewer than ``min_track_len`` detections get id −1.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Detections2D, Tracks2D
from pipeline.schema.joints import BODY_LIMBS

# COCO keypoint OKS sigmas; the foot points reuse the ankle's.
_COCO_SIGMAS = {
    "nose": 0.026, "left_eye": 0.025, "right_eye": 0.025, "left_ear": 0.035, "right_ear": 0.035,
    "left_shoulder": 0.079, "right_shoulder": 0.079, "left_elbow": 0.072, "right_elbow": 0.072,
    "left_wrist": 0.062, "right_wrist": 0.062, "left_hip": 0.107, "right_hip": 0.107,
    "left_knee": 0.087, "right_knee": 0.087, "left_ankle": 0.089, "right_ankle": 0.089,
}  # fmt: skip

# Limbs whose length ratios form the re-identification embedding.
_EMBED_LIMBS: tuple[tuple[str, str], ...] = BODY_LIMBS


@dataclass(frozen=True)
class TrackConfig:
    """Per-view tracker settings."""

    high_score: float = 0.5
    """Detections at or above this box score are matched first and may start tracks."""
    low_score: float = 0.1
    """Detections in ``[low_score, high_score)`` only extend existing tracks (ByteTrack)."""
    iou_weight: float = 0.5
    """Weight of box IoU in the similarity; the rest is keypoint OKS."""
    min_similarity: float = 0.2
    """Matches with a lower similarity (IoU/OKS mix) are rejected."""
    low_min_iou: float = 0.4
    """Minimum IoU for the second (low-score) matching stage."""
    min_keypoint_conf: float = 0.3
    """Keypoints below this confidence are ignored by OKS and the embedding."""
    max_age_s: float = 0.3
    """A track unmatched for longer than this is lost (only re-identification revives it)."""
    reid_max_gap_s: float = 20.0
    """Lost tracks older than this are forgotten."""
    reid_max_embed_dist: float = 0.25
    """Maximum mean absolute difference of limb-ratio embeddings for re-identification."""
    reid_gate_heights: float = 1.5
    """Position gate of re-identification: the new box centre must lie within this many
    box heights of the lost track's last centre (plus one height per second of gap)."""
    embed_momentum: float = 0.9
    """Exponential moving average factor of a track's embedding."""
    min_track_len: int = 5
    """Tracks with fewer detections are dropped (id −1)."""


# ---------------------------------------------------------------- Kalman filter


def _kalman_init(box: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    cx, cy, w, h = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2, box[2] - box[0], box[3] - box[1]
    x = np.array([cx, cy, w, h, 0, 0, 0, 0], float)
    s = max(h, 1.0)
    P = np.diag(np.array([s / 10, s / 10, s / 10, s / 10, s / 4, s / 4, s / 4, s / 4]) ** 2)
    return x, P


_F = np.eye(8)
_F[:4, 4:] = np.eye(4)
_H = np.eye(4, 8)


def _kalman_predict(x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = max(x[3], 1.0)
    Q = np.diag(np.array([s / 20, s / 20, s / 20, s / 20, s / 160, s / 160, s / 160, s / 160]) ** 2)
    x = _F @ x
    x[2:4] = np.maximum(x[2:4], 1.0)
    return x, _F @ P @ _F.T + Q


def _kalman_update(x: np.ndarray, P: np.ndarray, box: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    z = np.array([(box[0] + box[2]) / 2, (box[1] + box[3]) / 2, box[2] - box[0], box[3] - box[1]])
    s = max(x[3], 1.0)
    R = np.diag(np.array([s / 20, s / 20, s / 20, s / 20]) ** 2)
    S = _H @ P @ _H.T + R
    K = P @ _H.T @ np.linalg.inv(S)
    x = x + K @ (z - _H @ x)
    return x, (np.eye(8) - K @ _H) @ P


def _state_box(x: np.ndarray) -> np.ndarray:
    return np.array([x[0] - x[2] / 2, x[1] - x[3] / 2, x[0] + x[2] / 2, x[1] + x[3] / 2])


# ---------------------------------------------------------------- similarities


def iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n, m) IoU of xyxy boxes."""
    if len(a) == 0 or len(b) == 0:
        return np.zeros((len(a), len(b)))
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.prod(np.clip(rb - lt, 0, None), axis=2)
    area_a = np.prod(np.clip(a[:, 2:] - a[:, :2], 0, None), axis=1)
    area_b = np.prod(np.clip(b[:, 2:] - b[:, :2], 0, None), axis=1)
    return inter / np.maximum(area_a[:, None] + area_b[None] - inter, 1e-9)


def oks_matrix(
    kp_a: np.ndarray,
    ok_a: np.ndarray,
    kp_b: np.ndarray,
    ok_b: np.ndarray,
    area_b: np.ndarray,
    sigmas: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """(n, m) object keypoint similarity and a (n, m) bool "has common joints" mask.

    ``kp_* (n|m, J, 2)``, ``ok_* (n|m, J)``, ``area_b (m,)`` scale (box area) of ``b``.
    """
    d2 = np.sum((kp_a[:, None] - kp_b[None]) ** 2, axis=3)  # (n, m, J)
    var = (2 * sigmas) ** 2 * np.maximum(area_b, 1.0)[None, :, None] * 2
    e = np.exp(-d2 / var)
    both = ok_a[:, None] & ok_b[None]
    cnt = both.sum(axis=2)
    oks = np.where(cnt > 0, np.sum(e * both, axis=2) / np.maximum(cnt, 1), 0.0)
    return oks, cnt > 0


def limb_embedding(
    kp: np.ndarray, ok: np.ndarray, limbs: list[tuple[int, int]]
) -> tuple[np.ndarray, np.ndarray]:
    """Limb lengths divided by their mean over the valid limbs: ``(L,)`` values and ``(L,)`` validity."""
    a, b = np.array([i for i, _ in limbs]), np.array([j for _, j in limbs])
    length = np.linalg.norm(kp[a] - kp[b], axis=1)
    valid = ok[a] & ok[b] & (length > 1e-6)
    if valid.sum() < 4:
        return np.zeros(len(limbs)), np.zeros(len(limbs), bool)
    return np.where(valid, length / length[valid].mean(), 0.0), valid


# ---------------------------------------------------------------- tracker


@dataclass
class _Track:
    tid: int
    x: np.ndarray
    P: np.ndarray
    last_frame: int
    last_box: np.ndarray
    last_kp: np.ndarray
    last_ok: np.ndarray
    emb: np.ndarray
    emb_w: np.ndarray
    rows: list[int] = field(default_factory=list)

    def observe(
        self, row: int, frame: int, box: np.ndarray, kp: np.ndarray, ok: np.ndarray, emb: tuple, mom: float
    ) -> None:
        self.x, self.P = _kalman_update(self.x, self.P, box)
        self.last_frame, self.last_box, self.last_kp, self.last_ok = frame, box, kp, ok
        e, ev = emb
        both = ev & (self.emb_w > 0)
        self.emb = np.where(both, mom * self.emb + (1 - mom) * e, np.where(ev, e, self.emb))
        self.emb_w = np.where(ev, np.minimum(self.emb_w + 1, 50), self.emb_w)
        self.rows.append(row)

    def predicted_keypoints(self) -> np.ndarray:
        c_last = (self.last_box[:2] + self.last_box[2:]) / 2
        return self.last_kp + (self.x[:2] - c_last)


def _assign(sim: np.ndarray, thr: float) -> list[tuple[int, int]]:
    if sim.size == 0:
        return []
    r, c = linear_sum_assignment(-sim)
    return [(int(i), int(j)) for i, j in zip(r, c, strict=True) if sim[i, j] >= thr]


def track_view(dets: Detections2D, rows: np.ndarray, fps: float, cfg: TrackConfig) -> np.ndarray:
    """Track ids for the detection ``rows`` (all of one view); −1 for untracked rows."""
    names = dets.joint_names
    sigmas = np.array([_COCO_SIGMAS.get(n, 0.089) for n in names])
    limbs = [(names.index(a), names.index(b)) for a, b in _EMBED_LIMBS if a in names and b in names]
    max_age = max(1, int(round(cfg.max_age_s * fps)))
    reid_gap = max(max_age + 1, int(round(cfg.reid_max_gap_s * fps)))
    ok_all = dets.keypoint_valid & (dets.keypoint_conf >= cfg.min_keypoint_conf)
    active: list[_Track] = []
    lost: list[_Track] = []
    finished: list[_Track] = []
    next_id = 0
    frames = dets.frame[rows]
    order = rows[np.argsort(frames, kind="stable")]
    for f in np.unique(frames):
        fr = order[dets.frame[order] == f]
        for t in active:
            t.x, t.P = _kalman_predict(t.x, t.P)
        for t in lost:  # lost tracks coast without velocity (their box is only a gate)
            t.x[4:] = 0.0
        boxes, scores = dets.bbox_xyxy_px[fr], dets.bbox_score[fr]
        embs = [limb_embedding(dets.keypoints_px[r], ok_all[r], limbs) for r in fr]

        def observe(
            track: _Track,
            d: int,
            f: int = int(f),
            fr: np.ndarray = fr,
            boxes: np.ndarray = boxes,
            embs: list[tuple[np.ndarray, np.ndarray]] = embs,
        ) -> None:
            """Update ``track`` with this frame's detection ``d`` (an index into ``fr``)."""
            track.observe(
                int(fr[d]), f, boxes[d], dets.keypoints_px[fr[d]], ok_all[fr[d]], embs[d], cfg.embed_momentum
            )

        high = np.flatnonzero(scores >= cfg.high_score)
        low = np.flatnonzero((scores >= cfg.low_score) & (scores < cfg.high_score))
        # Stage 1: confident detections vs every active track, IoU + OKS.
        matched_t: set[int] = set()
        matched_d: set[int] = set()
        if active and high.size:
            tb = np.stack([_state_box(t.x) for t in active])
            db = boxes[high]
            iou = iou_matrix(tb, db)
            tkp = np.stack([t.predicted_keypoints() for t in active])
            tok = np.stack([t.last_ok for t in active])
            area = (db[:, 2] - db[:, 0]) * (db[:, 3] - db[:, 1])
            oks, has = oks_matrix(tkp, tok, dets.keypoints_px[fr[high]], ok_all[fr[high]], area, sigmas)
            sim = np.where(has, cfg.iou_weight * iou + (1 - cfg.iou_weight) * oks, iou)
            sim = np.where(iou > 0, sim, 0.0)
            for i, j in _assign(sim, cfg.min_similarity):
                d = int(high[j])
                observe(active[i], d)
                matched_t.add(i)
                matched_d.add(d)
        # Stage 2: low-score detections vs the remaining active tracks, IoU only.
        rest = [i for i in range(len(active)) if i not in matched_t]
        if rest and low.size:
            tb = np.stack([_state_box(active[i].x) for i in rest])
            for i, j in _assign(iou_matrix(tb, boxes[low]), cfg.low_min_iou):
                d = int(low[j])
                t = active[rest[i]]
                observe(t, d)
                matched_t.add(rest[i])
                matched_d.add(d)
        # Tracks unmatched for too long become lost.
        still: list[_Track] = []
        for t in active:
            (still if f - t.last_frame <= max_age else lost).append(t)
        active = still
        lost_keep: list[_Track] = []
        for t in lost:
            (lost_keep if f - t.last_frame <= reid_gap else finished).append(t)
        lost = lost_keep
        # Stage 3: unmatched confident detections — re-identify lost tracks, else new tracks.
        new = [int(d) for d in high if int(d) not in matched_d]
        if new and lost:
            cost = np.full((len(lost), len(new)), np.inf)
            for a, t in enumerate(lost):
                gap_s = (f - t.last_frame) / fps
                c_last = (t.last_box[:2] + t.last_box[2:]) / 2
                h = max(t.last_box[3] - t.last_box[1], 1.0)
                for b, d in enumerate(new):
                    e, ev = embs[d]
                    both = ev & (t.emb_w > 0)
                    if both.sum() < 4:
                        continue
                    de = float(np.mean(np.abs(e[both] - t.emb[both])))
                    c = (boxes[d, :2] + boxes[d, 2:]) / 2
                    dist_h = float(np.linalg.norm(c - c_last)) / h
                    gate = cfg.reid_gate_heights + gap_s
                    if de <= cfg.reid_max_embed_dist and dist_h <= gate:
                        cost[a, b] = de / cfg.reid_max_embed_dist + dist_h / gate
            finite = np.where(np.isfinite(cost), cost, 1e6)
            r, c = linear_sum_assignment(finite)
            revived = []
            for a, b in zip(r, c, strict=True):
                if not np.isfinite(cost[a, b]):
                    continue
                d = new[b]
                t = lost[a]
                t.x, t.P = _kalman_init(boxes[d])
                observe(t, d)
                revived.append(a)
                matched_d.add(d)
            for a in sorted(revived, reverse=True):
                active.append(lost.pop(a))
        for d in map(int, high):
            if d in matched_d:
                continue
            x, P = _kalman_init(boxes[d])
            e, ev = embs[d]
            t = _Track(
                next_id,
                x,
                P,
                int(f),
                boxes[d],
                dets.keypoints_px[fr[d]],
                ok_all[fr[d]],
                e.copy(),
                ev.astype(float),
            )
            t.rows.append(int(fr[d]))
            next_id += 1
            active.append(t)
    out = np.full(dets.n_dets, -1, np.int64)
    kept = sorted(
        (t for t in active + lost + finished if len(t.rows) >= cfg.min_track_len), key=lambda t: min(t.rows)
    )
    for k, t in enumerate(kept):
        out[t.rows] = k
    return out[rows]


def run(dets: Detections2D, rig: CameraRig, cfg: TrackConfig = TrackConfig()) -> Tracks2D:
    """Track every view independently; ids are numbered per view from 0 by first appearance.

    ``ValueError`` if the detections do not have the rig's number of views.
    """
    if dets.n_views != rig.n_views:
        raise ValueError(f"detections have {dets.n_views} views but the rig has {rig.n_views} ({rig.names})")
    track_id = np.full(dets.n_dets, -1, np.int64)
    for v in range(dets.n_views):
        rows = np.flatnonzero(dets.view == v)
        if rows.size:
            track_id[rows] = track_view(dets, rows, float(rig.fps), cfg)
    return Tracks2D.from_detections(dets, track_id)
