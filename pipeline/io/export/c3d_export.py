"""C3D export of 3D keypoints, written with ezc3d.

- Points: one labelled point per (athlete, joint), labels as the TRC export
  (``Red_left_wrist`` when several athletes, the joint name otherwise); ``POINT:DESCRIPTIONS``
  holds "athlete, joint".
- Units: millimetres (``POINT:UNITS = mm``, the C3D convention), stored as floats.
- Axes: the calibration world frame as is (z-up, right-handed), as lab-frame C3D files are.
- Rate: ``POINT:RATE`` = the session's frame rate. The header's first frame is the first
  exported video frame (readers show it 1-based: video frame index + 1); frames missing
  between the first and the last exported one are written as invalid samples.
- Residuals: ``-1`` for a joint without an estimate (its coordinates are NaN for ezc3d and 0 on
  disk), ``0`` for a valid one (no per-point residual in millimetres is known).
- Analog: an empty block (no channels, rate 0); the physics' ground reactions are not written yet.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pipeline.io.export.markers import marker_arrays, marker_labels
from pipeline.schema.keypoints3d import Keypoints3D

if TYPE_CHECKING:
    from pipeline.io.export.selection import ExportSelection


def keypoints3d_to_c3d(kp: Keypoints3D, names: dict[int, str]) -> bytes:
    """The C3D file of ``kp`` (see the module docstring); ``names`` maps person id -> athlete name."""
    import ezc3d

    if kp.n_frames == 0:
        raise ValueError("C3D export: no frame selected")
    labels = marker_labels(kp, names)
    xyz_m, valid = marker_arrays(kp)
    first = int(kp.frame_indices[0])
    rows = kp.frame_indices - first  # dense C3D frame of each keypoint row
    n = int(rows[-1]) + 1
    pts = np.full((4, len(labels), n), np.nan)
    pts[3] = 1.0
    res = np.full((1, len(labels), n), -1.0)
    pts[:3, :, rows] = np.where(valid[..., None], xyz_m * 1000.0, np.nan).transpose(2, 1, 0)
    res[0][:, rows] = np.where(valid, 0.0, -1.0).T
    c = ezc3d.c3d()
    point = c["parameters"]["POINT"]
    point["RATE"]["value"] = [float(kp.fps)]
    point["UNITS"]["value"] = ["mm"]
    point["LABELS"]["value"] = labels
    point["DESCRIPTIONS"]["value"] = [
        f"{names.get(int(p)) or f'person{int(p)}'}, {j}" for p in kp.person_ids for j in kp.joint_names
    ]
    c["header"]["points"]["first_frame"] = first
    c["data"]["points"] = pts
    c["data"]["meta_points"] = {"residuals": res, "camera_masks": np.zeros((7, len(labels), n), dtype=bool)}
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "markers.c3d"
        c.write(str(path))
        return path.read_bytes()


def build_c3d(sel: ExportSelection) -> dict[str, bytes]:
    """The registry's ``c3d`` format: the selected keypoints as one C3D (mm, world z-up)."""
    kp, chosen = sel.keypoints()
    names = {int(p): sel.name_of(int(p)) for p in kp.person_ids}
    return {f"keypoints3d_{chosen}.c3d": keypoints3d_to_c3d(kp, names)}
