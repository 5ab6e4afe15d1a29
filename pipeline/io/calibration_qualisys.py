"""Qualisys QTM calibration export (``.qca.txt``, XML) -> ``CameraRig``.

Semantics follow Pose2Sim's ``calib_qca_to_toml`` (the reference converter the
Pose2Sim demo data were made with), checked on the shared Pose2Sim multi-person
calibration against Pose2Sim's own converted TOML and by triangulating people
detected in the demo videos (``tests/io/test_calibration_qualisys.py``):

- ``<transform x y z r11..r33>``: ``(x, y, z)`` is the camera centre in the world, in
  **millimetres** (-> metres). The matrix ``M = [[r11 r12 r13], [r21 ..], ..]`` maps
  world directions into Qualisys' camera frame, whose axes differ from OpenCV's by a
  180-degree turn about x (Qualisys' camera looks along its -z). Hence
  ``R_cam_world = diag(1, -1, -1) @ M`` and ``t_cam_world = -R_cam_world @ C``.
- ``<intrinsic>`` values are in sensor sub-pixels (64 per pixel): ``f = focalLength/64``,
  ``c = centerPoint/64 - fov_video.(left|top)`` (the video is a crop of the sensor).
  A ``video_resolution`` attribute (``"540p"``) on the camera scales the intrinsics by
  ``res / 1080``; a ``binning_factor`` divides them. Distortion coefficients are also
  divided by 64 as Pose2Sim does (its ``calib_toml_to_qca`` multiplies them by 64, so
  files it wrote, like the demo's, round-trip exactly; for native QTM exports this
  follows Pose2Sim's reading and is a known approximation).
- Image size: ``fov_video`` ``(right - left + 1, bottom - top + 1)`` (scaled likewise).
- Only video cameras are kept (``model`` "Miqus Video", "Miqus Video UnderWater" or
  "none"), sorted naturally by ``serial``, which becomes the camera name.
- Rotated video: QTM stores a ``viewrotation`` (degrees) per camera. Its direction is
  not documented, so a nonzero value is an error unless ``video_rotation_cw`` says
  explicitly how the video frames are rotated relative to the sensor image.

World frame: QTM's lab frame (z up, as set by the L-frame), kept as is.
"""

from __future__ import annotations

import logging
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from pipeline.io.calibration_common import (
    as_float_array,
    check_intrinsics,
    image_size,
    natural_key,
    rig_from_extrinsics,
    rotate_images_cw,
)
from pipeline.schema.camera import CameraRig

log = logging.getLogger(__name__)

VIDEO_MODELS = ("Miqus Video", "Miqus Video UnderWater", "none")
SUBPIXELS = 64.0
# Qualisys camera frame -> OpenCV camera frame: 180 degrees about x.
_R_CV_QUALISYS = np.diag([1.0, -1.0, -1.0])


def _attr(where: str, el: ET.Element, key: str) -> float:
    raw = el.get(key)
    if raw is None:
        raise ValueError(f"{where}: <{el.tag}> has no attribute {key!r}")
    try:
        val = float(raw)
    except ValueError:
        raise ValueError(f"{where}: <{el.tag} {key}={raw!r}> is not a number") from None
    if not np.isfinite(val):
        raise ValueError(f"{where}: <{el.tag} {key}={raw!r}> is not finite")
    return val


def _child(where: str, cam: ET.Element, tag: str) -> ET.Element:
    el = cam.find(tag)
    if el is None:
        raise ValueError(f"{where}: camera has no <{tag}> element")
    return el


def _resolution_scale(where: str, cam: ET.Element) -> float:
    raw = cam.get("video_resolution")
    if raw is None:
        return 1.0
    digits = raw.rstrip("pP")
    if not digits.isdigit() or int(digits) <= 0:
        raise ValueError(f"{where}: video_resolution={raw!r} is not like '1080p' or '540p'")
    return int(digits) / 1080.0


def load_qualisys(
    path: str | Path,
    *,
    binning_factor: int = 1,
    video_rotation_cw: Mapping[str, int] | None = None,
    fps: float = 30.0,
) -> CameraRig:
    """Read a Qualisys ``.qca.txt`` calibration (see the module docstring).

    Args:
        binning_factor: sensor binning used when recording the videos (1 = none).
        video_rotation_cw: camera serial -> clockwise rotation in degrees (multiple of
            90) of the video frames relative to the sensor image. Required for every
            camera whose ``viewrotation`` attribute is nonzero; overrides it otherwise.
        fps: frame rate of the rig (the file does not store the video rate).
    Raises:
        ValueError naming the file and camera for malformed XML, missing elements or
        attributes, non-numeric values, an undeclared nonzero ``viewrotation``.
    """
    path = Path(path)
    if binning_factor < 1:
        raise ValueError(f"{path}: binning_factor must be >= 1, got {binning_factor}")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as e:
        raise ValueError(f"{path}: malformed Qualisys XML: {e}") from e
    if root.tag != "calibration":
        raise ValueError(f"{path}: root element is <{root.tag}>, expected <calibration> (Qualisys .qca.txt)")
    cams = root.findall("cameras/camera")
    if not cams:
        raise ValueError(f"{path}: no <cameras><camera> elements")
    rotation = dict(video_rotation_cw or {})
    rows = []
    for i, cam in enumerate(cams):
        serial = cam.get("serial") or f"camera{i + 1}"
        where = f"{path} [camera {serial}]"
        if cam.get("model") not in VIDEO_MODELS:
            log.info("%s: skipping non-video camera (model=%r)", where, cam.get("model"))
            continue
        res_scale = _resolution_scale(where, cam)
        scale = res_scale / binning_factor
        fov = _child(where, cam, "fov_video")
        left, top = _attr(where, fov, "left"), _attr(where, fov, "top")
        w = (_attr(where, fov, "right") - left + 1) * scale
        h = (_attr(where, fov, "bottom") - top + 1) * scale
        intr = _child(where, cam, "intrinsic")
        fu = _attr(where, intr, "focalLengthU") / SUBPIXELS * scale
        fv = _attr(where, intr, "focalLengthV") / SUBPIXELS * scale
        cu = (_attr(where, intr, "centerPointU") / SUBPIXELS / binning_factor - left) * res_scale
        cv = (_attr(where, intr, "centerPointV") / SUBPIXELS / binning_factor - top) * res_scale
        K = check_intrinsics(where, np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]]))
        dist = np.array(
            [
                _attr(where, intr, "radialDistortion1"),
                _attr(where, intr, "radialDistortion2"),
                _attr(where, intr, "tangentalDistortion1"),
                _attr(where, intr, "tangentalDistortion2"),
                0.0,
            ]
        ) / (SUBPIXELS * binning_factor)
        tr = _child(where, cam, "transform")
        M = as_float_array(
            where, "transform rotation", [_attr(where, tr, f"r{a}{b}") for a in "123" for b in "123"], (3, 3)
        )
        C_m = np.array([_attr(where, tr, k) for k in ("x", "y", "z")]) / 1000.0
        R_cam_world = _R_CV_QUALISYS @ M
        view_rot = int(round(_attr(where, cam, "viewrotation"))) if cam.get("viewrotation") else 0
        if serial in rotation:
            view_rot = int(rotation.pop(serial))
        elif view_rot % 360 != 0:
            raise ValueError(
                f"{where}: viewrotation={view_rot}: the video is rotated relative to the sensor; pass "
                f"video_rotation_cw={{{serial!r}: <clockwise degrees>}} to state how"
            )
        if view_rot % 90 != 0:
            raise ValueError(f"{where}: video rotation must be a multiple of 90 degrees, got {view_rot}")
        rows.append((serial, K, dist, R_cam_world, -R_cam_world @ C_m, image_size(where, [w, h]), view_rot))
    if rotation:
        raise ValueError(f"{path}: video_rotation_cw names unknown cameras {sorted(rotation)}")
    rows.sort(key=lambda r: natural_key(r[0]))
    rig = rig_from_extrinsics(
        str(path),
        [r[0] for r in rows],
        [r[1] for r in rows],
        [r[2] for r in rows],
        [r[3] for r in rows],
        [r[4] for r in rows],
        [r[5] for r in rows],
        fps,
    )
    turns = {r[0]: (r[6] // 90) % 4 for r in rows if r[6] % 360}
    return rotate_images_cw(rig, turns) if turns else rig
