"""Physics humanoids' collision geoms per frame, from ``physics/scene.xml`` + ``physics/result.npz``.

MuJoCo runs behind ``pipeline.backends.mujoco.geoms`` (imported lazily, in the viewer
process only: ``webui.launcher`` and the server never import this module). The MJCF is
compiled once; for a frame, the backend gives every geom's world pose at that ``qpos``;
each person's geoms are merged into one mesh whose faces never change, so the viewer only
streams new vertices per frame.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pipeline.schema.results import PhysicsResult
from webui.scene.meshes import box_mesh, capsule_mesh, cylinder_mesh, ellipsoid_mesh, merge_meshes

if TYPE_CHECKING:
    from pipeline.backends.mujoco.geoms import GeomShape

log = logging.getLogger(__name__)


def _geom_template(geom: GeomShape) -> tuple[np.ndarray, np.ndarray] | None:
    """A geom's vertices in its own frame and faces; None for what is not drawn."""
    size = geom.size
    if geom.kind == "sphere":
        return capsule_mesh(float(size[0]), 0.0)
    if geom.kind == "capsule":
        return capsule_mesh(float(size[0]), float(size[1]))
    if geom.kind == "ellipsoid":
        return ellipsoid_mesh(size)
    if geom.kind == "cylinder":
        return cylinder_mesh(float(size[0]), float(size[1]))
    if geom.kind == "box":
        return box_mesh(size)
    if geom.kind == "mesh" and geom.mesh_verts is not None and geom.mesh_faces is not None:
        return geom.mesh_verts, geom.mesh_faces
    return None  # planes (the floor) and height fields are not part of a humanoid


class PhysicsGeoms:
    """Per-person merged geom meshes of the physics result.

    ``person_mesh(person_id, row)`` -> (verts (V, 3) float32 world, faces (F, 3)), or None
    when the person has no geoms or was not seen in that frame (``PhysicsResult.observed``).
    Raises ``ValueError`` when the MJCF does not compile or its ``nq`` does not match ``qpos``.
    """

    def __init__(self, xml_path: Path, result: PhysicsResult) -> None:
        # heavy (mujoco): only in the viewer process, only when a physics result exists
        from pipeline.backends.mujoco.geoms import SceneKinematics

        self.scene = SceneKinematics(xml_path)
        if self.scene.nq != result.qpos.shape[1]:
            raise ValueError(f"{xml_path}: model nq={self.scene.nq} but physics/result.npz qpos has {result.qpos.shape[1]}")
        self.result = result
        self._observed = result.observed_mask()
        self._column = {int(p): i for i, p in enumerate(result.person_ids.tolist())}
        self._geoms: dict[int, list[tuple[int, np.ndarray]]] = {}  # pid -> [(geom id, local verts)]
        self.faces: dict[int, np.ndarray] = {}
        for pid in result.person_ids.tolist():
            pre = f"p{int(pid)}_"
            parts, ids = [], []
            for geom in self.scene.geoms:
                if not geom.body_name.startswith(pre):
                    continue
                tpl = _geom_template(geom)
                if tpl is None:
                    continue
                parts.append(tpl)
                ids.append(geom.geom_id)
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
        if not self._observed[row, self._column[int(person_id)]]:
            return None  # simulated but not seen in this frame: not the athlete's motion
        xpos, xmat = self.scene.geom_poses(self.result.qpos[row])
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
