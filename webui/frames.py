"""Camera frames for the GUI: lazy, cached decode per view, plus 2D overlays drawn with cv2.

Frames are kept at display resolution (``max_width``) in an LRU cache, so scrubbing back
and forth over recent frames costs a dictionary lookup; a sequential play decodes each
frame once (``grab`` continues from the last position instead of seeking).

Sessions without videos (the synthetic bout, keypoint imports) get a rendered
stand-in: a dark background with the ring floor projected through the calibration,
so that detections and reprojections still have a frame to sit on.
"""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from pipeline.geometry.projection import project
from pipeline.schema.camera import CameraRig
from pipeline.schema.joints import bone_indices
from webui.colors import IdentityPalette
from webui.scene.session_data import SessionData, frame_row

log = logging.getLogger(__name__)

BACKGROUND_RGB = (24, 26, 32)
FLOOR_RGB = (70, 74, 86)
RING_RGB = (160, 160, 170)


def display_scale(rig: CameraRig, view: int, max_width: int) -> float:
    w = int(rig.image_size_wh[view, 0])
    return min(1.0, max_width / float(w))


def _scaled_rig_view(rig: CameraRig, view: int, scale: float) -> CameraRig:
    sub = rig.subset([view])
    K = sub.K.copy()
    K[:, :2, :] *= scale
    size = np.maximum(1, np.round(sub.image_size_wh * scale)).astype(np.int64)
    return CameraRig(sub.names, K, sub.dist, sub.T_world_cam, size, sub.fps, sub.time_offset_s)


def _draw_world_polyline(img: np.ndarray, rig1: CameraRig, pts_m: np.ndarray, color: tuple[int, int, int], thick: int) -> None:
    """Draw a world polyline (subdivided, so lens distortion bends it) in a 1-view rig's image."""
    dense = np.concatenate([np.linspace(a, b, 24, endpoint=False) for a, b in zip(pts_m[:-1], pts_m[1:], strict=True)] + [pts_m[-1:]])
    uv, depth = project(rig1, dense)
    uv, depth = uv[0], depth[0]
    for i in range(len(dense) - 1):
        if depth[i] > 0.05 and depth[i + 1] > 0.05:
            p0 = tuple(int(round(c)) for c in uv[i])
            p1 = tuple(int(round(c)) for c in uv[i + 1])
            if max(abs(p0[0]), abs(p0[1]), abs(p1[0]), abs(p1[1])) < 20000:
                cv2.line(img, p0, p1, color, thick, cv2.LINE_AA)


def render_synthetic_background(rig: CameraRig, view: int, scale: float, ring_half_m: float = 3.05) -> np.ndarray:
    """(H, W, 3) uint8 RGB stand-in camera image: dark background, 1 m floor grid, ring square."""
    r1 = _scaled_rig_view(rig, view, scale)
    w, h = (int(x) for x in r1.image_size_wh[0])
    img = np.empty((h, w, 3), dtype=np.uint8)
    img[:] = BACKGROUND_RGB
    ext = 5.0
    for x in np.arange(-ext, ext + 1e-9, 1.0):
        _draw_world_polyline(img, r1, np.array([[x, -ext, 0.0], [x, ext, 0.0]]), FLOOR_RGB, 1)
        _draw_world_polyline(img, r1, np.array([[-ext, x, 0.0], [ext, x, 0.0]]), FLOOR_RGB, 1)
    s = ring_half_m
    square = np.array([[-s, -s, 0], [s, -s, 0], [s, s, 0], [-s, s, 0], [-s, -s, 0]], dtype=np.float64)
    _draw_world_polyline(img, r1, square, RING_RGB, 2)
    return img


class FrameProvider:
    """Display-resolution RGB frames of every view, decoded lazily and cached (thread-safe)."""

    def __init__(self, data: SessionData, max_width: int = 480, cache_frames: int = 512) -> None:
        self.rig = data.rig
        self.max_width = max_width
        self.cache_frames = cache_frames
        self._cache: OrderedDict[tuple[int, int], np.ndarray] = OrderedDict()
        self._lock = threading.Lock()
        self._view_locks = [threading.Lock() for _ in range(self.rig.n_views)]
        self._caps: dict[int, cv2.VideoCapture] = {}
        self._next_pos: dict[int, int] = {}
        self._backgrounds: dict[int, np.ndarray] = {}
        self.videos: dict[int, Path] = {}
        cfg = data.config
        if cfg.source == "video":
            for name, rel in cfg.camera_inputs().items():  # only the cameras the session uses
                p = Path(rel)
                self.videos[self.rig.index(name)] = p if p.is_absolute() else data.session_dir / p
        self._pool: ThreadPoolExecutor | None = None
        self.decoded = 0
        """Number of frames decoded from video so far (for tests and the bench)."""

    def scale(self, view: int) -> float:
        return display_scale(self.rig, view, self.max_width)

    def _decode(self, view: int, frame: int) -> np.ndarray | None:
        cap = self._caps.get(view)
        if cap is None:
            path = self.videos[view]
            cap = cv2.VideoCapture(str(path))
            if not cap.isOpened():
                raise ValueError(f"{path}: cannot open video of camera {self.rig.names[view]!r}")
            self._caps[view] = cap
            self._next_pos[view] = 0
        if self._next_pos.get(view) != frame:
            cap.set(cv2.CAP_PROP_POS_FRAMES, frame)
        ok, bgr = cap.read()
        self._next_pos[view] = frame + 1 if ok else -1
        if not ok:
            return None
        self.decoded += 1
        s = self.scale(view)
        if s < 1.0:
            bgr = cv2.resize(bgr, (max(1, round(bgr.shape[1] * s)), max(1, round(bgr.shape[0] * s))), interpolation=cv2.INTER_AREA)
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)

    def _background(self, view: int) -> np.ndarray:
        bg = self._backgrounds.get(view)
        if bg is None:
            bg = render_synthetic_background(self.rig, view, self.scale(view))
            self._backgrounds[view] = bg
        return bg

    def frame(self, view: int, frame: int) -> np.ndarray:
        """(H, W, 3) uint8 RGB frame (a copy: callers draw on it)."""
        if view not in self.videos:
            return self._background(view).copy()
        key = (view, frame)
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None:
                self._cache.move_to_end(key)
                return hit.copy()
        with self._view_locks[view]:
            img = self._decode(view, frame)
        if img is None:
            log.warning("camera %s: frame %d could not be decoded; showing a blank frame", self.rig.names[view], frame)
            return self._background(view).copy()
        with self._lock:
            self._cache[key] = img
            while len(self._cache) > self.cache_frames:
                self._cache.popitem(last=False)
        return img.copy()

    def frames(self, frame: int) -> list[np.ndarray]:
        """Frame ``frame`` of every view; videos are decoded in parallel (OpenCV releases the GIL)."""
        if not self.videos:
            return [self.frame(v, frame) for v in range(self.rig.n_views)]
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=min(4, self.rig.n_views), thread_name_prefix="decode")
        return list(self._pool.map(lambda v: self.frame(v, frame), range(self.rig.n_views)))

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False)
        for cap in self._caps.values():
            cap.release()
        self._caps.clear()


@dataclass(frozen=True)
class Overlay2D:
    """What to draw on one view at one frame (pixels of the full-resolution image).

    Fields:
        boxes_px: (n, 4) detection boxes xyxy.
        keypoints_px: (n, joints, 2) detected keypoints; keypoint_valid: (n, joints).
        track_ids: (n,) per-view track ids; persons: (n,) assigned person (-1 = none).
        confidence: (n,) identity confidence.
        joint_names: joint set of the detections.
        reproj_px: (persons, joints3d, 2) reprojected 3D result; reproj_valid: (persons, joints3d).
        reproj_persons: (persons,) ids of ``reproj_px`` rows.
        joint_names_3d: joint set of the 3D result.
    """

    boxes_px: np.ndarray
    keypoints_px: np.ndarray
    keypoint_valid: np.ndarray
    track_ids: np.ndarray
    persons: np.ndarray
    confidence: np.ndarray
    joint_names: tuple[str, ...]
    reproj_px: np.ndarray
    reproj_valid: np.ndarray
    reproj_persons: np.ndarray
    joint_names_3d: tuple[str, ...]


def overlay_for(data: SessionData, view: int, frame: int, source: str) -> Overlay2D:
    """Detections of ``view`` at ``frame`` and the reprojection of keypoint source ``source``."""
    rows = data.det_rows(view, frame)
    t = data.tracks
    if t is not None:
        boxes, kps, kv, tid = t.bbox_xyxy_px[rows], t.keypoints_px[rows], t.keypoint_valid[rows], t.track_id[rows]
        names = t.joint_names
    else:
        boxes, kps, kv, tid = np.zeros((0, 4)), np.zeros((0, 1, 2)), np.zeros((0, 1), bool), np.zeros(0, np.int64)
        names = ("none",)
    kp3 = data.keypoints.get(source)
    r = frame_row(kp3, frame) if kp3 is not None else None
    if kp3 is not None and r is not None:
        uv, depth = project(data.rig.subset([view]), kp3.xyz_m[r])
        rp = uv[0]
        rv = kp3.valid[r] & (depth[0] > 0.05)
        rpid = kp3.person_ids.astype(np.int64)
        names3 = kp3.joint_names
    else:
        rp, rv, rpid, names3 = np.zeros((0, 1, 2)), np.zeros((0, 1), bool), np.zeros(0, np.int64), ("none",)
    return Overlay2D(
        boxes, kps, kv, tid, data.person_of_rows(rows), data.confidence_of_rows(rows), names, rp, rv, rpid, names3
    )


def _pt(p: np.ndarray, scale: float) -> tuple[int, int]:
    return int(round(float(p[0]) * scale)), int(round(float(p[1]) * scale))


def draw_overlay(
    img: np.ndarray, ov: Overlay2D, scale: float, palette: IdentityPalette, selected_track: int | None = None,
    show_reprojection: bool = True,
) -> np.ndarray:
    """Draw ``ov`` on an RGB display image (in place; also returned).

    Detections: box + skeleton + ``#track`` label in the colour of their assigned identity
    (grey when unassigned). Reprojection: thin white-edged skeleton in the identity colour,
    so a mismatch between the two shows at a glance (``show_reprojection=False``: not drawn,
    e.g. while the 3D result is out of date). The selected track gets a thick box.
    """
    h, w = img.shape[:2]
    lim = 4 * max(h, w)

    def ok(p: tuple[int, int]) -> bool:
        return abs(p[0]) < lim and abs(p[1]) < lim

    bones3 = bone_indices(ov.joint_names_3d)
    for i in range(ov.reproj_px.shape[0] if show_reprojection else 0):
        col = palette.rgb(int(ov.reproj_persons[i]))
        pts = ov.reproj_px[i]
        for a, b in bones3:
            if ov.reproj_valid[i, a] and ov.reproj_valid[i, b]:
                pa, pb = _pt(pts[a], scale), _pt(pts[b], scale)
                if ok(pa) and ok(pb):
                    cv2.line(img, pa, pb, (255, 255, 255), 3, cv2.LINE_AA)
                    cv2.line(img, pa, pb, col, 1, cv2.LINE_AA)
    bones2 = bone_indices(ov.joint_names)
    for i in range(ov.boxes_px.shape[0]):
        pid = int(ov.persons[i])
        col = palette.rgb(pid)
        x0, y0 = _pt(ov.boxes_px[i, :2], scale)
        x1, y1 = _pt(ov.boxes_px[i, 2:], scale)
        tid = int(ov.track_ids[i])
        sel = selected_track is not None and tid == selected_track and tid >= 0
        cv2.rectangle(img, (x0, y0), (x1, y1), col, 3 if sel else 1, cv2.LINE_AA)
        if sel:
            cv2.rectangle(img, (x0 - 3, y0 - 3), (x1 + 3, y1 + 3), (255, 255, 255), 1, cv2.LINE_AA)
        kp = ov.keypoints_px[i]
        for a, b in bones2:
            if ov.keypoint_valid[i, a] and ov.keypoint_valid[i, b]:
                cv2.line(img, _pt(kp[a], scale), _pt(kp[b], scale), col, 2, cv2.LINE_AA)
        for j in np.flatnonzero(ov.keypoint_valid[i]):
            cv2.circle(img, _pt(kp[j], scale), 2, col, -1, cv2.LINE_AA)
        label = f"#{tid} {palette.name(pid)}" if tid >= 0 else "untracked"
        cv2.putText(img, label, (x0, max(10, y0 - 4)), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 2, cv2.LINE_AA)
        cv2.putText(img, label, (x0, max(10, y0 - 4)), cv2.FONT_HERSHEY_SIMPLEX, 0.4, col, 1, cv2.LINE_AA)
    return img
