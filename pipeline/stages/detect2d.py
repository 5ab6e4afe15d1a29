"""2D stage on videos: a person detector, then a top-down keypoint model on each box.

``run_videos`` streams each camera's video (never all frames in memory), detects
people in batches of frames, estimates ``COCO17_FEET`` keypoints per box (joints the
model does not provide are invalid) and returns flat ``Detections2D`` rows.
onnxruntime is only imported through ``pipeline.backends`` when ``run_videos`` runs.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Detections2D
from pipeline.schema.joints import COCO17_FEET

log = logging.getLogger(__name__)

ProgressFn = Callable[[float, float | None, str], None]


@dataclass(frozen=True)
class Detect2DConfig:
    """Models and thresholds of the video 2D stage."""

    detector: Literal["rtmdet_nano", "yolox_nano", "yolox_s", "yolox_m"] = "rtmdet_nano"
    """Person detector (registry name; see ``cornerman models list``)."""
    pose_model: Literal[
        "blazepose_full", "movenet_lightning", "rtmpose_m", "rtmpose_l", "vitpose_b", "vitpose_l", "vitpose_h"
    ] = "movenet_lightning"
    """Top-down keypoint model of the body. Of the small models that ship for tests, MoveNet
    is the more consistent across views on real video (see ``docs/design``); only BlazePose
    provides heels and big toes, hence ``foot_model``."""
    foot_model: Literal["none", "blazepose_full"] = "blazepose_full"
    """A second keypoint model run on the same boxes for the feet only: its heels and toes
    are kept where its ankles agree with the main model's (``foot_ankle_max_frac``), so a
    model without feet (MoveNet) still gets foot points. ``none``: only ``pose_model``'s."""
    foot_ankle_max_frac: float = 0.05
    """Largest distance between the two models' ankles, as a fraction of the box height, for
    the foot model's heel and toes of that side to be used, in (0, 1)."""
    models_dir: str | None = None
    """Folder searched first for the model files (else ``$CORNERMAN_MODELS_DIR``, then the cache)."""
    det_score_thr: float = 0.3
    """Person boxes below this detector score are dropped."""
    nms_iou: float = 0.45
    """IoU above which overlapping boxes are suppressed (YOLOX; RTMDet does NMS in-graph)."""
    max_persons: int = 12
    """At most this many boxes per frame (best scores first)."""
    min_box_height_frac: float = 0.05
    """Boxes shorter than this fraction of the image height are dropped (far-away people)."""
    det_input_size: int = 0
    """Square detector input side in pixels; 0 = the registry's size for that model."""
    batch_size: int = 4
    """Frames per camera per step: every camera's next ``batch_size`` frames are detected in
    one call and their person crops batched (models with a fixed batch of 1 run them one
    by one). Memory holds ``batch_size × cameras`` frames at most."""
    crop_scale: float = 1.25
    """Side of the keypoint crop relative to the box's longer side."""
    upright_crops: bool = True
    """BlazePose: re-run tilted people on a crop rotated upright (hips→shoulders)."""
    pose_flip_test: bool = False
    """MoveNet: average each joint over the crop and its mirror image (twice the model runs)."""
    pose_refine_scale: float = 1.3
    """MoveNet: > 0 runs a second pass on a square crop of this many times the first pass's
    keypoint extent (>= 1 in practice; see docs/design/pose-models.md); 0 = one pass."""
    min_keypoint_conf: float = 0.0
    """Keypoints below this confidence are marked invalid."""
    pose_nms_dist: float = 0.1
    """Pose NMS: two detections of one frame whose confident keypoints lie (median) within
    this fraction of the smaller box's height of each other describe one person (a top-down
    model given a box that holds two people often returns the other one's pose); the one
    whose box fits its keypoints worse is dropped. In [0, 1); 0 = off."""
    frame_step: int = 1
    """Process every n-th frame (frame indices keep the video's numbering)."""
    max_frames: int = 0
    """Stop after this many video frames per camera (0 = whole video)."""
    num_threads: int = 0
    """onnxruntime intra-op threads (0 = all cores)."""

    def __post_init__(self) -> None:
        if not 0.0 < self.foot_ankle_max_frac < 1.0:
            raise ValueError(f"Detect2DConfig.foot_ankle_max_frac must be in (0, 1), got {self.foot_ankle_max_frac!r}")
        if self.pose_refine_scale < 0.0:
            raise ValueError(f"Detect2DConfig.pose_refine_scale must be >= 0, got {self.pose_refine_scale!r}")
        if not 0.0 <= self.pose_nms_dist < 1.0:
            raise ValueError(f"Detect2DConfig.pose_nms_dist must be in [0, 1), got {self.pose_nms_dist!r}")


@dataclass(frozen=True)
class FrameResult:
    """Detections of one frame: ``boxes (n, 4)``, ``scores (n,)``, ``kp (n, J, 2)``, ``conf``/``valid (n, J)``."""

    boxes: np.ndarray
    scores: np.ndarray
    kp: np.ndarray
    conf: np.ndarray
    valid: np.ndarray


class Models:
    """The loaded detector and keypoint model of a ``Detect2DConfig``."""

    def __init__(self, cfg: Detect2DConfig) -> None:
        from pipeline.backends.onnx.detectors import DetectorParams, make_detector
        from pipeline.backends.onnx.pose import PoseParams, make_pose_estimator
        from pipeline.registry import get_model, resolve_model

        det_info, pose_info = get_model(cfg.detector), get_model(cfg.pose_model)
        if det_info.task != "detector" or pose_info.task != "pose":
            raise ValueError(f"detector={cfg.detector!r} / pose_model={cfg.pose_model!r}: wrong model kinds")
        size = cfg.det_input_size or det_info.input_size_hw[0]
        self.detector = make_detector(
            det_info.decoder,
            resolve_model(cfg.detector, cfg.models_dir),
            DetectorParams(cfg.det_score_thr, cfg.nms_iou, cfg.max_persons, (size, size), cfg.num_threads),
        )
        params = PoseParams(
            crop_scale=cfg.crop_scale,
            upright=cfg.upright_crops,
            num_threads=cfg.num_threads,
            flip_test=cfg.pose_flip_test,
            refine_scale=cfg.pose_refine_scale,
        )
        self.pose = make_pose_estimator(pose_info.decoder, resolve_model(cfg.pose_model, cfg.models_dir), params)
        self.feet = None
        if cfg.foot_model != "none" and cfg.foot_model != cfg.pose_model:
            foot_info = get_model(cfg.foot_model)
            self.feet = make_pose_estimator(foot_info.decoder, resolve_model(cfg.foot_model, cfg.models_dir), params)


def detect_boxes(
    images: list[np.ndarray], models: Models, cfg: Detect2DConfig
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Person boxes per image after the size filter."""
    out = []
    for im, (b, s) in zip(images, models.detector.detect(images), strict=True):
        keep = (b[:, 3] - b[:, 1]) >= cfg.min_box_height_frac * im.shape[0]
        out.append((b[keep], s[keep]))
    return out


def process_frames(images: list[np.ndarray], models: Models, cfg: Detect2DConfig) -> list[FrameResult]:
    """Detect people and estimate their keypoints on a batch of BGR frames."""
    from pipeline.backends.onnx.pose import estimate_many

    dets = detect_boxes(images, models, cfg)
    boxes = [b for b, _ in dets]
    poses = estimate_many(models.pose, images, boxes)
    if models.feet is not None:
        feet = estimate_many(models.feet, images, boxes)
        poses = [merge_feet(p, f, b, cfg.foot_ankle_max_frac) for p, f, b in zip(poses, feet, boxes, strict=True)]
    res = []
    for (b, s), (kp, conf, valid) in zip(dets, poses, strict=True):
        valid = valid & (conf >= cfg.min_keypoint_conf) & np.isfinite(kp).all(axis=2)
        keep = duplicate_pose_keep(b, kp, conf, valid, cfg.pose_nms_dist)
        res.append(FrameResult(b[keep], s[keep], kp[keep], conf[keep], valid[keep]))
    return res


_FOOT_POINTS = {
    side: ([COCO17_FEET.index(f"{side}_{p}") for p in ("big_toe", "small_toe", "heel")], COCO17_FEET.index(f"{side}_ankle"))
    for side in ("left", "right")
}


def merge_feet(
    main: tuple[np.ndarray, np.ndarray, np.ndarray],
    feet: tuple[np.ndarray, np.ndarray, np.ndarray],
    boxes: np.ndarray,
    max_frac: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``main``'s (kp (n, 23, 2), conf, valid) with the heel and toes of ``feet`` (same boxes)
    on each side where both models see the ankle within ``max_frac`` of the box height.

    The main model's own foot points are kept where it has them."""
    kp, conf, valid = (a.copy() for a in main)
    kf, cf, vf = feet
    height = boxes[:, 3] - boxes[:, 1] if boxes.size else np.zeros(0)
    for pts, ankle in _FOOT_POINTS.values():
        agree = valid[:, ankle] & vf[:, ankle]
        agree &= np.linalg.norm(kp[:, ankle] - kf[:, ankle], axis=-1) <= max_frac * height
        for j in pts:
            take = agree & vf[:, j] & ~valid[:, j]
            kp[take, j], conf[take, j], valid[take, j] = kf[take, j], cf[take, j], True
    return kp, conf, valid


def _box_iou(a: np.ndarray, b: np.ndarray) -> float:
    """IoU of two xyxy boxes."""
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = w * h
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def duplicate_pose_keep(
    boxes: np.ndarray, kp: np.ndarray, conf: np.ndarray, valid: np.ndarray, max_dist: float, min_conf: float = 0.3
) -> np.ndarray:
    """(n,) bool: the detections of one frame kept by pose NMS (see ``Detect2DConfig.pose_nms_dist``).

    boxes (n, 4) xyxy px, kp (n, J, 2) px, conf / valid (n, J). Two poses sharing at least 5
    confident keypoints whose median distance is below ``max_dist`` times the smaller box
    height are one person; of the two, the detection whose box has the lower IoU with the
    bounding box of its own confident keypoints is dropped.
    """
    n = boxes.shape[0]
    keep = np.ones(n, dtype=bool)
    if max_dist <= 0 or n < 2:
        return keep
    good = valid & (conf >= min_conf)
    fit = np.zeros(n)
    for i in range(n):
        pts = kp[i][good[i]]
        if pts.shape[0] >= 2:
            fit[i] = _box_iou(boxes[i], np.r_[pts.min(axis=0), pts.max(axis=0)])
    height = boxes[:, 3] - boxes[:, 1]
    for i in range(n):
        for k in range(i + 1, n):
            if not (keep[i] and keep[k]):
                continue
            both = good[i] & good[k]
            if both.sum() < 5:
                continue
            d = float(np.median(np.linalg.norm(kp[i, both] - kp[k, both], axis=-1)))
            if d < max_dist * min(height[i], height[k]):
                keep[k if fit[k] < fit[i] else i] = False
    return keep


def run_videos(
    videos: dict[str, Path],
    rig: CameraRig,
    progress: ProgressFn | None = None,
    cfg: Detect2DConfig = Detect2DConfig(),
) -> Detections2D:
    """Detections of every camera's video.

    Args:
        videos: camera name → video file; the names must be exactly the rig's.
        rig: the calibration (defines the view order).
        progress: ``progress(done_frames, total_frames, message)``.
        cfg: models and thresholds.

    Raises ``ValueError`` naming the camera for a name not in the rig or a rig camera
    without a video, and naming the file for a missing/corrupt/empty video or model.
    A camera where nobody is detected gets a logged warning and no rows.
    """
    from pipeline.io.video import iter_frames, video_info

    unknown = [k for k in videos if k not in rig.names]
    if unknown:
        raise ValueError(f"videos for camera(s) {unknown} that are not in the calibration {list(rig.names)}")
    missing = [n for n in rig.names if n not in videos]
    if missing:
        raise ValueError(f"no video for camera(s) {missing} of the calibration")
    if cfg.frame_step < 1 or cfg.batch_size < 1:
        raise ValueError(f"frame_step={cfg.frame_step} and batch_size={cfg.batch_size} must be >= 1")
    infos = {n: video_info(Path(videos[n])) for n in rig.names}
    stop = {
        n: (min(i.n_frames, cfg.max_frames) if cfg.max_frames > 0 else i.n_frames) for n, i in infos.items()
    }
    total = float(sum(len(range(0, s, cfg.frame_step)) for s in stop.values()))
    models = Models(cfg)
    rows: dict[str, list[Any]] = {k: [] for k in ("view", "frame", "box", "score", "kp", "conf", "valid")}
    done, n_frames = 0, 0
    n_view = [0] * rig.n_views
    for v, name in enumerate(rig.names):
        info = infos[name]
        w, h = (int(x) for x in rig.image_size_wh[v])
        if (info.width_px, info.height_px) != (w, h):
            log.warning(
                "camera %s: video %s is %dx%d but the calibration says %dx%d",
                name, info.path, info.width_px, info.height_px, w, h,
            )  # fmt: skip
        if info.fps > 0 and abs(info.fps - rig.fps) > 0.01 * rig.fps:
            log.warning(
                "camera %s: video %s is %.3g fps but the rig says %.3g fps (set the session's fps)",
                name, info.path, info.fps, rig.fps,
            )  # fmt: skip
    # All cameras advance in lockstep, ``batch_size`` frames each per step, so that the
    # detector and keypoint batches span views and only one step's frames are in memory.
    streams = {
        v: _chunks(
            iter_frames(infos[n].path, 0, cfg.max_frames if cfg.max_frames > 0 else None, cfg.frame_step),
            cfg.batch_size,
        )
        for v, n in enumerate(rig.names)
    }
    while streams:
        step: list[tuple[int, int, np.ndarray]] = []
        for v in list(streams):
            chunk = next(streams[v], None)
            if chunk is None:
                del streams[v]
                continue
            step += [(v, i, im) for i, im in chunk]
        if not step:
            break
        results = process_frames([im for _, _, im in step], models, cfg)
        for (v, fi, _), r in zip(step, results, strict=True):
            n = len(r.boxes)
            n_view[v] += n
            rows["view"].append(np.full(n, v))
            rows["frame"].append(np.full(n, fi))
            for k, a in (("box", r.boxes), ("score", r.scores), ("kp", r.kp), ("conf", r.conf), ("valid", r.valid)):
                rows[k].append(a)
            n_frames = max(n_frames, fi + 1)
        done += len(step)
        if progress is not None:
            progress(float(done), total, f"frame {max(fi for _, fi, _ in step) + 1}/{max(stop.values())}")
    for v, name in enumerate(rig.names):
        if n_view[v] == 0:
            log.warning(
                "camera %s (%s): no person detected in any frame; this view has no detections",
                name,
                infos[name].path,
            )
    J = len(COCO17_FEET)

    def cat(k: str, shape: tuple[int, ...], dtype: Any) -> np.ndarray:
        return np.concatenate(rows[k]).astype(dtype) if rows[k] else np.zeros(shape, dtype)

    valid = cat("valid", (0, J), bool)
    kp = np.where(valid[..., None], cat("kp", (0, J, 2), np.float64), 0.0)
    conf = np.where(valid, np.clip(cat("conf", (0, J), np.float64), 0.0, 1.0), 0.0)
    return Detections2D(
        joint_names=COCO17_FEET,
        n_views=rig.n_views,
        n_frames=max(n_frames, 1),
        view=cat("view", (0,), np.int64),
        frame=cat("frame", (0,), np.int64),
        bbox_xyxy_px=cat("box", (0, 4), np.float64),
        bbox_score=cat("score", (0,), np.float64),
        keypoints_px=kp,
        keypoint_conf=conf,
        keypoint_valid=valid,
    )


def _chunks(it: Any, n: int) -> Any:
    buf: list[Any] = []
    for x in it:
        buf.append(x)
        if len(buf) == n:
            yield buf
            buf = []
    if buf:
        yield buf
