"""C3D export of 3D keypoints, written with ezc3d.

- Points: one labelled point per (athlete, joint), labels as the TRC export
  (``Red_left_wrist`` when several athletes, the joint name otherwise); ``POINT:DESCRIPTIONS``
  holds "athlete, joint".
- Units: millimetres (``POINT:UNITS = mm``, the C3D convention), stored as floats.
- Axes: the floor world (the calibration's, levelled and lowered: calibrate/world.json; z-up,
  right-handed), as lab-frame C3D files are.
- Rate: ``POINT:RATE`` = the session's frame rate. The header's first frame is the first
  exported video frame (readers show it 1-based: video frame index + 1); frames missing
  between the first and the last exported one are written as invalid samples.
- Residuals: ``-1`` for a joint without an estimate (its coordinates are NaN for ezc3d and 0 on
  disk), ``0`` for a valid one (no per-point residual in millimetres is known).
- Analog: with ``--source physics`` (or ``latest`` when physics ran), the floor's force on each
  athlete from the physics humanoids (``pipeline.backends.mujoco.forces``): three channels per
  athlete ``Red_GRF_x/y/z``, newtons, world z-up, one sample per point frame (``ANALOG:RATE`` =
  ``POINT:RATE``). Otherwise an empty block (no channels, rate 0).
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


def keypoints3d_to_c3d(kp: Keypoints3D, names: dict[int, str], grf_n: np.ndarray | None = None) -> bytes:
    """The C3D file of ``kp`` (see the module docstring); ``names`` maps person id -> athlete name;
    ``grf_n``: optional (frames, persons, 3) floor force per keypoint row (N), written as analogs."""
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
    if grf_n is not None:
        if grf_n.shape != (kp.n_frames, kp.n_persons, 3):
            raise ValueError(
                f"C3D export: ground forces {grf_n.shape} do not match the keypoints {(kp.n_frames, kp.n_persons, 3)}"
            )
        chan = [f"{names.get(int(p)) or f'person{int(p)}'}_GRF_{ax}" for p in kp.person_ids for ax in "xyz"]
        analog = np.zeros((1, len(chan), n))
        analog[0][:, rows] = grf_n.reshape(kp.n_frames, -1).T
        a = c["parameters"]["ANALOG"]
        a["RATE"]["value"] = [float(kp.fps)]
        a["LABELS"]["value"] = chan
        a["UNITS"]["value"] = ["N"] * len(chan)
        a["DESCRIPTIONS"]["value"] = ["floor force on the athlete, physics, world z-up"] * len(chan)
        c["data"]["analogs"] = analog
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "markers.c3d"
        c.write(str(path))
        return path.read_bytes()


def build_c3d(sel: ExportSelection) -> dict[str, bytes]:
    """The registry's ``c3d`` format: the selected keypoints as one C3D (mm, world z-up)."""
    kp, chosen = sel.keypoints()
    names = {int(p): sel.name_of(int(p)) for p in kp.person_ids}
    grf = _ground_forces(sel, kp) if chosen == "physics" else None
    return {f"keypoints3d_{chosen}.c3d": keypoints3d_to_c3d(kp, names, grf)}


def _ground_forces(sel: ExportSelection, kp: Keypoints3D) -> np.ndarray:
    """(frames, persons, 3) floor force on each athlete of ``kp`` (N), from the physics result."""
    from pipeline.backends.mujoco.forces import ground_reaction_forces

    res, xml = sel.physics()
    grf = ground_reaction_forces(xml, res)
    rows = np.searchsorted(res.frame_indices, kp.frame_indices)
    cols = [[int(p) for p in res.person_ids].index(int(p)) for p in kp.person_ids]
    return grf[rows][:, cols]
