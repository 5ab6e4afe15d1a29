"""COCO-format keypoint JSON, one file per camera.

Accepted layouts:

- a dataset / ground-truth file: ``{"images": [...], "annotations": [...]}``; each
  annotation has ``image_id``, ``keypoints`` (``[x, y, v] * 17``, ``* 23`` with the
  feet, or ``* 133`` COCO-WholeBody whose first 23 are body + feet) and optionally
  ``foot_kpts`` (COCO-WholeBody, ``[x, y, v] * 6``; ignored if ``foot_valid`` is false),
  ``bbox`` (``[x, y, w, h]``), ``score``, ``track_id`` (PoseTrack) and ``category_id``
  (only person = 1 is read when present);
- a results file: a list of ``{"image_id", "keypoints", "score", ...}`` (the format of
  COCO keypoint detections), whose third values are confidences.

The third value of a keypoint is its confidence: 0 = missing/invalid, values above 1
(COCO's visibility flag 2) are clipped to 1.

Frames: images in the order of the trailing number of their ``file_name`` when every
image has one, else in image-id order (results files: sorted image ids); the frame
key is the rank. ``iscrowd`` annotations are skipped.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from pipeline.io.keypoints_common import CameraRows, read_json, trailing_number, triplets

_BODY17 = tuple(range(17)) + (-1,) * 6
_FULL23 = tuple(range(23))


def _image_order(path: Path, images: list[Any]) -> dict[Any, int]:
    ids, numbers = [], []
    for i, im in enumerate(images):
        if not isinstance(im, dict) or "id" not in im:
            raise ValueError(f"{path}: images[{i}] has no 'id'")
        ids.append(im["id"])
        numbers.append(trailing_number(Path(str(im.get("file_name", ""))).stem))
    if len(set(ids)) != len(ids):
        raise ValueError(f"{path}: duplicate image ids in 'images'")
    nums = [n for n in numbers if n is not None]
    if len(nums) == len(ids) and len(set(nums)) == len(nums):
        order = sorted(range(len(ids)), key=lambda i: nums[i])
    else:
        try:
            order = sorted(range(len(ids)), key=lambda i: ids[i])
        except TypeError as e:
            raise ValueError(f"{path}: image ids are not comparable: {e}") from e
    return {ids[i]: rank for rank, i in enumerate(order)}


def read_coco_file(path: Path) -> CameraRows:
    """Read one camera's COCO keypoint file. Raises ``ValueError`` naming the file."""
    if not path.is_file():
        raise ValueError(f"{path}: COCO keypoint file not found")
    doc = read_json(path)
    if isinstance(doc, dict):
        if not isinstance(doc.get("annotations"), list) or not isinstance(doc.get("images"), list):
            raise ValueError(f"{path}: a COCO file needs 'images' and 'annotations' lists")
        anns = doc["annotations"]
        frame_of = _image_order(path, doc["images"])
    elif isinstance(doc, list):
        anns = doc
        try:
            ids = sorted({a["image_id"] for a in anns})
        except (KeyError, TypeError) as e:
            raise ValueError(f"{path}: every result needs a comparable 'image_id': {e}") from e
        frame_of = {k: r for r, k in enumerate(ids)}
    else:
        raise ValueError(f"{path}: expected a COCO object or a list of results, got {type(doc).__name__}")
    out = CameraRows(source=path, frame_keys=sorted(frame_of.values()))
    for i, ann in enumerate(anns):
        where = f"{path}: annotations[{i}]"
        if not isinstance(ann, dict) or "keypoints" not in ann or "image_id" not in ann:
            raise ValueError(f"{where}: needs 'image_id' and 'keypoints'")
        if ann.get("category_id", 1) != 1 or ann.get("iscrowd", 0):
            continue
        if ann["image_id"] not in frame_of:
            raise ValueError(f"{where}: image_id {ann['image_id']!r} is not in 'images'")
        flat = ann["keypoints"]
        n = len(flat) // 3 if isinstance(flat, list) else -1
        if not isinstance(flat, list) or len(flat) % 3 or n not in (17, 23, 133):
            size = len(flat) if isinstance(flat, list) else type(flat).__name__
            raise ValueError(f"{where}: 'keypoints' must hold 3 x 17, 3 x 23 or 3 x 133 values, got {size}")
        xyc = triplets(where, flat, n)[:23]
        index = _BODY17
        if n >= 23:
            index = _FULL23
            out.has_feet = True
        elif "foot_kpts" in ann and ann.get("foot_valid", True):
            xyc = np.concatenate([xyc, triplets(f"{where} foot_kpts", ann["foot_kpts"], 6)])
            index = _FULL23
            out.has_feet = True
        box = None
        if "bbox" in ann:
            try:
                box = np.asarray(ann["bbox"], dtype=np.float64)
            except (TypeError, ValueError) as e:
                raise ValueError(f"{where}: bbox is not numeric: {e}") from e
            if box.shape != (4,) or not np.all(np.isfinite(box)):
                raise ValueError(f"{where}: bbox must be 4 finite numbers [x, y, w, h], got {ann['bbox']}")
        score = ann.get("score")
        if score is not None and not (isinstance(score, int | float) and np.isfinite(score)):
            raise ValueError(f"{where}: score must be a finite number, got {score!r}")
        tid = ann.get("track_id", -1)
        if not isinstance(tid, int) or isinstance(tid, bool):
            raise ValueError(f"{where}: track_id must be an integer, got {tid!r}")
        out.add(where, frame_of[ann["image_id"]], xyc, index, person_id=tid, bbox_xywh=box, score=score)
    return out
