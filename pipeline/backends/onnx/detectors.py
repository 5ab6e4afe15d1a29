"""Person detectors on ONNX: YOLOX (raw grid output, decoded + NMS here) and RTMDet
(mmdeploy "end2end" export, NMS inside the graph).

Both take BGR uint8 frames of any size and return, per frame, boxes in the frame's
pixels ``(n, 4) xyxy`` and scores ``(n,)``, person class only, best first.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from pipeline.backends.onnx.common import letterbox, make_session


@dataclass(frozen=True)
class DetectorParams:
    """Thresholds shared by the detectors.

    Fields:
        score_thr: detections below this person score are dropped.
        nms_iou: IoU above which the weaker of two boxes is suppressed (YOLOX only;
            RTMDet's NMS is inside the exported graph).
        max_dets: at most this many boxes per frame (best first).
        input_size_hw: network input size (YOLOX's export is fixed at 416×416).
        num_threads: onnxruntime intra-op threads (0 = all cores).
    """

    score_thr: float = 0.3
    nms_iou: float = 0.45
    max_dets: int = 20
    input_size_hw: tuple[int, int] = (416, 416)
    num_threads: int = 0


class PersonDetector(Protocol):
    def detect(self, images: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]: ...


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n, m) IoU between xyxy boxes ``a`` (n, 4) and ``b`` (m, 4)."""
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.prod(np.clip(rb - lt, 0, None), axis=2)
    area_a = np.prod(np.clip(a[:, 2:] - a[:, :2], 0, None), axis=1)
    area_b = np.prod(np.clip(b[:, 2:] - b[:, :2], 0, None), axis=1)
    return inter / np.maximum(area_a[:, None] + area_b[None] - inter, 1e-9)


def nms(boxes: np.ndarray, scores: np.ndarray, iou_thr: float) -> np.ndarray:
    """Greedy non-maximum suppression; indices of kept boxes, best first."""
    order = np.argsort(-scores, kind="stable")
    keep: list[int] = []
    while order.size:
        i = int(order[0])
        keep.append(i)
        if order.size == 1:
            break
        iou = box_iou(boxes[i : i + 1], boxes[order[1:]])[0]
        order = order[1:][iou <= iou_thr]
    return np.asarray(keep, dtype=np.int64)


def yolox_grid(
    input_hw: tuple[int, int], strides: tuple[int, ...] = (8, 16, 32)
) -> tuple[np.ndarray, np.ndarray]:
    """Anchor grid of YOLOX: ``(grid_xy (A, 2), stride (A, 1))`` in the output's row order."""
    grids, strs = [], []
    for s in strides:
        h, w = input_hw[0] // s, input_hw[1] // s
        ys, xs = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
        grids.append(np.stack([xs.ravel(), ys.ravel()], axis=1))
        strs.append(np.full((h * w, 1), s))
    return np.concatenate(grids).astype(np.float32), np.concatenate(strs).astype(np.float32)


def decode_yolox(
    raw: np.ndarray,
    input_hw: tuple[int, int],
    score_thr: float,
    nms_iou: float,
    max_dets: int,
    class_id: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Decode one image's raw YOLOX output ``(A, 5 + classes)`` to person boxes in input pixels.

    ``xy = (dxdy + grid) * stride``, ``wh = exp(logwh) * stride``, ``score = obj * cls``.
    """
    grid, stride = yolox_grid(input_hw)
    if raw.shape[0] != grid.shape[0]:
        raise ValueError(
            f"YOLOX output has {raw.shape[0]} anchors, expected {grid.shape[0]} for input {input_hw}"
        )
    score = raw[:, 4] * raw[:, 5 + class_id]
    m = score >= score_thr
    if not np.any(m):
        return np.zeros((0, 4), np.float32), np.zeros(0, np.float32)
    xy = (raw[m, :2] + grid[m]) * stride[m]
    wh = np.exp(np.clip(raw[m, 2:4], -10, 10)) * stride[m]
    boxes = np.concatenate([xy - wh / 2, xy + wh / 2], axis=1)
    keep = nms(boxes, score[m], nms_iou)[:max_dets]
    return boxes[keep].astype(np.float32), score[m][keep].astype(np.float32)


class YoloxDetector:
    """YOLOX exported with raw outputs (``[1, A, 85]``), BGR 0-255 input, top-left letterbox."""

    def __init__(self, path: Path, params: DetectorParams = DetectorParams()) -> None:
        self.params = params
        self.sess = make_session(path, params.num_threads)
        inp = self.sess.get_inputs()[0]
        self.input_name = inp.name
        shp = inp.shape
        fixed = isinstance(shp[2], int) and isinstance(shp[3], int)
        self.input_hw = (int(shp[2]), int(shp[3])) if fixed else params.input_size_hw
        self.fixed_batch = isinstance(shp[0], int)

    def detect(self, images: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
        p = self.params
        out: list[tuple[np.ndarray, np.ndarray]] = []
        chunk = 1 if self.fixed_batch else len(images)
        for s in range(0, len(images), max(chunk, 1)):
            batch = images[s : s + chunk]
            boxed = [letterbox(im, self.input_hw) for im in batch]
            x = np.stack([b[0] for b in boxed]).transpose(0, 3, 1, 2).astype(np.float32)
            raw = self.sess.run(None, {self.input_name: x})[0]
            for (_, scale), r, im in zip(boxed, raw, batch, strict=True):
                boxes, scores = decode_yolox(r, self.input_hw, p.score_thr, p.nms_iou, p.max_dets)
                out.append((_clip(boxes / scale, im.shape), scores))
        return out


class RtmdetDetector:
    """RTMDet mmdeploy end2end export: ``dets [N, K, 5]`` + ``labels [N, K]``, NMS in-graph.

    Input BGR normalised by mean ``[103.53, 116.28, 123.675]`` / std ``[57.375, 57.12, 58.395]``,
    top-left letterbox padded with 114; dynamic batch, so frames are batched.
    """

    MEAN = np.array([103.53, 116.28, 123.675], np.float32)
    STD = np.array([57.375, 57.12, 58.395], np.float32)

    def __init__(self, path: Path, params: DetectorParams = DetectorParams(input_size_hw=(320, 320))) -> None:
        self.params = params
        self.sess = make_session(path, params.num_threads)
        self.input_name = self.sess.get_inputs()[0].name

    def detect(self, images: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
        p = self.params
        if not images:
            return []
        boxed = [letterbox(im, p.input_size_hw) for im in images]
        x = ((np.stack([b[0] for b in boxed]).astype(np.float32) - self.MEAN) / self.STD).transpose(
            0, 3, 1, 2
        )
        dets, labels = self.sess.run(None, {self.input_name: np.ascontiguousarray(x)})[:2]
        out = []
        for (_, scale), d, lab, im in zip(boxed, dets, labels, images, strict=True):
            m = (lab == 0) & (d[:, 4] >= p.score_thr)
            d = d[m]
            order = np.argsort(-d[:, 4], kind="stable")[: p.max_dets]
            out.append(
                (_clip(d[order, :4] / scale, im.shape).astype(np.float32), d[order, 4].astype(np.float32))
            )
        return out


def _clip(boxes: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    h, w = shape[:2]
    b = boxes.copy()
    b[:, [0, 2]] = np.clip(b[:, [0, 2]], 0, w - 1)
    b[:, [1, 3]] = np.clip(b[:, [1, 3]], 0, h - 1)
    return b


def make_detector(kind: str, path: Path, params: DetectorParams) -> PersonDetector:
    """``kind`` is the registry's decoder type: ``"yolox"`` or ``"rtmdet_end2end"``."""
    if kind == "yolox":
        return YoloxDetector(path, params)
    if kind == "rtmdet_end2end":
        return RtmdetDetector(path, params)
    raise ValueError(f"unknown detector decoder {kind!r} for {path} (expected 'yolox' or 'rtmdet_end2end')")
