"""Load a calibration in any supported format (dispatch on file name, then content).

Supported formats (all give a ``CameraRig`` in metres, OpenCV camera frames, the
file's world frame):

- Pose2Sim / anipose TOML (``*.toml``): :mod:`pipeline.io.calibration_toml`.
- Qualisys QTM XML (``*.qca.txt``, ``*.qca``, or XML with a ``<calibration>`` root):
  :mod:`pipeline.io.calibration_qualisys`.
- EasyMocap OpenCV YAML (a folder with ``intri.yml`` + ``extri.yml``, or either file):
  :mod:`pipeline.io.calibration_easymocap`.
- Campus/Shelf-style JSON (``*.json``): :mod:`pipeline.io.calibration_json`.

Export: :func:`save_toml` writes any rig as a Pose2Sim-compatible TOML.
"""

from __future__ import annotations

import re
from pathlib import Path

from pipeline.io.calibration_common import rotate_images_cw, with_fps
from pipeline.io.calibration_easymocap import EXTRI_NAME, INTRI_NAME, load_easymocap
from pipeline.io.calibration_json import load_json_calibration
from pipeline.io.calibration_qualisys import load_qualisys
from pipeline.io.calibration_toml import load_toml, save_toml
from pipeline.schema.camera import CameraRig

__all__ = ["SUPPORTED_FORMATS", "calibration_files", "load_calibration", "resolve_calibration", "rotate_images_cw", "save_toml"]

SUPPORTED_FORMATS = (
    "Pose2Sim/anipose .toml",
    "Qualisys .qca.txt (XML)",
    f"EasyMocap folder with {INTRI_NAME} + {EXTRI_NAME} (or either file)",
    "Campus/Shelf-style .json",
)


def calibration_files(folder: Path) -> list[Path]:
    """The files directly in ``folder`` named as a calibration (``*.toml``, ``*.qca.txt``,
    ``*.qca``), sorted. JSON files are left out: an inputs folder's JSON is usually keypoints."""
    return sorted(p for p in folder.iterdir() if p.is_file() and p.name.lower().endswith((".toml", ".qca.txt", ".qca")))


def resolve_calibration(path: Path) -> Path:
    """``path`` itself, or for a folder that is not an EasyMocap one the single calibration file
    in it (``calibration_files``). Raises ``ValueError`` naming the path when it does not exist or
    the folder holds none or several."""
    if not path.exists():
        raise ValueError(f"{path}: calibration not found")
    if not path.is_dir() or (path / INTRI_NAME).exists() or (path / EXTRI_NAME).exists():
        return path
    found = calibration_files(path)
    if len(found) != 1:
        what = "no calibration file (*.toml, *.qca.txt, *.qca)" if not found else (
            f"several calibration files ({', '.join(p.name for p in found)})")
        raise ValueError(f"{path}: a folder, but not an EasyMocap one ({INTRI_NAME} + {EXTRI_NAME}), and it holds {what}; give the file")
    return found[0]


def _sniff(path: Path) -> str | None:
    """Guess a format from the first bytes of a file without a telling extension."""
    try:
        head = path.read_bytes()[:512].decode("utf-8", errors="replace").lstrip("\ufeff \t\r\n")
    except OSError as e:
        raise ValueError(f"{path}: cannot read calibration: {e}") from e
    if head.startswith("%YAML"):
        return "easymocap"
    if head.startswith("<") and "<calibration" in head:
        return "qualisys"
    if head.startswith(("{", "[")) and '"K"' in head:
        return "json"
    if re.match(r"\[[\w.\-\" ]+\]\s*\n", head):  # a TOML table header such as [cam_1]
        return "toml"
    return None


def calibration_format(path: str | Path) -> str:
    """One of ``toml``, ``qualisys``, ``easymocap``, ``json``; ``ValueError`` if unrecognised."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"{path}: calibration not found")
    name = path.name.lower()
    if path.is_dir():
        if (path / INTRI_NAME).exists() or (path / EXTRI_NAME).exists():
            return "easymocap"
        fmt = None
    elif name.endswith(".toml"):
        fmt = "toml"
    elif name.endswith((".qca.txt", ".qca")):
        fmt = "qualisys"
    elif name in (INTRI_NAME, EXTRI_NAME):
        fmt = "easymocap"
    elif name.endswith(".json"):
        fmt = "json"
    else:
        fmt = _sniff(path)
    if fmt is None:
        raise ValueError(
            f"{path}: unrecognised calibration format (supported: {'; '.join(SUPPORTED_FORMATS)})"
        )
    return fmt


def load_calibration(path: str | Path, *, fps: float | None = None) -> CameraRig:
    """Read a calibration file or folder into a ``CameraRig``.

    ``fps`` overrides the frame rate (TOML files may store one; the other formats
    default to 30). Raises ``ValueError`` naming the file and the problem, listing
    the supported formats when the format is not recognised.
    """
    path = Path(path)
    fmt = calibration_format(path)
    if fmt == "toml":
        rig = load_toml(path)
    elif fmt == "qualisys":
        rig = load_qualisys(path)
    elif fmt == "easymocap":
        rig = load_easymocap(path)
    else:
        rig = load_json_calibration(path)
    if fps is not None:
        if not fps > 0:
            raise ValueError(f"{path}: fps must be positive, got {fps}")
        rig = with_fps(rig, fps)
    return rig
