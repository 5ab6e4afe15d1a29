"""MuJoCo export of the physics result: the scene MJCF, the motion per frame and a replay script.

The ZIP holds:

- ``scene.xml``: the physics stage's MJCF as it ran (every athlete's humanoid, bodies and
  joints prefixed ``p{id}_``, a floor; meshes inline, so the file stands alone).
- ``motion.npz`` (no pickle): ``qpos`` (frames, nq) (per athlete: free root xyz in metres +
  ``quat_wxyz``, then hinge angles in radians), ``qvel`` (frames, nv) (m/s, rad/s), ``ctrl``
  (frames, nu) (the physics' controls, see ``actuation``), ``joint_torque_nm`` (frames, nu),
  ``time_s`` (frames,) = video frame index / fps, ``frame_indices`` (frames,) video frames,
  ``fps`` (scalar), ``person_ids`` (persons,), ``athlete_names`` (persons,), ``actuation``.
- ``replay.py``: under 20 lines, needs only ``mujoco`` and ``numpy``: loads the model, sets
  ``qpos`` per frame, runs ``mj_forward`` and shows it in ``mujoco.viewer``; with ``--headless``
  it opens no window. Either way it saves the body and site positions per frame (world,
  metres) to ``replayed.npz`` next to it.

Axes and units are MuJoCo's and the world's: metres, z-up, right-handed. The rate is the
session's frame rate. ``--frames`` restricts the frames; the scene always holds every athlete,
so ``--athlete`` is refused and ``--source`` does not apply.
"""

from __future__ import annotations

import io
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from pipeline.io.export.selection import ExportSelection

REPLAY_PY = '''\
"""Replay cornerman physics: python replay.py [--headless]; writes the body/site positions to replayed.npz."""
import sys
import time
from pathlib import Path

import mujoco
import mujoco.viewer
import numpy as np

here = Path(__file__).resolve().parent
model = mujoco.MjModel.from_xml_path(str(here / "scene.xml"))
data, motion, body_xpos, site_xpos = mujoco.MjData(model), np.load(here / "motion.npz"), [], []
viewer = None if "--headless" in sys.argv else mujoco.viewer.launch_passive(model, data)
for qpos in motion["qpos"]:
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    body_xpos.append(data.xpos.copy()); site_xpos.append(data.site_xpos.copy())
    if viewer is not None:
        viewer.sync(); time.sleep(1.0 / float(motion["fps"]))
np.savez(here / "replayed.npz", body_xpos=np.array(body_xpos), site_xpos=np.array(site_xpos))
'''


def build_mujoco(sel: ExportSelection) -> dict[str, bytes]:
    """The registry's ``mujoco`` format: ``scene.xml``, ``motion.npz`` and ``replay.py``;
    ``LookupError`` when the physics stage has not run; ``ValueError`` for ``--athlete`` (the
    scene simulates every athlete together, so one cannot be replayed alone)."""
    if sel.athletes:
        raise ValueError(
            "--athlete: the mujoco export holds the whole scene (every athlete); leave --athlete out"
        )
    try:
        res, xml = sel.physics()
    except (LookupError, FileNotFoundError) as e:
        raise LookupError(f"mujoco export needs the physics stage's result and scene: {e}") from e
    buf = io.BytesIO()
    np.savez_compressed(
        buf,
        qpos=res.qpos,
        qvel=res.qvel,
        ctrl=res.ctrl,
        joint_torque_nm=res.joint_torque_nm,
        time_s=res.frame_indices / res.fps,
        frame_indices=res.frame_indices,
        fps=np.float64(res.fps),
        person_ids=res.person_ids,
        athlete_names=np.array([sel.name_of(int(p)) for p in res.person_ids], dtype=str),
        actuation=np.array(res.actuation),
    )
    return {"scene.xml": xml.encode(), "motion.npz": buf.getvalue(), "replay.py": REPLAY_PY.encode()}
