"""Pose2Sim / anipose calibration TOML (Rodrigues rotation, translation in metres).

Each camera is a table ``[cam_name]`` with ``name``, ``size = [w, h]``,
``matrix`` (3x3 K), ``distortions`` (4 or 5 OpenCV coefficients), ``rotation``
(Rodrigues vector of R_cam_world) and ``translation`` (t_cam_world, metres), plus an
optional ``[metadata]`` table. cornerman adds ``fps`` and ``time_offset_s`` to the
metadata / camera tables; readers that do not know them ignore them.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import tomli_w

from pipeline.geometry.rotations import R_from_rodrigues, rodrigues_from_R
from pipeline.schema.camera import CameraRig


def _as_float_array(where: str, key: str, value: object, shape: tuple[int, ...]) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: {key} is not numeric: {e}") from e
    if arr.shape != shape:
        raise ValueError(f"{where}: {key} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{where}: {key} contains NaN/inf: {arr.tolist()}")
    return arr


def load_toml(path: str | Path, default_fps: float = 30.0) -> CameraRig:
    """Read a Pose2Sim/anipose calibration TOML. Errors name the file and camera."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{path}: malformed TOML: {e}") from e
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: not a text file: {e}") from e
    meta = data.get("metadata", {})
    fps = meta.get("fps", default_fps) if isinstance(meta, dict) else default_fps
    if isinstance(fps, bool) or not isinstance(fps, int | float) or not fps > 0:
        raise ValueError(f"{path} [metadata]: fps must be a positive number, got {fps!r}")
    names, Ks, dists, Ts, sizes, offsets = [], [], [], [], [], []
    for key, cam in data.items():
        if key == "metadata" or not isinstance(cam, dict):
            continue
        where = f"{path} [{key}]"
        for req in ("size", "matrix", "distortions", "rotation", "translation"):
            if req not in cam:
                raise ValueError(f"{where}: missing key {req!r}")
        if cam.get("fisheye", False):
            # The rig keeps OpenCV's pinhole distortion only; reading fisheye
            # coefficients as pinhole ones would silently misproject.
            raise ValueError(f"{where}: fisheye cameras are not supported (fisheye = true)")
        K = _as_float_array(where, "matrix", cam["matrix"], (3, 3))
        try:
            d = np.asarray(cam["distortions"], dtype=np.float64).ravel()
        except (TypeError, ValueError) as e:
            raise ValueError(f"{where}: distortions are not numeric: {e}") from e
        if d.size not in (4, 5) or not np.all(np.isfinite(d)):
            raise ValueError(f"{where}: distortions must be 4 or 5 finite numbers, got {cam['distortions']}")
        dist = np.zeros(5)
        dist[: d.size] = d
        rvec = _as_float_array(where, "rotation", cam["rotation"], (3,))
        tvec = _as_float_array(where, "translation", cam["translation"], (3,))
        size = _as_float_array(where, "size", cam["size"], (2,))
        R_cam_world = R_from_rodrigues(rvec)
        T = np.eye(4)
        T[:3, :3] = R_cam_world.T
        T[:3, 3] = -R_cam_world.T @ tvec
        names.append(str(cam.get("name", key)))
        Ks.append(K)
        dists.append(dist)
        Ts.append(T)
        sizes.append(np.round(size).astype(np.int64))
        offset = cam.get("time_offset_s", 0.0)
        if isinstance(offset, bool) or not isinstance(offset, int | float) or not np.isfinite(offset):
            raise ValueError(f"{where}: time_offset_s must be a finite number, got {offset!r}")
        offsets.append(float(offset))
    if not names:
        raise ValueError(f"{path}: no camera tables found")
    try:
        return CameraRig(
            names=tuple(names),
            K=np.stack(Ks),
            dist=np.stack(dists),
            T_world_cam=np.stack(Ts),
            image_size_wh=np.stack(sizes),
            fps=float(fps),
            time_offset_s=np.asarray(offsets),
        )
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from e


def save_toml(rig: CameraRig, path: str | Path) -> None:
    """Write ``rig`` as a Pose2Sim/anipose-compatible TOML (atomic)."""
    path = Path(path)
    T_cw = rig.T_cam_world
    doc: dict = {}
    for v, name in enumerate(rig.names):
        doc[name] = {
            "name": name,
            "size": [float(x) for x in rig.image_size_wh[v]],
            "matrix": rig.K[v].tolist(),
            "distortions": rig.dist[v].tolist(),
            "rotation": rodrigues_from_R(T_cw[v, :3, :3]).tolist(),
            "translation": T_cw[v, :3, 3].tolist(),
            "fisheye": False,
            "time_offset_s": float(rig.time_offset_s[v]),
        }
    doc["metadata"] = {"adjusted": False, "error": 0.0, "fps": float(rig.fps)}
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(tomli_w.dumps(doc))
    tmp.replace(path)
