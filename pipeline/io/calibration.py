"""Load a calibration in any supported format (dispatch on file name / content)."""

from __future__ import annotations

from pathlib import Path

from pipeline.io.calibration_toml import load_toml, save_toml
from pipeline.schema.camera import CameraRig

__all__ = ["load_calibration", "save_toml"]


def load_calibration(path: str | Path) -> CameraRig:
    """Read a calibration file or folder into a ``CameraRig``.

    Supported: Pose2Sim/anipose ``.toml``.
    Raises ``ValueError`` naming the file and the problem.
    """
    path = Path(path)
    if not path.exists():
        raise ValueError(f"{path}: calibration not found")
    if path.suffix.lower() == ".toml":
        return load_toml(path)
    raise ValueError(f"{path}: unrecognised calibration format (supported: .toml)")
