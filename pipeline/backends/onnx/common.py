"""Shared onnxruntime helpers: session creation and letterboxing."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort


def make_session(path: Path, num_threads: int = 0) -> ort.InferenceSession:
    """A CPU inference session; ``ValueError`` naming the file if it cannot be loaded.

    ``num_threads`` = 0 lets onnxruntime choose (all cores).
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"ONNX model file not found: {path}")
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = int(num_threads)
    opts.inter_op_num_threads = 1
    opts.log_severity_level = 3
    try:
        return ort.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])
    except Exception as e:  # onnxruntime raises its own exception types (Fail, InvalidProtobuf, ...)
        raise ValueError(f"cannot load ONNX model {path}: {e}") from e


def letterbox(img: np.ndarray, size_hw: tuple[int, int], pad_value: int = 114) -> tuple[np.ndarray, float]:
    """Resize keeping the aspect ratio, paste at the top-left, pad the rest.

    Returns ``(canvas, scale)`` with canvas (H, W, 3) uint8 and ``scale`` such that
    ``input_px = image_px * scale``.
    """
    h, w = img.shape[:2]
    H, W = size_hw
    scale = min(H / h, W / w)
    nh, nw = max(1, int(round(h * scale))), max(1, int(round(w * scale)))
    canvas = np.full((H, W, 3), pad_value, dtype=np.uint8)
    canvas[:nh, :nw] = cv2.resize(img, (nw, nh), interpolation=cv2.INTER_LINEAR)
    return canvas, scale
