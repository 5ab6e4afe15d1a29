"""Campus/Shelf-style JSON calibration (as in 4D Association's ``data/shelf/calibration.json``).

The file is a JSON object ``{camera_name: camera, ...}`` (or a list of cameras, named
by their ``name`` key or by their index). Accepted keys per camera:

- ``K``: intrinsics, 9 numbers row-major or a 3x3 nested list (pixels).
- extrinsics (world -> camera, OpenCV frame, translation in **metres**), either
  ``RT``: 12 numbers row-major or a 3x4 nested list ``[R | t]``, or
  ``R`` (3 Rodrigues numbers, 9 row-major numbers or 3x3) with ``T`` or ``t`` (3).
- distortion (optional, default none): ``distCoeff``, ``dist`` or ``distortion``,
  4 or 5 OpenCV coefficients ``k1 k2 p1 p2 [k3]``.
- image size (required): ``imgSize`` ``[w, h]``, or ``width`` and ``height``.
- ``name`` (optional, lists only).

Other keys are ignored. VoxelPose's Campus/Shelf files (``fx``/``fy``/``cx``/``cy`` and
``T`` = the camera centre in millimetres) use different conventions and are rejected
with an explicit error rather than misread. World frame: kept as the file's (Shelf and
Campus are z-up).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.geometry.rotations import R_from_rodrigues
from pipeline.io.calibration_common import (
    as_float_array,
    check_intrinsics,
    dist5,
    image_size,
    rig_from_extrinsics,
)
from pipeline.schema.camera import CameraRig

DIST_KEYS = ("distCoeff", "dist", "distortion")


def _extrinsics(where: str, cam: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    if "RT" in cam:
        RT = as_float_array(where, "RT", cam["RT"], (3, 4))
        return RT[:, :3], RT[:, 3]
    if "R" not in cam or not ("T" in cam or "t" in cam):
        raise ValueError(f"{where}: needs extrinsics 'RT' (3x4) or 'R' with 'T'/'t'; keys are {sorted(cam)}")
    try:
        n = int(np.asarray(cam["R"], dtype=np.float64).size)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: 'R' is not numeric: {e}") from e
    if n == 3:
        R = R_from_rodrigues(as_float_array(where, "R", cam["R"], (3,)))
    elif n == 9:
        R = as_float_array(where, "R", cam["R"], (3, 3))
    else:
        raise ValueError(f"{where}: 'R' must be 3 Rodrigues numbers or a 3x3 matrix, got {n} numbers")
    t = as_float_array(where, "T" if "T" in cam else "t", cam.get("T", cam.get("t")), (3,))
    return R, t


def _size(where: str, cam: dict[str, Any]) -> np.ndarray:
    if "imgSize" in cam:
        return image_size(where, cam["imgSize"])
    if "width" in cam and "height" in cam:
        return image_size(where, [cam["width"], cam["height"]])
    raise ValueError(f"{where}: needs the image size as 'imgSize' [w, h] or 'width' and 'height'")


def load_json_calibration(path: str | Path, *, fps: float = 30.0) -> CameraRig:
    """Read a Campus/Shelf-style JSON calibration (see the module docstring for the keys)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: malformed JSON at line {e.lineno}, column {e.colno}: {e.msg}") from e
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: not a text file: {e}") from e
    if isinstance(data, list):
        items = [(str(c.get("name", i)) if isinstance(c, dict) else str(i), c) for i, c in enumerate(data)]
    elif isinstance(data, dict):
        items = [(str(k), v) for k, v in data.items()]
    else:
        raise ValueError(f"{path}: expected a JSON object of cameras, got {type(data).__name__}")
    names, Ks, dists, Rs, ts, sizes = [], [], [], [], [], []
    for name, cam in items:
        where = f"{path} [camera {name}]"
        if not isinstance(cam, dict):
            raise ValueError(f"{where}: expected an object with 'K' and extrinsics, got {type(cam).__name__}")
        if "fx" in cam and "K" not in cam:
            raise ValueError(
                f"{where}: VoxelPose-style camera (fx/fy/cx/cy, T = centre in mm) is not supported; "
                "convert it to K and RT (world -> camera, metres)"
            )
        if "K" not in cam:
            raise ValueError(f"{where}: missing intrinsics 'K'; keys are {sorted(cam)}")
        Ks.append(check_intrinsics(where, as_float_array(where, "K", cam["K"], (3, 3))))
        R, t = _extrinsics(where, cam)
        Rs.append(R)
        ts.append(t)
        dkey = next((k for k in DIST_KEYS if k in cam), None)
        dists.append(dist5(f"{where} {dkey}", cam[dkey]) if dkey else np.zeros(5))
        sizes.append(_size(where, cam))
        names.append(name)
    return rig_from_extrinsics(str(path), names, Ks, dists, Rs, ts, sizes, fps)
