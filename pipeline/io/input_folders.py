"""Folders holding every camera's input, each entry named after its camera.

An entry is one camera's input: a video file (``cam01.mp4``, as a Pose2Sim project's
``videos/``), an OpenPose folder of per-frame JSON files (``cam0/``, as Shelf's
``keypoints2d/``; Pose2Sim's ``pose/cam01_json/``) or a COCO JSON file (``cam0.json``). An entry
matches a calibrated camera by its exact name, else by the name compared without case,
separators, leading zeros and a ``json`` suffix (``cam_0`` = ``cam0``, ``Cam01_json`` = ``cam1``),
when that match is unique. Used by ``cornerman new --video/--keypoints FOLDER`` and by the
server's inputs folders (``server.storage.session_from_folder``).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Literal

EntryKind = Literal["video", "openpose", "coco"]
KEYPOINT_SUBFOLDERS = ("keypoints2d", "keypoints", "pose")
"""Subfolders of an inputs folder searched, in this order, for per-camera OpenPose folders."""


def _key(name: str) -> str:
    """``name`` compared loosely: lower case, letters and digits only, no leading zeros in a
    number, no ``json`` suffix."""
    plain = re.sub(r"[^a-z0-9]", "", re.sub(r"[_\-. ]json$", "", name.lower()))
    return re.sub(r"(?<!\d)0+(?=\d)", "", plain)


def entries(folder: Path, kind: EntryKind) -> dict[str, str]:
    """Entry name -> path (``folder / name``) of each camera input of ``kind`` directly in
    ``folder``, sorted by name; ``{}`` when it holds none."""
    from pipeline.io.video import videos_in

    if kind == "video":
        return videos_in(folder)
    if kind == "coco":
        return {p.stem: str(p) for p in sorted(folder.glob("*.json")) if p.is_file()}
    return {p.name: str(p) for p in sorted(folder.iterdir()) if p.is_dir()}


def describe(kind: EntryKind) -> str:
    """What an entry of ``kind`` is, for messages."""
    from pipeline.io.video import VIDEO_SUFFIXES

    return {"video": f"video ({', '.join(VIDEO_SUFFIXES)})", "coco": "COCO *.json file",
            "openpose": "OpenPose camera folder"}[kind]  # fmt: skip


def match_cameras(found: dict[str, str], calibrated: tuple[str, ...], where: str) -> dict[str, str]:
    """``found`` (entry name -> path) keyed by the calibrated camera each entry stands for (see
    the module docstring); ``ValueError`` starting with ``where`` for an entry that matches no
    camera, matches ambiguously, or matches a camera another entry has. Calibrated cameras
    without an entry are left to the caller (``--cameras`` may leave them out)."""
    keys: dict[str, list[str]] = {}
    for cam in calibrated:
        keys.setdefault(_key(cam), []).append(cam)
    out: dict[str, str] = {}
    unknown: list[str] = []
    for name, path in found.items():
        cams = [name] if name in calibrated else keys.get(_key(name), [])
        if len(cams) > 1:
            raise ValueError(f"{where}: {name!r} could stand for cameras {cams}; rename it after one of them")
        if not cams:
            unknown.append(name)
        elif cams[0] in out:
            raise ValueError(f"{where}: two inputs for camera {cams[0]!r} ({Path(out[cams[0]]).name} and {name}); keep one")
        else:
            out[cams[0]] = path
    if unknown:
        raise ValueError(f"{where}: {unknown} named after no camera the calibration has; its cameras are {list(calibrated)}")
    return out
