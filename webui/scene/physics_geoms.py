"""Physics humanoids' collision geoms per frame, from ``physics/scene.xml`` + ``physics/result.npz``.

MuJoCo is imported lazily, in the viewer process only (``webui.launcher`` and the server
never import this module). The MJCF is compiled once; for a frame, ``qpos`` is set and
``mj_kinematics`` gives every geom's world pose; each person's geoms are merged into one
mesh whose faces never change, so the viewer only streams new vertices per frame.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.schema.results import PhysicsResult
from webui.scene.meshes import box_mesh, capsule_mesh, cylinder_mesh, ellipsoid_mesh, merge_meshes

log = logging.getLogger(__name__)

# mjtGeom values (stable MuJoCo ABI): plane 0, hfield 1, sphere 2, capsule 3, ellipsoid 4, cylinder 5, box 6, mesh 7.
_SPHERE, _CAPSULE, _ELLIPSOID, _CYLINDER, _BOX, _MESH = 2, 3, 4, 5, 6, 7


def _mesh_template(model: Any, g: int) -> tuple[np.ndarray, np.ndarray] | None:
    """A mesh geom's vertices (in the geom frame: MuJoCo re-centres meshes on compile) and faces."""
    mid = int(model.geom_dataid[g])
    if mid < 0:
        return None
    va, vn = int(model.mesh_vertadr[mid]), int(model.mesh_vertnum[mid])
    fa, fn = int(model.mesh_faceadr[mid]), int(model.mesh_facenum[mid])
    return np.array(model.mesh_vert[va : va + vn], dtype=np.float64), np.array(model.mesh_face[fa : fa + fn], dtype=np.int64)


def _geom_template(gtype: int, size: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    if gtype == _SPHERE:
        return capsule_mesh(float(size[0]), 0.0)
    if gtype == _CAPSULE:
        return capsule_mesh(float(size[0]), float(size[1]))
    if gtype == _ELLIPSOID:
        return ellipsoid_mesh(size)
    if gtype == _CYLINDER:
        return cylinder_mesh(float(size[0]), float(size[1]))
    if gtype == _BOX:
        return box_mesh(size)
    return None  # planes (the floor) and height fields are not part of a humanoid; meshes: _mesh_template


class PhysicsGeoms:
    """Per-person merged geom meshes of the physics result.

    ``person_mesh(person_id, row)`` -> (verts (V, 3) float32 world, faces (F, 3)) or None.
    Raises ``ValueError`` when the MJCF does not compile or its ``nq`` does not match ``qpos``.
    """

    def __init__(self, xml_path: Path, result: PhysicsResult) -> None:
        import mujoco  # heavy: only in the viewer process, only when a physics result exists

        self._mj = mujoco
        try:
            self.model = mujoco.MjModel.from_xml_path(str(xml_path))
        except ValueError as e:
            raise ValueError(f"{xml_path}: MJCF does not compile: {e}") from e
        if self.model.nq != result.qpos.shape[1]:
            raise ValueError(f"{xml_path}: model nq={self.model.nq} but physics/result.npz qpos has {result.qpos.shape[1]}")
        self.data = mujoco.MjData(self.model)
        self.result = result
        self._lock = threading.Lock()
        self._geoms: dict[int, list[tuple[int, np.ndarray]]] = {}  # pid -> [(geom id, local verts)]
        self.faces: dict[int, np.ndarray] = {}
        m = self.model
        for pid in result.person_ids.tolist():
            pre = f"p{int(pid)}_"
            parts, ids = [], []
            for g in range(m.ngeom):
                body_name = m.body(int(m.geom_bodyid[g])).name
                if not body_name.startswith(pre):
                    continue
                gtype = int(m.geom_type[g])
                tpl = _mesh_template(m, g) if gtype == _MESH else _geom_template(gtype, np.asarray(m.geom_size[g]))
                if tpl is None:
                    continue
                parts.append(tpl)
                ids.append(g)
            if not parts:
                log.warning("%s: no geoms for person %d (no bodies named %s*)", xml_path, pid, pre)
                continue
            _, faces = merge_meshes(parts)
            self._geoms[int(pid)] = [(g, p[0]) for g, p in zip(ids, parts, strict=True)]
            self.faces[int(pid)] = faces

    @property
    def person_ids(self) -> list[int]:
        return sorted(self._geoms)

    def person_mesh(self, person_id: int, row: int) -> tuple[np.ndarray, np.ndarray] | None:
        geoms = self._geoms.get(int(person_id))
        if geoms is None or not 0 <= row < self.result.qpos.shape[0]:
            return None
        with self._lock:
            self.data.qpos[:] = self.result.qpos[row]
            self._mj.mj_kinematics(self.model, self.data)
            xpos = np.array(self.data.geom_xpos)
            xmat = np.array(self.data.geom_xmat).reshape(-1, 3, 3)
        verts = np.concatenate([v @ xmat[g].T + xpos[g] for g, v in geoms])
        return verts.astype(np.float32), self.faces[int(person_id)]


def load_physics_geoms(xml_path: Path | None, result: PhysicsResult | None) -> Any:
    """``PhysicsGeoms`` or None (no physics result, or the MJCF cannot be used: logged)."""
    if xml_path is None or result is None:
        return None
    try:
        return PhysicsGeoms(xml_path, result)
    except (ValueError, ImportError) as e:
        log.warning("physics geoms unavailable (%s): showing physics keypoints only", e)
        return None
