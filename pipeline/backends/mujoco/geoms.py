"""A saved physics scene's geoms and their world poses for a ``qpos`` (for the viewer).

The MJCF (``physics/scene.xml``) is compiled once; ``geom_poses(qpos)`` sets ``qpos`` and
runs ``mj_kinematics``. What the viewer draws is described in plain numpy
(``GeomShape``), so the viewer builds its meshes without importing mujoco.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import mujoco
import numpy as np

GeomKind = Literal["plane", "hfield", "sphere", "capsule", "ellipsoid", "cylinder", "box", "mesh", "other"]
# mjtGeom values (stable MuJoCo ABI).
_KINDS: dict[int, GeomKind] = {
    int(mujoco.mjtGeom.mjGEOM_PLANE): "plane",
    int(mujoco.mjtGeom.mjGEOM_HFIELD): "hfield",
    int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
    int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
    int(mujoco.mjtGeom.mjGEOM_ELLIPSOID): "ellipsoid",
    int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder",
    int(mujoco.mjtGeom.mjGEOM_BOX): "box",
    int(mujoco.mjtGeom.mjGEOM_MESH): "mesh",
}


@dataclass(frozen=True)
class GeomShape:
    """One geom: ``geom_id`` (index into ``geom_poses``' arrays), the name of its body,
    its ``kind``, MuJoCo's ``size`` (3,) and, for a mesh, its vertices (V, 3) in the geom
    frame (MuJoCo re-centres meshes on compile) and faces (F, 3); else None."""

    geom_id: int
    body_name: str
    kind: GeomKind
    size: np.ndarray
    mesh_verts: np.ndarray | None = None
    mesh_faces: np.ndarray | None = None


def _mesh(model: mujoco.MjModel, g: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    mid = int(model.geom_dataid[g])
    if mid < 0:
        return None, None
    va, vn = int(model.mesh_vertadr[mid]), int(model.mesh_vertnum[mid])
    fa, fn = int(model.mesh_faceadr[mid]), int(model.mesh_facenum[mid])
    return np.array(model.mesh_vert[va : va + vn], dtype=np.float64), np.array(model.mesh_face[fa : fa + fn], dtype=np.int64)


class SceneKinematics:
    """A compiled MJCF file: its geoms and their world poses for a ``qpos``.

    Raises ``ValueError`` when the MJCF does not compile. ``geom_poses`` is thread-safe.
    """

    def __init__(self, xml_path: Path) -> None:
        try:
            self.model = mujoco.MjModel.from_xml_path(str(xml_path))
        except ValueError as e:
            raise ValueError(f"{xml_path}: MJCF does not compile: {e}") from e
        self.data = mujoco.MjData(self.model)
        self._lock = threading.Lock()
        m = self.model
        shapes = []
        for g in range(m.ngeom):
            kind = _KINDS.get(int(m.geom_type[g]), "other")
            verts, faces = _mesh(m, g) if kind == "mesh" else (None, None)
            body_name = m.body(int(m.geom_bodyid[g])).name
            shapes.append(GeomShape(g, body_name, kind, np.array(m.geom_size[g], dtype=np.float64), verts, faces))
        self.geoms: tuple[GeomShape, ...] = tuple(shapes)

    @property
    def nq(self) -> int:
        return int(self.model.nq)

    def geom_poses(self, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World positions (ngeom, 3) and rotation matrices (ngeom, 3, 3) of every geom at
        ``qpos`` (nq,)."""
        with self._lock:
            self.data.qpos[:] = qpos
            mujoco.mj_kinematics(self.model, self.data)
            xpos = np.array(self.data.geom_xpos)
            xmat = np.array(self.data.geom_xmat).reshape(-1, 3, 3)
        return xpos, xmat
