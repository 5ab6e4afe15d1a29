"""``cornerman new --video FOLDER`` / ``--keypoints FOLDER``: one folder holding every camera's input.

Each entry directly in the folder is one camera's input, named after the camera: a video file
(``cam01.mp4``, as a Pose2Sim project's ``videos/``), an OpenPose folder of per-frame JSON files
(``cam0/``, as Shelf's ``keypoints2d/``) or a COCO JSON file (``cam0.json``). An entry matches
a calibrated camera by its exact name, else by the name compared without case, separators and
leading zeros (``cam_0`` = ``cam0``, ``Cam01`` = ``cam1``), when that match is unique.
"""

from __future__ import annotations

import re
from pathlib import Path


def _key(name: str) -> str:
    """``name`` compared loosely: lower case, letters and digits only, no leading zeros in a number."""
    return re.sub(r"(?<!\d)0+(?=\d)", "", re.sub(r"[^a-z0-9]", "", name.lower()))


def folder_entries(folder: Path, option: str, keypoint_format: str = "") -> dict[str, str]:
    """Entry name -> absolute path of each camera input directly in ``folder`` (videos for
    ``--video``; per-camera folders for OpenPose, ``*.json`` files for COCO ``--keypoints``);
    ``ValueError`` naming the folder when it holds none."""
    from pipeline.io.video import VIDEO_SUFFIXES, videos_in

    if option == "--video":
        found, what = videos_in(folder), f"video ({', '.join(VIDEO_SUFFIXES)})"
    elif keypoint_format == "coco":
        found, what = {p.stem: str(p) for p in sorted(folder.glob("*.json")) if p.is_file()}, "COCO *.json file"
    else:
        found, what = {p.name: str(p) for p in sorted(folder.iterdir()) if p.is_dir()}, "OpenPose camera folder"
    if not found:
        raise ValueError(f"{option} {folder}: no {what} in this folder")
    return {k: str(Path(v).resolve()) for k, v in found.items()}


def match_cameras(entries: dict[str, str], calibrated: tuple[str, ...], folder: Path, option: str) -> dict[str, str]:
    """``entries`` keyed by the calibrated camera each one stands for (see the module docstring);
    ``ValueError`` naming the folder for an entry that matches no camera, or matches ambiguously.
    Calibrated cameras without an entry are left to the caller (``--cameras`` may leave them out)."""
    keys: dict[str, list[str]] = {}
    for cam in calibrated:
        keys.setdefault(_key(cam), []).append(cam)
    out: dict[str, str] = {}
    unknown: list[str] = []
    for name, path in entries.items():
        cams = [name] if name in calibrated else keys.get(_key(name), [])
        if len(cams) > 1:
            raise ValueError(f"{option} {folder}: {name!r} could stand for cameras {cams}; rename it after one of them")
        if not cams:
            unknown.append(name)
        elif cams[0] in out:
            raise ValueError(f"{option} {folder}: two inputs for camera {cams[0]!r} ({Path(out[cams[0]]).name} "
                             f"and {name}); keep one")  # fmt: skip
        else:
            out[cams[0]] = path
    if unknown:
        raise ValueError(
            f"{option} {folder}: {unknown} named after no camera the calibration has; its cameras are {list(calibrated)}"
        )
    return out
