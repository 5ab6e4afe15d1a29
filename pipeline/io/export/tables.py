"""CSV export of 3D keypoints: a long table, one row per (frame, athlete, joint).

Layout (first row is the header, no comment lines)::

    frame,time_s,athlete_id,athlete_name,joint,x_m,y_m,z_m,confidence,valid
    100,2.000000,0,Red,nose,0.104433,0.004023,1.564782,0.900,1

- ``frame``: video frame index; ``time_s = frame / fps`` (the session's frame rate).
- ``x_m, y_m, z_m``: metres in the floor world (``calibrate/world.json``; z-up, right-handed), rounded to
  1 micrometre; empty cells where ``valid`` is 0 (no estimate).
- ``confidence`` in [0, 1] (0 where invalid); ``valid`` 1 or 0.
- Rows are ordered by frame, then athlete (in the selection's order), then joint.
"""

from __future__ import annotations

import csv
import io
from typing import TYPE_CHECKING

from pipeline.schema.keypoints3d import Keypoints3D

if TYPE_CHECKING:
    from pipeline.io.export.selection import ExportSelection

CSV_COLUMNS = (
    "frame",
    "time_s",
    "athlete_id",
    "athlete_name",
    "joint",
    "x_m",
    "y_m",
    "z_m",
    "confidence",
    "valid",
)


def keypoints3d_to_csv(kp: Keypoints3D, names: dict[int, str]) -> str:
    """The long CSV table of ``kp`` (see the module docstring); ``names`` maps person id -> name."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    pids = [int(p) for p in kp.person_ids]
    for fi, frame in enumerate(kp.frame_indices.tolist()):
        t = f"{frame / kp.fps:.6f}"
        for pi, pid in enumerate(pids):
            for ji, joint in enumerate(kp.joint_names):
                ok = bool(kp.valid[fi, pi, ji])
                xyz = [f"{v:.6f}" for v in kp.xyz_m[fi, pi, ji]] if ok else ["", "", ""]
                conf = f"{kp.confidence[fi, pi, ji]:.3f}" if ok else "0.000"
                w.writerow([frame, t, pid, names.get(pid, ""), joint, *xyz, conf, int(ok)])
    return buf.getvalue()


def build_csv(sel: ExportSelection) -> dict[str, bytes]:
    """The registry's ``csv`` format: the selected keypoints as one long table."""
    kp, chosen = sel.keypoints()
    names = {int(p): sel.name_of(int(p)) for p in kp.person_ids}
    return {f"keypoints3d_{chosen}.csv": keypoints3d_to_csv(kp, names).encode()}
