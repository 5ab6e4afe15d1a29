"""Import 2D keypoints (OpenPose folders or COCO JSON, one source per camera) as ``Detections2D``.

The joint set is ``COCO17_FEET`` when any camera's source has foot points (OpenPose
BODY_25 / BODY_25B / HALPE_26, COCO-WholeBody) and ``COCO17`` otherwise; joints a
source lacks are ``keypoint_valid = False``. A keypoint with confidence 0 is invalid;
each box is the extent of the valid keypoints (or the COCO ``bbox``); its score is the
mean confidence of the valid keypoints (or the COCO ``score``).

Cameras are matched to the rig by name: a source camera absent from the rig is an
error, and so is a rig camera without a source unless ``allow_missing_cameras``.

Frames: every camera must cover the same frames (same file numbers for OpenPose with
``frame_from="number"``, same counts otherwise). Frame 0 is the smallest frame number
over all cameras. With ``pad_frames=True`` differing cameras are accepted and frames a
camera lacks simply have no detections there. Every problem is a ``ValueError``
naming the file or camera.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Literal

import numpy as np

from pipeline.io.keypoints_coco import read_coco_file
from pipeline.io.keypoints_common import CameraRows
from pipeline.io.keypoints_openpose import FrameFrom, OpenPoseSkeleton, read_openpose_folder
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Detections2D
from pipeline.schema.joints import COCO17, COCO17_FEET

log = logging.getLogger(__name__)

KeypointFormat = Literal["openpose", "coco"]

__all__ = ["KeypointFormat", "load_keypoints", "load_keypoints_with_ids"]


def _read_cameras(
    paths: Mapping[str, str | Path],
    fmt: KeypointFormat,
    rig: CameraRig,
    allow_missing_cameras: bool,
    openpose_skeleton: OpenPoseSkeleton,
    frame_from: FrameFrom,
) -> dict[str, CameraRows]:
    unknown = [c for c in paths if c not in rig.names]
    if unknown:
        raise ValueError(
            f"keypoints for camera(s) {unknown} ({[str(paths[c]) for c in unknown]}) that are not in the "
            f"calibration {list(rig.names)}"
        )
    missing = [c for c in rig.names if c not in paths]
    if missing and not allow_missing_cameras:
        given = [c for c in rig.names if c in paths]
        raise ValueError(
            f"calibration camera(s) {missing} have no keypoints; give them with --keypoints CAM=PATH "
            f'(session.json "keypoints"), or leave them out with --cameras {",".join(given)} '
            '(session.json "cameras")'
        )
    if fmt not in ("openpose", "coco"):
        raise ValueError(f"keypoint format must be 'openpose' or 'coco', got {fmt!r}")
    kind = "OpenPose keypoint folder" if fmt == "openpose" else "COCO keypoint file"
    for cam, p in paths.items():  # report a missing input before parsing the others
        if not Path(p).exists():
            raise ValueError(f"{p}: {kind} for camera {cam!r} not found")
        if fmt == "openpose" and not Path(p).is_dir():
            raise ValueError(
                f"{p}: expected a folder of OpenPose *.json files (one per frame) for camera {cam!r}"
            )
        if fmt == "coco" and not Path(p).is_file():
            raise ValueError(f"{p}: expected a COCO keypoint JSON file for camera {cam!r}, got a folder")
    out: dict[str, CameraRows] = {}
    for cam in rig.names:
        if cam not in paths:
            continue
        p = Path(paths[cam])
        if fmt == "openpose":
            out[cam] = read_openpose_folder(p, openpose_skeleton, frame_from)
        else:
            out[cam] = read_coco_file(p)
        if not out[cam].frame_keys:
            raise ValueError(f"{p}: {kind} for camera {cam!r} holds no frames (no images and no annotations)")
    return out


def _align_frames(cams: dict[str, CameraRows], pad_frames: bool) -> tuple[int, int]:
    """n_frames and the key offset, ``frame = key - offset`` (the smallest key of all cameras)."""
    sets = {c: set(r.frame_keys) for c, r in cams.items()}
    ref_cam = next(iter(sets))
    for c, s in sets.items():
        if s != sets[ref_cam] and not pad_frames:
            only_ref = sorted(sets[ref_cam] - s)[:5]
            only_c = sorted(s - sets[ref_cam])[:5]
            raise ValueError(
                f"camera {c!r} ({cams[c].source}) has {len(s)} frames but camera {ref_cam!r} "
                f"({cams[ref_cam].source}) has {len(sets[ref_cam])}; frames only in {ref_cam!r}: {only_ref}, "
                f"only in {c!r}: {only_c}; every camera's keypoints must cover the same frames"
            )
    lo = min(min(s) for s in sets.values())
    hi = max(max(s) for s in sets.values())
    return hi - lo + 1, lo


def load_keypoints_with_ids(
    paths: Mapping[str, str | Path],
    fmt: KeypointFormat,
    rig: CameraRig,
    *,
    allow_missing_cameras: bool = False,
    pad_frames: bool = False,
    openpose_skeleton: OpenPoseSkeleton = "auto",
    frame_from: FrameFrom = "number",
) -> tuple[Detections2D, np.ndarray | None]:
    """Like :func:`load_keypoints`, also returning the source's per-row person ids.

    Returns ``(detections, ids)``: ``ids`` is a (dets,) int64 array of OpenPose
    ``person_id`` / COCO ``track_id`` values (``-1`` where a row has none), or ``None``
    when no row has one.
    """
    cams = _read_cameras(paths, fmt, rig, allow_missing_cameras, openpose_skeleton, frame_from)
    n_frames, offset = _align_frames(cams, pad_frames)
    feet = any(r.has_feet for r in cams.values())
    joints = COCO17_FEET if feet else COCO17
    J = len(joints)
    view, frame, kp, conf, valid, box, score, pid = [], [], [], [], [], [], [], []
    for cam, r in cams.items():
        n = len(r.row_frame_key)
        if n == 0:
            log.warning("%s: no person with a valid keypoint", r.source)
            continue
        view.append(np.full(n, rig.index(cam), dtype=np.int64))
        frame.append(np.asarray(r.row_frame_key, dtype=np.int64) - offset)
        kp.append(np.stack(r.keypoints_px)[:, :J])
        conf.append(np.stack(r.keypoint_conf)[:, :J])
        valid.append(np.stack(r.keypoint_valid)[:, :J])
        box.append(np.stack(r.bbox_xyxy_px))
        score.append(np.asarray(r.bbox_score, dtype=np.float64))
        pid.append(np.asarray(r.person_id, dtype=np.int64))
    if view:
        arrays = [np.concatenate(a) for a in (view, frame, kp, conf, valid, box, score, pid)]
    else:
        arrays = [
            np.zeros(0, np.int64),
            np.zeros(0, np.int64),
            np.zeros((0, J, 2)),
            np.zeros((0, J)),
            np.zeros((0, J), bool),
            np.zeros((0, 4)),
            np.zeros(0),
            np.zeros(0, np.int64),
        ]
    v, f, k, c, ok, b, s, ids = arrays
    order = np.lexsort((v, f))  # rows sorted by frame, then view
    dets = Detections2D(
        joint_names=joints,
        n_views=rig.n_views,
        n_frames=int(n_frames),
        view=v[order],
        frame=f[order],
        bbox_xyxy_px=b[order],
        bbox_score=s[order],
        keypoints_px=k[order],
        keypoint_conf=c[order],
        keypoint_valid=ok[order],
    )
    ids = ids[order]
    return dets, (ids if np.any(ids >= 0) else None)


def load_keypoints(
    paths: Mapping[str, str | Path],
    fmt: KeypointFormat,
    rig: CameraRig,
    *,
    allow_missing_cameras: bool = False,
    pad_frames: bool = False,
    openpose_skeleton: OpenPoseSkeleton = "auto",
    frame_from: FrameFrom = "number",
) -> Detections2D:
    """Read 2D keypoints of every camera into one ``Detections2D``.

    Args:
        paths: camera name -> OpenPose folder (one JSON per frame) or COCO JSON file.
        fmt: ``"openpose"`` or ``"coco"``.
        rig: the calibration; its camera order defines the view indices.
        allow_missing_cameras: accept rig cameras without keypoints (no detections).
        pad_frames: accept cameras covering different frames (see module docstring).
        openpose_skeleton: OpenPose skeleton, ``"auto"`` = by keypoint count
            (25 -> BODY_25, 26 -> HALPE_26, 18 -> COCO-18); ``"body25b"`` must be explicit.
        frame_from: OpenPose frame index from the file-name number or the file order.
    Raises:
        ValueError naming the file/camera: unknown or missing cameras, missing folder,
        malformed JSON (with line and column), NaN values, wrong keypoint counts,
        mismatched frames across cameras.
    """
    dets, _ = load_keypoints_with_ids(
        paths,
        fmt,
        rig,
        allow_missing_cameras=allow_missing_cameras,
        pad_frames=pad_frames,
        openpose_skeleton=openpose_skeleton,
        frame_from=frame_from,
    )
    return dets
