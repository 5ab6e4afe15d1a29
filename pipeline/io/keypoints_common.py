"""Shared pieces of the 2D keypoint importers: JSON reading with located errors and
the per-camera row buffer that both the OpenPose and the COCO readers fill."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.schema.joints import COCO17, COCO17_FEET

N_BODY = len(COCO17)
N_FULL = len(COCO17_FEET)

_TRAILING_INT = re.compile(r"(\d+)(?!.*\d)")


def read_json(path: Path) -> Any:
    """Parse a JSON file; errors name the file, line and column."""
    try:
        text = path.read_text()
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: not a UTF-8 text file: {e}") from e
    except OSError as e:
        raise ValueError(f"{path}: cannot read: {e}") from e
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: malformed JSON at line {e.lineno}, column {e.colno}: {e.msg}") from e


def trailing_number(name: str) -> int | None:
    """The last integer in a file name (``cam1_000000000012_keypoints.json`` -> 12)."""
    m = _TRAILING_INT.search(name)
    return int(m.group(1)) if m else None


def triplets(where: str, values: Any, n_joints: int) -> np.ndarray:
    """A flat ``[x, y, c] * n`` list -> (n, 3) float array; NaN/inf and bad sizes raise."""
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: keypoints are not numbers: {e}") from e
    if arr.ndim != 1 or arr.size != 3 * n_joints:
        raise ValueError(
            f"{where}: expected {3 * n_joints} values (x, y, c for {n_joints} joints), got {arr.size}"
        )
    arr = arr.reshape(n_joints, 3)
    if not np.all(np.isfinite(arr)):
        j = int(np.argwhere(~np.isfinite(arr))[0, 0])
        raise ValueError(f"{where}: NaN/inf value in keypoint {j}: {arr[j].tolist()}")
    return arr


@dataclass
class CameraRows:
    """Detections of one camera before the frames of all cameras are aligned.

    ``frame_keys`` lists the frame key of every frame the source has for this camera
    (file number or rank); each row carries the key of its frame.
    """

    source: Path
    frame_keys: list[int] = field(default_factory=list)
    has_feet: bool = False
    row_frame_key: list[int] = field(default_factory=list)
    keypoints_px: list[np.ndarray] = field(default_factory=list)  # (23, 2)
    keypoint_conf: list[np.ndarray] = field(default_factory=list)  # (23,)
    keypoint_valid: list[np.ndarray] = field(default_factory=list)  # (23,)
    bbox_xyxy_px: list[np.ndarray] = field(default_factory=list)
    bbox_score: list[float] = field(default_factory=list)
    person_id: list[int] = field(default_factory=list)

    def add(
        self,
        where: str,
        frame_key: int,
        xyc: np.ndarray,
        src_index: tuple[int, ...],
        person_id: int = -1,
        bbox_xywh: np.ndarray | None = None,
        score: float | None = None,
    ) -> bool:
        """Add one person; ``xyc`` (n_src, 3) is mapped to COCO17_FEET by ``src_index``
        (-1 = the source lacks that joint). Confidence 0 marks a joint invalid; values
        above 1 are clipped to 1, negative ones raise. Returns False (and adds nothing)
        if the person has no valid joint."""
        kp = np.zeros((N_FULL, 2))
        conf = np.zeros(N_FULL)
        for j, s in enumerate(src_index):
            if s >= 0:
                kp[j] = xyc[s, :2]
                conf[j] = xyc[s, 2]
        if np.any(conf < 0):
            j = int(np.argmax(conf < 0))
            raise ValueError(f"{where}: negative confidence {conf[j]} for joint {COCO17_FEET[j]}")
        valid = conf > 0
        if not valid.any():
            return False
        conf = np.minimum(conf, 1.0)
        kp[~valid] = 0.0
        if bbox_xywh is not None:
            x, y, w, h = bbox_xywh
            if w < 0 or h < 0:
                raise ValueError(f"{where}: bbox has negative size {bbox_xywh.tolist()}")
            box = np.array([x, y, x + w, y + h])
        else:
            pts = kp[valid]
            box = np.concatenate([pts.min(axis=0), pts.max(axis=0)])
        self.row_frame_key.append(frame_key)
        self.keypoints_px.append(kp)
        self.keypoint_conf.append(conf)
        self.keypoint_valid.append(valid)
        self.bbox_xyxy_px.append(box)
        self.bbox_score.append(float(np.clip(score if score is not None else conf[valid].mean(), 0.0, 1.0)))
        self.person_id.append(int(person_id))
        return True
