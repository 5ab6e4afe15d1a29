from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("onnxruntime")

from pipeline.backends.onnx.common import letterbox  # noqa: E402
from pipeline.backends.onnx.detectors import (  # noqa: E402
    DetectorParams,
    RtmdetDetector,
    YoloxDetector,
    box_iou,
    decode_yolox,
    nms,
    yolox_grid,
)


def test_nms_keeps_best_of_overlaps() -> None:
    boxes = np.array([[0, 0, 10, 10], [1, 1, 11, 11], [50, 50, 60, 60], [0, 0, 10, 9.5]], float)
    scores = np.array([0.8, 0.9, 0.5, 0.7])
    assert nms(boxes, scores, 0.5).tolist() == [1, 2]


def test_letterbox_top_left_pad_114() -> None:
    img = np.full((100, 200, 3), 7, np.uint8)
    out, scale = letterbox(img, (416, 416))
    assert scale == pytest.approx(416 / 200)
    assert out.shape == (416, 416, 3)
    assert np.all(out[:208] == 7) and np.all(out[208:] == 114)


def test_decode_yolox_synthetic_grid() -> None:
    hw = (416, 416)
    grid, stride = yolox_grid(hw)
    raw = np.zeros((grid.shape[0], 85), np.float32)
    # One person at stride-16 cell (10, 7) with offset (0.5, 0.25), 64x128 px.
    a = 52 * 52 + 7 * 26 + 10
    assert tuple(grid[a]) == (10, 7) and stride[a, 0] == 16
    raw[a, :4] = [0.5, 0.25, np.log(64 / 16), np.log(128 / 16)]
    raw[a, 4], raw[a, 5] = 0.9, 0.8
    raw[a + 1, :6] = [0.5, 0.25, np.log(4), np.log(8), 0.9, 0.7]  # overlapping neighbour, suppressed
    raw[a + 2, :5] = [0, 0, 0, 0, 0.9]
    raw[a + 2, 6] = 0.95  # a non-person class: ignored
    boxes, scores = decode_yolox(raw, hw, 0.3, 0.45, 10)
    cx, cy = (10 + 0.5) * 16, (7 + 0.25) * 16
    np.testing.assert_allclose(boxes, [[cx - 32, cy - 64, cx + 32, cy + 64]], atol=1e-4)
    np.testing.assert_allclose(scores, [0.72], atol=1e-6)


def _frame(test_data_dir: Path) -> np.ndarray:
    from pipeline.io.video import iter_frames

    p = test_data_dir / "pose2sim_multiperson" / "videos" / "cam01.mp4"
    return next(iter(iter_frames(p, 0, 1)))[1]


@pytest.mark.requires_models
@pytest.mark.requires_data
def test_real_detectors_agree_on_the_two_performers(models_dir: Path, test_data_dir: Path) -> None:
    img = _frame(test_data_dir)
    yolox = YoloxDetector(models_dir / "yolox_nano.onnx", DetectorParams(num_threads=1))
    rtm = RtmdetDetector(
        models_dir / "rtmdet_nano.onnx", DetectorParams(input_size_hw=(320, 320), num_threads=1)
    )
    ((by, sy),) = yolox.detect([img])
    (br, sr), (br2, _) = rtm.detect([img, img[:, ::-1].copy()])  # batch of 2, second mirrored
    for b, s in ((by, sy), (br, sr)):
        assert (s > 0.5).sum() >= 2
        h, w = img.shape[:2]
        assert np.all(b[:, [0, 2]] <= w) and np.all(b[:, [1, 3]] <= h) and np.all(b[:, 2:] > b[:, :2])
    # The two best boxes of both detectors are the same people (the performers are tall).
    iou = box_iou(by[:2], br[:2])
    assert iou.max(axis=1).min() > 0.7
    assert np.all(by[:2, 3] - by[:2, 1] > 0.35 * img.shape[0])
    # Batching: the mirrored frame's boxes are the mirror of the original's.
    mir = br2[:2].copy()
    mir[:, [0, 2]] = img.shape[1] - 1 - mir[:, [2, 0]]
    assert box_iou(br[:2], mir).max(axis=1).min() > 0.8
