"""OpenPose JSON folders (one ``*.json`` per frame, ``people[].pose_keypoints_2d``).

Skeletons (chosen by ``skeleton`` or, with ``"auto"``, by the keypoint count):

- ``body25`` (25 points, OpenPose's default): COCO-17 + big toe, small toe, heel of
  each foot -> ``COCO17_FEET``; neck and mid-hip are dropped.
- ``body25b`` (25 points, OpenPose's experimental BODY_25B, used by Pose2Sim's demos):
  COCO-17 order first, then upper neck, head top and the six foot points. It has the
  same count as ``body25``, so it must be asked for explicitly; ``"auto"`` rejects
  25-point data whose "mid-hip" (point 8) is not between the hips (the BODY_25B signature).
- ``halpe26`` (26 points, HALPE/RTMPose written in OpenPose format): -> ``COCO17_FEET``.
- ``coco18`` (18 points, OpenPose COCO): -> ``COCO17`` (the neck is dropped).

Frame keys: the trailing number of each file name (``frame_from="number"``, OpenPose's
``<video>_000000000012_keypoints.json``) or the rank in natural file order
(``frame_from="order"``). ``person_id`` (OpenPose's optional tracking id, ``[-1]`` =
none) is kept per row.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np

from pipeline.io.calibration_common import natural_key
from pipeline.io.keypoints_common import CameraRows, read_json, trailing_number, triplets

OpenPoseSkeleton = Literal["auto", "body25", "body25b", "halpe26", "coco18"]
FrameFrom = Literal["number", "order"]

_FEET_NONE = (-1,) * 6
# For each COCO17_FEET joint, its index in the source skeleton (-1 = not provided).
SKELETONS: dict[str, tuple[int, tuple[int, ...]]] = {
    "body25": (25, (0, 16, 15, 18, 17, 5, 2, 6, 3, 7, 4, 12, 9, 13, 10, 14, 11, 19, 20, 21, 22, 23, 24)),
    "body25b": (25, tuple(range(17)) + (19, 20, 21, 22, 23, 24)),
    "halpe26": (26, tuple(range(17)) + (20, 22, 24, 21, 23, 25)),
    "coco18": (18, (0, 15, 14, 17, 16, 5, 2, 6, 3, 7, 4, 11, 8, 12, 9, 13, 10) + _FEET_NONE),
}
_BY_COUNT = {25: "body25", 26: "halpe26", 18: "coco18"}


def _person_id(where: str, person: dict) -> int:
    pid = person.get("person_id", -1)
    if isinstance(pid, list):
        pid = pid[0] if pid else -1
    if isinstance(pid, bool) or not isinstance(pid, int | float) or pid != int(pid):
        raise ValueError(
            f"{where}: person_id must be an integer or [integer], got {person.get('person_id')!r}"
        )
    return int(pid)


def _check_body25(folder: Path, samples: list[np.ndarray]) -> None:
    """Reject BODY_25B data auto-read as BODY_25.

    BODY_25's point 8 (mid-hip) lies between points 9 and 12 (the hips), within a few
    percent of the person's size; in BODY_25B those are the right elbow, left wrist
    and right hip. ``samples`` holds, per person, points 8, 9, 12 and the extent of
    the person's valid keypoints.
    """
    if not samples:
        return
    arr = np.stack(samples)  # (people, 4, 2)
    size = np.linalg.norm(arr[:, 3], axis=1)
    off = np.linalg.norm(arr[:, 0] - 0.5 * (arr[:, 1] + arr[:, 2]), axis=1)
    ok = size > 1.0
    if ok.any() and np.median(off[ok] / size[ok]) > 0.1:
        raise ValueError(
            f"{folder}: 25-point keypoints whose point 8 is not between points 9 and 12, so this is not "
            "BODY_25 (mid-hip between the hips); if it is BODY_25B pass openpose_skeleton='body25b'"
        )


def read_openpose_folder(
    folder: Path, skeleton: OpenPoseSkeleton = "auto", frame_from: FrameFrom = "number"
) -> CameraRows:
    """Read one camera's OpenPose folder. Raises ``ValueError`` naming the file and problem."""
    if not folder.exists():
        raise ValueError(f"{folder}: OpenPose keypoint folder not found")
    if not folder.is_dir():
        raise ValueError(f"{folder}: expected a folder of OpenPose *.json files (one per frame), got a file")
    files = sorted(
        (p for p in folder.iterdir() if p.suffix.lower() == ".json"), key=lambda p: natural_key(p.name)
    )
    if not files:
        raise ValueError(f"{folder}: no OpenPose *.json files")
    if frame_from == "number":
        keys = []
        for f in files:
            n = trailing_number(f.stem)
            if n is None:
                raise ValueError(f"{f}: no frame number in the file name (use frame_from='order')")
            keys.append(n)
        if len(set(keys)) != len(keys):
            dup = sorted({k for k in keys if keys.count(k) > 1})[:5]
            raise ValueError(f"{folder}: several files have the same frame number {dup}")
    elif frame_from == "order":
        keys = list(range(len(files)))
    else:
        raise ValueError(f"frame_from must be 'number' or 'order', got {frame_from!r}")
    if skeleton != "auto" and skeleton not in SKELETONS:
        raise ValueError(f"openpose_skeleton must be one of auto/{'/'.join(SKELETONS)}, got {skeleton!r}")
    out = CameraRows(source=folder, frame_keys=keys)
    hips: list[np.ndarray] = []
    chosen: str | None = None if skeleton == "auto" else skeleton
    for f, key in zip(files, keys, strict=True):
        doc = read_json(f)
        if not isinstance(doc, dict) or not isinstance(doc.get("people"), list):
            raise ValueError(f"{f}: not an OpenPose file (expected an object with a 'people' list)")
        for i, person in enumerate(doc["people"]):
            where = f"{f}: person {i}"
            if not isinstance(person, dict) or "pose_keypoints_2d" not in person:
                raise ValueError(f"{where}: missing 'pose_keypoints_2d'")
            flat = person["pose_keypoints_2d"]
            if not isinstance(flat, list):
                raise ValueError(f"{where}: 'pose_keypoints_2d' must be a list, got {type(flat).__name__}")
            if not flat:  # OpenPose writes an empty list when the body was not estimated
                continue
            n = len(flat) // 3
            if len(flat) % 3 or (chosen is None and n not in _BY_COUNT):
                raise ValueError(
                    f"{where}: {len(flat)} values in pose_keypoints_2d; expected 3 x 25 (BODY_25/BODY_25B), "
                    "3 x 26 (HALPE_26) or 3 x 18 (COCO-18)"
                )
            name = chosen or _BY_COUNT[n]
            n_src, index = SKELETONS[name]
            if chosen is None:
                chosen = name
            xyc = triplets(where, flat, n_src)
            if name == "body25" and skeleton == "auto" and np.all(xyc[[8, 9, 12], 2] > 0):
                pts = xyc[xyc[:, 2] > 0, :2]
                hips.append(np.vstack([xyc[[8, 9, 12], :2], pts.max(axis=0) - pts.min(axis=0)]))
            out.add(where, key, xyc, index, person_id=_person_id(where, person))
    if chosen is not None:
        out.has_feet = chosen != "coco18"
    if chosen == "body25" and skeleton == "auto":
        _check_body25(folder, hips)
    return out
