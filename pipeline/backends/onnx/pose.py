"""Top-down 2D keypoint models on ONNX, and the generic keypoint decoders.

Every estimator takes a BGR frame and person boxes and returns, per box, keypoints in
the frame's pixels in the ``COCO17_FEET`` joint set with confidence and a validity
mask (joints the model does not provide are invalid):

- ``BlazePoseEstimator``: MediaPipe BlazePose GHUM full (33 landmarks; heel and foot
  index map to ``*_heel`` / ``*_big_toe``), crop rotated upright from hips→shoulders.
- ``MoveNetEstimator``: MoveNet SinglePose Lightning (COCO-17).
- ``HeatmapEstimator`` / ``SimCCEstimator``: mmpose-style ViTPose (heatmaps) and
  RTMPose (SimCC) exports with COCO-17 outputs, decoded by ``decode_heatmaps`` /
  ``decode_simcc``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from pipeline.backends.onnx.common import make_session
from pipeline.schema.joints import COCO17, COCO17_FEET

# MediaPipe landmark index for each COCO17_FEET joint (-1 = not provided: small toes).
BLAZEPOSE_TO_COCO17_FEET: tuple[int, ...] = (
    0, 2, 5, 7, 8, 11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28,  # COCO-17
    31, -1, 29, 32, -1, 30,  # left big toe, small toe, heel, right big toe, small toe, heel
)  # fmt: skip
_COCO17_IN_FEET = np.array([COCO17_FEET.index(n) for n in COCO17], np.int64)


@dataclass(frozen=True)
class PoseParams:
    """Options shared by the top-down estimators.

    Fields:
        crop_scale: side of the square crop relative to the box's longer side.
        upright: BlazePose only — re-run a person whose hips→shoulders direction is
            tilted by more than ``upright_min_deg`` on a crop rotated upright.
        upright_min_deg: tilt that triggers the rotated second pass.
        min_presence: BlazePose only — below this pose-presence probability the crop is
            taken to hold no person and all its keypoint confidences are set to 0.
        num_threads: onnxruntime intra-op threads (0 = all cores).
        flip_test: MoveNet only — also run the mirrored crop and average both estimates
            per joint, weighted by confidence (left and right swapped back).
        refine_scale: MoveNet only — when > 0, a second pass on a square crop around the
            first pass's confident keypoints, of side ``refine_scale`` × their extent
            (a closer crop, so more model pixels per body pixel); 0 = one pass.
    """

    crop_scale: float = 1.25
    upright: bool = True
    upright_min_deg: float = 25.0
    min_presence: float = 0.3
    num_threads: int = 0
    flip_test: bool = False
    refine_scale: float = 0.0


class PoseEstimator(Protocol):
    def estimate(self, image: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


def sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.clip(x, -50, 50)))


def crop_transform(center_xy: np.ndarray, size_px: float, angle_rad: float, out_size: int) -> np.ndarray:
    """2×3 affine map image → crop of a square of side ``size_px`` centred at ``center_xy``,
    output ``out_size`` pixels square.

    ``angle_rad`` is the body's tilt: the angle of its up direction (hips→shoulders)
    from image-up (0, −1) towards +x. The crop is rotated so that this direction
    becomes crop-up, i.e. the body appears upright.
    """
    s = out_size / size_px
    c, si = np.cos(angle_rad), np.sin(angle_rad)
    R = np.array([[c, si], [-si, c]]) * s
    t = out_size / 2 - R @ np.asarray(center_xy, float)
    return np.concatenate([R, t[:, None]], axis=1)


def crop_transform_rect(box_xyxy: np.ndarray, out_wh: tuple[int, int], scale: float) -> np.ndarray:
    """2×3 affine map image → crop (mmpose top-down): the box expanded to ``out_wh``'s aspect ratio, times ``scale``."""
    x1, y1, x2, y2 = box_xyxy
    cx, cy = (x1 + x2) / 2, (y1 + y2) / 2
    w, h = (x2 - x1) * scale, (y2 - y1) * scale
    aspect = out_wh[0] / out_wh[1]
    if w > h * aspect:
        h = w / aspect
    else:
        w = h * aspect
    sx, sy = out_wh[0] / w, out_wh[1] / h
    return np.array([[sx, 0, out_wh[0] / 2 - sx * cx], [0, sy, out_wh[1] / 2 - sy * cy]])


def apply_inverse(M: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Map crop points ``(..., 2)`` back to the image with the inverse of the 2×3 map ``M``."""
    Mi = cv2.invertAffineTransform(M)
    return xy @ Mi[:, :2].T + Mi[:, 2]


def decode_heatmaps(heatmaps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Argmax + quadratic sub-pixel refinement of heatmaps ``(N, J, H, W)``.

    Returns ``xy (N, J, 2)`` in heatmap pixels (cell centres at integers) and the peak
    value ``(N, J)`` as the score. The refinement fits a parabola through the peak and
    its two neighbours along each axis (at the border the peak is kept as is).
    """
    N, J, H, W = heatmaps.shape
    flat = heatmaps.reshape(N, J, -1)
    idx = np.argmax(flat, axis=2)
    score = np.take_along_axis(flat, idx[..., None], axis=2)[..., 0]
    y, x = np.divmod(idx, W)
    xy = np.stack([x, y], axis=-1).astype(np.float64)
    n, j = np.meshgrid(np.arange(N), np.arange(J), indexing="ij")
    for axis, (lo_ok, hi_ok) in enumerate([(x > 0, x < W - 1), (y > 0, y < H - 1)]):
        ok = lo_ok & hi_ok
        dx, dy = (1, 0) if axis == 0 else (0, 1)
        xm, ym = np.clip(x - dx, 0, W - 1), np.clip(y - dy, 0, H - 1)
        xp, yp = np.clip(x + dx, 0, W - 1), np.clip(y + dy, 0, H - 1)
        fm, f0, fp = heatmaps[n, j, ym, xm], heatmaps[n, j, y, x], heatmaps[n, j, yp, xp]
        den = fm - 2 * f0 + fp
        off = np.where(ok & (den < -1e-12), 0.5 * (fm - fp) / np.where(den < -1e-12, den, -1.0), 0.0)
        xy[..., axis] += np.clip(off, -0.5, 0.5)
    return xy, score


def decode_simcc(
    simcc_x: np.ndarray, simcc_y: np.ndarray, split_ratio: float = 2.0
) -> tuple[np.ndarray, np.ndarray]:
    """SimCC decoding (RTMPose): argmax of the per-axis 1-D classifications.

    ``simcc_x (N, J, W*k)``, ``simcc_y (N, J, H*k)`` with ``k = split_ratio``. Returns
    ``xy (N, J, 2)`` in input pixels and the score ``min(max_x, max_y)`` (as mmpose).
    """
    x = np.argmax(simcc_x, axis=2)
    y = np.argmax(simcc_y, axis=2)
    score = np.minimum(simcc_x.max(axis=2), simcc_y.max(axis=2))
    xy = np.stack([x, y], axis=-1).astype(np.float64) / split_ratio
    return xy, score


def _empty(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    J = len(COCO17_FEET)
    return np.zeros((n, J, 2)), np.zeros((n, J)), np.zeros((n, J), bool)


def _square(box: np.ndarray, scale: float) -> tuple[np.ndarray, float]:
    x1, y1, x2, y2 = box
    return np.array([(x1 + x2) / 2, (y1 + y2) / 2]), max(x2 - x1, y2 - y1, 1.0) * scale


class BlazePoseEstimator:
    """BlazePose GHUM full landmark model (``input_1 [1,256,256,3]`` RGB in [0, 1])."""

    SIZE = 256

    def __init__(self, path: Path, params: PoseParams = PoseParams()) -> None:
        self.params = params
        self.sess = make_session(path, params.num_threads)
        self.input_name = self.sess.get_inputs()[0].name

    def _run(self, rgb: np.ndarray, M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        crop = cv2.warpAffine(rgb, M, (self.SIZE, self.SIZE), flags=cv2.INTER_LINEAR, borderValue=(0, 0, 0))
        x = (crop.astype(np.float32) / 255.0)[None]
        lm, presence = self.sess.run(["Identity", "Identity_1"], {self.input_name: x})
        lm = lm.reshape(39, 5)[:33]
        xy = apply_inverse(M, lm[:, :2].astype(np.float64))
        vis = sigmoid(lm[:, 3])
        if float(sigmoid(presence.reshape(-1)[:1])[0]) < self.params.min_presence:
            vis = np.zeros_like(vis)  # no person in the crop: every landmark is a guess
        return xy, vis

    def estimate(self, image: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Keypoints for each box: ``(xy (n, 23, 2), conf (n, 23), valid (n, 23))``."""
        xy_out, conf_out, valid_out = _empty(len(boxes))
        if len(boxes) == 0:
            return xy_out, conf_out, valid_out
        rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
        src = np.array(BLAZEPOSE_TO_COCO17_FEET)
        have = src >= 0
        for i, box in enumerate(boxes):
            center, size = _square(box, self.params.crop_scale)
            M = crop_transform(center, size, 0.0, self.SIZE)
            xy, vis = self._run(rgb, M)
            if self.params.upright:
                hips, shoulders = (xy[23] + xy[24]) / 2, (xy[11] + xy[12]) / 2
                d = shoulders - hips
                # Angle between the body axis and image "up" (0, -1); rotate the crop by it.
                tilt = float(np.arctan2(d[0], -d[1]))
                if abs(np.degrees(tilt)) > self.params.upright_min_deg and np.linalg.norm(d) > 1e-3:
                    M2 = crop_transform(center, size, tilt, self.SIZE)
                    xy, vis = self._run(rgb, M2)
            xy_out[i, have] = xy[src[have]]
            conf_out[i, have] = vis[src[have]]
            valid_out[i, have] = np.isfinite(xy[src[have]]).all(axis=1)
        return xy_out, conf_out, valid_out


COCO17_FLIP: tuple[int, ...] = (0, 2, 1, 4, 3, 6, 5, 8, 7, 10, 9, 12, 11, 14, 13, 16, 15)
"""COCO-17 index of each joint's mirror image (left and right swapped)."""

REFINE_MIN_CONF = 0.3
"""MoveNet refine pass: keypoints at least this confident (in [0, 1]) span the closer crop."""
REFINE_MIN_JOINTS = 8
"""MoveNet refine pass: fewer confident keypoints than this keep the first pass."""


class MoveNetEstimator:
    """MoveNet SinglePose Lightning int8 (``[1,192,192,3]`` uint8 RGB → ``[1,1,17,3]`` (y, x, score))."""

    SIZE = 192

    def __init__(self, path: Path, params: PoseParams = PoseParams()) -> None:
        self.params = params
        self.sess = make_session(path, params.num_threads)
        inp = self.sess.get_inputs()[0]
        self.input_name = inp.name
        self.size = int(inp.shape[1]) if isinstance(inp.shape[1], int) else self.SIZE

    def estimate(self, image: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        xy_out, conf_out, valid_out = _empty(len(boxes))
        if len(boxes) == 0:
            return xy_out, conf_out, valid_out
        rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
        for i, box in enumerate(boxes):
            center, size = _square(box, self.params.crop_scale)
            xy, conf = self._pass(rgb, center, size)
            if self.params.refine_scale > 0:
                sure = conf >= REFINE_MIN_CONF
                if sure.sum() >= REFINE_MIN_JOINTS:
                    lo, hi = xy[sure].min(axis=0), xy[sure].max(axis=0)
                    side = float(np.max(hi - lo)) * self.params.refine_scale
                    if side > 0.5 * size / self.params.crop_scale:  # never zoom onto a fragment
                        xy, conf = self._pass(rgb, 0.5 * (lo + hi), side)
            xy_out[i, _COCO17_IN_FEET] = xy
            conf_out[i, _COCO17_IN_FEET] = conf
            valid_out[i, _COCO17_IN_FEET] = True
        return xy_out, conf_out, valid_out

    def _pass(self, rgb: np.ndarray, center: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray]:
        """Image keypoints (17, 2) and confidences (17,) from the square crop of side ``size`` at ``center``."""
        M = crop_transform(center, size, 0.0, self.size)
        crop = cv2.warpAffine(rgb, M, (self.size, self.size), flags=cv2.INTER_LINEAR)
        out = self.sess.run(None, {self.input_name: crop[None].astype(np.uint8)})[0].reshape(17, 3)
        xy = out[:, [1, 0]].astype(np.float64) * self.size
        conf = np.clip(out[:, 2].astype(np.float64), 0.0, 1.0)
        if self.params.flip_test:
            mirrored = np.ascontiguousarray(crop[:, ::-1])
            back = self.sess.run(None, {self.input_name: mirrored[None]})[0].reshape(17, 3)[list(COCO17_FLIP)]
            xy_f = back[:, [1, 0]].astype(np.float64) * self.size
            xy_f[:, 0] = (self.size - 1) - xy_f[:, 0]
            conf_f = np.clip(back[:, 2].astype(np.float64), 0.0, 1.0)
            w = conf + conf_f
            safe = np.where(w > 0, w, 1.0)
            xy = np.where((w > 0)[:, None], (xy * conf[:, None] + xy_f * conf_f[:, None]) / safe[:, None], xy)
            conf = 0.5 * w
        return apply_inverse(M, xy), conf


class _MMPoseTopDown:
    """mmpose-style top-down export: ``input [N,3,H,W]`` RGB normalised with ImageNet mean/std,
    crop = box × ``crop_scale`` expanded to the input's aspect ratio; COCO-17 outputs."""

    MEAN = np.array([123.675, 116.28, 103.53], np.float32)
    STD = np.array([58.395, 57.12, 57.375], np.float32)

    def __init__(
        self, path: Path, params: PoseParams = PoseParams(), input_hw: tuple[int, int] = (256, 192)
    ) -> None:
        self.params = params
        self.sess = make_session(path, params.num_threads)
        inp = self.sess.get_inputs()[0]
        self.input_name = inp.name
        shp = inp.shape
        self.input_hw = (
            (int(shp[2]), int(shp[3])) if isinstance(shp[2], int) and isinstance(shp[3], int) else input_hw
        )
        self.fixed_batch = isinstance(shp[0], int)

    def _decode(self, outputs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError  # abstract: each subclass decodes its own output layout

    def estimate(self, image: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.estimate_many([image], [boxes])[0]

    def estimate_many(
        self, images: list[np.ndarray], boxes: list[np.ndarray], max_batch: int = 64
    ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Like ``estimate`` for several frames (e.g. all views of a time step): the crops of
        every person in every frame go through the network in batches of ``max_batch``."""
        H, W = self.input_hw
        Ms: list[np.ndarray] = []
        crops: list[np.ndarray] = []
        for image, bxs in zip(images, boxes, strict=True):
            if len(bxs) == 0:
                continue
            rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
            for b in bxs:
                M = crop_transform_rect(b, (W, H), self.params.crop_scale)
                Ms.append(M)
                crops.append(cv2.warpAffine(rgb, M, (W, H), flags=cv2.INTER_LINEAR))
        xys, scores = [], []
        chunk = 1 if self.fixed_batch else max(1, max_batch)
        for s in range(0, len(crops), chunk):
            x = ((np.stack(crops[s : s + chunk]).astype(np.float32) - self.MEAN) / self.STD).transpose(0, 3, 1, 2)
            xy, sc = self._decode(self.sess.run(None, {self.input_name: np.ascontiguousarray(x)}))
            xys.append(xy)
            scores.append(sc)
        out = []
        k = 0
        for bxs in boxes:
            xy_out, conf_out, valid_out = _empty(len(bxs))
            for i in range(len(bxs)):
                M = Ms[k]
                xy, sc = xys[k // chunk][k % chunk], scores[k // chunk][k % chunk]
                xy_out[i, _COCO17_IN_FEET] = apply_inverse(M, xy[:17])
                conf_out[i, _COCO17_IN_FEET] = np.clip(sc[:17], 0.0, 1.0)
                valid_out[i, _COCO17_IN_FEET] = True
                k += 1
            out.append((xy_out, conf_out, valid_out))
        return out


class HeatmapEstimator(_MMPoseTopDown):
    """ViTPose-style heatmap model: output ``(N, 17, H/4, W/4)``."""

    def _decode(self, outputs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        hm = outputs[0]
        xy, score = decode_heatmaps(hm)
        stride = np.array([self.input_hw[1] / hm.shape[3], self.input_hw[0] / hm.shape[2]])
        # mmpose's MSRA heatmap codec encodes ``keypoint / stride`` (no half-cell shift).
        return xy * stride, score


class SimCCEstimator(_MMPoseTopDown):
    """RTMPose-style SimCC model: outputs ``simcc_x (N, 17, W*2)``, ``simcc_y (N, 17, H*2)``."""

    def _decode(self, outputs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        sx, sy = outputs[0], outputs[1]
        return decode_simcc(sx, sy, split_ratio=sx.shape[2] / self.input_hw[1])


def estimate_many(
    est: PoseEstimator, images: list[np.ndarray], boxes: list[np.ndarray]
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Keypoints for the boxes of several frames; batched across frames when the model
    accepts a dynamic batch (mmpose-style exports), else one crop at a time."""
    many = getattr(est, "estimate_many", None)
    if many is not None:
        return many(images, boxes)
    return [est.estimate(im, b) for im, b in zip(images, boxes, strict=True)]


def make_pose_estimator(kind: str, path: Path, params: PoseParams) -> PoseEstimator:
    """``kind`` is the registry's decoder type."""
    makers: dict[str, Callable[[Path, PoseParams], PoseEstimator]] = {
        "blazepose": BlazePoseEstimator,
        "movenet": MoveNetEstimator,
        "heatmap": HeatmapEstimator,
        "simcc": SimCCEstimator,
    }
    if kind not in makers:
        raise ValueError(f"unknown keypoint decoder {kind!r} for {path} (expected one of {sorted(makers)})")
    return makers[kind](path, params)
